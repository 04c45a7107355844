"""Pellet feed of the sluice inlet (particles.clump): bounding diameter, uniform random
orientations, feed velocity from the pellet mass, the mass rate met, pellets held by their body
velocity constraint in the hold zone and released past it."""

import math

import numpy as np
import pytest

from cfddem.particles.clumps import pellet
from cfddem.particles.contact import LinearContact
from cfddem.particles.inlets import SluiceInlet, bounding_diameter, random_quaternions
from cfddem.particles.system import ParticleSystem

D = 0.003
RHO = 2550.0


def test_bounding_diameter_of_the_pellets():
    assert bounding_diameter(pellet(2, D, RHO)) == pytest.approx(1.5 * D, rel=1e-6)
    # tetrahedron of edge d/2: circumradius (d/2) sqrt(6)/4, plus the sphere radius d/2 (the
    # gridded centre of mass of the overlapping spheres is off the centroid by ~1e-7 m, 2e-5 d)
    assert bounding_diameter(pellet(4, D, RHO)) == pytest.approx((1.0 + math.sqrt(6.0) / 4.0) * D, rel=1e-4)


def test_random_quaternions_uniform_and_deterministic():
    q = random_quaternions(np.random.default_rng(5), 40000)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, rtol=1e-14)
    # uniform on S^3: <q q^T> = I/4 (sampling error ~ 1/sqrt(n) ~ 0.005)
    np.testing.assert_allclose(q.T @ q / len(q), 0.25 * np.eye(4), atol=0.01)
    np.testing.assert_array_equal(q[:10], random_quaternions(np.random.default_rng(5), 10))


def test_pellet_feed_velocity_follows_from_the_pellet_mass():
    shape = pellet(2, D, RHO)
    inl = SluiceInlet(width=0.02, height=0.012, z=0.0, diameter=D, density=RHO, mass_rate=0.05, shape=shape)
    assert inl.lattice.a == pytest.approx(2 * 1.5 * D * 1.02 / math.sqrt(3), rel=1e-6)
    assert inl.particle_mass == pytest.approx(shape.mass, rel=1e-14)
    # the union of two spheres d/2 apart: 2 V_sphere - lens, V/V_sphere = 2 - 5/16 = 1.6875
    assert shape.mass == pytest.approx(1.6875 * RHO * math.pi / 6 * D ** 3, rel=2e-3)
    assert inl.velocity == pytest.approx(0.05 * inl.lattice.a / (shape.mass * inl.lattice.per_period), rel=1e-12)
    with pytest.raises(ValueError):
        SluiceInlet(width=0.02, height=0.012, z=0.0, diameter=D, diameter_max=0.004, density=RHO,
                    mass_rate=0.05, shape=shape)


def _system(dt):
    c = LinearContact(k_n=500.0, e_n=0.7, e_t=0.5, mu=0.3)
    return ParticleSystem(pp=c, walls=[], dt=dt, gravity=(0.0, -9.81, 0.0))


@pytest.mark.parametrize("n", [2, 4])
def test_pellet_feed_meets_the_rate_holds_then_releases(n, one_numba_thread):
    shape = pellet(n, D, RHO)
    dt = 2e-5
    sys_ = _system(dt)
    inl = SluiceInlet(width=0.02, height=0.012, z=0.0, diameter=D, density=RHO, mass_rate=0.05, shape=shape)
    T = 0.1
    steps = int(round(T / dt))
    n_held_checked = 0
    for s in range(steps):
        t = s * dt
        inl.insert(sys_, t, dt)
        if s % 50 == 0 and sys_.clumps is not None and sys_.clumps.nb:
            c = sys_.clumps
            held = c.vfix[:, 2] != 0
            # held pellets move at the feed velocity and do not fall; released ones fall
            np.testing.assert_allclose(c.vel[held], np.tile([0.0, 0.0, inl.velocity], (int(held.sum()), 1)),
                                       atol=1e-14)
            assert np.all(c.com[held, 2] <= inl.z_insert + inl.hold_length + inl.velocity * 50 * dt + 1e-12)
            n_held_checked += int(held.sum())
        sys_.step(1)
    c = sys_.clumps
    # every pellet is whole: n spheres per body
    assert sys_.n == n * c.nb == n * inl.count_inserted
    # the rate: mass fed = mdot T to within one lattice layer (the last may be due just after T)
    layer_mass = shape.mass * len(inl.lattice.corner)
    assert inl.mass_dropped == 0.0
    assert abs(inl.mass_inserted - 0.05 * T) <= layer_mass
    assert inl.mass_inserted == pytest.approx(shape.mass * c.nb, rel=1e-12)
    assert float(np.sum(sys_.mass)) == pytest.approx(inl.mass_inserted, rel=1e-12)
    assert n_held_checked > 0
    released = c.vfix[:, 2] == 0
    assert released.sum() > 0
    # released pellets fall freely (no walls): vy = -g (t - t_release) < 0, z velocity kept
    assert np.all(c.vel[released, 1] < 0.0)
    assert np.all(c.com[released, 2] > inl.z_insert + inl.hold_length - 1e-12)
    # no pellet was inserted overlapping another (nothing touches in free flight at equal speed)
    assert sys_.max_overlap_ratio() == 0.0
