"""`cfddem compare`: report files and the summary numbers from two synthetic runs."""

import json
import subprocess
import sys

import numpy as np
import pytest

from cfddem.io.results import ResultsFile
from cfddem.measure.chute import ChuteMeasurements


def fake_run(folder, speed, gas, wall, rpm=16.0):
    """A run folder whose particles move at `speed` m/s along z everywhere."""
    folder.mkdir(parents=True)
    rng = np.random.default_rng(0)
    n = 4000
    pos = np.c_[rng.uniform(0.002, 0.078, n), rng.uniform(0.0015, 0.012, n), rng.uniform(-0.1, 0.8, n)]
    vel = np.zeros((n, 3))
    vel[:, 2] = speed
    vel[:, 0] = 0.1 * speed
    rad = np.full(n, 0.0015)
    m = ChuteMeasurements(width=0.08, z_range=(-0.1, 0.8), start_time=0.0)
    for t in (0.0, 0.01):
        m.measure(t, pos, vel, rad)
    with ResultsFile(folder / "results.h5") as res:
        res.write_config("", {"gas": {"enabled": gas}, "frame": {"rpm": rpm}, "exit": {"z": 0.8}})
        res.append_series(time=0.0, n_particles=n)
        res.write_measurements(m.group, m.results(), m.attrs())
        if gas:
            vg = np.zeros((16, 15, 150, 3))
            vg[..., 2] = 0.5
            res.write_measurements("gas", {"mean_velocity": vg, "x": np.linspace(0.0025, 0.0775, 16),
                                           "z": np.linspace(-0.097, 0.797, 150)})
        res.write_metadata(wall_time=wall, time_particles=0.8 * wall, time_gas=0.15 * wall if gas else 0.0,
                           time_output=0.05 * wall)
        if gas:  # as Simulation stores CoupledGas.run_stats()
            res.write_metadata(gas_steps=2188, gas_cg_iterations_mean=6.61, gas_cg_iterations_max=7,
                               gas_pressure_residual_max=2.37e-7, gas_mass_defect_max=2.88e-9, gas_cfl_max=0.475)
    return folder


def test_compare_report_and_summary(tmp_path):
    a = fake_run(tmp_path / "nogas", 2.0, False, 100.0)
    b = fake_run(tmp_path / "gas", 1.9, True, 120.0)
    out = tmp_path / "cmp"
    p = subprocess.run([sys.executable, "-m", "cfddem.cli", "compare", str(a), str(b), "--out", str(out)],
                       capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["velocity_end_a"] == pytest.approx(2.0)
    assert s["velocity_end_b"] == pytest.approx(1.9)
    assert s["relative_difference_end"] == pytest.approx(-0.05)
    assert s["wall_time_a"] == 100.0 and s["wall_time_b"] == 120.0
    assert s["wall_time_ratio"] == pytest.approx(1.2)
    for f in ("velocity_along_chute.png", "bed_height.png", "surface_velocity.png", "depth_profiles.png",
              "top_view.png", "cost.png"):
        assert (out / f).stat().st_size > 5000, f
    md = (out / "report.md").read_text()
    assert "-5.00 %" in md
    assert s["gas_solver_a"] is None and s["gas_solver_b"]["gas_steps"] == 2188
    assert ("gas solver (with gas): 2188 gas steps, pressure CG iterations mean 6.61 (max 7), mass-balance "
            "defect at most 2.88e-09, Courant number at most 0.475") in md
    assert "gas solver (no gas)" not in md
    h = (out / "report.html").read_text()
    assert h.count("data:image/png;base64,") == 6


def test_compare_refuses_runs_without_measurements(tmp_path):
    d = tmp_path / "empty"
    d.mkdir()
    with ResultsFile(d / "results.h5") as res:
        res.write_config("", {})
    p = subprocess.run([sys.executable, "-m", "cfddem.cli", "compare", str(d), str(d)], capture_output=True,
                       text=True)
    assert p.returncode == 2 and "no time-averaged chute measurements" in p.stderr
