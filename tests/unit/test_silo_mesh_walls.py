"""The silo with its container from STL files (``silo.walls = "mesh"``, issue #18): the STL
written from the analytic walls gives the analytic contacts, the scene keeps only the gate and
still opens it, the case errors, the check line, and cases/silo_hopper_stl is cases/silo_hopper
with these files."""

import math
import subprocess
import sys

import numpy as np
import pytest

from cfddem.config import build_case, load_case
from cfddem.errors import CaseError
from cfddem.particles import ParticleSystem
from cfddem.particles.mesh import MeshWall
from cfddem.scenes.common import wall_specs
from cfddem.scenes.silo import (CONTAINER_GROUPS, WALL_GROUPS, SiloGeometry, container_meshes,
                                container_walls_toml, mesh_cover_line, write_container_stl)
from cfddem.simulation import Simulation, contact_law, engine_wall

from ..conftest import CASES

D = 0.0038
R = 0.5 * D
CASE = """
[time]
end_time = {end}
dt = 2e-5
threads = 1
[output]
series_interval = 0.01
snapshot_interval = 1.0
vtk = false
plots = false
[particles]
diameter = 0.0038
density = 950.0
[contact.particle_particle]
k_n = 1000.0
e_n = 0.8
mu = 0.3
mu_r = 0.02
[contact.particle_wall]
k_n = 1000.0
e_n = 0.8
e_t = 0.4
mu = 0.3
mu_r = 0.02
[geometry]
type = "silo"
[silo]
walls = "{walls}"
width = 0.06
depth = 0.03
outlet_width = 0.02
hopper_angle_deg = 60.0
height = 0.2
n_particles = {n}
gate = "time"
gate_time = 0.15
clog_time = 0.1
field_start = 0.0
"""
GROUPS = """
[silo.front_back]
mu = 0.1
mu_r = 0.005
[silo.sides]
mu = 0.45
e_n = 0.6
[silo.bottom]
mu = 0.25
"""


def silo_pair(write_case, tmp_path, n=30, end=0.1):
    """The same small hopper silo twice: analytic walls, and its container written to STL (mm)
    and read back as mesh walls with the groups' contact keys."""
    ana = write_case(CASE.format(walls="analytic", n=n, end=end) + GROUPS, name="analytic")
    a = load_case(ana)
    paths = write_container_stl(a, tmp_path / "mesh", units="mm")
    text = CASE.format(walls="mesh", n=n, end=end) + "\n" + container_walls_toml(a, paths, "mm")
    (tmp_path / "mesh" / "case.toml").write_text(text)
    return a, load_case(tmp_path / "mesh")


def one_step(case, pos, vel, omega):
    s = ParticleSystem(pp=contact_law(case.resolved["contact"]["particle_particle"]),
                       walls=[engine_wall(w) for w in wall_specs(case)], dt=1e-9)
    s.add_particles(pos, vel, R, 950.0, omega=omega)
    assert s.step(1).ok
    return s


def test_stl_container_gives_the_analytic_wall_contacts(write_case, tmp_path, one_numba_thread):
    a, m = silo_pair(write_case, tmp_path)
    specs = {w.name: w for w in wall_specs(m)}
    assert set(specs) == {"gate", *CONTAINER_GROUPS}
    assert specs["front_back"].kind == "mesh" and specs["gate"].kind == "rectangle"
    # each mesh wall has its group's contact parameters
    ana = {w.name: w for w in wall_specs(a)}
    for w in ana.values():
        if WALL_GROUPS[w.name] in specs:
            assert specs[WALL_GROUPS[w.name]].params == w.params
    g = SiloGeometry(a.resolved["silo"], D)
    ang = math.radians(60.0)
    n_h = np.array([math.sin(ang), math.cos(ang), 0.0])  # left hopper normal
    x_edge = g.xc - 0.5 * g.b
    foot = np.array([x_edge - 0.012 * math.cos(ang), 0.012 * math.sin(ang), 0.5 * g.L])
    pos = np.array([
        foot + 0.9 * R * n_h,                               # on the left hopper plane
        [g.W - 0.8 * R, g.y_h + 0.03, 0.011],               # against the right side wall
        [x_edge + 0.85 * R, -0.45 * g.lip, 0.009],          # against the left lip, in the slot
        [g.xc + 0.3 * g.b, -g.lip + 0.9 * R, 0.02],         # on the closed gate
        [0.02, g.y_h + 0.05, 0.7 * R],                      # against the front wall
        [0.93 * R, (0.9 * R - (0.93 * R - x_edge) * n_h[0]) / n_h[1], 0.015],  # side wall and hopper: corner
        [0.035, g.y_h + 0.05, g.L - 0.95 * R],              # against the back wall
    ])
    rng = np.random.default_rng(4)
    vel = rng.uniform(-0.3, 0.3, (len(pos), 3))
    om = rng.uniform(-20.0, 20.0, (len(pos), 3))
    sa, sm = one_step(a, pos, vel, om), one_step(m, pos, vel, om)
    ia, im = np.argsort(sa.ids), np.argsort(sm.ids)  # (the system may reorder its particles)
    assert sm.mesh_contacts()[im].tolist() == [1, 1, 1, 0, 1, 2, 1]
    f = np.linalg.norm(sa.force[ia], axis=1)
    assert np.all(f > 0.05)  # every particle is pressed by a wall (k_n 0.05..0.2 R = 0.1..0.4 N)
    np.testing.assert_allclose(sm.force[im], sa.force[ia], rtol=1e-9, atol=1e-9 * f.min())
    np.testing.assert_allclose(sm.torque[im], sa.torque[ia], rtol=1e-9, atol=1e-9 * f.min() * R)
    # the force on each mesh wall is the sum over its group's rectangles
    fa = dict(zip([w.name for w in wall_specs(a)], sa.wall_forces()))
    fm = dict(zip([mw.name for mw in sm.meshes], sm.mesh_forces()))
    for grp in CONTAINER_GROUPS:
        ref = sum(v for k, v in fa.items() if WALL_GROUPS[k] == grp)
        np.testing.assert_allclose(fm[grp], ref, rtol=1e-9, atol=1e-9 * f.min())
        assert np.linalg.norm(ref) > 1e-4
    np.testing.assert_allclose(sm.wall_forces()[0], fa["gate"], rtol=1e-12)


def test_slot_edge_is_one_contact_in_the_mesh(write_case, tmp_path, one_numba_thread):
    """The one place the STL container differs: over the slot edge the analytic hopper plane and
    lip give two equal edge contacts at the same point, the mesh (hopper and lip share the
    welded edge) one, with the same normal: half the force."""
    a, m = silo_pair(write_case, tmp_path)
    g = SiloGeometry(a.resolved["silo"], D)
    edge = np.array([g.xc - 0.5 * g.b, 0.0, 0.01])
    u = np.array([math.cos(0.4), math.sin(0.4), 0.0])  # between the hopper's and the lip's normals
    sa, sm = (one_step(c, [edge + 0.9 * R * u], [[0.0, 0.0, 0.0]], [[0.0, 0.0, 0.0]]) for c in (a, m))
    assert sm.mesh_contacts().tolist() == [1]
    # (the force is evaluated after a 1e-9 s step: the sphere has moved off at 1.3e-5 m/s
    # there, twice as fast with the analytic walls, so the dashpot terms differ by ~1e-6)
    np.testing.assert_allclose(sa.force, 2.0 * sm.force, rtol=1e-5)
    assert sm.force[0] @ u == pytest.approx(1000.0 * 0.1 * R, rel=1e-5)


def test_mesh_silo_runs_and_its_gate_opens(write_case, tmp_path, one_numba_thread):
    """The scene's fill, gate and removal work unchanged with the STL container: the fill rests
    on the hopper mesh and the gate, nothing leaves before the gate opens at 0.15 s, the
    particles run out after."""
    _, m = silo_pair(write_case, tmp_path, n=40, end=0.35)
    summary = Simulation(m, tmp_path / "o", echo=False, progress=False).run()
    assert summary.status == "done"
    from cfddem.io.results import read_series

    s = read_series(tmp_path / "o" / "results.h5")
    t = s["time"]
    shut = t < 0.15 - 1e-9
    assert np.all(s["discharged_count"][shut] == 0) and np.all(s["gate_open"][shut] == 0.0)
    assert s["gate_open"][-1] == 1.0 and s["discharged_count"][-1] >= 10
    np.testing.assert_array_equal(s["mass_lost"], 0.0)
    np.testing.assert_array_equal(s["n_particles"] + s["discharged_count"], 40)
    assert np.any(s["mesh_bottom_fy"][shut] < 0.0)  # the fill rests on the hopper mesh


def _base(**silo):
    raw = {"time": {"end_time": 0.1, "dt": 2e-5}, "particles": {"diameter": D, "density": 950.0},
           "geometry": {"type": "silo"},
           "silo": dict({"width": 0.05, "depth": 0.012, "outlet_width": 0.016, "n_particles": 50}, **silo)}
    return raw


def test_mesh_silo_case_errors(write_case, tmp_path):
    with pytest.raises(CaseError) as e:
        build_case(_base(walls="mesh"))
    assert e.value.key == "silo.walls" and "[[geometry.walls]]" in e.value.reason
    with pytest.raises(CaseError) as e:
        build_case(_base(walls="meshes"))
    assert e.value.key == "silo.walls"
    # the container's group keys belong to the mesh walls
    d = write_case(CASE.format(walls="analytic", n=10, end=0.1), name="a")
    paths = write_container_stl(load_case(d), d, units="m")
    text = CASE.format(walls="mesh", n=10, end=0.1) + "[silo.sides]\nmu = 0.4\n" + container_walls_toml(
        load_case(d), paths, "m")
    (d / "case.toml").write_text(text)
    with pytest.raises(CaseError) as e:
        load_case(d)
    assert e.value.key == "silo.sides.mu"
    # the outlet-width study would move the gate and the measurements but not the meshes' slot
    from cfddem.silo_study import run_beverloo_study

    with pytest.raises(CaseError) as e:
        run_beverloo_study(CASES / "silo_hopper_stl", [0.03, 0.04], tmp_path / "bev", echo=None)
    assert e.value.key == "silo.walls"
    # the command line: one line naming the key, no traceback
    d2 = write_case(CASE.format(walls="mesh", n=10, end=0.1), name="b")
    p = subprocess.run([sys.executable, "-m", "cfddem.cli", "check", str(d2)], capture_output=True, text=True,
                       timeout=120)
    assert p.returncode == 2
    assert len(p.stderr.strip().splitlines()) == 1 and "silo.walls" in p.stderr


def test_check_line_says_whether_the_meshes_cover_the_silo(write_case, tmp_path):
    a, m = silo_pair(write_case, tmp_path, n=30)
    line = mesh_cover_line(m)
    assert "the meshes front_back, sides, bottom and the scene's gate" in line
    assert "cover the silo's box [0, -0.0038, 0] .. [0.06, 0.2, 0.03] m" in line and "WARNING" not in line
    # a silo taller than the meshes: the line says what is short
    txt = (tmp_path / "mesh" / "case.toml").read_text().replace("height = 0.2", "height = 0.25")
    (tmp_path / "mesh" / "case.toml").write_text(txt)
    line = mesh_cover_line(load_case(tmp_path / "mesh"))
    assert "WARNING: do not cover" in line and "y to 0.2038 m, not 0.25 m" in line


def test_silo_hopper_stl_is_silo_hopper_with_its_walls_from_the_stl_files():
    """Every key of cases/silo_hopper_stl is silo_hopper's but the walls; the STL files are
    silo_hopper's container as written now (to 1e-12 m); each mesh wall has its group's contact
    parameters."""
    h = load_case(CASES / "silo_hopper")
    s = load_case(CASES / "silo_hopper_stl")
    rh, rs = h.resolved, s.resolved
    assert rs["silo"]["walls"] == "mesh" and rh["silo"]["walls"] == "analytic"
    strip = ("walls", "front_back", "sides", "bottom")
    assert {k: v for k, v in rs["silo"].items() if k not in strip} == {
        k: v for k, v in rh["silo"].items() if k not in strip}
    for sec in rh:
        if sec not in ("silo", "case", "geometry"):
            assert rs[sec] == rh[sec], sec
    assert rs["geometry"]["type"] == "silo" and not rh["geometry"]["walls"]
    spec_h = {w.name: w for w in wall_specs(h)}
    spec_s = {w.name: w for w in wall_specs(s)}
    assert spec_s["gate"].params == spec_h["gate"].params
    ref = container_meshes(h)
    for grp in CONTAINER_GROUPS:
        for name, w in spec_h.items():
            if WALL_GROUPS[name] == grp:
                assert spec_s[grp].params == w.params, (grp, name)
        mesh = MeshWall.from_file(spec_s[grp].mesh["file"], None, units=spec_s[grp].mesh["units"])
        V, F = ref[grp]
        want = MeshWall(V, F, None)
        assert mesh.n_triangles == want.n_triangles
        np.testing.assert_allclose(mesh.vertices[mesh.triangles], want.vertices[want.triangles], rtol=0, atol=1e-12)


def test_write_stl_command(write_case, tmp_path, capsys):
    """``python -m cfddem.scenes.silo CASE --write-stl DIR``: the files and the tables of a mesh
    case that loads; ``--max-edge`` splits the rectangles (same bounds, more triangles)."""
    from cfddem.scenes.silo import main

    d = write_case(CASE.format(walls="analytic", n=30, end=0.1) + GROUPS, name="a")
    assert main([str(d), "--write-stl", str(tmp_path / "m"), "--units", "cm"]) == 0
    out = capsys.readouterr().out
    assert out.count("[[geometry.walls]]") == 3 and 'units = "cm"' in out and "mu = 0.45" in out
    assert sorted(p.name for p in (tmp_path / "m").iterdir()) == ["bottom.stl", "front_back.stl", "sides.stl"]
    (tmp_path / "m" / "case.toml").write_text(CASE.format(walls="mesh", n=30, end=0.1) + out)
    m = load_case(tmp_path / "m")
    coarse = {w.name: MeshWall.from_file(w.mesh["file"], None, units="cm") for w in wall_specs(m) if w.kind == "mesh"}
    assert {k: v.n_triangles for k, v in coarse.items()} == {"front_back": 4, "sides": 4, "bottom": 8}
    assert main([str(d), "--write-stl", str(tmp_path / "f"), "--max-edge", "0.01", "--units", "m"]) == 0
    capsys.readouterr()
    fine = MeshWall.from_file(tmp_path / "f" / "front_back.stl", None)
    np.testing.assert_allclose(fine.bounds(), coarse["front_back"].bounds(), atol=1e-12)
    assert fine.n_triangles > 100 and float(fine.edge_lengths().max()) < 0.01 * math.sqrt(2) + 1e-12
    assert main([str(d), "--write-stl", str(tmp_path / "x"), "--set", "silo.width=-1"]) == 2
    assert "silo.width" in capsys.readouterr().err
