"""`cfddem compare`: report files and the summary numbers from two synthetic runs."""

import json
import subprocess
import sys

import numpy as np
import pytest

from cfddem.io.results import ResultsFile
from cfddem.measure.chute import ChuteMeasurements


def fake_run(folder, speed, gas, wall, rpm=16.0, compile_time=None):
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
        if compile_time is not None:
            res.write_metadata(time_compile=compile_time)
        if gas:  # the gas's budget as GasBudget writes it (terms in N; a few of them)
            terms = {"drag": 1.5e-3, "gravity": 1.8e-2, "pressure_z-": -2.0e-2, "flux_z-": 1.2e-3, "shear_y-": -2.0e-4}
            gb = dict(terms, storage=5e-4, residual=-3e-15, residual_relative=1.5e-13, particle_drag=-1.5e-3,
                      n_steps=np.int64(313), t_first=0.2, t_last=0.3)
            gb.update({f"{k}_err": 1e-5 for k in terms})
            res.write_measurements("gas_budget", gb, {"axis": "z", "n_blocks": 10, "terms": ",".join(terms),
                                                      "side_names": "y-=floor,z-=inlet"})
        if gas:  # as Simulation stores CoupledGas.run_stats()
            res.write_metadata(gas_steps=2188, gas_cg_iterations_mean=6.61, gas_cg_iterations_max=7,
                               gas_pressure_residual_max=2.37e-7, gas_mass_defect_max=2.88e-9, gas_cfl_max=0.475)
    return folder


def compare_summary(a, b, out):
    """``cfddem compare A B --out OUT`` (it must succeed); its summary.json."""
    p = subprocess.run([sys.executable, "-m", "cfddem.cli", "compare", str(a), str(b), "--out", str(out)],
                       capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    return json.loads((out / "summary.json").read_text())


def test_compare_report_and_summary(tmp_path):
    a = fake_run(tmp_path / "nogas", 2.0, False, 100.0)
    b = fake_run(tmp_path / "gas", 1.9, True, 120.0)
    out = tmp_path / "cmp"
    s = compare_summary(a, b, out)
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
    assert ("- axes right-handed, x across, y up from the floor, z down the chute; positive rpm = counter-clockwise "
            "seen from above; left/right seen in the direction of flow (the x = 0 wall is the right wall)") in md
    assert s["gas_solver_a"] is None and s["gas_solver_b"]["gas_steps"] == 2188
    assert ("gas solver (with gas): 2188 gas steps, pressure CG iterations mean 6.61 (max 7), mass-balance "
            "defect at most 2.88e-09, Courant number at most 0.475") in md
    assert "gas solver (no gas)" not in md
    h = (out / "report.html").read_text()
    assert h.count("data:image/png;base64,") == 6
    # the gas's budget table (run B only), sizes in mN and against the largest term (20 mN)
    assert "## Momentum budget of the gas (with gas)" in md
    assert "| reaction to the drag on the particles | 1.5 ± 0.01 | +7.5 % |" in md
    assert "| pressure on inlet (z-) | -20 ± 0.01 | -100 % |" in md
    assert "| shear on floor (y-) | -0.2 ± 0.01 | -1 % |" in md
    assert "| storage dP/dt | 0.5 | +2.5 % |" in md
    assert "closes to 1.5e-13 of the largest term" in md
    assert s["gas_budget_b"]["shear_y-"] == pytest.approx(-2e-4) and "gas_budget_a" not in s
    assert s["gas_budget_residual_relative_b"] == pytest.approx(1.5e-13)


def test_compare_leaves_numba_compilation_out_of_the_cost_ratio(tmp_path):
    """The first run on a fresh machine compiles the kernels: the ratio compares the wall times
    without it, and the report says how much it was."""
    a = fake_run(tmp_path / "nogas", 2.0, False, 100.0)  # written before compilation was timed
    b = fake_run(tmp_path / "gas", 1.9, True, 180.0, compile_time=60.0)
    out = tmp_path / "cmp"
    s = compare_summary(a, b, out)
    assert s["wall_time_ratio"] == pytest.approx(1.2)
    assert s["compile_time_a"] == 0.0 and s["compile_time_b"] == 60.0
    assert "compilation of the kernels: 0.0 s in A, 60.0 s in B" in (out / "report.md").read_text()


def test_compare_refuses_runs_without_measurements(tmp_path):
    d = tmp_path / "empty"
    d.mkdir()
    with ResultsFile(d / "results.h5") as res:
        res.write_config("", {})
    p = subprocess.run([sys.executable, "-m", "cfddem.cli", "compare", str(d), str(d)], capture_output=True,
                       text=True)
    assert p.returncode == 2 and "no time-averaged chute measurements" in p.stderr


def fake_silo_run(folder, rate, gas, wall, clogged=False):
    """A silo run folder whose discharge is linear at `rate` kg/s from the gate opening at 0.2 s
    until 4 g are out."""
    folder.mkdir(parents=True)
    t = np.arange(0.2, 1.2001, 0.01)
    m = np.minimum(rate * (t - 0.2), 0.004)
    fx, fy = np.linspace(0.001, 0.023, 12), np.linspace(0.0, 0.03, 16)
    vy = -0.1 * np.ones((16, 12))
    with ResultsFile(folder / "results.h5") as res:
        res.write_config("", {"gas": {"enabled": gas}, "frame": {"rpm": 0.0}, "exit": {"z": None}})
        res.append_series(time=0.0, n_particles=10)
        res.write_measurements(None, {
            "mass_flow_rate": rate, "bulk_density": 1400.0 + (5.0 if gas else 0.0),
            "clogged": np.int64(1 if clogged else 0),
            "silo": {"discharge_time": t, "discharge_mass": m, "gate_open_time": 0.2,
                     "fit_window": np.array([0.2 + 0.2 * 0.004 / rate, 0.2 + 0.8 * 0.004 / rate, 0.0008, 0.0032]),
                     "fit_residual_rel": 0.01, "field": {"x": fx, "y": fy, "vy": vy, "vx": 0 * vy}}})
        res.write_metadata(wall_time=wall, time_particles=0.8 * wall, time_gas=0.15 * wall if gas else 0.0)
        if gas:
            res.write_metadata(gas_steps=5000, gas_cg_iterations_mean=5.0, gas_cg_iterations_max=7,
                               gas_pressure_residual_max=1e-8, gas_mass_defect_max=2e-10, gas_cfl_max=0.07)
    return folder


def test_compare_silo_report_from_its_measurements(tmp_path):
    """Runs holding a silo discharge get the silo report: flow rates, their difference, bulk
    density, clogging, wall times, the gas solver; a chute run is not compared with a silo run."""
    a = fake_silo_run(tmp_path / "nogas", 0.0068, False, 40.0)
    b = fake_silo_run(tmp_path / "gas", 0.0065, True, 70.0, clogged=True)
    out = tmp_path / "cmp"
    p = subprocess.run([sys.executable, "-m", "cfddem.cli", "compare", str(a), str(b), "--out", str(out)],
                       capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert "silo mass flow rate 6.8 g/s (no gas), 6.5 g/s (with gas) (-4.41 %)" in p.stdout
    s = json.loads((out / "summary.json").read_text())
    assert s["kind"] == "silo"
    assert s["relative_difference_flow"] == pytest.approx(0.0065 / 0.0068 - 1.0)
    assert s["bulk_density_a"] == 1400.0 and s["bulk_density_b"] == 1405.0
    assert s["clogged_a"] is False and s["clogged_b"] is True
    assert s["discharged_mass_b"] == pytest.approx(0.004)
    assert s["wall_time_ratio"] == pytest.approx(70.0 / 40.0)
    assert s["gas_solver_a"] is None and s["gas_solver_b"]["gas_steps"] == 5000
    for f in ("discharge.png", "velocity_field.png", "cost.png"):
        assert (out / f).stat().st_size > 5000, f
    md = (out / "report.md").read_text()
    assert "A not clogged, B clogged" in md and "gas solver (with gas): 5000 gas steps" in md
    c = fake_run(tmp_path / "chute", 2.0, False, 100.0)
    p = subprocess.run([sys.executable, "-m", "cfddem.cli", "compare", str(c), str(b), "--out", str(tmp_path / "x")],
                       capture_output=True, text=True)
    assert p.returncode == 2 and "cannot compare a chute run" in p.stderr


def test_compare_reads_a_run_written_before_the_sides_with_todays_names(tmp_path):
    """A run folder from before the side names (x = 0 side called "left", no ``sides``
    attribute) is read with the x = 0 side as the right, and compares with a run written now."""
    import h5py

    from cfddem.measure.chute import _renamed
    from cfddem.report.compare import Run, compare_runs

    old = fake_run(tmp_path / "old", 2.0, False, 100.0)
    new = Run(fake_run(tmp_path / "new", 2.0, False, 100.0))
    with h5py.File(old / "results.h5", "a") as f:  # rename as the old writer named them (the swap is its own inverse)
        g = f["measurements/chute"]
        moves = {k: _renamed(k, ("profile_", "slice_")) for k in g}
        for k in moves:
            g.move(k, "tmp_" + k)
        for k, b in moves.items():
            g.move("tmp_" + k, b)
        del g.attrs["sides"]
        g.attrs["sensor_names"] = "left,centre,right"
    with h5py.File(old / "results.h5", "r") as f:
        assert f["measurements/chute/slice_left"][0] == 0.0  # the x = 0 slice, by its old name
    r = Run(old)
    for k in ("slice_right", "slice_left_half", "profile_right_phi", "profile_left_half_vz"):
        np.testing.assert_array_equal(r.chute[k], new.chute[k])
    np.testing.assert_array_equal(r.chute["slice_right"], [0.0, 0.025])
    s = compare_runs(old, tmp_path / "new", tmp_path / "cmp")
    assert s["relative_difference_end"] == pytest.approx(0.0, abs=1e-12)
