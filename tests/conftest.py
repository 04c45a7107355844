import os
from pathlib import Path

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")

ROOT = Path(__file__).resolve().parents[1]
CASES = ROOT / "cases"


@pytest.fixture
def root():
    return ROOT


@pytest.fixture
def write_case(tmp_path):
    """Write a case.toml into a fresh folder and return the folder."""

    def _write(text: str, name: str = "case") -> Path:
        d = tmp_path / name
        d.mkdir(parents=True, exist_ok=True)
        (d / "case.toml").write_text(text)
        return d

    return _write


@pytest.fixture
def one_numba_thread():
    """Tiny grids: one numba thread avoids the thread start-up cost of every parallel kernel
    (30x faster on a loaded 2-core machine); thread independence is tested with the kernels."""
    import numba

    n = numba.get_num_threads()
    numba.set_num_threads(1)
    yield
    numba.set_num_threads(n)
