"""Triangle-mesh walls (cfddem.particles.mesh): closest-point features, one contact per point,
agreement with the analytic walls, reading STL/OBJ, defect reports, bad input, motion, gate,
forces on the mesh, restart and the cell-binned search."""

import math
import xml.etree.ElementTree as ET

import meshio
import numpy as np
import pytest

from cfddem.errors import CaseError
from cfddem.particles import (HertzMindlinContact, LinearContact, MeshWall, ParticleSystem, PlaneWall,
                              RectangleWall)
from cfddem.particles.mesh import (EDGE, FACE, VERTEX, box_surface, cylinder_surface, grid_surface,
                                   mesh_closest_py, triangle_rows)

R, RHO = 1.5e-3, 2550.0
M = RHO * 4.0 / 3.0 * math.pi * R**3
C = LinearContact(k_n=1000.0, e_n=0.5, e_t=0.5, mu=0.3, mu_r=0.02)


def grid(n=4, half=0.02, y=0.0):
    """Flat square mesh |x|, |z| <= half in the plane y, normal +y, 2 n^2 triangles; each
    interior vertex is shared by six triangles."""
    return grid_surface((-half, y, -half), (0, 0, 2 * half), (2 * half, 0, 0), n, n)


def one_eval(walls, x, vel=(0.0, 0.0, 0.0), omega=(0.0, 0.0, 0.0), law=C):
    """Force and torque on one sphere at x after one step of 1e-9 s (no gravity)."""
    s = ParticleSystem(pp=law, walls=walls, dt=1e-9)
    s.add_particles([x], [vel], R, RHO, omega=[omega])
    assert s.step(1).ok
    return s


# ---------------------------------------------------------------------- geometry kernel

def test_closest_point_features():
    V = np.array([[0.0, 0, 0], [1.0, 0, 0], [0.0, 0, 1.0]])
    T = triangle_rows(V, np.array([[0, 2, 1]]))  # normal +y
    assert np.allclose(T[0, 9:12], [0, 1, 0])
    f, k, qx, qy, qz, d2, h = mesh_closest_py(T, 0, np.array([0.2, 0.3, 0.2]))
    assert (f, (qx, qy, qz), d2, h) == (FACE, (0.2, 0.0, 0.2), pytest.approx(0.09), pytest.approx(0.3))
    f, k, qx, qy, qz, d2, h = mesh_closest_py(T, 0, np.array([0.5, 0.1, -0.3]))  # below edge P0-P2 (z = 0)
    assert f == EDGE and (qx, qy, qz) == pytest.approx((0.5, 0.0, 0.0)) and d2 == pytest.approx(0.1)
    f, k, qx, qy, qz, d2, h = mesh_closest_py(T, 0, np.array([-0.3, 0.2, -0.4]))
    assert f == VERTEX and k == 0 and (qx, qy, qz) == (0.0, 0.0, 0.0) and d2 == pytest.approx(0.29)
    f, k, qx, qy, qz, d2, h = mesh_closest_py(T, 0, np.array([0.8, -0.1, 0.8]))  # beyond the hypotenuse
    assert f == EDGE and (qx, qy, qz) == pytest.approx((0.5, 0.0, 0.5)) and h == pytest.approx(-0.1)


# ---------------------------------------------------------------------- one contact per point

@pytest.mark.parametrize("x", [(0.0067, 0.0, 0.0033),   # face interior
                               (0.005, 0.0, 0.0),       # on an edge of two triangles
                               (0.0, 0.0, 0.0),         # on a vertex of six triangles
                               (0.0, 0.0, 1e-13),       # 1e-13 m off the seam (round-off scale)
                               (0.0, 0.0, 3e-9),        # 3e-9 m off the seam
                               (0.005, 0.0, 0.005 + 1e-10)])  # next to a diagonal seam
@pytest.mark.parametrize("law", [C, HertzMindlinContact(E=5e6, nu=0.3, e=0.6, mu=0.3, mu_r=0.02)])
def test_flat_mesh_one_contact_equal_to_plane(x, law):
    x = np.array(x) + np.array([0.0, 0.8 * R, 0.0])
    V, F = grid()
    vel, om = (0.05, -0.2, 0.03), (3.0, -1.0, 7.0)
    s = one_eval([MeshWall(V, F, law)], x, vel, om, law)
    p = one_eval([PlaneWall(contact=law, point=(0, 0, 0), normal=(0, 1, 0))], x, vel, om, law)
    assert s.mesh_contacts().tolist() == [1]
    assert np.array_equal(s.force, p.force) and np.array_equal(s.torque, p.torque)
    assert np.array_equal(s.mesh_forces(), p.wall_forces())


def test_mesh_rectangle_equals_rectangle_wall_at_edges_and_corners():
    """Two triangles make a rectangle: face, edge and corner contacts equal RectangleWall's."""
    V = np.array([[-0.01, 0, -0.01], [-0.01, 0, 0.01], [0.01, 0, 0.01], [0.01, 0, -0.01]])
    F = np.array([[0, 1, 2], [0, 2, 3]])
    rect = RectangleWall(contact=C, point=(0, 0, 0), normal=(0, 1, 0), axis1=(1, 0, 0), half1=0.01, half2=0.01)
    for x in [(0.003, 0.001, 0.002), (0.0105, 0.001, 0.004), (0.0108, 0.0007, -0.0106),
              (-0.004, 0.0009, 0.0109), (0.0, 0.0009, 0.0)]:
        s = one_eval([MeshWall(V, F, C)], x, (0.02, -0.1, 0.0))
        p = one_eval([rect], x, (0.02, -0.1, 0.0))
        assert s.mesh_contacts().tolist() == [1]
        np.testing.assert_allclose(s.force, p.force, rtol=1e-12, atol=1e-18)
        np.testing.assert_allclose(s.torque, p.torque, rtol=1e-12, atol=1e-22)


@pytest.mark.parametrize("angle_deg", [90.0, 120.0])
def test_concave_corner_gives_two_plane_contacts(angle_deg):
    """A floor and a wall meeting at a concave crease (one mesh): a sphere touching both gets
    the two contacts of the two analytic planes."""
    a = math.radians(angle_deg)
    wn = np.array([math.sin(a), -math.cos(a), 0.0])  # the wall's normal, towards the particles
    wd = np.array([math.cos(a), math.sin(a), 0.0])   # up the wall
    L = 0.02
    V = np.array([[0, 0, -L], [0, 0, L], [L, 0, L], [L, 0, -L],
                  list(L * wd + [0, 0, -L]), list(L * wd + [0, 0, L])])
    F = np.array([[0, 1, 2], [0, 2, 3],          # floor, normal +y
                  [0, 4, 5], [0, 5, 1]])         # wall
    m = MeshWall(V, F, C)
    assert np.allclose(triangle_rows(m.vertices, m.triangles)[2, 9:12], wn)
    # centre at distance 0.8 R from the floor and 0.9 R from the wall
    x = np.array([0.0, 0.8 * R, 0.001])
    x = x + (0.9 * R - x @ wn) / (wn[0]) * np.array([1.0, 0, 0])
    assert x @ wn == pytest.approx(0.9 * R) and x[1] == pytest.approx(0.8 * R)
    s = one_eval([m], x, (0.01, -0.05, 0.0))
    p = one_eval([PlaneWall(contact=C, point=(0, 0, 0), normal=(0, 1, 0)),
                  PlaneWall(contact=C, point=(0, 0, 0), normal=tuple(wn))], x, (0.01, -0.05, 0.0))
    assert s.mesh_contacts().tolist() == [2]
    np.testing.assert_allclose(s.force, p.force, rtol=1e-12)
    np.testing.assert_allclose(s.torque, p.torque, rtol=1e-9, atol=1e-20)


def test_convex_edge_and_corner_of_a_box_one_contact():
    """Outside a closed box (normals outwards): beyond an edge and beyond a corner the sphere
    gets one contact at the edge / corner point, of overlap R - |x - q|."""
    V, F = box_surface((-0.01, -0.01, -0.01), (0.01, 0.01, 0.01))
    m = MeshWall(V, F, C, flip_normals=True)
    assert m.closed and m.signed_volume > 0
    d = 0.7 * R
    for x, q in [((0.01 + d / math.sqrt(2), 0.01 + d / math.sqrt(2), 0.003), (0.01, 0.01, 0.003)),
                 ((-0.01 - d / math.sqrt(3), 0.01 + d / math.sqrt(3), 0.01 + d / math.sqrt(3)), (-0.01, 0.01, 0.01)),
                 ((0.002, 0.01 + d, -0.0099), (0.002, 0.01, -0.0099))]:
        s = one_eval([m], x)
        assert s.mesh_contacts().tolist() == [1]
        n = (np.array(x) - q) / np.linalg.norm(np.array(x) - q)
        np.testing.assert_allclose(s.force[0], C.k_n * (R - d) * n, rtol=1e-5)  # + damping of 1e-9 s of motion


def test_inside_box_corner_three_contacts():
    V, F = box_surface((0, 0, 0), (0.02, 0.02, 0.02))
    m = MeshWall(V, F, C)
    assert m.closed and m.signed_volume < 0
    s = one_eval([m], (0.9 * R, 0.8 * R, 0.7 * R))
    assert s.mesh_contacts().tolist() == [3]
    np.testing.assert_allclose(s.force[0], C.k_n * R * np.array([0.1, 0.2, 0.3]), rtol=1e-5)


# ---------------------------------------------------------------------- reading and checks

def _write_binary_stl(path, tri_pts):
    rec = np.zeros(len(tri_pts), dtype=[("n", "<f4", (3,)), ("v", "<f4", (3, 3)), ("a", "<u2")])
    rec["v"] = tri_pts
    with open(path, "wb") as fh:
        fh.write(b"binary stl written by the test".ljust(80, b" "))
        fh.write(np.uint32(len(tri_pts)).tobytes())
        fh.write(rec.tobytes())


def test_read_stl_binary_ascii_and_obj(tmp_path):
    V, F = box_surface((0, 0, 0), (20.0, 10.0, 30.0))  # millimetres
    _write_binary_stl(tmp_path / "b.stl", V[F])
    meshio.write(tmp_path / "a.stl", meshio.Mesh(V, [("triangle", F)]), binary=False)
    quads = np.array([[0, 1, 3, 2]])  # an OBJ quad is split into two triangles
    meshio.write(tmp_path / "q.obj", meshio.Mesh(V, [("quad", quads)]))
    a = MeshWall.from_file(tmp_path / "a.stl", C, units="mm")
    b = MeshWall.from_file(tmp_path / "b.stl", C, scale=1e-3, translate=(1.0, 0, 0),
                           rotate=((0, 0, 1), 90.0))
    q = MeshWall.from_file(tmp_path / "q.obj", C, units="mm")
    assert a.n_triangles == b.n_triangles == 12 and q.n_triangles == 2
    assert a.closed and b.closed and a.n_inconsistent_edges == 0
    np.testing.assert_allclose(a.bounds()[1], [0.02, 0.01, 0.03])
    # rotated by 90 deg about z (x -> y, y -> -x), then shifted by 1 m in x
    np.testing.assert_allclose(b.bounds()[0], [0.99, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(b.bounds()[1], [1.0, 0.02, 0.03], atol=1e-12)
    lines = a.check_lines(particle_diameter=0.003)
    assert lines == ["mesh a: 12 triangles, bounds [0, 0, 0] .. [0.02, 0.01, 0.03] m, smallest edge 0.01 m = "
                     "3.33 particle diameters; closed, normals point inwards (particles inside)"]


def test_defects_are_reported(tmp_path):
    V, F = grid(2)
    F2 = F.copy()
    F2[0] = F2[0, [0, 2, 1]]             # one triangle flipped
    F2 = np.vstack([F2, F2[3:4], [[0, 0, 1]], [[0, 1, 2]]])   # a duplicate and two degenerate ones
    m = MeshWall(V, F2, C, name="floor")
    assert m.n_triangles == 8
    w = "\n".join(m.check_lines())
    assert "2 degenerate triangles (zero area) dropped" in w
    assert "1 duplicate triangles dropped" in w
    assert "edges with inconsistent normals" in w and m.n_inconsistent_edges == 2
    assert "8 open edges" in w


@pytest.mark.parametrize("make, match", [
    (lambda p: MeshWall(np.zeros((0, 3)), np.zeros((0, 3), int), C), "empty mesh"),
    (lambda p: MeshWall([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]], C), "all 1 triangles are degenerate"),
    (lambda p: MeshWall([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 3]], C), "index out of range"),
    (lambda p: MeshWall.from_file(p / "missing.stl", C), "no such file"),
    (lambda p: MeshWall.from_file(p / "notes.stl", C), "cannot read notes.stl as a mesh"),
    (lambda p: MeshWall.from_file(p / "empty.stl", C), "holds no triangles|cannot read"),
    (lambda p: MeshWall.from_file(p / "flat.stl", C), "degenerate"),
    (lambda p: MeshWall.from_file(p / "flat.stl", C, units="furlong"), "unknown unit"),
])
def test_bad_meshes_one_line_errors(tmp_path, make, match):
    (tmp_path / "notes.stl").write_text("these are my notes, not a mesh\nsecond line\n")
    (tmp_path / "empty.stl").write_text("solid x\nendsolid x\n")
    _write_binary_stl(tmp_path / "flat.stl", np.array([[[0, 0, 0], [1, 0, 0], [2, 0, 0]]], float))
    with pytest.raises(CaseError, match=match) as e:
        make(tmp_path)
    assert "\n" not in str(e.value)


# ---------------------------------------------------------------------- motion, gate, forces

def test_translating_mesh_equals_translating_rectangle():
    v = np.array([0.003, 0.0, 0.0])
    V = np.array([[-0.05, 0, -0.05], [-0.05, 0, 0.05], [0.05, 0, 0.05], [0.05, 0, -0.05]])
    mesh = MeshWall(V, np.array([[0, 1, 2], [0, 2, 3]]), C, velocity=v, name="belt")
    rect = RectangleWall(contact=C, point=(0, 0, 0), normal=(0, 1, 0), axis1=(1, 0, 0), half1=0.05,
                         half2=0.05, velocity=tuple(v))
    out = []
    for w in (mesh, rect):
        s = ParticleSystem(pp=C, walls=[w], dt=1e-5, gravity=(0, -9.81, 0))
        s.add_particles([[0.0, R - 1e-5, 0.0]], 0.0, R, RHO)
        assert s.step(3000).ok
        out.append(s)
    np.testing.assert_allclose(out[0].pos, out[1].pos, rtol=1e-10)
    np.testing.assert_allclose(out[0].vel, out[1].vel, rtol=1e-8, atol=1e-15)
    np.testing.assert_allclose(out[0].mesh_vertices("belt"), V + 3000 * 1e-5 * v, rtol=1e-12)
    np.testing.assert_allclose(out[0].mesh_forces(), out[1].wall_forces(), rtol=1e-8)
    assert out[0].mesh_forces()[0, 1] == pytest.approx(-M * 9.81, rel=1e-3)


def test_rotating_plate_drags_sphere_with_its_surface_velocity():
    """A square plate spinning about its normal (a turntable): a sphere resting on it ends up
    sticking, its contact point moving with the plate's surface velocity w x (q - c)."""
    w = np.array([0.0, 2.0, 0.0])
    V, F = grid(6, 0.03)
    s = ParticleSystem(pp=C, walls=[MeshWall(V, F, C, angular_velocity=w, center=(0, 0, 0), name="disk")],
                       dt=1e-5, gravity=(0, -9.81, 0))
    s.add_particles([[0.01, R - 2e-5, 0.0]], 0.0, R, RHO)
    assert s.step(20000).ok
    q = s.pos[0] - np.array([0.0, R, 0.0])
    vc = s.vel[0] + np.cross(s.omega[0], np.array([0.0, -R, 0.0]))
    np.testing.assert_allclose(vc, np.cross(w, q), rtol=2e-3, atol=1e-6)
    # the plate has turned by 0.4 rad: its vertices too
    Rz = np.array([[math.cos(0.4), 0, math.sin(0.4)], [0, 1, 0], [-math.sin(0.4), 0, math.cos(0.4)]])
    np.testing.assert_allclose(s.mesh_vertices("disk"), V @ Rz.T, atol=1e-12)
    # the analytic plane with the same spin about its normal gives the same motion
    p = ParticleSystem(pp=C, walls=[PlaneWall(contact=C, point=(0, 0, 0), normal=(0, 1, 0), spin=2.0)],
                       dt=1e-5, gravity=(0, -9.81, 0))
    p.add_particles([[0.01, R - 2e-5, 0.0]], 0.0, R, RHO)
    assert p.step(20000).ok
    np.testing.assert_allclose(s.pos, p.pos, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(s.omega, p.omega, rtol=1e-7)


def test_gate_schedule_switches_mesh():
    V, F = grid(2, 0.01)
    gate = MeshWall(V, F, C, schedule=[(0.1, False), (0.2, True)], name="gate")
    s = ParticleSystem(pp=C, walls=[gate], dt=1e-5, gravity=(0, -9.81, 0))
    s.add_particles([[0.0, R, 0.0]], 0.0, R, RHO)
    assert s.step(9990).ok
    assert s.mesh_active("gate") and s.mesh_forces()[0, 1] == pytest.approx(-M * 9.81, rel=1e-3)
    y0 = s.pos[0, 1]
    assert s.step(20).ok and not s.mesh_active("gate")
    assert np.all(s.mesh_forces() == 0.0)
    assert s.step(10000).ok and s.mesh_active("gate")
    assert s.pos[0, 1] < y0 - 0.04  # fell through while the gate was open


def test_restart_bit_identical_with_moving_mesh():
    V, F = grid(4, 0.02)
    mk = lambda: MeshWall(V, F, C, velocity=(0.01, 0, 0), angular_velocity=(0, 0.5, 0), center=(0, 0, 0))
    s = ParticleSystem(pp=C, walls=[mk()], dt=1e-5, gravity=(0, -9.81, 0))
    rng = np.random.default_rng(1)
    s.add_particles(np.c_[rng.uniform(-0.01, 0.01, 6), R + 0.004 * np.arange(6), rng.uniform(-0.01, 0.01, 6)],
                    0.0, R, RHO)
    assert s.step(2000).ok
    s2 = ParticleSystem(pp=C, walls=[mk()], dt=1e-5, gravity=(0, -9.81, 0))
    s2.set_state(s.get_state())
    assert s.step(1500).ok and s2.step(1500).ok
    assert np.array_equal(s.pos, s2.pos) and np.array_equal(s.omega, s2.omega)
    assert np.array_equal(s.mesh_vertices(0), s2.mesh_vertices(0))


# ---------------------------------------------------------------------- search

def test_binned_search_and_thread_independence():
    """Spheres on a 20x20-cell floor (800 triangles): each sees only the few triangles near it,
    and the parallel and serial kernels give identical results."""
    V, F = grid(20, 0.05)
    rng = np.random.default_rng(3)
    g = np.arange(-0.042, 0.043, 0.004)
    X, Y, Z = np.meshgrid(g, [R + 1e-4, R + 4e-3], g, indexing="ij")
    pos = np.c_[X.ravel(), Y.ravel(), Z.ravel()] + rng.uniform(-4e-4, 4e-4, (X.size, 3))
    out = []
    for serial_below in (10**9, 0):
        s = ParticleSystem(pp=C, walls=[MeshWall(V, F, C)], dt=1e-5, gravity=(0, -9.81, 0))
        s.serial_below = serial_below
        s.add_particles(pos, 0.0, R, RHO)
        assert s.step(2000).ok
        out.append(s)
    assert np.array_equal(out[0].pos, out[1].pos)
    st = out[0].mesh_stats()
    assert st["triangles"] == 800 and st["contacts"] > 0
    assert st["candidates_per_particle"] < 12  # against 800 without binning


def test_paraview_meshes_per_frame_when_moving(tmp_path):
    from cfddem.io.vtk import ParaViewOutput

    V, F = grid(2, 0.01)
    still = MeshWall(V + [0, -0.05, 0], F, C, name="floor")
    blade = MeshWall(V, F, C, angular_velocity=(0, 3.0, 0), center=(0, 0, 0), name="blade")
    moving = {"meshes/meshes_000000.vtu", "meshes/meshes_000001.vtu"}
    for walls, files in (([still], {"meshes.vtu"}), ([still, blade], moving)):
        out = ParaViewOutput(tmp_path / str(len(walls)))
        s = ParticleSystem(pp=C, walls=walls, dt=1e-4)
        for _ in range(2):
            s.step(10)
            out.write(s.time, np.zeros((0, 3)), np.zeros(0), meshes=s.mesh_surfaces())
        d = tmp_path / str(len(walls)) / "vtk"
        entries = [ds.get("file") for ds in ET.parse(d / "meshes.pvd").getroot().iter("DataSet")]
        assert len(entries) == 2 and set(entries) == files
        back = meshio.read(d / sorted(files)[-1])
        k = back.cell_data["mesh"][0]
        assert len(k) == 8 * len(walls) and set(k.tolist()) == set(range(len(walls)))
        np.testing.assert_allclose(back.points[back.cells[0].data[k == len(walls) - 1]],
                                   s.mesh_vertices(len(walls) - 1)[walls[-1].triangles], atol=1e-15)


def test_binned_candidates_equal_brute_force():
    """The cell-binned candidate lists hold exactly the triangles within r + skin of each
    particle (checked against all triangles), for a tilted drum with long thin facets."""
    V, F = cylinder_surface((0.01, 0.02, -0.01), (1.0, 2.0, 0.5), 0.03, 0.08, 24, 3)
    m = MeshWall(V, F, C)
    rng = np.random.default_rng(5)
    pos = rng.uniform(-0.04, 0.06, (400, 3))
    keep = [0]
    for i in range(1, len(pos)):
        if np.min(np.linalg.norm(pos[keep] - pos[i], axis=1)) > 2.2 * R:
            keep.append(i)
    s = ParticleSystem(pp=C, walls=[m], dt=1e-7)
    s.add_particles(pos[keep], 0.0, R, RHO)
    s.step(1)
    T = triangle_rows(m.vertices, m.triangles)
    skin = s._skin_built
    for i in range(s.n):
        got = s._mlist[s._mstart[i]:s._mstart[i + 1]].tolist()
        want = [t for t in range(len(T)) if mesh_closest_py(T, t, s._ref[i])[5] < (R + skin) ** 2]
        assert got == want
    assert s.mesh_stats()["candidates"] > 0


def test_clump_tumbling_on_a_mesh_floor_equals_the_plane():
    """A three-sphere clump thrown spinning onto a mesh floor moves as on the analytic plane
    (its members touch faces, seams and vertices of the 2 mm triangles)."""
    from cfddem.particles.clumps import ClumpShape

    sh = ClumpShape.from_spheres([[-1.2e-3, 0, 0], [0, 0, 0], [1.2e-3, 0.4e-3, 0]], 1e-3, 2500.0)
    V, F = grid(20, 0.02)
    out = []
    for w in (MeshWall(V, F, C), PlaneWall(contact=C, point=(0, 0, 0), normal=(0, 1, 0))):
        s = ParticleSystem(pp=C, walls=[w], dt=1e-5, gravity=(0, -9.81, 0))
        s.add_clumps(sh, [[0.0013, 0.004, 0.0007]], vel=[[0.2, -0.1, 0.05]], omega=[[20.0, 5.0, -30.0]])
        assert s.step(5000).ok
        out.append(s)
    np.testing.assert_allclose(out[0].clumps.com, out[1].clumps.com, rtol=1e-9)
    np.testing.assert_allclose(out[0].mesh_forces(), out[1].wall_forces(), rtol=1e-6, atol=1e-12)
    assert out[0].clumps.com[0, 0] > 0.003  # it moved over several triangles


def test_moving_mesh_reaches_a_resting_sphere():
    """A plate approaching a sphere at rest (no gravity): the plate's own displacement triggers
    the rebuild of the candidate lists, so the plate pushes the sphere instead of passing it."""
    V, F = grid(4, 0.01, y=-0.005)
    s = ParticleSystem(pp=C, walls=[MeshWall(V, F, C, velocity=(0, 0.1, 0), name="piston")], dt=1e-5)
    s.add_particles([[0.001, 0.0, 0.002]], 0.0, R, RHO)
    assert s.step(10000).ok  # the plate has moved 1 cm, hitting the sphere after 3.5 mm
    # a collision with restitution e_n = 0.5 off a wall at 0.1 m/s: the sphere leaves at 0.15 m/s
    # (to 1 %: 60 steps per contact); without the rebuild the plate would pass the sphere (v = 0)
    assert s.vel[0, 1] == pytest.approx(0.15, rel=1e-2) and s.pos[0, 1] > 0.005 + R


def test_more_contacts_than_slots_stops_with_a_message():
    V, F = box_surface((0, 0, 0), (0.02, 0.02, 0.02))
    s = ParticleSystem(pp=C, walls=[MeshWall(V, F, C)], dt=1e-6, mesh_slots=2)
    s.add_particles([[0.9 * R, 0.8 * R, 0.7 * R]], 0.0, R, RHO)
    st = s.step(1)
    assert not st.ok and st.flag == "mesh_contacts" and "mesh_slots = 2" in st.message
