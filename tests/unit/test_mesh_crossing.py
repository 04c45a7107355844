"""A particle through a mesh wall is diagnosed (cfddem.particles.crossing): teleported or fired
through a thin mesh plate with the right triangle and depth, relative to a moving mesh; not for
spheres resting on or bouncing off a mesh, rolling across its seams or leaving over an open
edge.  In a run: the one-line RunError naming the mesh wall and triangle, the diagnostic kept."""

import math
import subprocess
import sys

import h5py
import meshio
import numpy as np
import pytest

from cfddem.particles import LinearContact, MeshWall, ParticleSystem
from cfddem.particles.crossing import crossing_mark, find_crossing
from cfddem.particles.mesh import box_surface, grid_surface

R, RHO = 1.5e-3, 2550.0
C = LinearContact(k_n=1000.0, e_n=0.5, e_t=0.5, mu=0.3, mu_r=0.02)
HALF = 0.02


def plate(n=4, **kw):
    """Flat open plate |x|, |z| <= 2 cm in y = 0, normal +y, 2 n^2 triangles."""
    V, F = grid_surface((-HALF, 0.0, -HALF), (0, 0, 2 * HALF), (2 * HALF, 0, 0), n, n)
    return MeshWall(V, F, C, name="plate", **kw)


def triangles_holding(m, x, z):
    """Indices of the triangles of mesh m (in y = 0) whose closed face holds (x, 0, z)."""
    V, F = m.vertices, m.triangles
    p0, e1, e2 = V[F[:, 0]], V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]
    q = np.array([x, 0.0, z]) - p0
    d11, d12, d22 = (np.einsum("ij,ij->i", a, b) for a, b in ((e1, e1), (e1, e2), (e2, e2)))
    d1, d2 = np.einsum("ij,ij->i", q, e1), np.einsum("ij,ij->i", q, e2)
    det = d11 * d22 - d12 * d12
    v, w = (d22 * d1 - d12 * d2) / det, (d11 * d2 - d12 * d1) / det
    return set(np.flatnonzero((v >= -1e-12) & (w >= -1e-12) & (v + w <= 1 + 1e-12)).tolist())


def system(walls, pos, vel=None, gravity=(0.0, 0.0, 0.0), dt=1e-5):
    s = ParticleSystem(pp=C, walls=walls, dt=dt, gravity=gravity)
    pos = np.atleast_2d(pos)
    s.add_particles(pos, np.zeros_like(pos) if vel is None else np.atleast_2d(vel), R, RHO)
    return s


@pytest.mark.parametrize("x, z", [(0.0067, 0.0033),   # a face interior
                                  (0.005, 0.0),       # an edge of two triangles (the grid line z = 0)
                                  (0.0, 0.0),         # a vertex of six triangles
                                  (0.0137, -0.0121)])
def test_teleport_through_a_plate_is_diagnosed_with_its_triangle(x, z):
    m = plate()
    s = system([m], [[x, 0.002, z], [0.0, 0.01, 0.0]])  # the second one stays in front
    mark = crossing_mark(s)
    s.pos[0] = [x, -0.005, z]  # through the plate: 5 mm behind it
    c = find_crossing(s, mark)
    assert c is not None and c.wall == "plate" and c.index == 0 and c.pid == int(s.ids[0])
    assert c.triangle in triangles_holding(m, x, z)
    assert c.depth == pytest.approx(0.005, rel=1e-9)


def test_not_a_crossing_within_r_behind_from_behind_or_around_the_edge():
    m = plate()
    s = system([m], [[0.0067, 0.002, 0.0033], [0.003, -0.004, 0.003], [0.0195, 0.002, 0.0]])
    mark = crossing_mark(s)
    s.pos[0] = [0.0067, -0.0014, 0.0033]      # behind, but less than r = 1.5 mm
    s.pos[1] = [0.003, -0.010, 0.003]         # was behind already
    s.pos[2] = [0.0225, -0.004, 0.0]          # over the open edge x = 20 mm: the chord meets y = 0 at 20.5 mm
    assert find_crossing(s, mark) is None
    s.pos[2] = [0.0195, -0.004, 0.0]          # the same depth through the plate's rim
    c = find_crossing(s, mark)
    assert c is not None and c.index == 2 and c.depth == pytest.approx(0.004)


def test_fired_through_a_plate_with_a_huge_time_step():
    """One step of 2 ms at 10 m/s: the sphere jumps 20 mm, from 5 mm in front of the plate to
    15 mm behind it (the contact never sees it)."""
    m = plate()
    s = system([m], [0.0011, 0.005, -0.0042], vel=[0.0, -10.0, 0.0], dt=2e-3)
    mark = crossing_mark(s)
    assert s.step(1).ok
    c = find_crossing(s, mark)
    assert c is not None and c.triangle in triangles_holding(m, 0.0011, -0.0042)
    assert c.depth == pytest.approx(0.015, rel=1e-6)


def test_a_moving_plate_is_seen_at_rest():
    """The plate moves up 10 mm between two checks: a resting sphere 3 mm above it is swept
    through (7 mm behind it now: diagnosed); one carried along with the plate is not."""
    m = plate(velocity=(0.0, 1.0, 0.0))
    s = system([m], [[0.0067, 0.003, 0.0033], [-0.01, 0.003, 0.01]])
    mark = crossing_mark(s)
    for _ in range(1000):  # the mesh alone moves: 1000 x 1e-5 s at 1 m/s
        s._move_meshes(s.time + s.dt)
    s.pos[1] += [0.0, 0.01, 0.0]
    c = find_crossing(s, mark)
    assert c is not None and c.index == 0 and c.depth == pytest.approx(0.007, rel=1e-9)
    s.pos[0] += [0.0, 0.01, 0.0]
    assert find_crossing(s, mark) is None


def test_a_plate_switched_off_since_the_mark_is_not_checked():
    m = plate(schedule=[(5e-5, False)])
    s = system([m], [0.0067, 0.002, 0.0033])
    mark = crossing_mark(s)
    for _ in range(10):
        s._move_meshes(s.time + s.dt)
        s.time += s.dt
    assert not s.mesh_active("plate")
    s.pos[0] = [0.0067, -0.005, 0.0033]
    assert find_crossing(s, mark) is None


def _checked_run(s, steps, every):
    """Run ``steps`` steps, checking for crossings every ``every`` steps (as a run does)."""
    mark = crossing_mark(s)
    for _ in range(steps // every):
        assert s.step(every).ok
        assert find_crossing(s, mark) is None
        mark = crossing_mark(s)


def test_resting_bouncing_rolling_and_leaving_over_an_edge_are_not_crossings():
    g = (0.0, -9.81, 0.0)
    # resting: four spheres placed on the plate (on a face, an edge, vertices), 0.1 s
    s = system([plate()], [[0.0067, R, 0.0033], [0.005, R, 0.0], [0.0, R, -0.01], [-0.01, R, -0.01]],
               gravity=g)
    _checked_run(s, 10000, 100)
    assert np.allclose(s.pos[:, 1], R, atol=0.02 * R)
    # bouncing: dropped at 2 m/s (checks every 0.2 ms, shorter than the contact)
    s = system([plate()], [0.0023, 0.004, -0.0071], vel=[0.0, -2.0, 0.0], gravity=g)
    _checked_run(s, 500, 20)
    assert s.vel[0, 1] > 0.5  # on its way up again
    # rolling across the seams of a fine plate (64 x 64 cells of 0.625 mm): over 15 mm in 0.1 s
    s = system([plate(n=64)], [-0.015, R, 0.0013], vel=[0.3, 0.0, 0.0], gravity=g)
    _checked_run(s, 10000, 100)
    assert s.pos[0, 0] > 0.0 and abs(s.pos[0, 1] - R) < 0.02 * R
    # leaving over the open edge x = 20 mm at 0.5 m/s, falling 16 mm below the plate
    s = system([plate()], [0.012, R, 0.0], vel=[0.5, 0.0, 0.0], gravity=g)
    _checked_run(s, 8000, 100)
    assert s.pos[0, 1] < -10 * R and s.pos[0, 0] > HALF + R


def test_the_check_tests_a_few_triangles_per_particle():
    """2000 spheres anywhere in a closed box of 768 triangles, chords of about 1 mm (1 m/s over
    a 1 ms check interval): about 7 triangle tests per particle (measured 6.6 with 100k), not
    768; none crosses."""
    V, F = box_surface((0, 0, 0), (0.1, 0.1, 0.1), n=8)
    rng = np.random.default_rng(1)
    pos = rng.uniform(0.0015, 0.0985, (2000, 3))
    s = system([MeshWall(V, F, C, name="box")], pos)
    mark = crossing_mark(s)
    s.pos[:] = pos + np.clip(rng.normal(0.0, 1e-3, pos.shape), -1.4e-3, 1.4e-3)
    stats = {}
    assert find_crossing(s, mark, stats) is None
    assert 2.0 < stats["mesh_tests"] / len(pos) < 12.0


CLI = [sys.executable, "-m", "cfddem.cli"]
CASE = """
[case]
name = "tunnel_mesh"
[time]
end_time = 0.02
dt = {dt}
[output]
series_interval = 0.001
snapshot_interval = 0.01
plots = false
vtk = false
[particles]
density = 2550.0
diameter = 0.003
max_overlap_ratio = 1.0
initial = [{{pos = [0.0067, 0.0041, 0.0033], vel = [0, -20.0, 0]}}]
[contact.particle_particle]
k_n = 100.0
e_n = 0.5
[contact.particle_wall]
k_n = 100.0
e_n = 0.5
[geometry]
type = "none"
[[geometry.walls]]
name = "plate"
type = "mesh"
file = "plate.stl"
[measurements]
enabled = false
"""


def _case(d, dt):
    d.mkdir()
    V, F = grid_surface((-HALF, 0.0, -HALF), (0, 0, 2 * HALF), (2 * HALF, 0, 0), 4, 4)
    meshio.write(d / "plate.stl", meshio.Mesh(V, [("triangle", F)]), binary=True)
    (d / "case.toml").write_text(CASE.format(dt=dt))
    return d


def test_a_run_stops_with_one_line_naming_the_mesh_and_triangle(tmp_path):
    """20 m/s with dt = 1e-4 s (1.5 t_c/20): 2 mm per step, from 0.1 mm in front of the plate
    (overlap 0.93 r) to 1.9 mm behind it (no contact) in one step."""
    d = _case(tmp_path / "c", 1e-4)
    out = tmp_path / "o"
    p = subprocess.run(CLI + ["run", str(d), "--out", str(out), "--quiet"], capture_output=True, text=True,
                       timeout=300)
    assert p.returncode == 3, p.stderr
    assert len(p.stderr.strip().splitlines()) == 1
    msg = p.stderr.strip()
    m = plate()
    tri = int(msg.split("triangle ")[1].split(")")[0])
    assert "went through wall 'plate' (mesh, triangle" in msg and tri in triangles_holding(m, 0.0067, 0.0033)
    assert "now at [0.0067," in msg and "time step too large" in msg and "radii per step" in msg
    with h5py.File(out / "results.h5") as h:  # the run keeps what it wrote, and the diagnostic
        assert "time step too large" in h["measurements/diagnostic"].attrs["message"]
        y = np.asarray(h["measurements/diagnostic/pos"])[0, 1]
    depth = float(msg.split(" mm behind it")[0].rsplit(", ", 1)[1])
    assert depth == pytest.approx(-y * 1e3, rel=1e-2) and depth > 1.5
