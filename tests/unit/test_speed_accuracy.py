"""Speed-against-accuracy post-processing of a sweep folder."""

import csv
import json
import subprocess
import sys

import pytest

from .test_compare import fake_run


def test_deviations_and_chart(tmp_path):
    sweep = tmp_path / "sweep"
    sweep.mkdir()
    # dt 1e-5 is the reference (speed 2.0); 2e-5 deviates by 1 %; 4e-5 by 5 %; 8e-5 blew up
    fake_run(sweep / "time.dt=1e-05", 2.0, False, 400.0)
    fake_run(sweep / "time.dt=2e-05", 2.02, False, 200.0)
    fake_run(sweep / "time.dt=4e-05", 2.10, False, 100.0)
    with (sweep / "summary.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["name", "time.dt", "status", "wall_time", "error"])
        w.writerow(["time.dt=1e-05", "1e-05", "done", "400", ""])
        w.writerow(["time.dt=2e-05", "2e-05", "done", "200", ""])
        w.writerow(["time.dt=4e-05", "4e-05", "done", "100", ""])
        w.writerow(["time.dt=8e-05", "8e-05", "failed", "5", "overlap"])
    p = subprocess.run([sys.executable, "-m", "cfddem.cli", "accuracy", str(sweep)], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    res = json.loads((sweep / "speed_accuracy.json").read_text())
    assert res["reference"] == "time.dt=1e-05"
    rows = {r["name"]: r for r in res["rows"]}
    assert rows["time.dt=1e-05"]["surface_velocity_rel_rms"] == pytest.approx(0.0)
    assert rows["time.dt=2e-05"]["surface_velocity_rel_rms"] == pytest.approx(0.01, rel=1e-6)
    assert rows["time.dt=4e-05"]["surface_velocity_rel_rms"] == pytest.approx(0.05, rel=1e-6)
    assert rows["time.dt=2e-05"]["within_bands"] is True
    assert rows["time.dt=4e-05"]["within_bands"] is False
    assert rows["time.dt=8e-05"]["status"] == "failed"
    assert (sweep / "speed_accuracy.png").stat().st_size > 10000
