"""Neighbour search against brute force; thread independence of a whole run."""

import numba
import numpy as np
import pytest

from cfddem.particles import LinearContact, ParticleSystem, PlaneWall
from cfddem.particles.neighbours import brute_force_pairs

RHO = 2550.0


def _random_system(n, periodic, seed, capacity=64):
    rng = np.random.default_rng(seed)
    L = 0.03
    per = tuple((0.0, L) if p else None for p in periodic)
    s = ParticleSystem(pp=LinearContact(1000.0, 0.9, 0.5, 0.3), walls=[], dt=1e-5, periodic=per,
                       skin=4e-4, capacity=capacity)
    pos = rng.uniform(0, L, (n, 3))
    pos[:, 1] *= 0.5  # anisotropic bounding box
    rad = rng.uniform(0.5e-3, 1.6e-3, n)  # polydisperse, overlaps allowed here
    s.add_particles(pos, 0.0, rad, RHO)
    return s


@pytest.mark.nojit
@pytest.mark.parametrize("periodic", [(False, False, False), (True, False, True), (True, True, True)])
@pytest.mark.parametrize("seed", [0, 1])
def test_pairs_equal_brute_force(periodic, seed):
    s = _random_system(400, periodic, seed)
    # start with a tiny pair capacity to exercise the overflow -> grow -> refill path
    s._cur = s._alloc_pairs(8, s._cap)
    s._rebuild()
    assert s._cur["pcap"] >= s.n_pairs > 8
    plen = np.array([0.03 if p else 0.0 for p in periodic])
    ref = brute_force_pairs(s.pos, s.radius, s.skin, plen)
    ids = s.ids
    ref_ids = {(min(ids[i], ids[j]), max(ids[i], ids[j])) for i, j in ref}
    got = {tuple(p) for p in s.pairs().tolist()}
    assert len(got) == s.n_pairs  # no duplicates
    assert got == ref_ids
    # the CSR of incident pairs covers every pair exactly twice
    cur = s._cur
    fs, ss = cur["first_start"], cur["second_start"]
    assert fs[s.n] == s.n_pairs and ss[s.n] == s.n_pairs
    assert np.all(cur["pi"][: s.n_pairs] < cur["pj"][: s.n_pairs])
    assert sorted(cur["second_list"][: s.n_pairs].tolist()) == list(range(s.n_pairs))


@pytest.mark.nojit
@pytest.mark.parametrize("lengths,periodic", [
    ((0.03, 0.0095, 0.03), (False, True, True)),   # 2 cells across a periodic axis: no wrap there
    ((0.011, 0.03, 0.0095), (True, False, True)),  # 3 and 2 cells, the long axis open
    ((0.05, 0.011, 0.011), (True, True, True)),    # rows of 3 cells along a periodic stride-1 axis
])
def test_pairs_equal_brute_force_on_thin_periodic_boxes(lengths, periodic):
    """The search's rows of cells (one or two ranges of j along the stride-1 axis, wrapped at a
    periodic seam, no wrap across an axis of fewer than 3 cells) find every pair once."""
    rng = np.random.default_rng(7)
    per = tuple((0.0, L) if p else None for L, p in zip(lengths, periodic))
    s = ParticleSystem(pp=LinearContact(1000.0, 0.9, 0.5, 0.3), walls=[], dt=1e-5, periodic=per,
                       skin=4e-4, capacity=64)
    n = 300
    pos = rng.uniform(0, 1, (n, 3)) * np.array(lengths)
    rad = rng.uniform(0.8e-3, 1.4e-3, n)
    s.add_particles(pos, 0.0, rad, RHO)
    s._rebuild()
    plen = np.array([L if p else 0.0 for L, p in zip(lengths, periodic)])
    ref = brute_force_pairs(s.pos, s.radius, s.skin, plen)
    ids = s.ids
    ref_ids = {(min(ids[i], ids[j]), max(ids[i], ids[j])) for i, j in ref}
    got = {tuple(p) for p in s.pairs().tolist()}
    assert len(ref_ids) > 100
    assert len(got) == s.n_pairs
    assert got == ref_ids


@pytest.mark.nojit
def test_far_away_particle_does_not_blow_up_the_grid():
    s = _random_system(100, (False, False, False), 2)
    s.add_particles([[1.0e3, 5.0, -2.0e3]], 0.0, 1e-3, RHO)
    s._rebuild()
    ref = brute_force_pairs(s.pos, s.radius, s.skin, np.zeros(3))
    assert s.n_pairs == len(ref)


def _run(threads):
    numba.set_num_threads(threads)
    c = LinearContact(1000.0, 0.8, 0.5, 0.3, mu_r=0.02)
    L = 0.03
    s = ParticleSystem(pp=c, walls=[PlaneWall(contact=c, point=(0, 0, 0), normal=(0, 1, 0))],
                       dt=2e-5, gravity=(2.0, -9.0, 0.5), periodic=((0, L), None, (0, L)),
                       omega=(0, 0.5, 0), axis_point=(0.01, 0, 0.02))
    s.serial_below = 0  # use the parallel kernels
    rng = np.random.default_rng(11)
    g = (np.arange(8) + 0.5) * L / 8
    pos = np.array([[x, y, z] for x in g for z in g for y in (0.002, 0.0055, 0.009, 0.0125)])
    pos += rng.uniform(-2e-4, 2e-4, pos.shape)
    s.add_particles(pos, rng.normal(0, 0.1, pos.shape), rng.uniform(1.2e-3, 1.6e-3, len(pos)), RHO)
    st = s.step(300)
    assert st.ok, st.message
    return s.get_state(), s.n_rebuilds


def test_bit_identical_with_1_and_2_threads():
    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("needs 2 numba threads")
    old = numba.get_num_threads()
    try:
        a, nr = _run(1)
        b, _ = _run(2)
    finally:
        numba.set_num_threads(old)
    assert a["n"] == 256 and nr > 1 and a["npairs"] > 0
    for k in a:
        if isinstance(a[k], np.ndarray):
            assert np.array_equal(a[k], b[k]), k
        else:
            assert a[k] == b[k], k


@pytest.mark.parametrize("periodic", [(None, None, None), ((0.0, 0.05), None, None), (None, (0.0, 0.1), (0.0, 0.02))])
def test_rebuild_velocity_field_is_the_least_squares_fit(periodic):
    """The affine field fitted at a rebuild (normal equations from one compiled pass) is the
    least-squares fit of numpy's lstsq on the particles' velocities, constant along periodic axes."""
    from cfddem.particles import LinearContact, ParticleSystem

    rng = np.random.default_rng(3)
    c = LinearContact(k_n=1000.0, e_n=0.9, e_t=0.5, mu=0.3)
    s = ParticleSystem(pp=c, walls=[], dt=1e-5, periodic=periodic)
    pos = rng.uniform([0.0, 0.0, 0.0], [0.05, 0.1, 0.02], (500, 3)) + np.array([0.3, -0.2, 0.7]) * [
        p is None for p in periodic]
    G_true = rng.normal(0.0, 20.0, (3, 3))
    vel = np.array([0.5, -1.0, 2.0]) + pos @ G_true.T + rng.normal(0.0, 0.05, (500, 3))
    s.add_particles(pos, vel, 1e-4, 2500.0)
    s._rebuild()
    free = [a for a in range(3) if periodic[a] is None]
    x = s.pos[:, free]
    A = np.c_[np.ones(len(x)), x]
    coef, *_ = np.linalg.lstsq(A, s.vel, rcond=None)
    G = np.zeros((3, 3))
    G[:, free] = coef[1:].T
    np.testing.assert_allclose(s._ugrad, G, rtol=0, atol=1e-9 * np.abs(G).max())
    np.testing.assert_allclose(s._ubar, coef[0], rtol=0, atol=1e-9 * np.abs(s.vel).max())
    assert np.all(s._ugrad[:, [a for a in range(3) if periodic[a] is not None]] == 0.0)
