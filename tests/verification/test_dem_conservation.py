"""Energy and momentum conservation."""

import math

import numpy as np

from cfddem.particles import LinearContact, ParticleSystem, PlaneWall, RectangleWall

R, RHO = 1.5e-3, 2550.0
M = RHO * 4.0 / 3.0 * math.pi * R**3


def test_elastic_frictionless_spheres_in_closed_box_conserve_energy():
    """e_n = 1, mu = 0, 8 polydisperse spheres bouncing in a 1 cm box of planes and rectangles:
    kinetic + spring energy constant to 1e-3 over 1e5 steps."""
    c = LinearContact(k_n=1000.0, e_n=1.0, e_t=0.5, mu=0.0)
    L = 0.01
    walls = [PlaneWall(contact=c, point=(0, 0, 0), normal=(1, 0, 0)),
             PlaneWall(contact=c, point=(L, 0, 0), normal=(-1, 0, 0)),
             PlaneWall(contact=c, point=(0, 0, 0), normal=(0, 1, 0)),
             PlaneWall(contact=c, point=(0, L, 0), normal=(0, -1, 0)),
             RectangleWall(contact=c, point=(L / 2, L / 2, 0), normal=(0, 0, 1), axis1=(1, 0, 0),
                           half1=L / 2, half2=L / 2),
             RectangleWall(contact=c, point=(L / 2, L / 2, L), normal=(0, 0, -1), axis1=(1, 0, 0),
                           half1=L / 2, half2=L / 2)]
    tc = c.collision_time(M / 2 * 0.5)
    s = ParticleSystem(pp=c, walls=walls, dt=tc / 60)
    rng = np.random.default_rng(3)
    g = (np.arange(2) + 0.5) * L / 2
    pos = np.array([[x, y, z] for x in g for y in g for z in g]) + rng.uniform(-3e-4, 3e-4, (8, 3))
    rad = rng.uniform(0.8, 1.2, 8) * R
    s.add_particles(pos, rng.normal(0, 0.2, (8, 3)), rad, RHO, omega=rng.normal(0, 30, (8, 3)))
    w0 = s.omega[np.argsort(s.ids)].copy()
    e0 = s.kinetic_energy() + s.elastic_energy()
    n_contacts_seen = 0
    for _ in range(100):
        assert s.step(1000).ok
        n_contacts_seen += s.max_overlap_ratio() > 0
    e1 = s.kinetic_energy() + s.elastic_energy()
    assert s.step_count == 100_000
    assert n_contacts_seen > 5  # it did collide
    print(f"energy: relative change over 1e5 steps {e1 / e0 - 1:.3g}")
    assert abs(e1 / e0 - 1) < 1e-3
    # frictionless: no tangential force, spins exactly untouched
    assert np.array_equal(s.omega[np.argsort(s.ids)], w0)


def test_particle_collisions_conserve_momentum_to_round_off():
    """Dissipative, frictional, polydisperse collisions in a triply periodic box (no walls, no
    gravity): total momentum stays at its initial value to round-off."""
    c = LinearContact(k_n=1000.0, e_n=0.5, e_t=0.4, mu=0.4, mu_r=0.1)
    L = 0.012
    s = ParticleSystem(pp=c, walls=[], dt=2e-5, periodic=((0, L), (0, L), (0, L)))
    rng = np.random.default_rng(5)
    g = (np.arange(3) + 0.5) * L / 3
    pos = np.array([[x, y, z] for x in g for y in g for z in g]) + rng.uniform(-2e-4, 2e-4, (27, 3))
    s.add_particles(pos, rng.normal(0, 0.3, (27, 3)), rng.uniform(0.7, 1.0, 27) * R,
                    rng.uniform(2000, 3000, 27), omega=rng.normal(0, 50, (27, 3)))
    p0 = s.momentum()
    scale = float(np.sum(s.mass * np.linalg.norm(s.vel, axis=1)))
    ke0 = s.kinetic_energy()
    assert s.step(20000).ok
    assert s.kinetic_energy() < 0.9 * ke0  # collisions happened and dissipated
    print(f"momentum: max |P - P0| / sum m|v| = {np.abs(s.momentum() - p0).max() / scale:.3g}")
    assert np.all(np.abs(s.momentum() - p0) < 1e-13 * scale)
