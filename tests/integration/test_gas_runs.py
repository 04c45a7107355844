"""Gas through the same CLI and case format: a gas-only chute and a short coupled chute."""

import re
import subprocess
import sys

import numpy as np
import pytest

from cfddem.io.results import list_snapshots, read_metadata, read_series, read_snapshot

from ..conftest import CASES

CLI = [sys.executable, "-m", "cfddem.cli"]


def test_gas_only_chute_writes_gas_fields(tmp_path):
    out = tmp_path / "gas"
    p = subprocess.run(CLI + ["run", str(CASES / "gas_chute_16rpm"), "--out", str(out), "--quiet",
                              "--set", "gas.cells=[8, 6, 40]", "--set", "time.end_time=0.02",
                              "--set", "output.snapshot_interval=0.01", "--set", "output.vtk_interval=0.01"],
                       capture_output=True, text=True, timeout=900)
    assert p.returncode == 0, p.stderr[-3000:]
    s = read_series(out / "results.h5")
    assert s["time"][-1] == pytest.approx(0.02)
    assert np.all(s["n_particles"] == 0)
    assert np.all(np.isfinite(s["gas_cfl"])) and np.max(s["gas_max_divergence"]) < 1e-8
    snaps = list_snapshots(out / "results.h5")
    assert len(snaps) == 3
    last = read_snapshot(out / "results.h5", -1)
    u = last["gas_velocity"]
    assert u.shape == (8, 6, 40, 3)
    assert np.all(last["gas_porosity"] == 1.0)
    # continuity: the co-flow entering at 0.4 m/s leaves through the outlet (the cross-wind's
    # flux through the lid, omega sin(theta) (x - x_axis), sums to zero across the width), so
    # every cross-section carries the inlet's flow rate
    for k in (5, 20, 35):
        assert u[:, :, k, 2].mean() == pytest.approx(0.4, rel=0.02)
    pvd = (out / "vtk" / "gas.pvd").read_text()
    assert pvd.count("<DataSet") == 3
    assert len(list((out / "vtk" / "gas").glob("*.vtu"))) == 3
    # the pressure solve's iterations and residuals: per sampled step in the series, over the
    # whole run in the log (every one of the 200 gas steps)
    # (the solve stops at the relative residual 1e-8 or once the true residual guarantees a
    # mass-balance defect below 1e-10, whichever comes first: here the latter, at relative
    # residuals of about 1e-4 to 1e-3)
    assert np.all(np.isfinite(s["gas_pressure_residual"])) and np.all(s["gas_pressure_residual"][1:] > 0)
    log = (out / "run.log").read_text()
    m = re.search(r"gas: (\d+) steps; pressure solve \(mg\): CG iterations mean ([\d.]+), max (\d+); "
                  r"relative residual at most ([\d.e+-]+) \(stops at 1e-08 or once the defect is sure to be below "
                  r"1e-10\); mass-balance defect at most ([\d.e+-]+); Courant number at most ([\d.e+-]+)", log)
    assert m, log[-2000:]
    assert int(m[1]) == 200
    assert 1.0 <= float(m[2]) <= int(m[3]) and int(m[3]) >= np.max(s["gas_pressure_iterations"])
    assert float(m[4]) >= np.max(s["gas_pressure_residual"]) * (1 - 1e-2)
    assert np.max(s["gas_max_divergence"]) * (1 - 1e-2) <= float(m[5]) < 1e-8
    assert float(m[6]) >= np.max(s["gas_cfl"]) * (1 - 1e-2)
    meta = read_metadata(out / "results.h5")  # the same numbers, for the comparison report
    assert int(meta["gas_steps"]) == 200 and int(meta["gas_cg_iterations_max"]) == int(m[3])
    assert f"{float(meta['gas_mass_defect_max']):.2e}" == m[5]
    # a gas-only case: no particle or contact numbers, no warning about particles it does not have
    assert "particles: none" in log
    assert "particle-wall" not in log and "noisy porosity" not in log and "relaxation time" not in log


def test_gas_step_too_large_is_diagnosed(tmp_path):
    out = tmp_path / "cfl"
    p = subprocess.run(CLI + ["run", str(CASES / "gas_chute_16rpm"), "--out", str(out), "--quiet",
                              "--set", "gas.cells=[8, 6, 40]", "--set", "time.dt=0.1", "--set", "time.end_time=1.0"],
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 3, p.stderr[-2000:]
    err = p.stderr.strip().splitlines()
    assert len(err) == 1 and "gas CFL number" in err[0] and "gas.coupling_interval" in err[0]
    assert read_series(out / "results.h5")["time"][0] == 0.0  # what was written before stays
