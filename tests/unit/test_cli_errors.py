"""Bad input at the command line and around the output folder: one line, exit code 2, no
traceback (issue: runs that survive)."""

import subprocess
import sys

import h5py
import numpy as np
import pytest

from cfddem.config import build_case, load_case
from cfddem.errors import CaseError
from cfddem.scenes.common import initial_particles
from cfddem.simulation import check_disk_space, prepare_out_dir

from ..conftest import CASES

CLI = [sys.executable, "-m", "cfddem.cli"]


def run_cli(*args):
    p = subprocess.run(CLI + list(args), capture_output=True, text=True, timeout=120)
    return p.returncode, p.stderr.strip().splitlines(), p.stdout


def one_line_error(args, words):
    code, err, _ = run_cli(*args)
    assert code == 2, err
    assert len(err) == 1, err
    assert "Traceback" not in err[0]
    assert words in err[0], err[0]


def test_missing_case(tmp_path):
    one_line_error(["check", str(tmp_path / "nope")], "no case file")


def test_resume_and_overwrite_contradict(tmp_path):
    one_line_error(["run", str(CASES / "chute_0rpm"), "--out", str(tmp_path / "o"), "--resume", "--overwrite"],
                   "--resume")


def test_resume_without_a_run(tmp_path):
    one_line_error(["run", str(CASES / "chute_0rpm"), "--out", str(tmp_path / "o"), "--resume"], "no cfddem run")


def test_bad_set_syntax(tmp_path):
    one_line_error(["check", str(CASES / "chute_0rpm"), "--set", "particles.diameter"], "KEY=VALUE")
    one_line_error(["check", str(CASES / "chute_0rpm"), "--set", "particles..diameter=1"], "dotted key")


def test_unknown_command_and_option():
    code, err, _ = run_cli("fly")
    assert code == 2 and len(err) == 1
    code, err, _ = run_cli("run", "x", "--speed", "9")
    assert code == 2 and len(err) == 1


def test_dt_refused_and_warned(tmp_path):
    one_line_error(["check", str(CASES / "chute_0rpm"), "--set", "time.dt=1.5e-4"], "above t_c/5")  # 0.36 t_c
    # 0.47 t_c: above the stable step of one contact (0.433 t_c, docs/stability.md): the failure predicted
    one_line_error(["check", str(CASES / "chute_0rpm"), "--set", "time.dt=2e-4"], "the run would fail (overlap)")
    code, err, out = run_cli("check", str(CASES / "chute_0rpm"), "--set", "time.dt=4e-5")
    assert code == 0 and "WARNING: above t_c/20" in out and any("t_c/20" in e for e in err)


def test_output_path_is_a_file(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    one_line_error(["run", str(CASES / "chute_0rpm"), "--out", str(f)], "not a folder")


def test_unwritable_folder_in_process(tmp_path, monkeypatch):
    # also for root: make the probe write fail
    def deny(self, *a, **k):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr("pathlib.Path.write_text", deny)
    with pytest.raises(CaseError) as e:
        prepare_out_dir(tmp_path / "x", overwrite=False)
    assert e.value.key == "--out" and "cannot write" in str(e.value)


def test_disk_space_checked_before_the_run(tmp_path, monkeypatch):
    case = load_case(CASES / "chute_16rpm")

    class Usage:
        free = 10 * 2**20

    monkeypatch.setattr("shutil.disk_usage", lambda p: Usage())
    with pytest.raises(CaseError) as e:
        check_disk_space(case, tmp_path)
    assert "MiB free" in str(e.value)


def test_initial_particles_from_hdf5_and_csv(tmp_path):
    pos = np.array([[0.01, 0.01, 0.01], [0.02, 0.01, 0.01]])
    with h5py.File(tmp_path / "p.h5", "w") as h:
        h["pos"] = pos
        h["radius"] = [0.001, 0.0015]
        h["vel"] = [[1.0, 0, 0], [0, 0, 0]]
    (tmp_path / "p.csv").write_text("x,y,z,radius,vz\n0.01,0.01,0.01,0.001,2.0\n")
    raw = {"geometry": {"type": "box", "hi": [0.05, 0.05, 0.05]}, "measurements": {"enabled": False}}
    c = build_case(dict(raw, particles={"initial_file": "p.h5"}), case_dir=tmp_path)
    d = initial_particles(c)
    assert np.array_equal(d["pos"], pos) and d["vel"][0, 0] == 1.0 and d["radius"][1] == 0.0015
    c = build_case(dict(raw, particles={"initial_file": "p.csv"}), case_dir=tmp_path)
    d = initial_particles(c)
    assert d["pos"].shape == (1, 3) and d["vel"][0, 2] == 2.0 and d["omega"][0, 0] == 0.0
    (tmp_path / "bad.csv").write_text("x,y,radius\n1,2,3\n")
    with pytest.raises(CaseError) as e:
        initial_particles(build_case(dict(raw, particles={"initial_file": "bad.csv"}), case_dir=tmp_path))
    assert "missing column 'z'" in str(e.value)
    (tmp_path / "neg.csv").write_text("x,y,z,radius\n0.01,0.01,0.01,-1\n")
    with pytest.raises(CaseError) as e:
        initial_particles(build_case(dict(raw, particles={"initial_file": "neg.csv"}), case_dir=tmp_path))
    assert "radius must be positive" in str(e.value)


@pytest.mark.parametrize("key,value,words", [
    ("gas.cells", "[16,8]", "array of 3 integers, got 2"),
    ("measurements.sensors_x", "[0.01,0.02]", "array of 3 numbers, got 2"),
    ("gas.cells", "[]", "array of 3 integers, got 0"),
    ("geometry.lo", "[0,0]", "array of 3 numbers"),
    ("measurements.stations", "[]", "got an empty array"),
])
def test_list_keys_checked_before_any_folder(tmp_path, key, value, words):
    """A list of the wrong length or shape: exit 2, one line naming the key, no run folder; the
    corrected run then starts in that folder."""
    out = tmp_path / "X"
    one_line_error(["run", str(CASES / "chute_16rpm"), "--set", f"{key}={value}", "--out", str(out)], key)
    code, err, _ = run_cli("run", str(CASES / "chute_16rpm"), "--set", f"{key}={value}", "--out", str(out))
    assert words in err[0] and not out.exists()


def test_case_refused_at_build_writes_nothing(tmp_path):
    """Problems found only when the run is built (overlapping initial particles) leave no folder."""
    out = tmp_path / "X"
    one_line_error(["run", str(CASES / "box_small"), "--out", str(out), "--set",
                    "particles.initial=[{pos=[0.01,0.01,0.01]},{pos=[0.01,0.01,0.0101]}]"], "overlap")
    assert not out.exists()
    code, err, _ = run_cli("run", str(CASES / "box_small"), "--out", str(out))
    assert code == 0 and (out / "results.h5").exists(), err
