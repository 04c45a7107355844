"""The sluice inlet: bcc lattice, feed velocity from the mass rate, no overlaps, exact rate."""

import math

import numpy as np
import pytest

from cfddem.particles.inlets import SluiceInlet, bcc_sluice_lattice

pytestmark = pytest.mark.nojit  # also run as plain Python (tests/unit/test_nojit_tier.py)


class FakeSystem:
    """Minimal stand-in for ParticleSystem: brute-force overlaps, free flight at feed speed."""

    def __init__(self):
        self.pos = np.zeros((0, 3))
        self.vel = np.zeros((0, 3))
        self.radius = np.zeros(0)

    def overlaps(self, pos, radius):
        allp = np.concatenate([self.pos, pos])
        allr = np.concatenate([self.radius, radius])
        n0 = len(self.pos)
        out = np.zeros(len(pos), bool)
        for i in range(len(pos)):
            d = np.linalg.norm(allp - pos[i], axis=1)
            lim = allr + radius[i]
            d[n0 + i] = np.inf
            out[i] = np.any(d < lim)
        return out

    n = property(lambda self: len(self.pos))

    def release(self, mask):
        return int(np.sum(mask))

    def add_particles(self, pos, vel, radius, density, omega=None, held=False, label=0):
        self.pos = np.concatenate([self.pos, pos])
        self.vel = np.concatenate([self.vel, vel])
        self.radius = np.concatenate([self.radius, radius])

    def advance(self, dt):
        self.pos = self.pos + dt * self.vel


def test_lattice_fits_and_no_overlap():
    d = 0.003
    lat = bcc_sluice_lattice(0.08, 0.045, d, gap=0.02)
    assert lat.a == pytest.approx(2 * d * 1.02 / math.sqrt(3))
    r = d / 2
    for layer in (lat.corner, lat.centre):
        assert layer[:, 0].min() >= r and layer[:, 0].max() <= 0.08 - r
        assert layer[:, 1].min() >= r and layer[:, 1].max() <= 0.045 - r
    # as many as fit: one more column/row would not fit
    nx = len(np.unique(lat.corner[:, 0]))
    assert (nx) * lat.a + 2 * r * 1.02 > 0.08
    # nearest-neighbour distance in the 3-D lattice is a sqrt(3)/2 >= d
    pts = np.concatenate([np.c_[lat.corner, np.zeros(len(lat.corner))],
                          np.c_[lat.centre, np.full(len(lat.centre), lat.a / 2)]])
    dd = np.linalg.norm(pts[:, None] - pts[None], axis=2) + np.eye(len(pts)) * 1e9
    assert dd.min() == pytest.approx(lat.a * math.sqrt(3) / 2)
    assert dd.min() > d


def test_feed_velocity_from_mass_rate():
    inl = SluiceInlet(width=0.08, height=0.045, z=-0.1, diameter=0.003, density=2550.0, mass_rate=1.6)
    m = 2550.0 * math.pi / 6 * 0.003 ** 3
    assert inl.particle_mass == pytest.approx(m)
    lin = m * inl.lattice.per_period / inl.lattice.a
    assert inl.velocity == pytest.approx(1.6 / lin)


def test_mass_rate_exact_and_never_overlapping():
    sysm = FakeSystem()
    inl = SluiceInlet(width=0.02, height=0.012, z=0.0, diameter=0.003, density=2550.0, mass_rate=0.05)
    dt = 1e-4
    t = 0.0
    T = 0.5
    while t < T - 1e-12:
        inl.insert(sysm, t, dt)
        sysm.advance(dt)
        t += dt
    # mass inserted equals the rate times time to within one layer
    layer_mass = inl.particle_mass * max(len(inl.lattice.corner), len(inl.lattice.centre))
    assert abs(inl.mass_inserted - 0.05 * T) <= layer_mass
    assert inl.mass_inserted == pytest.approx(len(sysm.pos) * inl.particle_mass)
    # no two particles overlap
    p = sysm.pos
    dd = np.linalg.norm(p[:, None] - p[None], axis=2) + np.eye(len(p))
    assert dd.min() >= 0.003 * (1 - 1e-9)
    # the lattice is periodic in space: successive layers a/2 apart along z, to within the
    # distance the feed moves in one step (layers enter at the first step after they are due)
    zs = np.unique(np.round(p[:, 2], 9))
    gaps = np.diff(zs)
    assert np.allclose(gaps, inl.lattice.a / 2, atol=inl.velocity * dt * 1.0001)


def test_blocked_sites_are_retried_then_dropped():
    """A bead on the first corner site that moves with the lattice keeps that site blocked: it is
    retried as the lattice moves on and dropped after retry_periods lattice periods; every other
    site enters on time, and inserted + dropped = rate x time."""
    sysm = FakeSystem()
    inl = SluiceInlet(width=0.02, height=0.012, z=0.0, diameter=0.003, density=2550.0, mass_rate=0.05)
    site = inl.layer(0)[0]
    sysm.pos = site[None, :].copy()
    sysm.vel = np.array([[0.0, 0.0, inl.velocity]])
    sysm.radius = np.array([0.0015])
    dt = 1e-4
    t = 0.0
    T = 0.3
    while t < T - 1e-12:
        inl.insert(sysm, t, dt)
        sysm.advance(dt)
        t += dt
    assert inl.count_dropped == 1 and inl.n_pending == 0
    assert inl.mass_dropped == pytest.approx(inl.count_dropped * inl.particle_mass)
    layer_mass = inl.particle_mass * max(len(inl.lattice.corner), len(inl.lattice.centre))
    assert abs(inl.mass_inserted + inl.mass_dropped - 0.05 * T) <= layer_mass
    p = sysm.pos
    dd = np.linalg.norm(p[:, None] - p[None], axis=2) + np.eye(len(p))
    assert dd.min() >= 0.003 * (1 - 1e-9)


def test_blocked_site_enters_late_at_its_lattice_position():
    """A site blocked at its due time enters as soon as the blocker has moved, at the position
    the lattice has reached by then (not at the insertion plane), with the feed velocity."""
    sysm = FakeSystem()
    inl = SluiceInlet(width=0.02, height=0.012, z=0.0, diameter=0.003, density=2550.0, mass_rate=0.05)
    site = inl.layer(0)[0]
    sysm.pos = site[None, :].copy()
    sysm.vel = np.zeros((1, 3))
    sysm.radius = np.array([0.0015])
    inl.insert(sysm, 0.0, 1e-4)
    n_layer = len(inl.layer(0))
    assert len(sysm.pos) == 1 + n_layer - 1 and inl.n_pending == 1
    sysm.pos[0, 1] += 0.5  # the blocker leaves
    t = 2e-3
    inl.insert(sysm, t, 1e-4)
    assert inl.n_pending == 0
    new = sysm.pos[-1]
    assert new[0] == pytest.approx(site[0]) and new[1] == pytest.approx(site[1])
    assert new[2] == pytest.approx(site[2] + inl.velocity * t)
    assert sysm.vel[-1, 2] == pytest.approx(inl.velocity)


def test_pending_sites_survive_a_restart():
    sysm = FakeSystem()
    inl = SluiceInlet(width=0.02, height=0.012, z=0.0, diameter=0.003, density=2550.0, mass_rate=0.05)
    sysm.pos = inl.layer(0)[:2].copy()
    sysm.vel = np.zeros((2, 3))
    sysm.radius = np.full(2, 0.0015)
    inl.insert(sysm, 0.0, 1e-4)
    st = inl.get_state()
    inl2 = SluiceInlet(width=0.02, height=0.012, z=0.0, diameter=0.003, density=2550.0, mass_rate=0.05)
    inl2.set_state(st)
    assert inl2.n_pending == inl.n_pending == 2
    assert [(k, t, s.tolist()) for k, t, s in inl2.pending] == [(k, t, s.tolist()) for k, t, s in inl.pending]


def test_polydisperse_feed_sizes_and_rate():
    sysm = FakeSystem()
    inl = SluiceInlet(width=0.02, height=0.012, z=0.0, diameter=0.002, diameter_max=0.003, density=2550.0,
                      mass_rate=0.05, seed=7)
    # the feed velocity uses the mean mass: E[d^3] = (b^4 - a^4) / (4 (b - a))
    ed3 = (0.003 ** 4 - 0.002 ** 4) / (4 * 0.001)
    assert inl.particle_mass == pytest.approx(2550.0 * math.pi / 6 * ed3)
    dt = 1e-4
    t = 0.0
    while t < 1.0 - 1e-12:
        inl.insert(sysm, t, dt)
        sysm.advance(dt)
        t += dt
    r = sysm.radius
    assert r.min() >= 0.001 and r.max() <= 0.0015
    assert np.mean((2 * r) ** 3) == pytest.approx(ed3, rel=0.03)
    assert inl.mass_inserted == pytest.approx(np.sum(2550.0 * 4 / 3 * math.pi * r ** 3))
    assert inl.mass_inserted == pytest.approx(0.05, rel=0.06)
    # the same layer always gets the same sizes (waiting, restarts)
    assert np.array_equal(inl.radii(5, 10), inl.radii(5, 10))
