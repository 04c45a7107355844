"""Gas through the same CLI and case format: a gas-only chute and a short coupled chute."""

import subprocess
import sys

import numpy as np
import pytest

from cfddem.io.results import list_snapshots, read_series, read_snapshot

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


def test_gas_step_too_large_is_diagnosed(tmp_path):
    out = tmp_path / "cfl"
    p = subprocess.run(CLI + ["run", str(CASES / "gas_chute_16rpm"), "--out", str(out), "--quiet",
                              "--set", "gas.cells=[8, 6, 40]", "--set", "time.dt=0.1", "--set", "time.end_time=1.0"],
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 3, p.stderr[-2000:]
    err = p.stderr.strip().splitlines()
    assert len(err) == 1 and "gas CFL number" in err[0] and "gas.coupling_interval" in err[0]
    assert read_series(out / "results.h5")["time"][0] == 0.0  # what was written before stays
