"""The force pass: slabs of the colour scheme, the fused pair sums, the wall candidates."""

import numba
import numpy as np
import pytest

from cfddem.particles import CylinderWall, LinearContact, ParticleSystem, PlaneWall, RectangleWall
from cfddem.particles import neighbours as nb

RHO = 2550.0


def _system(n, periodic, seed, walls=(), L=0.03, mu_r=0.0):
    rng = np.random.default_rng(seed)
    per = tuple((0.0, L) if p else None for p in periodic)
    c = LinearContact(1000.0, 0.9, 0.5, 0.3, mu_r=mu_r)
    s = ParticleSystem(pp=c, walls=[w(c) for w in walls], dt=1e-5, periodic=per, skin=4e-4,
                       gravity=(0.3, -9.81, 0.2))
    pos = rng.uniform(0.002, L - 0.002, (n, 3))
    rad = rng.uniform(0.5e-3, 1.2e-3, n)
    s.add_particles(pos, rng.normal(0.0, 0.05, (n, 3)), rad, RHO, omega=rng.normal(0.0, 5.0, (n, 3)))
    return s


@pytest.mark.parametrize("periodic", [(False, False, False), (True, False, True), (False, True, True),
                                      (True, True, True)])
@pytest.mark.parametrize("seed", [0, 1])
def test_pairs_join_particles_of_the_same_or_neighbouring_slabs(periodic, seed):
    s = _system(900, periodic, seed)
    s._rebuild()
    st = s._slab_start
    ns = len(st) - 1
    assert st[0] == 0 and st[-1] == s.n and np.all(np.diff(st) >= 0)
    slab = np.searchsorted(st, np.arange(s.n), side="right") - 1
    cur = s._cur
    a = slab[cur["pi"][: s.n_pairs]]
    b = slab[cur["pj"][: s.n_pairs]]
    d = np.abs(a - b)
    assert ns >= 6  # the slabs are layers of cells: several here
    # the colour scheme runs slabs three apart at once: a pair must join the same or
    # neighbouring slabs (across the ends only when they are neighbours by periodicity)
    wrap = d == ns - 1
    assert np.all((d <= 1) | wrap)
    if np.any(wrap):
        assert ns % 3 == 0


def test_slabs_along_a_periodic_axis_come_in_threes():
    nc = nb.grid_strides(np.array([4, 2, 10]), 2)
    assert list(nc[3:]) == [2, 1, 8]  # axis 2 slowest, then 0, then 1
    cell_start = np.arange(4 * 2 * 10 + 1)  # one particle per cell
    st = nb.slab_starts(nc, cell_start, (False, False, True))
    assert len(st) - 1 == 9 and st[-1] == 80  # 10 layers merged into 9 slabs
    assert list(np.diff(st)) == [8] * 8 + [16] or sorted(np.diff(st)) == [8] * 8 + [16]
    st = nb.slab_starts(nc, cell_start, (True, True, False))
    assert len(st) - 1 == 10  # not periodic along the slab axis: one slab per layer


def _forces(s):
    """Step once (no kick) and return the particles' forces and torques in id order."""
    s._forces_stale = True
    s.step(0)
    st = s._refresh()
    assert st is None
    o = np.argsort(s.ids)
    return s.force[o].copy(), s.torque[o].copy()


@pytest.mark.parametrize("periodic", [(False, False, False), (True, False, True)])
def test_fused_pair_sums_equal_newtons_third_law_pair_by_pair(periodic):
    s = _system(700, periodic, 3, mu_r=0.05)
    s.step(20)
    F, T = _forces(s)
    p = s.pair_forces()
    n = s.n
    f = np.zeros((n, 3))
    t = np.zeros((n, 3))
    np.add.at(f, p["pi"], p["force"])
    np.add.at(f, p["pj"], -p["force"])
    ra = s.radius[p["pi"]][:, None]
    rb = s.radius[p["pj"]][:, None]
    np.add.at(t, p["pi"], ra * p["nxft"] + p["rolling"])
    np.add.at(t, p["pj"], rb * p["nxft"] - p["rolling"])
    o = np.argsort(s.ids)
    g = s.mass[o, None] * s.gravity[None, :]
    scale = np.abs(F).max()
    assert np.sum(np.any(p["force"] != 0.0, axis=1)) > 100  # many contacts
    np.testing.assert_allclose(F, f[o] + g, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(T, t[o], rtol=0, atol=1e-12 * np.abs(T).max())


WALLS = [
    lambda c: PlaneWall(contact=c, point=(0, 0.001, 0), normal=(0, 1, 0), name="floor"),
    lambda c: PlaneWall(contact=c, point=(0.0015, 0, 0), normal=(1, 0, 0), name="left"),
    lambda c: RectangleWall(contact=c, point=(0.015, 0.015, 0.0285), normal=(0, 0, -1), axis1=(1, 0, 0),
                            half1=0.01, half2=0.01, name="lid"),
    lambda c: CylinderWall(contact=c, point=(0.015, 0.015, 0.015), axis=(0, 1, 0), radius=0.014,
                           half_height=0.02, inside=True, name="ring"),
]


def test_wall_candidates_give_the_forces_of_visiting_every_wall():
    s = _system(900, (False, False, False), 4, walls=WALLS, mu_r=0.05)
    s.step(50)
    assert 0 < s._wall_candidates < s.n * len(WALLS) / 2  # filtering does something
    near = s._wmask[: s.n] != 0
    F, T = _forces(s)
    won = s._won[: s.n].copy()
    assert np.sum(won == 1) > 20
    # every particle visits every wall
    s._wmask[: s.n] = (1 << len(WALLS)) - 1
    s._wplist = np.arange(s.n, dtype=np.int64)
    st = s._forces(kick=False, dt_hist=0.0)
    o = np.argsort(s.ids)
    assert st == 0
    # (the second evaluation projects the tangential springs once more: rounding only)
    np.testing.assert_allclose(s.force[o], F, rtol=1e-12, atol=1e-15 * np.abs(F).max())
    np.testing.assert_allclose(s.torque[o], T, rtol=1e-12, atol=1e-15 * np.abs(T).max())
    np.testing.assert_array_equal(s._won[: s.n], won)
    assert near.sum() < s.n


def test_wall_candidates_follow_a_wall_switched_on_and_a_moving_wall():
    c = LinearContact(1000.0, 0.9, 0.5, 0.3)
    gate = PlaneWall(contact=c, point=(0, 0.004, 0), normal=(0, 1, 0), name="gate")
    s = ParticleSystem(pp=c, walls=[gate], dt=1e-5, skin=4e-4)
    s.add_particles([[0.0, 0.0045, 0.0], [0.01, 0.05, 0.0]], 0.0, 1e-3, RHO)
    s.set_wall_active("gate", False)
    s.step(1)
    assert s._wall_candidates == 0
    s.set_wall_active("gate", True)  # a rebuild finds the particle on it
    s.step(1)
    assert s._wall_candidates == 1 and s.force[np.argsort(s.ids)][0, 1] > 0.0
    s.set_wall_velocity("gate", (0.0, 2.0, 0.0))  # moving: visited by every particle at once
    st = s.step(2000)
    assert st.ok or "overlap" in st.message
    assert s._wfilt[0] == 0


def _threaded_run(threads):
    numba.set_num_threads(threads)
    c = LinearContact(1000.0, 0.9, 0.5, 0.3, mu_r=0.05)
    L = 0.06
    s = ParticleSystem(pp=c, walls=[w(c) for w in WALLS[:2]], dt=1e-5, periodic=(None, None, (0.0, L)),
                       skin=4e-4, gravity=(-2.0, -9.81, 1.0))
    s.serial_below = 0  # the parallel kernels (1 thread: the serial twins)
    rng = np.random.default_rng(5)
    g = np.arange(0.0025, 0.03, 0.0026)
    pos = np.array([[x, y, z] for x in g for y in g[:6] for z in np.arange(0.0013, L, 0.0026)])
    pos += rng.uniform(-2e-4, 2e-4, pos.shape)
    s.add_particles(pos, rng.normal(0.0, 0.1, pos.shape), rng.uniform(1.0e-3, 1.2e-3, len(pos)), RHO)
    st = s.step(200)
    assert st.ok, st.message
    return s


def test_walls_and_slabs_bit_identical_with_1_and_2_threads():
    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("needs 2 numba threads")
    old = numba.get_num_threads()
    try:
        a = _threaded_run(1)
        b = _threaded_run(2)
    finally:
        numba.set_num_threads(old)
    assert len(a._slab_start) - 1 >= 9 and a.n_rebuilds > 1 and np.sum(a._won[: a.n] == 1) >= 5
    sa, sb = a.get_state(), b.get_state()
    for k in sa:
        if isinstance(sa[k], np.ndarray):
            assert np.array_equal(sa[k], sb[k]), k
        else:
            assert sa[k] == sb[k], k


def _drifting_gas(drift, seed=7):
    rng = np.random.default_rng(seed)
    c = LinearContact(1000.0, 0.9, 0.5, 0.3)
    L = 0.04
    floor = PlaneWall(contact=c, point=(0, 0, 0), normal=(0, 1, 0), name="floor")
    s = ParticleSystem(pp=c, walls=[floor], dt=2e-5, periodic=((0.0, L), None, (0.0, L)), skin=6e-4)
    g = np.arange(0.002, L, 0.004)
    pos = np.array([[x, y, z] for x in g for y in (0.0012, 0.005, 0.009) for z in g])
    pos += rng.uniform(-5e-4, 5e-4, pos.shape)
    pos[:, 1] = np.maximum(pos[:, 1], 0.0011)
    vel = rng.normal(0.0, 0.3, pos.shape) + np.asarray(drift)
    vel[:, 1] = rng.normal(0.0, 0.3, len(pos))
    s.add_particles(pos, vel, 1e-3, RHO)
    return s


def test_a_bed_moving_as_a_whole_keeps_its_lists():
    """The same relative motion with and without a fast common drift along the walls: the
    rebuilds follow the relative motion, not the drift."""
    still = _drifting_gas((0.0, 0.0, 0.0))
    moving = _drifting_gas((3.0, 0.0, 2.0))
    for s in (still, moving):
        assert s.step(400).ok
    assert moving.n_rebuilds <= still.n_rebuilds + 2


@pytest.mark.parametrize("drift", [(0.0, 0.0, 0.0), (3.0, 0.0, 2.0)])
def test_no_contact_is_ever_missing_from_the_list(drift):
    s = _drifting_gas(drift, seed=8)
    for _ in range(300):
        assert s.step(1).ok
        touching = nb.brute_force_pairs(s.pos, s.radius, 0.0, s._plen)
        ids = s.ids
        listed = {tuple(p) for p in s.pairs().tolist()}
        for i, j in touching:
            assert (min(ids[i], ids[j]), max(ids[i], ids[j])) in listed
        # the floor: every particle touching it is among the wall candidates
        on = s.pos[:, 1] < s.radius
        assert np.all(s._wmask[: s.n][on] & 1)


def test_walls_across_a_periodic_axis_are_visited_by_every_particle():
    """A particle that wraps round a periodic axis jumps by a period: a wall across that axis
    (a floor in a vertically periodic silo) cannot rely on the candidate bits."""
    c = LinearContact(1000.0, 0.9, 0.5, 0.3)
    walls = [PlaneWall(contact=c, point=(0, 0.0, 0), normal=(0, 1, 0), name="floor"),
             PlaneWall(contact=c, point=(0.0, 0, 0), normal=(1, 0, 0), name="side"),
             CylinderWall(contact=c, point=(0.02, 0.0, 0.02), axis=(0, 1, 0), radius=0.02, half_height=1.0,
                          name="barrel"),
             CylinderWall(contact=c, point=(0.02, 0.0, 0.02), axis=(1, 0, 0), radius=0.02, half_height=1.0,
                          inside=False, name="rod")]
    s = ParticleSystem(pp=c, walls=walls, dt=1e-5, skin=4e-4, periodic=(None, (-0.05, 0.05), None))
    s.add_particles([[0.01, 0.01, 0.02], [0.02, 0.03, 0.01]], 0.0, 1e-3, RHO)
    s.step(1)
    assert list(s._wfilt[:4]) == [0, 1, 1, 0]
    assert np.all(s._wmask[: s.n] & 0b1001 == 0b1001)


@pytest.mark.parametrize("slots", [0, 2, 64])
def test_every_search_path_gives_the_brute_force_pairs(slots):
    """First build (count and fill), too few slots (a second pass with more), enough slots."""
    s = _system(600, (True, False, True), 9)
    s._rebuild()
    s._pair_slots = slots
    s._rebuild()
    ref = nb.brute_force_pairs(s.pos, s.radius, s.skin, s._plen)
    ids = s.ids
    want = {(min(ids[i], ids[j]), max(ids[i], ids[j])) for i, j in ref}
    got = {tuple(p) for p in s.pairs().tolist()}
    assert len(got) == s.n_pairs > 300 and got == want
    assert s._pair_slots == int(s._cur["counts"][: s.n].max()) + 4


@pytest.mark.parametrize("periodic", [(False, False, False), (True, False, True), (True, True, True)])
@pytest.mark.parametrize("serial", [True, False])
def test_pair_pass_zeroes_every_particle_inside_its_colours(periodic, serial):
    """The pair pass has no zeroing loop of its own (the first colour zeroes each slab's group,
    the last slab before the colours): sums into arrays full of NaN equal sums into zeros."""
    s = _system(900, periodic, 4)
    s.step(10)
    n = s.n
    ns = len(s._slab_start) - 1
    assert ns >= 6
    out = []
    numba.set_num_threads(2 if not serial else 1)
    try:
        for fill in (0.0, np.nan):
            f = np.full((n, 3), fill)
            t = np.full((n, 3), fill)
            hist = s._cur["hist"][: max(s.n_pairs, 1)].copy()
            s._pair_pass(f, t, hist, False, s._no_pf, s._no_pr, 0.0, serial)
            out.append((f, t))
    finally:
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    assert np.all(np.isfinite(out[1][0])) and np.all(np.isfinite(out[1][1]))
    assert np.abs(out[0][0]).max() > 0.0
    np.testing.assert_array_equal(out[0][0], out[1][0])
    np.testing.assert_array_equal(out[0][1], out[1][1])
