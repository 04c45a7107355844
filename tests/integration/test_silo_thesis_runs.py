"""The chapter-5 silo studies end to end on tiny silos: the periodic depth runs (no front/back
walls, particles wrap round z), and ``python -m cfddem.silo_thesis`` writes its table, CSV and
charts with finite numbers (a 150-particle silo, two variants, ~10 s)."""

import csv
import math
import os
import subprocess
import sys

import h5py
import numpy as np
import pytest

from cfddem.config import load_case
from cfddem.simulation import Simulation

TINY = ["--set", "silo.width=0.04", "--set", "silo.depth=0.012", "--set", "silo.outlet_width=0.014",
        "--set", "silo.n_particles=150", "--set", "time.end_time=0.35", "--set", "silo.gate_time=0.15",
        "--set", "silo.profile_heights=[0.005,0.01]", "--set", "silo.profile_window=[0.05,0.15]",
        "--set", "output.plots=false"]


def test_periodic_depth_runs_without_front_back_walls_and_wraps(root, tmp_path, one_numba_thread):
    case = load_case(root / "cases" / "silo_thesis_small",
                     overrides=["silo.depth_boundary='periodic'", "silo.width=0.04", "silo.depth=0.012",
                                "silo.outlet_width=0.014", "silo.n_particles=150"])
    sim = Simulation(case, tmp_path / "out", echo=False, progress=False)
    sim.build()
    names = {w.name for w in sim.walls}
    assert "front" not in names and "back" not in names and {"left", "right", "gate"} <= names
    sim.scene.start()
    sys_ = sim.system
    assert sys_.n == 150
    sys_.vel[:, 2] = 0.5  # everyone moves through the depth: 10 mm in 0.02 s, most cross z = depth
    z0 = dict(zip(sys_.ids.tolist(), sys_.pos[:, 2].tolist()))
    sys_.step(1000)  # 0.018 s: 9 mm through the 12 mm depth
    assert sys_.n == 150 and sorted(sys_.ids.tolist()) == sorted(z0)
    z = dict(zip(sys_.ids.tolist(), sys_.pos[:, 2].tolist()))
    assert all(0.0 <= v < 0.012 for v in z.values())
    shift = 0.5 * sys_.time
    crossing = [i for i in z0 if z0[i] + shift > 0.012 + 0.002]  # past z = depth by more than a radius
    assert len(crossing) > 50
    # they came back in at z = 0: now below where they started, at about z0 + shift - depth
    assert all(z[i] < z0[i] for i in crossing)
    err = np.array([z[i] - (z0[i] + shift - 0.012) for i in crossing])
    assert np.median(np.abs(err)) < 0.001

def test_study_command_writes_table_csv_and_charts(root, tmp_path):
    out = tmp_path / "fb"
    env = dict(os.environ, PYTHONPATH=str(root), MPLBACKEND="Agg")
    p = subprocess.run([sys.executable, "-m", "cfddem.silo_thesis", "front-back", "--values", "0.3",
                        "--out", str(out), "--workers", "1", *TINY], capture_output=True, text=True, env=env,
                       cwd=root, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:]
    for name in ("front-back.csv", "front-back.md", "front-back.png", "front-back_profiles.png",
                 "front-back_walls.png"):
        assert (out / name).is_file() and (out / name).stat().st_size > 300, name
    rows = list(csv.DictReader(open(out / "front-back.csv")))
    assert [r["label"] for r in rows] == ["front/back mu 0.3", "periodic depth"]
    for r in rows:
        assert r["status"] == "done"
        assert math.isfinite(float(r["flow_rate"])) and float(r["flow_rate"]) > 0
        assert math.isfinite(float(r["B_5"])) and 0.0 < float(r["B_5"]) < 20.0  # mm
        assert math.isfinite(float(r["channel_5"])) and 0.0 < float(r["channel_5"]) <= 40.0
        assert r["flow_pattern"] in ("mass", "semi-mass", "internal")
        assert float(r["wall_time"]) > 0
        shares = [float(r[k]) for k in ("share_front_back", "share_sides", "share_floor")]
        assert abs(sum(shares) - 100.0) < 10.0 and shares[2] > 60.0  # per cent of the weight (a bed still settling)
    assert float(rows[1]["share_front_back"]) == 0.0  # the periodic depth has no front/back walls
    md = (out / "front-back.md").read_text()
    assert "| front/back mu 0.3 |" in md and "| periodic depth |" in md and "B at 5 mm (mm)" in md


def test_end_of_fill_stress_against_janssen_and_hydrostatic(root, tmp_path, one_numba_thread):
    """silo.stress_profile: at the gate opening the scene stores the coarse-grained vertical
    pressure with the hydrostatic line rho_b g (H - y) and Janssen's curve, which lies below it
    (walls with friction carry weight) and meets it at the top."""
    ov = [a for a in TINY if a != "--set"] + ["time.end_time=0.16", "silo.stress_profile=true"]
    sim = Simulation(load_case(root / "cases" / "silo_thesis_small", overrides=ov), tmp_path / "out",
                     echo=False, progress=False)
    assert sim.run().status == "done" and sim.scene.gate_open
    st = sim.scene.stress
    y, H, g = st["y"], st["H"], sim.case.gravity.g
    inside = (y >= 0.0) & (y < H)
    assert inside.sum() >= 3 and 0.005 < H < 0.05
    np.testing.assert_allclose(st["hydrostatic"][inside], st["rho_b"] * g * (H - y[inside]), rtol=1e-12)
    assert np.all(st["janssen"][inside] <= st["hydrostatic"][inside] * (1 + 1e-12))
    assert np.all(st["janssen"][inside] > 0.0) and st["z_c"] > 0.0
    band = inside & (y > 0.1 * H) & (y < 0.5 * H)
    ratio = st["pressure"][band] / st["hydrostatic"][band]
    assert band.any() and np.all((ratio > 0.3) & (ratio < 1.3))  # a 150-particle bed: the weight, roughly


def test_end_of_fill_wall_load_adds_up_to_the_weight(root, tmp_path, one_numba_thread):
    """At the gate opening the scene stores how the walls carry the bed's weight: the force of
    the particles on each wall along gravity over the weight; for a bed at rest the shares add
    up to 1 and the floor (bottom plates, lips, gate) carries most of it (in this 150-particle
    silo the walls with friction take or add a few per cent)."""
    ov = [a for a in TINY if a != "--set"] + ["time.end_time=0.3", "silo.gate_time=0.28"]
    sim = Simulation(load_case(root / "cases" / "silo_thesis_small", overrides=ov), tmp_path / "out",
                     echo=False, progress=False)
    assert sim.run().status == "done" and sim.scene.gate_open
    wl = sim.scene.wall_load
    share = dict(zip(wl["labels"], wl["share"]))
    assert wl["weight"] == pytest.approx(float(np.sum(sim.system.mass)) * 9.81, rel=1e-12)
    assert abs(sum(share.values()) - 1.0) < 0.02  # at rest: the walls carry the weight
    floor = sum(v for k, v in share.items() if k.startswith(("bottom", "lip")) or k == "gate")
    assert 0.8 < floor < 1.1 and share["gate"] > 0.05
    assert abs(share["front"] + share["back"]) < 0.3  # 2-3 % either way in this thin silo
    with h5py.File(tmp_path / "out" / "results.h5", "r") as f:
        g = f["measurements/silo/fill_wall_load"]
        assert [x.decode() for x in g["labels"][()]] == list(wl["labels"])
        np.testing.assert_allclose(g["share"][()], wl["share"], rtol=1e-12)


def _tiny_drop_case(root, *extra):
    ov = [a for a in TINY if a != "--set"] + ["time.end_time=0.4", "silo.gate='settled'",
                                              "silo.floor_drop_wait=0.05", *extra]
    return load_case(root / "cases" / "silo_thesis_small", overrides=ov)


def test_floor_drop_lowers_the_floor_and_mobilises_the_front_back_friction(root, tmp_path, one_numba_thread):
    """silo.floor_drop: once the fill has settled the floor (bottom plates, lips, gate) moves down
    by exactly the drop at the set speed, the gate opens a wait later, and the front and back
    walls, which pulled the tiny bed down by a few per cent before, now hold it up."""
    runs = {}
    for drop in (0.0, 0.0005):
        sim = Simulation(_tiny_drop_case(root, f"silo.floor_drop={drop}"), tmp_path / f"d{drop}", echo=False,
                         progress=False)
        assert sim.run().status == "done" and sim.scene.gate_open
        runs[drop] = sim
    ref, sim = runs[0.0], runs[0.0005]
    sc, dt = sim.scene, sim.dt
    assert ref.scene.drop_phase == 0 and sc.drop_phase == 2
    assert sc.drop_done - sc.drop_start == pytest.approx(0.0005 / 0.005, abs=1.01 * dt)  # 0.1 s at 5 mm/s
    assert sc.gate_open_time >= sc.drop_done + 0.05 - dt
    for w in ("bottom_left", "bottom_right", "lip_left", "lip_right", "gate"):
        moved = ref.system.wall_position(w) - sim.system.wall_position(w)
        np.testing.assert_allclose(moved, [0.0, 0.0005, 0.0], atol=1e-15)
    for w in ("front", "back", "left", "right"):
        np.testing.assert_array_equal(ref.system.wall_position(w), sim.system.wall_position(w))
    fb = {}
    for drop, s in runs.items():
        share = dict(zip(s.scene.wall_load["labels"], s.scene.wall_load["share"]))
        assert abs(sum(share.values()) - 1.0) < 0.02
        fb[drop] = share["front"] + share["back"]
    assert fb[0.0] < 0.0 < fb[0.0005] and fb[0.0005] - fb[0.0] > 0.03
    # the wall stresses against height add up to the walls' loads, and no bin carries more than mu
    for s in runs.values():
        wl, g = s.scene.wall_load, s.scene.g
        prof, lab = wl["profile"], list(wl["labels"])
        dy = np.diff(prof["y"])[0]
        k = (prof["y"] - g.d) / (2 * g.d)  # bins aligned with the floor y = 0
        assert dy == pytest.approx(2 * g.d, rel=1e-12) and np.allclose(k, np.round(k), atol=1e-9)
        assert prof["y"][0] < 0.0 < prof["y"][1]  # the slot's particles (above the gate) have a bin
        for key, names, width, mu in (("front_back", ("front", "back"), g.W, 0.2), ("sides", ("left", "right"), g.L,
                                                                                   0.17)):
            load = sum(wl["load"][lab.index(w)] for w in names)
            assert np.nansum(prof[f"tau_{key}"]) * 2 * width * dy == pytest.approx(load, rel=1e-9, abs=1e-12)
            sig = prof[f"sigma_{key}"]
            on = sig > 1e-3 * np.nanmax(sig)
            assert on.sum() >= 2 and np.all(np.abs(prof[f"tau_{key}"][on]) <= 1.05 * mu * sig[on])
    with h5py.File(tmp_path / "d0.0005" / "results.h5", "r") as f:
        g = f["measurements/silo/floor_drop"]
        assert float(g["depth"][()]) == 0.0005 and float(g["end_time"][()]) == sc.drop_done
        pr = f["measurements/silo/fill_wall_load/profile"]
        np.testing.assert_array_equal(pr["tau_front_back"][()], sc.wall_load["profile"]["tau_front_back"])
    with h5py.File(tmp_path / "d0.0" / "results.h5", "r") as f:
        assert "floor_drop" not in f["measurements/silo"]


def test_floor_drop_resumes_mid_drop_bit_identically(root, tmp_path, one_numba_thread):
    """A run stopped while the floor moves (t = 0.23 s, the drop runs 0.18-0.28 s) and resumed
    ends in the same state as the run that went through."""
    extra = ("silo.floor_drop=0.0005", "checkpoint.interval=0.1")
    ref = Simulation(_tiny_drop_case(root, *extra), tmp_path / "ref", echo=False, progress=False)
    assert ref.run().status == "done"
    part = Simulation(_tiny_drop_case(root, *extra, "time.max_steps=12800"), tmp_path / "part", echo=False,
                      progress=False)
    assert part.run().status == "stopped" and part.scene.drop_phase == 1
    res = Simulation(_tiny_drop_case(root, *extra), tmp_path / "part", resume=True, echo=False, progress=False)
    assert res.run().status == "done"
    assert res.scene.drop_done == ref.scene.drop_done and res.scene.gate_open_time == ref.scene.gate_open_time
    np.testing.assert_array_equal(res.system.wall_position("gate"), ref.system.wall_position("gate"))
    ia, ib = np.argsort(ref.system.ids), np.argsort(res.system.ids)
    np.testing.assert_array_equal(ref.system.pos[ia], res.system.pos[ib])
    np.testing.assert_array_equal(ref.scene.wall_load["share"], res.scene.wall_load["share"])
    # stopped after the gate opened (0.34 s): the walls' shares and profile at the opening survive
    late = Simulation(_tiny_drop_case(root, *extra, "time.max_steps=20000"), tmp_path / "late", echo=False,
                      progress=False)
    assert late.run().status == "stopped" and late.scene.gate_open
    res = Simulation(_tiny_drop_case(root, *extra), tmp_path / "late", resume=True, echo=False, progress=False)
    assert res.run().status == "done"
    assert list(res.scene.wall_load["labels"]) == list(ref.scene.wall_load["labels"])
    np.testing.assert_array_equal(res.scene.wall_load["share"], ref.scene.wall_load["share"])
    with h5py.File(tmp_path / "late" / "results.h5", "r") as f, h5py.File(tmp_path / "ref" / "results.h5", "r") as g:
        a, b = f["measurements/silo/fill_wall_load"], g["measurements/silo/fill_wall_load"]
        np.testing.assert_array_equal(a["share"][()], b["share"][()])
        np.testing.assert_array_equal(a["profile/tau_front_back"][()], b["profile/tau_front_back"][()])


@pytest.mark.parametrize("sets, says", [
    (["silo.floor_drop=0.001"], "needs silo.gate = 'settled'"),
    (["silo.floor_drop=0.002", "silo.gate='settled'"], "more than half a particle diameter"),
])
def test_floor_drop_refuses_what_it_cannot_do(root, sets, says):
    from cfddem.errors import CaseError

    with pytest.raises(CaseError, match="silo.floor_drop") as e:
        load_case(root / "cases" / "silo_thesis_small", overrides=sets)
    assert says in str(e.value)


def test_floor_drop_study_command_tabulates_the_depths(root, tmp_path):
    """``python -m cfddem.silo_thesis floor-drop`` on the tiny bed: one run per depth with the
    settled gate, a table with the depth the scene stored, the front/back walls carrying more of
    the weight after the drop, and the mobilised-friction chart."""
    out = tmp_path / "drop"
    env = dict(os.environ, PYTHONPATH=str(root), MPLBACKEND="Agg")
    sets = ["time.end_time=0.4" if a == "time.end_time=0.35" else a for a in TINY]
    p = subprocess.run([sys.executable, "-m", "cfddem.silo_thesis", "floor-drop", "--values", "0,0.0005",
                        "--out", str(out), "--workers", "1", *sets, "--set", "silo.floor_drop_wait=0.05"],
                       capture_output=True, text=True, env=env, cwd=root, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:]
    for name in ("floor-drop.csv", "floor-drop.md", "floor-drop.png", "floor-drop_mobilised.png"):
        assert (out / name).is_file() and (out / name).stat().st_size > 300, name
    rows = list(csv.DictReader(open(out / "floor-drop.csv")))
    assert [r["label"] for r in rows] == ["floor drop 0 mm", "floor drop 0.5 mm"]
    assert [float(r["floor_drop"]) for r in rows] == [0.0, 0.5]
    assert all(r["status"] == "done" for r in rows)
    fb = [float(r["share_front_back"]) for r in rows]
    assert fb[0] < 0.0 < fb[1] and fb[1] - fb[0] > 3.0  # per cent of the weight (as the scene test finds)
    assert float(rows[1]["mobilised_front_back"]) > float(rows[0]["mobilised_front_back"])
    assert "hydrostatic_low" in rows[0]  # (the tiny bed is too low for the 0.1-0.2 H stress band)


def test_study_with_replicas_tabulates_each_fill_and_their_mean(root, tmp_path):
    """``--replicas 2`` on the tiny bed: two fills of the variant (seeds 6 and 7, the case's and
    the next: other jitters of the lattice, so other numbers), every run in _runs.csv, the main
    CSV their mean and standard deviation, the Markdown table mean ± s.d."""
    out = tmp_path / "rep"
    env = dict(os.environ, PYTHONPATH=str(root), MPLBACKEND="Agg")
    p = subprocess.run([sys.executable, "-m", "cfddem.silo_thesis", "front-back", "--values", "0.3", "--no-periodic",
                        "--replicas", "2", "--out", str(out), "--workers", "1", *TINY],
                       capture_output=True, text=True, env=env, cwd=root, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:]
    each = list(csv.DictReader(open(out / "front-back_runs.csv")))
    assert [r["seed"] for r in each] == ["6", "7"] and all(r["status"] == "done" for r in each)
    f = np.array([float(r["flow_rate"]) for r in each])
    assert np.all(f > 0) and f[0] != f[1]  # independent fills
    row, = csv.DictReader(open(out / "front-back.csv"))
    assert float(row["flow_rate"]) == pytest.approx(f.mean(), rel=1e-12)
    assert float(row["flow_rate_sd"]) == pytest.approx(f.std(ddof=1), rel=1e-9)
    assert row["status"] == "2 of 2 done" and row["replicas"] == "2"
    md = (out / "front-back.md").read_text()
    assert " ± " in md and "2 fills a variant (particles.seed 6-7)" in md
    assert (out / "front-back.png").stat().st_size > 1000
    assert sorted(d.name for d in out.iterdir() if d.is_dir()) == ["silo.front_back.mu=0.3",
                                                                   "silo.front_back.mu=0.3__particles.seed=7"]


def test_floor_speed_study_drops_the_floor_at_each_speed(root, tmp_path):
    """``python -m cfddem.silo_thesis floor-speed`` on the tiny bed: each variant lowers the floor
    by --depth at its speed (the drop lasts depth / speed), and the CSV and the mobilised chart
    carry the speed."""
    out = tmp_path / "speed"
    env = dict(os.environ, PYTHONPATH=str(root), MPLBACKEND="Agg")
    p = subprocess.run([sys.executable, "-m", "cfddem.silo_thesis", "floor-speed", "--values", "0.005,0.02",
                        "--depth", "0.0005", "--out", str(out), "--workers", "1", *TINY,
                        "--set", "time.end_time=0.45", "--set", "silo.floor_drop_wait=0.05"],
                       capture_output=True, text=True, env=env, cwd=root, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:]
    rows = list(csv.DictReader(open(out / "floor-speed.csv")))
    assert [r["label"] for r in rows] == ["drop at 5 mm/s", "drop at 20 mm/s"]
    assert [float(r["floor_drop_speed"]) for r in rows] == pytest.approx([5.0, 20.0], rel=1e-12)
    assert all(float(r["floor_drop"]) == pytest.approx(0.5, rel=1e-12) and r["status"] == "done" for r in rows)
    for speed in (0.005, 0.02):
        run = out / f"silo.floor_drop=0.0005__silo.floor_drop_speed={speed}__silo.gate=settled"
        with h5py.File(run / "results.h5", "r") as f:
            g = f["measurements/silo/floor_drop"]
            lasted = float(g["end_time"][()]) - float(g["start_time"][()])
            assert float(g["speed"][()]) == speed
            assert lasted == pytest.approx(0.0005 / speed, abs=1.8e-5 * 1.01)  # to a time step
    assert (out / "floor-speed_mobilised.png").stat().st_size > 1000
