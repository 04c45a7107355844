"""Wall control: a wall switched off (silo gate) lets particles pass and drops its history; a
moving wall translates by v dt per step, drags a resting sphere by friction, and restarts
bit-identically."""

import math

import numpy as np
import pytest

from cfddem.particles import LinearContact, ParticleSystem, PlaneWall, RectangleWall

R, RHO = 1.5e-3, 2550.0
M = RHO * 4.0 / 3.0 * math.pi * R**3
C = LinearContact(k_n=1000.0, e_n=0.5, e_t=0.5, mu=0.5)
G = (0.0, -9.81, 0.0)


def _gate_system():
    floor = PlaneWall(contact=C, point=(0, -0.1, 0), normal=(0, 1, 0), name="floor")
    gate = RectangleWall(contact=C, point=(0, 0, 0), normal=(0, 1, 0), axis1=(1, 0, 0),
                         half1=0.01, half2=0.01, name="gate")
    s = ParticleSystem(pp=C, walls=[floor, gate], dt=1e-5, gravity=G)
    s.add_particles(np.array([[0.0, R, 0.0]]), np.zeros((1, 3)), np.array([R]), RHO)
    return s


def test_gate_holds_then_releases():
    s = _gate_system()
    assert s.step(20000).ok  # 0.2 s: settles on the gate
    assert s.pos[0, 1] == pytest.approx(R - M * 9.81 / 1000.0, rel=1e-3)
    assert s.wall_forces()[1, 1] == pytest.approx(-M * 9.81, rel=1e-3)
    s.set_wall_active("gate", False)
    assert not s.wall_active("gate")
    assert s.step(1000).ok
    assert np.all(s.wall_forces()[1] == 0.0)
    # free fall from rest (plus the spring's release, < 1 % of the distance here)
    t = 1000 * 1e-5
    assert s.pos[0, 1] == pytest.approx(R - M * 9.81 / 1000.0 - 0.5 * 9.81 * t * t, abs=2e-6)
    s.set_wall_active(1, True)
    assert s.wall_active("gate")


def test_moving_floor_drags_sphere_and_translates():
    v = np.array([0.003, 0.0, 0.0])
    floor = RectangleWall(contact=C, point=(0, 0, 0), normal=(0, 1, 0), axis1=(1, 0, 0),
                          half1=0.05, half2=0.05, name="ring")
    s = ParticleSystem(pp=C, walls=[floor], dt=1e-5, gravity=G)
    s.add_particles(np.array([[0.0, R - 1e-5, 0.0]]), np.zeros((1, 3)), np.array([R]), RHO)
    s.set_wall_velocity("ring", v)
    s.step(30000)
    assert np.allclose(s.wall_position("ring"), 30000 * 1e-5 * v, rtol=1e-9, atol=1e-15)
    # after the start-up transient the contact sticks: the sphere's contact point moves with the
    # floor (the sphere itself rolls, so its centre is slower than the floor)
    vc = s.vel[0] + np.cross(s.omega[0], np.array([0.0, -R, 0.0]))
    assert vc[0] == pytest.approx(v[0], rel=1e-3)
    # restart round trip keeps the wall where it was
    st = s.get_state()
    s2 = ParticleSystem(pp=C, walls=[floor], dt=1e-5, gravity=G)
    s2.set_state(st)
    assert np.array_equal(s2.wall_position("ring"), s.wall_position("ring"))
    s.step(100)
    s2.step(100)
    assert np.array_equal(s.pos, s2.pos) and np.array_equal(s.vel, s2.vel)


def test_wall_by_unknown_name():
    s = _gate_system()
    with pytest.raises(KeyError, match="no wall named"):
        s.set_wall_active("door", False)


def test_held_particles_move_at_their_velocity_and_push():
    """A held sphere (a feed) keeps its velocity under gravity and contact, pushes a free sphere
    ahead of it, and falls freely once released."""
    s = ParticleSystem(pp=C, walls=[], dt=1e-5, gravity=G)
    v0 = np.array([0.0, 0.0, 0.2])
    s.add_particles(np.array([[0.0, 0.0, 0.0]]), v0, R, RHO, held=True)
    s.add_particles(np.array([[0.0, 0.0, 2 * R + 1e-4]]), np.zeros(3), R, RHO)
    assert s.held.tolist() == [True, False]
    s.step(5000)
    ih = int(np.flatnonzero(s.ids == 0)[0])
    jf = int(np.flatnonzero(s.ids == 1)[0])
    assert np.array_equal(s.vel[ih], v0) and np.all(s.omega[ih] == 0.0)
    assert s.pos[ih] == pytest.approx(v0 * 5000 * 1e-5, abs=1e-12)
    assert s.vel[jf, 2] > 0.1  # pushed ahead
    # free: it falls (slightly held back by the contact with the held sphere, which does not)
    assert -9.81 * 0.05 < s.vel[jf, 1] < -0.9 * 9.81 * 0.05
    assert s.release(np.ones(2, bool)) == 1 and not s.held.any()
    s.step(1000)
    ih = int(np.flatnonzero(s.ids == 0)[0])
    assert s.vel[ih, 1] == pytest.approx(-9.81 * 0.01, rel=1e-6)
    # the flag survives a restart
    s2 = ParticleSystem(pp=C, walls=[], dt=1e-5, gravity=G)
    s.add_particles(np.array([[0.1, 0.0, 0.0]]), v0, R, RHO, held=True)
    s2.set_state(s.get_state())
    assert s2.held.sum() == 1
