"""Mesh walls against the analytic walls they approximate (cfddem.particles.mesh): rebounds on
a face, an edge and a vertex; rolling down an incline of many triangles (physics.md §1.3);
spheres fired at a closed mesh box; a box filled with spheres; a rotating drum."""

import itertools
import math

import numpy as np
import pytest

from cfddem.particles import (CylinderWall, HertzMindlinContact, LinearContact, MeshWall, ParticleSystem,
                              PlaneWall)
from cfddem.particles.mesh import box_surface, cylinder_surface, grid_surface

R, RHO = 1.5e-3, 2550.0
M = RHO * 4.0 / 3.0 * math.pi * R**3
G = 9.81
LIN = LinearContact(k_n=1000.0, e_n=0.5, e_t=0.5, mu=0.3, mu_r=0.02)
HM = HertzMindlinContact(E=5e6, nu=0.3, e=0.6, mu=0.3, mu_r=0.02)


def _rebound(wall, x0, law):
    """A sphere thrown at the floor y = 0 with a tangential velocity and spin: velocity and spin
    after the rebound and the contact time."""
    s = ParticleSystem(pp=law, walls=[wall], dt=1e-6)
    s.add_particles([[x0[0], R + 1e-5, x0[1]]], [0.1, -0.5, 0.05], R, RHO, omega=[[5.0, -3.0, 20.0]])
    t_on = None
    for _ in range(20000):
        assert s.step(1).ok
        touching = (s.mesh_contacts()[0] if s.nm else s._won[0, 0]) != 0
        if touching and t_on is None:
            t_on = s.time
        if t_on is not None and not touching:
            return s.vel[0].copy(), s.omega[0].copy(), s.time - t_on
    raise AssertionError("no rebound")


@pytest.mark.parametrize("law", [LIN, HM], ids=["linear", "hertz"])
def test_rebound_on_face_edge_vertex_equals_plane(law):
    """Face centre, the edge shared by two triangles, the vertex shared by six: rebound velocity,
    spin and contact time equal the analytic plane's to 1e-6 (relative)."""
    V, F = grid_surface((-0.02, 0.0, -0.02), (0, 0, 0.04), (0.04, 0, 0), 4, 4)  # 1 cm cells
    v_ref, w_ref, t_ref = _rebound(PlaneWall(contact=law, point=(0, 0, 0), normal=(0, 1, 0)), (0.0, 0.0), law)
    for where, x0 in [("face", (0.01 / 3, 0.02 / 3)), ("edge", (0.005, 0.0)), ("vertex", (0.0, 0.0))]:
        v, w, t = _rebound(MeshWall(V, F, law), x0, law)
        dv = np.max(np.abs(v - v_ref)) / np.max(np.abs(v_ref))
        dw = np.max(np.abs(w - w_ref)) / np.max(np.abs(w_ref))
        print(f"{law.__class__.__name__} {where}: |dv|/|v| = {dv:.2g}, |dw|/|w| = {dw:.2g}, "
              f"t_c = {t:.6g} s (plane {t_ref:.6g} s)")
        assert dv <= 1e-6 and dw <= 1e-6 and abs(t - t_ref) <= 1e-6 * t_ref


def _incline_run(wall_for, theta, t_end=0.25):
    """A sphere rolling down the plane through the origin tilted by theta (downhill +x): every
    step the normal force on the wall, every 1 ms the downhill velocity."""
    pw = LinearContact(k_n=1000.0, e_n=0.5, e_t=0.5, mu=0.3, mu_r=0.05)
    n = np.array([math.sin(theta), math.cos(theta), 0.0])
    d = np.array([math.cos(theta), -math.sin(theta), 0.0])
    s = ParticleSystem(pp=pw, walls=[wall_for(pw, n, d)], dt=1e-5, gravity=(0.0, -G, 0.0))
    x0 = (R - M * G * math.cos(theta) / pw.k_n) * n + 0.0013 * np.array([0, 0, 1.0])  # static overlap
    s.add_particles([x0], 0.0, R, RHO)
    fn, ts, vs = [], [], []
    for k in range(int(round(t_end / 1e-5))):
        assert s.step(1).ok
        f = s.mesh_forces()[0] if s.nm else s.wall_forces()[0]
        fn.append(-f @ n)
        if k % 100 == 99:
            ts.append(s.time)
            vs.append(s.vel[0] @ d)
    return np.array(fn), np.array(ts), np.array(vs), pw


@pytest.mark.parametrize("tan_theta", [0.3, 0.8])
def test_rolling_down_a_plane_of_many_triangles(tan_theta):
    """The incline of physics.md §1.3 made of 1020 triangles of 2 mm: the acceleration is the
    analytic 5/7 g (sin - mu_r cos) within 1 %, and the normal force does not jump at the seams
    (it stays at m g cos(theta) as on the analytic plane)."""
    theta = math.atan(tan_theta)

    def mesh(pw, n, d):
        V, F = grid_surface(-0.01 * d + np.array([0, 0, 0.006]), 0.17 * d, np.array([0, 0, -0.012]), 85, 6)
        return MeshWall(V, F, pw)

    fn, t, v, pw = _incline_run(mesh, theta)
    fn_p, t_p, v_p, _ = _incline_run(lambda pw, n, d: PlaneWall(contact=pw, point=(0, 0, 0), normal=tuple(n)), theta)
    sel = t >= 0.05
    a = np.polyfit(t[sel], v[sel], 1)[0]
    a_th = 5.0 / 7.0 * G * (math.sin(theta) - pw.mu_r * math.cos(theta))
    late = slice(5000, None)  # after 0.05 s: the start-up oscillation has died out
    w = M * G * math.cos(theta)
    spike = np.max(np.abs(fn[late] - w)) / w
    spike_p = np.max(np.abs(fn_p[late] - w)) / w
    print(f"tan={tan_theta}: a/a_th = {a / a_th:.6f}, max |F_n - mg cos| / mg cos = {spike:.2g} "
          f"(analytic plane {spike_p:.2g}), travelled {v[-1] ** 2 / (2 * a):.3g} m")
    assert a == pytest.approx(a_th, rel=1e-2)
    assert np.max(np.abs(v - v_p)) < 1e-6 * np.max(np.abs(v_p))
    assert spike < 1e-6


def test_spheres_fired_at_a_closed_box_stay_inside():
    """Spheres at 5 m/s towards every face centre, edge, corner and face-grid vertex (shared by
    six triangles) of a closed mesh box of 2 cm (each face 3 x 3 cells) stay inside."""
    h = 0.01
    law = LinearContact(k_n=1e5, e_n=0.9, e_t=0.5, mu=0.3)
    V, F = box_surface((-h, -h, -h), (h, h, h), 3)
    dirs1 = [np.array(d, float) for d in itertools.product((-1, 0, 1), repeat=3) if any(d)]  # 26
    dirs2 = []
    for a in range(3):
        for sgn in (-1, 1):
            for u, v in itertools.product((-1 / 3, 1 / 3), repeat=2):
                d = np.zeros(3)
                d[a] = sgn
                d[(a + 1) % 3], d[(a + 2) % 3] = u, v
                dirs2.append(d)  # 24 directions at the vertices (h, +-h/3, +-h/3) of the faces
    for dirs in (dirs1, dirs2):
        dirs = np.array([d / np.linalg.norm(d) for d in dirs])
        s = ParticleSystem(pp=law, walls=[MeshWall(V, F, law)], dt=2e-6)
        s.add_particles(0.006 * dirs, 5.0 * dirs, R, RHO)
        worst = -1.0
        for _ in range(40):  # 40 ms: every sphere hits the walls many times
            st = s.step(500)
            assert st.ok, st.message
            worst = max(worst, float(np.max(np.abs(s.pos))))
        print(f"{len(dirs)} spheres: max |x_i| over 40 ms = {worst * 1e3:.4f} mm (walls at {h * 1e3} mm, "
              f"R = {R * 1e3} mm); kinetic energy left {s.kinetic_energy():.3g} J")
        assert worst < h - 0.8 * R  # the overlap never exceeded 0.2 R


def _fill_box(walls, seed, n=1000, L=0.03):
    """n spheres rained from a jittered lattice into a box of base L x L (``walls``); after 0.8 s
    returns (mean centre height, rms speed)."""
    law = LinearContact(k_n=2000.0, e_n=0.3, e_t=0.5, mu=0.3)
    rng = np.random.default_rng(seed)
    s = ParticleSystem(pp=law, walls=walls(law), dt=2e-5, gravity=(0.0, -G, 0.0))
    g = np.arange(R * 1.1, L - R * 1.1, 2.3 * R)
    X, Y, Z = np.meshgrid(g, np.arange(R * 1.2, 10 * L, 2.3 * R), g, indexing="ij")
    pos = np.c_[X.ravel(), Y.ravel(), Z.ravel()]
    pos = pos[np.argsort(pos[:, 1], kind="stable")][:n]
    pos += rng.uniform(-0.1 * R, 0.1 * R, pos.shape)
    s.add_particles(pos, rng.normal(0.0, 0.05, pos.shape), R, RHO)
    for _ in range(40):
        assert s.step(1000).ok
    return float(np.mean(s.pos[:, 1])), float(np.sqrt(2 * s.kinetic_energy() / (n * M)))


@pytest.mark.slow
def test_mesh_box_fill_packs_like_six_planes():
    """1000 spheres settle in a closed mesh cube to the mean height they reach in the box of six
    analytic planes, within the seed-to-seed scatter."""
    L = 0.03

    def planes(law):
        return [PlaneWall(contact=law, point=(0, 0, 0), normal=(1, 0, 0)),
                PlaneWall(contact=law, point=(L, 0, 0), normal=(-1, 0, 0)),
                PlaneWall(contact=law, point=(0, 0, 0), normal=(0, 1, 0)),
                PlaneWall(contact=law, point=(0, 10 * L, 0), normal=(0, -1, 0)),
                PlaneWall(contact=law, point=(0, 0, 0), normal=(0, 0, 1)),
                PlaneWall(contact=law, point=(0, 0, L), normal=(0, 0, -1))]

    def mesh(law):
        return [MeshWall(*box_surface((0, 0, 0), (L, 10 * L, L), 4), law)]

    hp = [_fill_box(planes, seed) for seed in range(3)]
    hm = [_fill_box(mesh, seed) for seed in range(3)]
    yp, ym = np.array([h for h, _ in hp]), np.array([h for h, _ in hm])
    scatter = max(np.std(yp, ddof=1), np.std(ym, ddof=1))
    print(f"mean centre height: planes {yp.mean() * 1e3:.4f} +- {np.std(yp, ddof=1) * 1e3:.4f} mm, "
          f"mesh {ym.mean() * 1e3:.4f} +- {np.std(ym, ddof=1) * 1e3:.4f} mm; rms speed at the end "
          f"{max(v for _, v in hp + hm):.2g} m/s")
    assert max(v for _, v in hp + hm) < 0.01  # settled
    assert abs(ym.mean() - yp.mean()) < 3 * scatter


def _drum(mesh: bool, seed: int, rpm=30.0, Rd=0.025, Ld=0.012, n=300, t_settle=1.0, t_avg=1.0):
    """A drum (axis z, horizontal, gravity -y) of radius Rd and length Ld rotating at ``rpm``
    with n spheres: the time-averaged torque about the axis that the spheres exert on it
    (sampled every 1 ms over t_avg after t_settle)."""
    law = LinearContact(k_n=2000.0, e_n=0.5, e_t=0.5, mu=0.4)
    w = 2.0 * math.pi * rpm / 60.0
    if mesh:
        walls = [MeshWall(*cylinder_surface((0, 0, 0), (0, 0, 1), Rd, Ld, 64), law,
                          angular_velocity=(0, 0, w), center=(0, 0, 0), name="drum")]
    else:
        walls = [CylinderWall(contact=law, point=(0, 0, 0), axis=(0, 0, 1), radius=Rd, half_height=Ld / 2,
                              spin=w, name="drum"),
                 PlaneWall(contact=law, point=(0, 0, -Ld / 2), normal=(0, 0, 1), spin=w),
                 PlaneWall(contact=law, point=(0, 0, Ld / 2), normal=(0, 0, -1), spin=-w)]
    s = ParticleSystem(pp=law, walls=walls, dt=1e-5, gravity=(0.0, -G, 0.0))
    rng = np.random.default_rng(seed)
    g = np.arange(-Rd + 1.2 * R, Rd - 1.2 * R, 2.2 * R)
    X, Y, Z = np.meshgrid(g, g, np.arange(-Ld / 2 + 1.2 * R, Ld / 2 - 1.1 * R, 2.2 * R), indexing="ij")
    pos = np.c_[X.ravel(), Y.ravel(), Z.ravel()]
    pos = pos[np.hypot(pos[:, 0], pos[:, 1]) < Rd - 1.3 * R]
    pos = pos[np.argsort(pos[:, 1], kind="stable")][:n] + rng.uniform(-0.05 * R, 0.05 * R, (n, 3))
    s.add_particles(pos, 0.0, R, RHO)
    assert s.step(int(round(t_settle / 1e-5))).ok
    tq = []
    for _ in range(int(round(t_avg / 1e-3))):
        assert s.step(100).ok
        tq.append(s.mesh_torques()[0, 2] if mesh else float(np.sum(s.wall_torques()[:, 2])))
    return float(np.mean(tq))


@pytest.mark.slow
def test_rotating_mesh_drum_torque_equals_analytic_cylinder():
    """A 64-sided mesh drum with end caps and the analytic rotating cylinder with two spinning
    end plates, 300 spheres at 30 rpm: the same mean torque within the seed-to-seed scatter."""
    ta = np.array([_drum(False, seed) for seed in range(3)])
    tm = np.array([_drum(True, seed) for seed in range(3)])
    scatter = max(np.std(ta, ddof=1), np.std(tm, ddof=1))
    mg_r = 300 * M * G * 0.025
    print(f"drum torque: analytic {ta.mean() * 1e6:.3f} +- {np.std(ta, ddof=1) * 1e6:.3f} uN m, "
          f"mesh {tm.mean() * 1e6:.3f} +- {np.std(tm, ddof=1) * 1e6:.3f} uN m (M g R_drum = {mg_r * 1e6:.1f} uN m)")
    assert abs(ta.mean()) > 0.1 * mg_r  # the bed is lifted: a real torque
    assert abs(tm.mean() - ta.mean()) < 3 * scatter + 0.01 * abs(ta.mean())
