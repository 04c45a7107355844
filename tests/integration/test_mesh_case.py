"""Mesh walls in the case format (issue #18): cases/mesh_box_drop checks and runs (beads at
rest in a closed STL box: the mesh force balances their weight), and bad mesh-wall tables give
one line naming the key."""

import math
import os
import shutil
import subprocess
import sys

import h5py
import numpy as np
import pytest

from cfddem.config import load_case
from cfddem.errors import CaseError
from cfddem.simulation import Simulation

from ..conftest import CASES

CASE = CASES / "mesh_box_drop"
CLI = [sys.executable, "-m", "cfddem.cli"]


def test_check_prints_the_mesh_line():
    p = subprocess.run(CLI + ["check", str(CASE)], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    line = [x for x in p.stdout.splitlines() if "mesh box:" in x]
    assert len(line) == 1, p.stdout
    assert "48 triangles" in line[0] and "[-0.015, 0, -0.015] .. [0.015, 0.04, 0.015] m" in line[0]
    assert "smallest edge 0.015 m = 5 particle diameters" in line[0]
    assert "normals point inwards" in line[0]
    assert "particle-wall (box):" in p.stdout
    assert "warning" not in p.stdout


def test_beads_rest_in_the_box_and_the_mesh_carries_their_weight(tmp_path):
    case = load_case(CASE, overrides=["time.end_time=0.12", "time.max_steps=2400", "output.vtk=true",
                                      "output.vtk_interval=0.06"])
    Simulation(case, tmp_path / "o", echo=False, progress=False).run()
    with h5py.File(tmp_path / "o" / "results.h5") as h:
        s = {k: np.asarray(v) for k, v in h["series"].items()}
        last = sorted(h["snapshots"].keys())[-1]
        pos = np.asarray(h["snapshots"][last]["pos"])
    n = 32
    assert s["n_particles"][-1] == n and s["mass_lost"][-1] == 0.0
    assert np.all(np.abs(pos[:, [0, 2]]) < 0.015 - 0.0015 + 1e-4) and np.all(pos[:, 1] > 0.0015 - 1e-4)
    w = n * case.particles.density * math.pi / 6 * case.particles.diameter ** 3 * 9.81
    assert s["time"][-1] == pytest.approx(0.12)
    assert s["kinetic_energy"][-1] < 1e-8
    # the particles push the floor down with their weight; nothing sideways
    assert s["mesh_box_fy"][-1] == pytest.approx(-w, rel=0.02)
    assert abs(s["mesh_box_fx"][-1]) < 0.02 * w and abs(s["mesh_box_fz"][-1]) < 0.02 * w
    assert s["mesh_box_fy"][0] == 0.0  # dropped from above the floor
    assert (tmp_path / "o" / "vtk" / "meshes.vtu").exists()  # a fixed mesh: written once
    assert not (tmp_path / "o" / "vtk" / "meshes").exists()
    assert not (tmp_path / "o" / "vtk" / "walls.vtu").exists()  # no analytic walls to draw


def _bad(tmp_path, table: str, extra_files=()):
    d = tmp_path / "c"
    d.mkdir()
    shutil.copy(CASE / "box.stl", d / "box.stl")
    for name, text in extra_files:
        (d / name).write_text(text)
    txt = (CASE / "case.toml").read_text().replace('file = "box.stl"\nunits = "mm"\n', table)
    (d / "case.toml").write_text(txt)
    return d


@pytest.mark.parametrize("table, extra, key, words", [
    ('file = "nope.stl"\n', (), "geometry.walls[0].file", "no such file"),
    ('file = "notes.stl"\n', [("notes.stl", "just some text\n")], "geometry.walls[0].file", "as a mesh"),
    ('file = "box.stl"\nrotate = [0, 0, 1]\n', (), "geometry.walls[0].rotate", "angle in degrees"),
    ('file = "box.stl"\nrotate = [0, 0, 0, 90]\n', (), "geometry.walls[0].rotate", "zero vector"),
    ('file = "box.stl"\nunits = "yd"\n', (), "geometry.walls[0].units", "not allowed"),
    ('file = "box.stl"\nvelocity = [0, 1]\n', (), "geometry.walls[0].velocity", "3 numbers"),
    ('file = "box.stl"\nschedule = [[0.1]]\n', (), "geometry.walls[0].schedule", "time, true or false"),
    ('file = "box.stl"\nnormal = [0, 1, 0]\n', (), "geometry.walls[0].normal", "not a key of a mesh wall"),
    ('units = "mm"\n', (), "geometry.walls[0].file", "required"),
])
def test_bad_mesh_wall_is_one_line(tmp_path, table, extra, key, words):
    d = _bad(tmp_path, table, extra)
    with pytest.raises(CaseError) as e:
        load_case(d)
    assert e.value.key == key and words in e.value.reason, str(e.value)
    p = subprocess.run(CLI + ["check", str(d)], capture_output=True, text=True, timeout=300)
    err = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(err) == 1 and key in err[0], p.stderr


def test_moving_mesh_case_keys(tmp_path):
    """A rotating, switched mesh from the case: the engine's MeshWall carries the motion."""
    d = _bad(tmp_path, 'file = "box.stl"\nunits = "mm"\nrotate = [0, 1, 0, 90]\ntranslate = [0, 0.001, 0]\n'
                       'angular_velocity = [0, 2.0, 0]\ncenter = [0, 0.02, 0]\nschedule = [[0.5, false], [0.7, true]]\n'
                       'mu = 0.3\n')
    from cfddem.scenes.common import mesh_wall, wall_specs, walls_bounding_box
    from cfddem.simulation import engine_wall

    case = load_case(d)
    spec = [w for w in wall_specs(case) if w.kind == "mesh"][0]
    m = engine_wall(spec, case.contact.model)
    assert m.name == "box" and m.schedule == [(0.5, False), (0.7, True)]
    assert np.allclose(m.angular_velocity, [0, 2, 0]) and np.allclose(m.center, [0, 0.02, 0])
    assert m.contact.mu == 0.3
    lo, hi = m.bounds()
    assert np.allclose(lo, [-0.015, 0.001, -0.015]) and np.allclose(hi, [0.015, 0.041, 0.015])
    # rotating about its centre: the lost-particle box holds the sphere swept by its vertices
    blo, bhi = walls_bounding_box([spec], case)
    r = np.max(np.linalg.norm(mesh_wall(spec).vertices - [0, 0.02, 0], axis=1))
    assert np.allclose(blo, np.array([0, 0.02, 0]) - r) and np.allclose(bhi, np.array([0, 0.02, 0]) + r)


def test_rotating_mesh_is_written_every_frame(tmp_path):
    """A mesh turning about the y axis at 10 rad/s: one meshes VTU per frame, its vertices turned
    by 10 rad/s times the frame's time; the torque series exist."""
    import meshio

    d = _bad(tmp_path, 'file = "box.stl"\nunits = "mm"\nangular_velocity = [0, 10.0, 0]\ncenter = [0, 0.02, 0]\n')
    case = load_case(d, overrides=["time.end_time=0.01", "output.vtk=true", "output.vtk_interval=0.005"])
    Simulation(case, tmp_path / "o", echo=False, progress=False).run()
    frames = sorted((tmp_path / "o" / "vtk" / "meshes").glob("meshes_*.vtu"))
    assert len(frames) == 3  # t = 0, 0.005, 0.01
    v0 = meshio.read(frames[0]).points
    v2 = meshio.read(frames[2]).points
    ang = np.arctan2(-v2[:, 2], v2[:, 0]) - np.arctan2(-v0[:, 2], v0[:, 0])
    ang = np.angle(np.exp(1j * ang))
    far = np.hypot(v0[:, 0], v0[:, 2]) > 1e-3
    assert np.allclose(ang[far], 10.0 * 0.01, atol=1e-9)
    assert np.allclose(v2[:, 1], v0[:, 1])
    with h5py.File(tmp_path / "o" / "results.h5") as h:
        assert {"mesh_box_tx", "mesh_box_ty", "mesh_box_tz"} <= set(h["series"].keys())


def test_the_mesh_file_is_read_once(tmp_path, monkeypatch):
    """`cfddem check` and a run's build of cases/mesh_box_drop in one process read box.stl once
    (validation, the check's mesh line, the bounding box and the particle system share it); a
    changed file is read again."""
    import meshio

    from cfddem.cli import main
    from cfddem.particles.mesh import _read_triangles

    reads = []
    real = meshio.read
    monkeypatch.setattr(meshio, "read", lambda path, *a, **k: reads.append(str(path)) or real(path, *a, **k))
    _read_triangles.cache_clear()
    assert main(["check", str(CASE)]) == 0
    assert [p.rsplit("/", 1)[-1] for p in reads] == ["box.stl"]
    sim = Simulation(load_case(CASE), tmp_path / "o", echo=False, progress=False)
    sim.build()
    assert len(reads) == 1 and sim.system.nm == 1 and sim.system.meshes[0].n_triangles == 48
    d = tmp_path / "copy"
    shutil.copytree(CASE, d)
    Simulation(load_case(d), tmp_path / "o2", echo=False, progress=False).build()
    assert len(reads) == 2  # another file
    st = (d / "box.stl").stat()  # the same file touched (a new modification time)
    os.utime(d / "box.stl", ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    Simulation(load_case(d), tmp_path / "o3", echo=False, progress=False).build()
    assert len(reads) == 3
