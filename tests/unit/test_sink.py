"""The engine's sink plane (ParticleSystem.set_sink): particles past it leave at the next
neighbour rebuild that a step makes, not at a rebuild of their own; the count and the mass
are exact, the particles that stay are not disturbed, clumps leave whole."""

import math

import numpy as np
import pytest

from cfddem.particles import LinearContact, ParticleSystem, PlaneWall
from cfddem.particles.clumps import ClumpShape

RHO = 2500.0
C = LinearContact(k_n=2000.0, e_n=0.6, e_t=0.5, mu=0.4)
L = 0.012  # periodic depth (z)


def _stream(sink: bool, blob: bool = False, seed: int = 3):
    """A layer of spheres sliding down a plane inclined along +x (gravity tilted), periodic
    in z, crossing x = 0.03; with ``blob`` a second group at rest far upstream."""
    s = ParticleSystem(pp=C, walls=[PlaneWall(contact=C, point=(0, 0, 0), normal=(0, 1, 0))], dt=2e-5,
                       gravity=(5.0, -8.0, 0.0), periodic=(None, None, (0, L)))
    rng = np.random.default_rng(seed)
    xs = np.arange(0.0, 0.028, 0.0032)
    zs = (np.arange(3) + 0.5) * L / 3
    pos = np.array([[x, y, z] for x in xs for z in zs for y in (0.0016, 0.0048)])
    s.add_particles(pos + rng.uniform(-2e-4, 2e-4, pos.shape), np.tile([1.0, 0.0, 0.0], (len(pos), 1)),
                    rng.uniform(1.3e-3, 1.5e-3, len(pos)), RHO)
    if blob:
        b = np.array([[-0.2 + 0.0031 * i, 0.0015, 0.006] for i in range(4)])
        s.add_particles(b, 0.0, 1.5e-3, RHO, label=1)
    if sink:
        s.set_sink((0.03, 0.0, 0.0), (1.0, 0.0, 0.0))
    return s


def test_sink_takes_exact_count_and_mass_at_rebuilds_only():
    s = _stream(sink=True)
    n0, m0 = s.n, float(s.mass.sum())
    taken_n, taken_m, beyond_after_rebuild = 0, 0.0, []
    for _ in range(2500):
        r0 = s.n_rebuilds
        assert s.step(1).ok
        k, m = s.take_sunk()
        taken_n += k
        taken_m += m
        if k and s.n:
            assert s.n_rebuilds == r0 + 1  # it left with a rebuild the step made anyway
        if s.n_rebuilds > r0:
            beyond_after_rebuild.append(int(np.sum(s.pos[:, 0] > 0.03)))
    assert taken_n > 20  # most of the layer went through
    assert taken_n + s.n == n0
    assert taken_m + float(s.mass.sum()) == pytest.approx(m0, rel=1e-12)
    assert s.take_sunk() == (0, 0.0)
    # right after a rebuild, the only particles past the plane are those that crossed in its step
    # (positions drift before the rebuild, so none can be left over from earlier steps)
    assert max(beyond_after_rebuild) <= 3


def test_sink_costs_no_rebuilds_of_its_own():
    """Against removing the particles past the plane after every 5 steps (what an exit check
    does), the sink makes fewer rebuilds, and the same number as the lists need anyway."""
    a = _stream(sink=True)
    b = _stream(sink=False)
    for _ in range(500):
        assert a.step(5).ok
        assert b.step(5).ok
        out = b.pos[:, 0] > 0.03
        if out.any():
            b.remove_particles(out)
    ka, _ = a.take_sunk()
    assert ka > 20 and abs(a.n - b.n) <= 6  # the same flow, give or take the last crossers
    assert a.n_rebuilds < 0.7 * b.n_rebuilds  # 26 against 58
    c = _stream(sink=False)  # nothing removed: the rebuilds the flow needs
    assert c.step(2500).ok
    assert a.n_rebuilds <= c.n_rebuilds + 2  # 26 against 28


def test_particles_that_stay_are_not_disturbed():
    """A group far upstream moves the same with the stream taken by the sink mid-step as with
    the stream kept (rows moved inside a step would show)."""
    a = _stream(sink=True, blob=True)
    b = _stream(sink=False, blob=True)
    assert a.step(2500).ok and b.step(2500).ok
    assert a.take_sunk()[0] > 20
    ia, ib = np.flatnonzero(a.label == 1), np.flatnonzero(b.label == 1)
    oa, ob = ia[np.argsort(a.ids[ia])], ib[np.argsort(b.ids[ib])]
    assert np.array_equal(a.ids[oa], b.ids[ob])
    assert np.allclose(a.pos[oa], b.pos[ob], rtol=0, atol=1e-12)
    assert np.allclose(a.vel[oa], b.vel[ob], rtol=0, atol=1e-10)
    # and the stream's particles still upstream of the plane are the same particles
    keep_a = set(a.ids[(a.label == 0)].tolist())
    keep_b = set(b.ids[(b.label == 0) & (b.pos[:, 0] <= 0.03)].tolist())
    assert len(keep_a ^ keep_b) <= 6  # the ones crossing since the last rebuild


def test_added_particles_past_the_plane_leave_at_the_next_step():
    s = _stream(sink=True)
    assert s.step(5).ok
    n = s.n
    s.add_particles([[0.05, 0.0015, 0.006], [0.06, 0.0015, 0.006]], 0.0, 1.4e-3, RHO)
    assert s.step(1).ok
    k, m = s.take_sunk()
    assert k == 2 and m == pytest.approx(2 * RHO * 4 / 3 * math.pi * 1.4e-3**3, rel=1e-12)
    assert s.n == n
    k2, _ = s.drain_sink()  # nothing left past it
    assert k2 == 0


def test_clumps_leave_whole():
    c = LinearContact(k_n=2000.0, e_n=0.6, e_t=0.5, mu=0.4)
    s = ParticleSystem(pp=c, walls=[PlaneWall(contact=c, point=(0, 0, 0), normal=(0, 1, 0))], dt=2e-5,
                       gravity=(5.0, -8.0, 0.0), periodic=(None, None, (0, L)))
    shape = ClumpShape.from_spheres([[-0.7e-3, 0, 0], [0.7e-3, 0, 0]], [1.0e-3, 1.0e-3], RHO)
    com = np.array([[x, 0.0012, z] for x in np.arange(0.0, 0.026, 0.0036) for z in (0.003, 0.009)])
    s.add_clumps(shape, com, vel=np.tile([1.0, 0.0, 0.0], (len(com), 1)))
    s.set_sink((0.03, 0.0, 0.0), (1.0, 0.0, 0.0))
    nb0, m0 = s.clumps.nb, float(s.mass.sum())
    got = 0
    for _ in range(250):
        assert s.step(10).ok
        k, m = s.take_sunk()
        assert k % 2 == 0  # members of whole clumps
        got += k
    assert got >= 8
    assert s.clumps.nb == nb0 - got // 2 and s.n == 2 * s.clumps.nb
    assert float(s.mass.sum()) == pytest.approx(m0 * s.n / (2 * nb0), rel=1e-12)
    # each clump's two members are still together, their template distance apart
    bodies = s.body
    for b in np.unique(bodies):
        p = s.pos[bodies == b]
        assert len(p) == 2 and np.linalg.norm(p[0] - p[1]) == pytest.approx(1.4e-3, rel=1e-9)


def test_sink_rejects_a_zero_normal():
    s = _stream(sink=False)
    with pytest.raises(Exception, match="normal"):
        s.set_sink((0, 0, 0), (0, 0, 0))
