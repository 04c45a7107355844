"""End-to-end runs through the CLI and the Python API: outputs, bad folders, checkpoints,
resume (bit-identical), signals (SIGTERM, SIGKILL), blow-up diagnostics."""

import json
import os
import signal
import subprocess
import sys
import time

import h5py
import numpy as np
import pytest

from cfddem.config import load_case
from cfddem.io.results import list_snapshots, read_measurements, read_series, read_snapshot
from cfddem.simulation import Simulation

from ..conftest import CASES

CLI = [sys.executable, "-m", "cfddem.cli"]

# a small closed box with a few dozen particles on a lattice, falling and colliding
BOX = """
[time]
end_time = {end}
dt = 2e-5
[output]
series_interval = 0.002
snapshot_interval = 0.01
vtk = {vtk}
plots = false
progress_interval = 0.2
[checkpoint]
interval = {ck}
wall_interval = 0.0
[geometry]
type = "box"
lo = [0, 0, 0]
hi = [0.03, 0.06, 0.03]
[contact.particle_particle]
e_n = 0.9
[contact.particle_wall]
e_n = 0.9
[particles]
initial_file = "init.csv"
[measurements]
enabled = false
"""


def box_case(tmp_path, end=0.06, ck=0.0, vtk="false", n_side=4, name="box"):
    d = tmp_path / name
    d.mkdir()
    (d / "case.toml").write_text(BOX.format(end=end, ck=ck, vtk=vtk))
    rng = np.random.default_rng(1)
    rows = ["x,y,z,vx,vy,vz,radius"]
    for i in range(n_side):
        for j in range(2 * n_side):
            for k in range(n_side):
                x, y, z = 0.004 + 0.0065 * i, 0.004 + 0.0065 * j, 0.004 + 0.0065 * k
                v = rng.uniform(-0.2, 0.2, 3)
                rows.append(f"{x},{y},{z},{v[0]},{v[1]},{v[2]},{0.0015 + 0.0003 * rng.random()}")
    (d / "init.csv").write_text("\n".join(rows) + "\n")
    return d


def test_chute_run_writes_every_output(tmp_path):
    out = tmp_path / "run"
    p = subprocess.run(CLI + ["run", str(CASES / "chute_16rpm"), "--out", str(out), "--end-time", "0.03",
                              "--set", "measurements.start_time=0.01", "--set", "output.vtk_interval=0.01",
                              "--set", "output.snapshot_interval=0.01"],
                       capture_output=True, text=True, timeout=900)
    assert p.returncode == 0, p.stderr[-2000:]
    s = read_series(out / "results.h5")
    for k in ("time", "n_particles", "mass_in", "mass_out", "kinetic_energy", "max_overlap_ratio"):
        assert k in s
    assert s["time"][-1] == pytest.approx(0.03)
    assert s["n_particles"][-1] > 1000  # the sluice has fed layers
    # the feed follows the mass rate (1.6 kg/s) to within one lattice layer
    assert s["mass_in"][-1] == pytest.approx(1.6 * 0.03, abs=0.012)
    assert np.all(np.diff(s["mass_in"]) >= 0)
    snaps = list_snapshots(out / "results.h5")
    assert len(snaps) == 4  # t = 0, 0.01, 0.02, 0.03
    last = read_snapshot(out / "results.h5", -1)
    assert last["pos"].shape == (int(s["n_particles"][-1]), 3)
    assert len(set(last["ids"].tolist())) == len(last["ids"])
    m = read_measurements(out / "results.h5")
    assert m["chute"]["n_samples"] >= 2
    assert m["chute"]["bed_height_sensor"].shape[0] == 3
    pvd = (out / "vtk" / "particles.pvd").read_text()
    assert pvd.count("<DataSet") == 4
    assert len(list((out / "vtk" / "particles").glob("*.vtu"))) == 4
    assert (out / "vtk" / "walls.vtu").exists()
    for png in ("bed_height.png", "surface_velocity.png", "mean_velocity.png", "series.png"):
        assert (out / "report" / png).stat().st_size > 5000
    assert "done" in (out / "run.log").read_text()
    assert (out / "case.resolved.toml").exists()
    assert json.loads((out / "run.json").read_text())["status"] == "done"
    # an existing run folder is refused without --overwrite (one line, exit 2)
    p2 = subprocess.run(CLI + ["run", str(CASES / "chute_16rpm"), "--out", str(out), "--end-time", "0.01",
                               "--set", "measurements.start_time=0"], capture_output=True, text=True)
    assert p2.returncode == 2 and "--overwrite" in p2.stderr and len(p2.stderr.strip().splitlines()) == 1


def test_overwrite_never_deletes_foreign_files(tmp_path):
    d = box_case(tmp_path)
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("precious")
    p = subprocess.run(CLI + ["run", str(d), "--out", str(out), "--overwrite"], capture_output=True, text=True)
    assert p.returncode == 2 and "refusing to delete" in p.stderr
    assert (out / "notes.txt").read_text() == "precious"


def _final_state(out):
    snap = read_snapshot(out / "results.h5", -1)
    return snap


def test_resume_is_bit_identical(tmp_path):
    d = box_case(tmp_path, end=0.06, ck=0.02)
    ref = Simulation(load_case(d), tmp_path / "ref", echo=False, progress=False).run()
    assert ref.status == "done"
    # the same run stopped at step 1500 (t = 0.03, after the checkpoint of t = 0.02) ...
    part = Simulation(load_case(d, overrides=["time.max_steps=1500"]), tmp_path / "part", echo=False,
                      progress=False).run()
    assert part.status == "stopped" and part.steps == 1500
    # ... and resumed from its newest checkpoint
    t0 = time.perf_counter()
    res = Simulation(load_case(d), tmp_path / "part", resume=True, echo=False, progress=False).run()
    seg = time.perf_counter() - t0
    assert res.status == "done" and res.steps == ref.steps
    # the wall time adds the run's time before its checkpoint to the resumed part, like the
    # cost categories do: it is at least their sum and more than the resumed part alone
    other = sum(v for k, v in res.timings.items() if k != "total")
    assert res.wall_time == res.timings["total"] >= other > 0
    assert res.wall_time > seg - 1e-3 and res.wall_time > 0.0
    a, b = _final_state(tmp_path / "ref"), _final_state(tmp_path / "part")
    for k in ("pos", "vel", "omega", "ids"):
        assert np.array_equal(a[k], b[k]), k
    sa, sb = read_series(tmp_path / "ref" / "results.h5"), read_series(tmp_path / "part" / "results.h5")
    assert np.array_equal(sa["time"], sb["time"])
    assert np.array_equal(sa["kinetic_energy"], sb["kinetic_energy"])


def _wait_for(pred, timeout):
    t0 = time.time()
    while time.time() - t0 < timeout:
        if pred():
            return True
        time.sleep(0.2)
    return False


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signal_writes_checkpoint_and_exits_cleanly(tmp_path, sig):
    d = box_case(tmp_path, end=50.0)
    out = tmp_path / "run"
    proc = subprocess.Popen(CLI + ["run", str(d), "--out", str(out), "--quiet"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        assert _wait_for(lambda: len(list((out / "results_snapshots").glob("*.h5"))) >= 3, 300)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 128 + int(sig), err
    assert json.loads((out / "run.json").read_text())["status"] == "interrupted"
    assert len(list((out / "checkpoints").glob("ckpt_*.h5"))) >= 1
    s = read_series(out / "results.h5")
    assert len(s["time"]) >= 3


def test_sigkill_leaves_readable_results_and_resumes(tmp_path):
    d = box_case(tmp_path, end=1.0, ck=0.01)
    out = tmp_path / "run"
    proc = subprocess.Popen(CLI + ["run", str(d), "--out", str(out), "--quiet"], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        assert _wait_for(lambda: len(list((out / "checkpoints").glob("ckpt_*.h5"))) >= 1
                         and len(list((out / "results_snapshots").glob("*.h5"))) >= 3, 300)
        time.sleep(0.37)  # an arbitrary moment
        assert proc.poll() is None, "the run ended before it could be killed"
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        proc.kill()
    # readable, with every record flushed before the kill
    s = read_series(out / "results.h5")
    assert len(s["time"]) >= 3 and np.all(np.diff(s["time"]) > 0)
    for k, t, step in list_snapshots(out / "results.h5"):
        assert read_snapshot(out / "results.h5", k)["pos"].shape[1] == 3
    with h5py.File(out / "results.h5", "r") as h:
        assert "config" in h
    p = subprocess.run(CLI + ["run", str(d), "--out", str(out), "--resume", "--quiet"], capture_output=True,
                       text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    s2 = read_series(out / "results.h5")
    assert s2["time"][-1] == pytest.approx(1.0)
    assert np.all(np.diff(s2["time"]) > 0)  # no duplicated rows after the resume
    # and no missing ones: the rows up to the checkpoint were on disk before it was written
    np.testing.assert_allclose(np.diff(s2["time"]), 0.002, rtol=1e-6)


def test_blow_up_is_diagnosed(tmp_path):
    d = box_case(tmp_path, end=0.05)
    out = tmp_path / "run"
    # a time step far above t_c/5: refused ...
    p = subprocess.run(CLI + ["run", str(d), "--out", str(out), "--set", "time.dt=5e-4"], capture_output=True,
                       text=True)
    assert p.returncode == 2 and "time.dt" in p.stderr and "t_c" in p.stderr
    # ... and, forced, it blows up with a message naming the cause; what was written stays
    p = subprocess.run(CLI + ["run", str(d), "--out", str(out), "--set", "time.dt=5e-4", "--force",
                              "--set", "contact.particle_particle.k_n=1e5", "--quiet"],
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 3, p.stderr
    assert "time step" in p.stderr or "overlap" in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1
    assert json.loads((out / "run.json").read_text())["status"] == "failed"
    m = read_measurements(out / "results.h5")
    assert "diagnostic" in m and m["diagnostic"]["pos"].shape[1] == 3


# a 5 cm box without gravity for a few particles given one by one, a forced large time step
FREE_BOX = """
[time]
end_time = {end}
dt = 2e-4
force = true
[output]
vtk = false
plots = false
[geometry]
type = "box"
lo = [0, 0, 0]
hi = [0.05, 0.05, 0.05]
[gravity]
g = 0.0
[particles]
{particles}
[measurements]
enabled = false
{extra}"""


def free_box_case(d, particles, end, extra=""):
    d.mkdir()
    (d / "case.toml").write_text(FREE_BOX.format(end=end, particles=particles, extra=extra))
    return d


def test_particle_through_a_wall_is_diagnosed(tmp_path):
    d = free_box_case(tmp_path / "tunnel", "max_overlap_ratio = 1.0\n"
                      "initial = [{pos = [0.025, 0.005, 0.025], radius = 0.0015, vel = [0, -20.0, 0]}]", 0.01)
    p = subprocess.run(CLI + ["run", str(d), "--out", str(tmp_path / "o"), "--quiet"], capture_output=True,
                       text=True, timeout=300)
    assert p.returncode == 3, p.stderr
    assert "went through wall 'y-'" in p.stderr and "time step too large" in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1


def test_repeated_lost_particle_warning_is_rate_limited(tmp_path):
    """12 particles leave the box one by one (one lost-particle warning per exit/lost check,
    every 1 ms): run.log shows the 1st and the 10th and, at the end, the total."""
    # outside the x+ wall, each crossing the lost margin (x = 0.055 m) 1.5 ms after the one before
    parts = ", ".join(f"{{pos = [0.052, {0.005 + 0.01 * (k % 4):.3f}, {0.01 + 0.015 * (k // 4):.3f}], "
                      f"radius = 0.0015, vel = [{2.0 / (k + 1):.6f}, 0, 0]}}" for k in range(12))
    d = free_box_case(tmp_path / "leak", f"initial = [{parts}]", 0.02, extra="[exit]\nlost_margin = 0.005\n")
    s = Simulation(load_case(d), tmp_path / "o", echo=False, progress=False).run()
    assert s.status == "done" and s.n_particles == 0
    lines = [ln for ln in (tmp_path / "o" / "run.log").read_text().splitlines() if "left the domain" in ln]
    assert len(lines) == 3, lines
    assert "WARNING" in lines[0] and ": 1 particle(s) left the domain and were removed as lost" in lines[0]
    assert "WARNING" in lines[1] and "[10th time; repeats are counted" in lines[1]
    assert "INFO" in lines[2] and "warning repeated 12 times in this run (2 logged), the last: t = 0.0" in lines[2]


def test_checkpoint_every_steps(tmp_path):
    d = box_case(tmp_path, end=0.01)
    out = tmp_path / "run"
    s = Simulation(load_case(d, overrides=["checkpoint.every_steps=200", "checkpoint.keep=10"]), out, echo=False,
                   progress=False).run()
    assert s.status == "done" and s.steps == 500
    names = sorted(p.name for p in (out / "checkpoints").glob("ckpt_*.h5"))
    assert names == ["ckpt_000000000200.h5", "ckpt_000000000400.h5"]


def test_numba_compilation_inside_the_loop_is_timed(tmp_path):
    """A kernel compiled for the first time inside the time loop (here one called from a step
    hook) is counted in ``timings["compile"]`` (inside the other parts and the total); the
    compare report's wall-time ratio leaves it out."""
    import numba

    d = box_case(tmp_path, end=0.01)
    sim = Simulation(load_case(d), tmp_path / "run", echo=False, progress=False)
    sim.build()

    @numba.njit(cache=False)
    def fresh(x):  # a new function object: compiled at its first call, never from a cache
        s = 0.0
        for i in range(x.shape[0]):
            s += np.sin(x[i]) * np.cos(x[i]) + np.sqrt(abs(x[i]))
        return s

    calls = []
    sim.system.step_hook = lambda s: calls.append(fresh(s.pos[:, 0]))
    res = sim.run()
    assert res.status == "done" and len(calls) == res.steps
    c = res.timings["compile"]
    assert 0.02 < c < res.wall_time
    with h5py.File(tmp_path / "run" / "results.h5", "r") as h:
        assert h["metadata"].attrs["time_compile"] == pytest.approx(c)
    # a second run of the same process compiles nothing new
    sim2 = Simulation(load_case(d), tmp_path / "run2", echo=False, progress=False)
    sim2.build()
    sim2.system.step_hook = lambda s: calls.append(fresh(s.pos[:, 0]))
    assert sim2.run().timings["compile"] < 0.01
