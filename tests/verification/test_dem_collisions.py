"""Single collisions measured back against the derived contact parameters (physics.md §1.1)."""

import math

import numpy as np
import pytest

from cfddem.particles import LinearContact, ParticleSystem, PlaneWall
from tests.analytic import LinearCollision

pytestmark = pytest.mark.nojit  # also run as plain Python (tests/unit/test_nojit_tier.py)

R = 1.5e-3
RHO = 2550.0
M = RHO * 4.0 / 3.0 * math.pi * R**3


def _gap_pp(s):
    p = s.pos
    return float(np.linalg.norm(p[1] - p[0]) - s.radius[0] - s.radius[1])


def _run_collision(s, gap, vrel, tc):
    """Step until the contact ends; return (contact duration from interpolated gap zero
    crossings, relative normal velocity before and after)."""
    v_before = vrel(s)
    g_prev, t_in, t_out = gap(s), None, None
    for _ in range(100000):
        s.step(1)
        g = gap(s)
        if t_in is None and g < 0 <= g_prev:
            t_in = s.time - s.dt * (-g) / (g_prev - g)
        if t_in is not None and g >= 0 > g_prev:
            t_out = s.time - s.dt * g / (g - g_prev)
            break
        g_prev = g
    assert t_out is not None, "contact did not end"
    s.step(5)  # leave the contact; no other force acts
    return t_out - t_in, v_before, vrel(s)


@pytest.mark.parametrize("e_n", [0.3, 0.7, 0.97])
def test_normal_pp_collision(e_n):
    pp = LinearContact(k_n=1000.0, e_n=e_n, e_t=0.5, mu=0.3)
    ref = LinearCollision(k_n=1000.0, e_n=e_n, m_eff=M / 2)
    tc = ref.t_c
    assert pp.collision_time(M / 2) == pytest.approx(tc, rel=1e-14)
    s = ParticleSystem(pp=pp, walls=[], dt=tc / 1000)
    s.add_particles([[0, 0, 0], [2 * R + 1e-5, 0, 0]], [[0.25, 0, 0], [-0.25, 0, 0]], R, RHO)
    ids = s.ids.copy()

    def vrel(s):
        v = s.vel[np.argsort(s.ids)]
        return float(v[1, 0] - v[0, 0])

    dur, vb, va = _run_collision(s, _gap_pp, vrel, tc)
    print(f"pp e_n={e_n}: measured e_n {-va / vb:.5f}, t_c/t_c,input {dur / tc:.5f}")
    assert va == pytest.approx(ref.rebound_velocity(vb), rel=5e-3)
    assert dur == pytest.approx(tc, rel=1e-2)
    assert set(s.ids) == set(ids)


@pytest.mark.parametrize("e_n", [0.3, 0.7, 0.97])
def test_normal_wall_collision(e_n):
    pw = LinearContact(k_n=1000.0, e_n=e_n, e_t=0.5, mu=0.3)
    ref = LinearCollision(k_n=1000.0, e_n=e_n, m_eff=M)  # wall: m* = m
    tc = ref.t_c
    assert pw.collision_time(M) == pytest.approx(tc, rel=1e-14)
    s = ParticleSystem(pp=pw, walls=[PlaneWall(contact=pw, point=(0, 0, 0), normal=(0, 1, 0))],
                       dt=tc / 1000)
    s.add_particles([[0, R + 1e-5, 0]], [[0, -0.3, 0]], R, RHO)
    dur, vb, va = _run_collision(s, lambda s: float(s.pos[0, 1] - R), lambda s: float(s.vel[0, 1]), tc)
    print(f"pw e_n={e_n}: measured e_n {-va / vb:.5f}, t_c/t_c,input {dur / tc:.5f}")
    assert va == pytest.approx(ref.rebound_velocity(vb), rel=5e-3)
    assert dur == pytest.approx(tc, rel=1e-2)
    # the wall felt the reaction only during contact; afterwards it is free again
    assert np.allclose(s.wall_forces(), 0.0)


@pytest.mark.parametrize("e_t", [0.33, 0.8])
def test_oblique_sticking_wall_impact_returns_e_t(e_t):
    """High friction: the contact sticks; the contact-point tangential velocity reverses with
    factor e_t (tangential oscillation has the same period as the normal one)."""
    pw = LinearContact(k_n=1000.0, e_n=0.9, e_t=e_t, mu=1e6)
    ref = LinearCollision(k_n=1000.0, e_n=0.9, m_eff=M, e_t=e_t)
    tc = ref.t_c
    s = ParticleSystem(pp=pw, walls=[PlaneWall(contact=pw, point=(0, 0, 0), normal=(0, 1, 0))],
                       dt=tc / 1000)
    s.add_particles([[0, R + 1e-5, 0]], [[0.1, -0.3, 0.05]], R, RHO, omega=[[2.0, 0.0, -10.0]])

    def u_t(s):  # tangential velocity of the contact point (n_ab = (0, -1, 0))
        v, w = s.vel[0], s.omega[0]
        u = v + R * np.cross(w, [0, -1, 0])
        return np.array([u[0], u[2]])

    u0 = u_t(s)
    dur, vb, va = _run_collision(s, lambda s: float(s.pos[0, 1] - R), lambda s: float(s.vel[0, 1]), tc)
    u1 = u_t(s)
    print(f"pw e_t={e_t}: measured {(-u1 / u0).tolist()}")
    assert np.allclose(u1 / ref.tangential_rebound(u0), 1.0, rtol=1e-2)
    assert va == pytest.approx(ref.rebound_velocity(vb), rel=5e-3)


def test_oblique_sticking_pp_impact_returns_e_t():
    e_t = 0.5
    pp = LinearContact(k_n=1000.0, e_n=0.9, e_t=e_t, mu=1e6)
    ref = LinearCollision(k_n=1000.0, e_n=0.9, m_eff=M / 2, e_t=e_t)
    tc = ref.t_c
    s = ParticleSystem(pp=pp, walls=[], dt=tc / 1000)
    # slow normal approach: n rotates by ~ v_n t_c / d during contact (here 0.5 %), which the
    # measurement in the final tangent plane would otherwise mix into u_t
    s.add_particles([[0, 0, 0], [2 * R + 1e-6, 0, 0]], [[0.02, 0.03, 0], [-0.02, -0.02, 0.02]], R, RHO)

    def u_t(s):
        o = np.argsort(s.ids)
        p, v, w = s.pos[o], s.vel[o], s.omega[o]
        n = (p[1] - p[0]) / np.linalg.norm(p[1] - p[0])
        u = v[0] - v[1] + np.cross(R * w[0] + R * w[1], n)
        return u - np.dot(u, n) * n

    u0 = u_t(s)
    _run_collision(s, _gap_pp, lambda s: 0.0, tc)
    u1 = u_t(s)
    print(f"pp e_t={e_t}: measured {-np.dot(u1, u0) / np.dot(u0, u0):.5f}")
    u_ref = ref.tangential_rebound(u0)
    assert np.dot(u1, u0) / np.dot(u_ref, u0) == pytest.approx(1.0, rel=1e-2)
    # no component out of the original tangential direction beyond the rotation of n
    assert np.linalg.norm(u1 - u_ref) < 2e-2 * np.linalg.norm(u0)
