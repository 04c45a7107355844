"""Rigid clumps: free rotation (energy, angular momentum, Dzhanibekov), rest on a plane,
collisions (momentum), intra-clump pairs, threads and restart bit-identical."""

import numba
import numpy as np
import pytest

from cfddem.particles import LinearContact, ParticleSystem, PlaneWall
from cfddem.particles.clumps import ClumpShape, matrix_from_quat, pellet

PP = LinearContact(k_n=2000.0, e_n=0.5, e_t=0.5, mu=0.4)


def _asym_shape():
    """Three spheres of different radii, non-collinear, overlapping: I1 < I2 < I3 all different."""
    c = np.array([[0.0, 0.0, 0.0], [0.003, 0.0, 0.0], [0.0, 0.0025, 0.0005]])
    r = np.array([0.002, 0.0015, 0.0012])
    return ClumpShape.from_spheres(c, r, 1000.0)


def _lab_L(sys):
    """Total angular momentum about the origin: bodies (L + M r x v)."""
    c = sys.clumps
    return c.L.sum(axis=0) + np.sum(c.mass[:, None] * np.cross(c.com, c.vel), axis=0)


def test_free_tumbling_conserves_energy_and_angular_momentum():
    sh = _asym_shape()
    assert len(set(np.round(sh.inertia / sh.inertia.max(), 6))) == 3
    sys = ParticleSystem(pp=PP, walls=[], dt=2e-5)
    w0 = np.array([120.0, -80.0, 180.0])  # rad/s, generic direction
    sys.add_clumps(sh, [[0.01, 0.02, 0.03]], vel=[[0.1, 0.0, -0.05]], omega=[w0])
    e0 = sys.kinetic_energy()
    L0 = _lab_L(sys)
    p0 = sys.momentum()
    angle = 0.0
    emax = 0.0
    for _ in range(20):
        sys.step(1000)
        emax = max(emax, abs(sys.kinetic_energy() / e0 - 1.0))
        angle += 1000 * sys.dt * np.linalg.norm(sys.clumps.omega()[0])
    assert angle > 2 * np.pi * 5  # many rotations
    assert emax < 1e-6
    assert np.max(np.abs(_lab_L(sys) - L0)) < 1e-12 * np.linalg.norm(L0) * 1e3
    assert np.linalg.norm(_lab_L(sys) - L0) / np.linalg.norm(L0) < 1e-11
    assert np.allclose(sys.momentum(), p0, rtol=0, atol=1e-18)
    # members are rigidly attached: distances between member centres unchanged
    d = np.linalg.norm(sys.pos[0] - sys.pos[1])
    assert abs(d - np.linalg.norm(sh.offsets[0] - sh.offsets[1])) < 1e-12
    # |q| = 1
    assert abs(np.linalg.norm(sys.clumps.quat[0]) - 1.0) < 1e-14
    # members' velocities are v + w x s
    s = sys.pos - sys.clumps.com[0]
    vm = sys.clumps.vel[0] + np.cross(sys.clumps.omega()[0], s)
    assert np.allclose(sys.vel, vm, rtol=0, atol=1e-12)


def test_intermediate_axis_is_unstable():
    """Dzhanibekov: a spin about the intermediate principal axis flips; about the largest it stays."""
    sh = _asym_shape()

    def run(axis):
        sys = ParticleSystem(pp=PP, walls=[], dt=2e-5)
        R = matrix_from_quat(sh.orientation_identity())  # principal axes in the lab: R columns
        w = 100.0 * R[:, axis] + 0.1 * R[:, (axis + 1) % 3]
        sys.add_clumps(sh, [[0.0, 0.0, 0.0]], omega=[w])
        proj = []
        for _ in range(100):
            sys.step(200)
            Rb = matrix_from_quat(sys.clumps.quat[0])
            proj.append(np.dot(Rb.T @ sys.clumps.omega()[0], np.eye(3)[axis]) / 100.0)
        return np.array(proj)

    mid = run(1)
    assert mid.min() < -0.9  # the spin about the intermediate axis reversed
    big = run(2)
    assert big.min() > 0.99


def test_clump_resting_on_plane_stays_at_rest():
    sh = pellet(4, 0.004, 1500.0)
    floor = PlaneWall(contact=PP, point=(0, 0, 0), normal=(0, 0, 1))
    dt = 2e-5
    sys = ParticleSystem(pp=PP, walls=[floor], dt=dt, gravity=(0, 0, -9.81))
    sys.add_clumps(sh, [[0.0, 0.0, 0.004]])
    sys.step(40000)  # 0.8 s: falls on a corner, tips over onto a face and settles
    z1 = sys.clumps.com[0].copy()
    sys.step(10000)
    v = np.linalg.norm(sys.clumps.vel[0])
    w = np.linalg.norm(sys.clumps.omega()[0])
    assert v < 1e-7 and w < 1e-4
    assert np.linalg.norm(sys.clumps.com[0] - z1) < 1e-9
    # the wall carries the clump's weight
    fz = sys.wall_forces()[0, 2]
    assert abs(-fz / (sh.mass * 9.81) - 1.0) < 1e-6


@pytest.mark.parametrize("mu", [0.4, 0.0])
def test_two_clumps_collide_conserving_momentum(mu):
    sh = pellet(2, 0.004, 1500.0)
    sys = ParticleSystem(pp=LinearContact(k_n=2000.0, e_n=0.5, e_t=0.5, mu=mu), walls=[], dt=2e-5)
    sys.add_clumps(sh, [[0.0, 0.0, 0.0], [0.012, 0.001, 0.0005]], vel=[[0.5, 0, 0], [-0.3, 0.1, 0]],
                   omega=[[0, 0, 20.0], [5.0, 0, 0]])
    p0 = sys.momentum()
    L0 = _lab_L(sys)
    e0 = sys.kinetic_energy()
    sys.step(2000)
    assert sys.n_pairs >= 0
    # they collided (energy lost through damping) and momentum is conserved
    assert sys.kinetic_energy() < 0.95 * e0
    assert np.allclose(sys.momentum(), p0, rtol=0, atol=1e-14 * np.abs(p0).max() + 1e-18)
    if mu == 0.0:
        # frictionless contacts are central: angular momentum conserved to round-off (with
        # friction the DEM torque R n x F_t of the sphere law does not conserve it exactly:
        # the defect is overlap * n x F_t per contact)
        assert np.linalg.norm(_lab_L(sys) - L0) < 1e-12 * np.linalg.norm(L0)


def test_members_of_one_clump_are_not_paired():
    sh = pellet(4, 0.004, 1500.0)
    sys = ParticleSystem(pp=PP, walls=[], dt=2e-5)
    sys.add_clumps(sh, [[0, 0, 0], [0.0045, 0, 0]])
    sys.step(1)
    pairs = sys.pairs()
    body = dict(zip(sys.ids.tolist(), sys.body.tolist()))
    for a, b in pairs:
        assert body[a] != body[b]
    assert len(pairs) > 0


def _mixed_run(threads, stop_at=None, state=None):
    old = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        sh = pellet(2, 0.003, 1500.0)
        floor = PlaneWall(contact=PP, point=(0, 0, 0), normal=(0, 0, 1))
        sys = ParticleSystem(pp=PP, walls=[floor], dt=2e-5, gravity=(0, 0, -9.81))
        sys.serial_below = 0
        rng = np.random.default_rng(3)
        g = np.array([[x, y, z] for x in range(4) for y in range(4) for z in range(3)], float) * 0.006
        com = g + 0.0005 * rng.standard_normal(g.shape) + [0, 0, 0.004]
        q = rng.standard_normal((len(g), 4))
        sys.add_clumps(sh, com[::2], quat=q[::2])
        sys.add_particles(com[1::2], 0.0, 0.0015, 1500.0)
        if state is not None:
            sys.set_state(state)
            sys.step(300)
        else:
            sys.step(300 if stop_at is None else stop_at)
            if stop_at is not None:
                return sys.get_state()
            sys.step(0)
        return np.concatenate([sys.pos[np.argsort(sys.ids)].ravel(), sys.vel[np.argsort(sys.ids)].ravel(),
                               sys.clumps.com.ravel(), sys.clumps.L.ravel(), sys.clumps.quat.ravel()])
    finally:
        numba.set_num_threads(old)


def test_restart_bit_identical():
    full = _mixed_run(1, None)
    # 300 steps in one go = 120 + (checkpoint) 180... restart after 120, continue 300-120 steps
    st = _mixed_run(1, stop_at=120)
    import copy

    st2 = copy.deepcopy(st)
    old = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        sh = pellet(2, 0.003, 1500.0)
        floor = PlaneWall(contact=PP, point=(0, 0, 0), normal=(0, 0, 1))
        sys = ParticleSystem(pp=PP, walls=[floor], dt=2e-5, gravity=(0, 0, -9.81))
        sys.serial_below = 0
        sys.set_state(st2)
        sys.step(180)
        res = np.concatenate([sys.pos[np.argsort(sys.ids)].ravel(), sys.vel[np.argsort(sys.ids)].ravel(),
                              sys.clumps.com.ravel(), sys.clumps.L.ravel(), sys.clumps.quat.ravel()])
    finally:
        numba.set_num_threads(old)
    assert np.array_equal(res, full)


def test_bit_identical_with_1_and_2_threads():
    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("needs 2 numba threads")
    assert np.array_equal(_mixed_run(1), _mixed_run(2))


def test_add_clumps_rejects_bad_input():
    from cfddem.errors import CaseError

    sh = pellet(2, 0.003, 1500.0)
    sys = ParticleSystem(pp=PP, walls=[], dt=2e-5)
    with pytest.raises(CaseError):
        sys.add_clumps(sh, [[0.0, 0.0]])
    with pytest.raises(CaseError):
        sys.add_clumps(sh, [[0.0, np.nan, 0.0]])
    with pytest.raises(CaseError):
        pellet(3, 0.003, 1500.0)
    with pytest.raises(CaseError):
        ClumpShape.from_spheres([[0, 0, 0]], [-1.0], 1000.0)


def test_removing_a_member_removes_its_clump():
    sh = pellet(2, 0.003, 1500.0)
    sys = ParticleSystem(pp=PP, walls=[], dt=2e-5)
    sys.add_clumps(sh, [[0, 0, 0], [0.01, 0, 0], [0.02, 0, 0]])
    sys.add_particles([[0.03, 0, 0]], 0.0, 0.001, 1000.0)
    mask = np.zeros(sys.n, bool)
    mask[np.flatnonzero(sys.body == 1)[0]] = True
    cnt, m = sys.remove_particles(mask)
    assert cnt == 2 and abs(m - sh.mass) < 1e-15
    assert sys.clumps.nb == 2 and sys.n == 5
    assert sorted(set(sys.body.tolist())) == [-1, 0, 1]
    assert np.allclose(sorted(sys.clumps.com[:, 0]), [0.0, 0.02])
    st = sys.step(10)
    assert st.ok


def test_rotating_frame_one_sphere_clump_follows_a_free_sphere():
    """A clump of one sphere and a free sphere in a rotating frame with gravity: same Boris kick
    (Coriolis) and centrifugal force, same path to round-off."""
    om = (0.0, 0.0, 2.0)  # rad/s about z
    kw = dict(pp=PP, walls=[], dt=1e-4, gravity=(0, -9.81, 0), omega=om, axis_point=(0.01, 0, 0))
    a = ParticleSystem(**kw)
    a.add_particles([[0.2, 0.1, 0.0]], [[0.3, 0.0, 0.1]], 0.002, 1000.0)
    b = ParticleSystem(**kw)
    sh = ClumpShape.from_spheres([[0.0, 0.0, 0.0]], 0.002, 1000.0)
    b.add_clumps(sh, [[0.2, 0.1, 0.0]], vel=[[0.3, 0.0, 0.1]])
    a.step(3000)
    b.step(3000)
    assert np.linalg.norm(a.pos[0] - [0.2, 0.1, 0.0]) > 0.1  # it moved
    assert np.allclose(b.clumps.com[0], a.pos[0], rtol=0, atol=1e-13)
    assert np.allclose(b.clumps.vel[0], a.vel[0], rtol=0, atol=1e-12)


def test_body_force_in_a_rotating_frame_is_exact():
    """Body force of a clump at rest = M g + M Omega^2 (r_perp) whatever the members' mass shares;
    centrifugal torque about the centre of mass = -Omega x (I Omega)."""
    om = np.array([0.0, 3.0, 0.0])
    sys = ParticleSystem(pp=PP, walls=[], dt=1e-5, gravity=(0, -9.81, 0), omega=om)
    sh = _asym_shape()
    q = np.array([0.9, 0.2, -0.3, 0.1])
    sys.add_clumps(sh, [[0.05, 0.02, -0.03]], quat=[q])
    sys.step(0)
    sys._refresh()
    c = sys.clumps
    M = sh.mass
    r = np.array([0.05, 0.02, -0.03])
    expect = M * np.array([0, -9.81, 0]) - M * np.cross(om, np.cross(om, r))
    assert np.allclose(c.force[0], expect, rtol=1e-12, atol=0)
    R = matrix_from_quat(c.quat[0])
    I_lab = R @ np.diag(sh.inertia) @ R.T
    assert np.allclose(c.torque[0], -np.cross(om, I_lab @ om), rtol=1e-10, atol=1e-22)
