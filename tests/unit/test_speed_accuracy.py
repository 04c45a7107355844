"""Speed-against-accuracy post-processing of a sweep folder."""

import csv
import json
import subprocess
import sys

import numpy as np
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
    # mean streamwise velocity over the last 0.1 m, and its difference from the reference's
    assert rows["time.dt=4e-05"]["velocity_end"] == pytest.approx(2.10)
    assert rows["time.dt=4e-05"]["velocity_end_rel"] == pytest.approx(0.05)
    assert rows["time.dt=4e-05"]["within_bands"] is False
    assert rows["time.dt=8e-05"]["status"] == "failed"
    assert (sweep / "speed_accuracy.png").stat().st_size > 10000


def _gas_field(cells, lengths, fn):
    x, y, z = [(np.arange(n) + 0.5) * L / n for n, L in zip(cells, lengths)]
    X, Y, Z = np.meshgrid(x, y, z, indexing="ij")
    mv = np.zeros(tuple(cells) + (3,))
    mv[..., 2] = fn(X, Y, Z)
    return {"mean_velocity": mv, "x": x, "y": y, "z": z}


def test_gas_deviation_same_grid_and_across_grids():
    from cfddem.report.speed_accuracy import gas_deviation

    L = (0.08, 0.045, 0.9)
    ref = _gas_field((16, 15, 150), L, lambda x, y, z: 1.0 + 0.0 * x)
    run = _gas_field((16, 15, 150), L, lambda x, y, z: 1.01 + 0.0 * x)
    assert gas_deviation(ref, run) == pytest.approx(0.01, rel=1e-12)
    assert gas_deviation(ref, ref) == 0.0
    # a linear field on a coarser grid is interpolated exactly between the coarse centres and
    # clamped to the nearest centre outside them
    fn = lambda x, y, z: 2.0 + 5.0 * x - 4.0 * y + 3.0 * z  # noqa: E731
    ref = _gas_field((16, 15, 150), L, fn)
    run = _gas_field((8, 5, 75), L, fn)
    cx, cy, cz = [np.clip(ref[k], run[k][0], run[k][-1]) for k in "xyz"]
    X, Y, Z = np.meshgrid(cx, cy, cz, indexing="ij")
    wr = ref["mean_velocity"][..., 2]
    expected = np.sqrt(np.mean((fn(X, Y, Z) - wr) ** 2)) / np.sqrt(np.mean(wr**2))
    assert expected > 1e-3
    assert gas_deviation(ref, run) == pytest.approx(expected, rel=1e-10)
    # one cell across an axis (a pseudo-2-D grid): its only value is used
    run1 = _gas_field((1, 15, 150), L, lambda x, y, z: 1.0 + 0.0 * x)
    ref1 = _gas_field((16, 15, 150), L, lambda x, y, z: 1.0 + 0.0 * x)
    assert gas_deviation(ref1, run1) == pytest.approx(0.0, abs=1e-14)
