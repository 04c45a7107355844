"""cases/silo_hopper_stl (the hopper silo's container read from STL files) discharges at the
rate of cases/silo_hopper (analytic walls) within the seed-to-seed scatter (issue #18)."""

import math

import numpy as np
import pytest

from cfddem.config import load_case
from cfddem.io.results import read_measurements
from cfddem.simulation import Simulation

from ..conftest import CASES

#: the reduced hopper silo of the seed study (docs/silo.md "cases/silo_hopper_stl, measured"):
#: 8,000 particles (the fill just above the hopper top), gate from 0.3 s, one thread
REDUCED = ["silo.n_particles=8000", "silo.gate_time=0.3", "time.threads=1", "output.vtk=false",
           "output.plots=false", "output.snapshot_interval=10.0"]
SEEDS = (1, 2, 3)


def flow_rate(name: str, seed: int, out) -> float:
    case = load_case(CASES / name, overrides=REDUCED + [f"particles.seed={seed}"])
    summary = Simulation(case, out, echo=False, progress=False).run()
    assert summary.status == "done" and "silo empty" in summary.message, summary.message
    m = read_measurements(out / "results.h5")
    assert int(m["clogged"]) == 0
    return float(m["mass_flow_rate"])


@pytest.mark.slow
def test_stl_hopper_discharges_at_the_analytic_rate(tmp_path):
    """Three seeds (particles.seed 1, 2, 3: the fill lattice's jitter) of each, 8,000 particles.
    Each run is about 38,000 steps (gate at 0.3 s, empty at 0.68-0.69 s; a few minutes on one
    thread).  Measured (docs/silo.md): analytic 0.7121, 0.7101, 0.7133 kg/s (mean 0.7119,
    s = 0.0016); STL 0.7021, 0.7125, 0.7206 kg/s (mean 0.7118, s = 0.0093); difference
    -0.0001 kg/s, combined scatter
    sqrt(s_a^2 + s_STL^2) = 0.0094 kg/s.  Asserted: |mean_STL - mean_analytic| <= that combined
    scatter (s the sample standard deviation over the seeds), and every run empties the silo
    without clogging."""
    rates = {name: np.array([flow_rate(name, s, tmp_path / f"{name}_{s}") for s in SEEDS])
             for name in ("silo_hopper", "silo_hopper_stl")}
    a, m = rates["silo_hopper"], rates["silo_hopper_stl"]
    scatter = math.sqrt(a.std(ddof=1) ** 2 + m.std(ddof=1) ** 2)
    assert abs(m.mean() - a.mean()) <= scatter, (a, m)
    assert 0.6 < a.mean() < 0.85  # the hopper's rate (0.735 kg/s at 12,000 particles, docs/silo.md)
