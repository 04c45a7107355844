"""Coarse graining (cfddem/measure/coarse.py): conservation of mass and momentum by the
normalised kernel, the contact stress's integral (the virial) for pairs, walls, periodic images
and clumps, and the hydrostatic stress of a column at rest."""

import math

import numpy as np
import pytest

from cfddem.errors import CaseError
from cfddem.measure.coarse import coarse_grain, janssen, lateral_pressure_ratio
from cfddem.particles import LinearContact, ParticleSystem, PlaneWall
from cfddem.particles.clumps import pellet

R = 0.002
RHO = 1000.0
G = 9.81


def _law():
    return LinearContact(k_n=1e4, e_n=0.05, e_t=0.5, mu=0.3)


def _integral(f, values):
    return values.sum(axis=(0, 1, 2)) * f.cell_volume


def _random_cloud(seed, n=60, periodic=(None, None, None)):
    rng = np.random.default_rng(seed)
    s = ParticleSystem(pp=_law(), walls=[], dt=1e-5, periodic=periodic)
    pos = rng.uniform(0.01, 0.03, (n, 3))
    keep = np.ones(n, bool)
    for i in range(n):  # no overlaps: drop the later of two overlapping spheres
        d = np.linalg.norm(pos[:i] - pos[i], axis=1)
        keep[i] = not np.any(d[keep[:i]] < 2.2 * R)
    pos = pos[keep]
    s.add_particles(pos, rng.normal(0.0, 0.3, (len(pos), 3)), R * rng.uniform(0.8, 1.2, len(pos)), RHO)
    return s


def test_mass_and_momentum_conserved_by_the_kernel():
    s = _random_cloud(1)
    w = 1.5 * R
    # the grid holds every kernel whole (particles 0.01-0.03, cutoff 3 w = 9 mm)
    f = coarse_grain(s, [-0.002] * 3, [0.042] * 3, 0.001, w)
    M = s.mass.sum()
    assert abs(_integral(f, f.density) / M - 1) < 1e-10
    P = np.sum(s.mass[:, None] * s.vel, axis=0)
    assert np.allclose(_integral(f, f.momentum), P, rtol=0, atol=1e-10 * np.abs(P).max())
    V = np.sum(4 / 3 * np.pi * s.radius**3)
    assert abs(_integral(f, f.solid_fraction) / V - 1) < 1e-10
    assert np.all(f.coverage[f.density > 0] > 0)
    # a grid cut through the cloud loses the kernels' parts beyond its edges: less than the
    # mass of the particles whose centres lie inside plus those within the cutoff outside
    g = coarse_grain(s, [0.0] * 3, [0.02] * 3, 0.001, w)
    inside = np.all(s.pos < 0.02, axis=1)
    near = np.all(s.pos < 0.02 + 3 * w, axis=1)
    mg = _integral(g, g.density)
    assert mg < s.mass[near].sum() and mg > 0.5 * s.mass[inside].sum()


def test_periodic_grid_wraps_the_kernel():
    L = 0.04
    s = _random_cloud(2, periodic=((0, L), None, (0, L)))
    s.add_particles([[0.0005, 0.02, 0.039]], [[1.0, 0.0, 0.0]], R, RHO)  # at the corner of the period
    f = coarse_grain(s, [0.0, -0.01, 0.0], [L, 0.05, L], 0.002, 2 * R)
    assert abs(_integral(f, f.density) / s.mass.sum() - 1) < 1e-10
    P = np.sum(s.mass[:, None] * s.vel, axis=0)
    assert np.allclose(_integral(f, f.momentum), P, rtol=0, atol=1e-10 * np.abs(P).max())


def test_uniform_motion_has_no_kinetic_stress():
    s = _random_cloud(3)
    s.vel[:] = [0.3, -0.2, 0.1]
    f = coarse_grain(s, [0.0] * 3, [0.04] * 3, 0.002, 2 * R)
    rv2 = (f.density * 0.14).max()
    assert np.abs(f.kinetic_stress).max() < 1e-10 * rv2
    on = f.density > 1e-6 * f.density.max()
    assert np.allclose(f.velocity[on], [0.3, -0.2, 0.1], rtol=0, atol=1e-10)
    # two interpenetrating streams: -sum m v'v' = -rho (dv/2)^2 along the streams' axis
    s2 = ParticleSystem(pp=_law(), walls=[], dt=1e-5)
    s2.add_particles([[0.02, 0.02, 0.02]] * 1, [[1.0, 0, 0]], R, RHO)
    s2.add_particles([[0.02, 0.02, 0.02 + 1e-9]], [[-1.0, 0, 0]], R, RHO)  # overlapping on purpose
    f2 = coarse_grain(s2, [0.0] * 3, [0.04] * 3, 0.002, 2 * R)
    assert np.allclose(f2.kinetic_stress[..., 0, 0], -f2.density * 1.0, rtol=1e-6, atol=1e-12)


def _pair_system(periodic=(None, None, None), centre=(0.02, 0.02, 0.02)):
    s = ParticleSystem(pp=_law(), walls=[], dt=1e-5, periodic=periodic)
    c = np.asarray(centre)
    u = np.array([0.8, 0.6, 0.0])
    s.add_particles([c, c + 1.95 * R * u], [[0.1, 0.0, 0.0], [0.0, 0.2, 0.05]], R, RHO)
    return s


def _virial_of_pairs(s):
    """-sum f_ij (x) r_ij over the touching pairs (f on i from j, r_ij = x_i - x_j, minimum image)."""
    fb = s.force_breakdown()["contacts"]
    assert len(s.pos) == 2
    d = s.pos[0] - s.pos[1]
    for a in range(3):
        if s._plen[a] > 0:
            d[a] -= s._plen[a] * np.round(d[a] / s._plen[a])
    return -np.outer(fb[0], d)


def test_pair_stress_integrates_to_the_virial():
    s = _pair_system()
    f = coarse_grain(s, [0.0] * 3, [0.045] * 3, 0.0015, 1.5 * R)
    ref = _virial_of_pairs(s)
    assert np.abs(ref).max() > 1e-5  # the pair touches, with friction (a non-normal force)
    got = _integral(f, f.contact_stress)
    assert np.abs(got - ref).max() < 1e-8 * np.abs(ref).max()
    # compression: the normal stress along the branch is negative (tension positive)
    assert got[0, 0] < 0 and got[1, 1] < 0
    # a narrow kernel puts the stress on the segment between the centres, not beside it
    fn = coarse_grain(s, [0.0] * 3, [0.045] * 3, 0.0005, 0.5 * R)
    x, y = fn.centres(0), fn.centres(1)
    on = fn.contact_stress[..., 1, 1].sum(axis=2)
    i, j = np.unravel_index(np.argmin(on), on.shape)
    mid = s.pos.mean(axis=0)
    assert abs(x[i] - mid[0]) < 2.5 * R and abs(y[j] - mid[1]) < 2.5 * R


def test_pair_across_a_periodic_boundary():
    L = 0.04
    s = _pair_system(periodic=((0, L), (0, L), (0, L)), centre=(L - 0.001, L - 0.0005, 0.02))
    f = coarse_grain(s, [0.0] * 3, [L] * 3, 0.002, 1.5 * R)
    ref = _virial_of_pairs(s)
    assert np.abs(ref).max() > 1e-5
    assert np.abs(_integral(f, f.contact_stress) - ref).max() < 1e-8 * np.abs(ref).max()


def test_wall_contact_branch_runs_to_the_contact_point():
    c = _law()
    s = ParticleSystem(pp=c, walls=[PlaneWall(contact=c, point=(0, 0, 0), normal=(0, 1, 0))], dt=1e-5,
                       gravity=(0, -G, 0))
    s.add_particles([[0.02, 0.999 * R, 0.02]], 0.0, R, RHO)
    s.step(1)
    fw = -s.wall_forces()[0]  # force on the particle
    q = np.array([s.pos[0, 0], 0.0, s.pos[0, 2]])
    ref = np.outer(fw, q - s.pos[0])
    f = coarse_grain(s, [0.0, -0.01, 0.0], [0.04, 0.03, 0.04], 0.001, R)
    got = _integral(f, f.contact_stress)
    assert ref[1, 1] < 0
    assert np.abs(got - ref).max() < 1e-8 * np.abs(ref).max()


def test_clumps_are_bodies_with_branches_from_their_centres_of_mass():
    d = 2 * R
    s = ParticleSystem(pp=_law(), walls=[], dt=1e-5)
    s.add_clumps(pellet(2, d, RHO), com=[[0.02, 0.02, 0.02], [0.02 + 1.45 * d, 0.02 + 0.3 * d, 0.02]],
                 vel=[[0.1, 0.0, 0.0], [0.0, 0.0, 0.0]], omega=[[0.0, 0.0, 5.0], [0.0, 0.0, 0.0]])
    f = coarse_grain(s, [-0.01] * 3, [0.05] * 3, 0.0015, 1.5 * R, solid_density=RHO)
    c = s.clumps
    assert abs(_integral(f, f.density) / c.mass.sum() - 1) < 1e-10
    P = np.sum(c.mass[:, None] * c.vel, axis=0)
    assert np.allclose(_integral(f, f.momentum), P, rtol=0, atol=1e-10 * np.abs(P).max())
    # the force on body 0 from body 1 acts at the members' contact point; the stress integrates
    # to -F (x) (X_0 - X_1) with the centres of mass (the contact points cancel)
    fb = s.force_breakdown()["contacts"]
    F0 = fb[s.body == 0].sum(axis=0)
    assert np.linalg.norm(F0) > 1e-5
    ref = -np.outer(F0, c.com[0] - c.com[1])
    got = _integral(f, f.contact_stress)
    assert np.abs(got - ref).max() < 1e-8 * np.abs(ref).max()
    # with member centres instead, the integral would differ by the lever arm
    members = -np.outer(F0, s.pos[s.body == 0][1] - s.pos[s.body == 1][0])
    assert np.abs(members - ref).max() > 0.1 * np.abs(ref).max()
    with pytest.raises(CaseError, match="solid_density"):
        coarse_grain(s, [-0.01] * 3, [0.05] * 3, 0.0015, 1.5 * R)


def _column(ns=4, N=16):
    """A simple-cubic stack of N layers of ns x ns spheres on a floor, periodic sideways (a
    0.02 R gap between neighbours of one layer), at rest: quenched (velocities zeroed every 50
    steps) until the contact forces carry the weight."""
    dl = 2.02 * R
    L = ns * dl
    c = _law()
    s = ParticleSystem(pp=c, walls=[PlaneWall(contact=c, point=(0, 0, 0), normal=(0, 1, 0))], dt=6e-6,
                       gravity=(0, -G, 0), periodic=((0, L), None, (0, L)))
    ix, iy, iz = np.meshgrid(np.arange(ns), np.arange(N), np.arange(ns), indexing="ij")
    s.add_particles(np.stack([(ix + 0.5) * dl, R + 2 * R * iy, (iz + 0.5) * dl], -1).reshape(-1, 3), 0.0, R, RHO)
    for _ in range(60):
        assert s.step(50).ok
        s.vel[:] = 0.0
    assert s.step(200).ok
    return s, dl, L


def test_hydrostatic_column():
    s, dl, L = _column()
    ys = np.unique(np.round(s.pos[:, 1], 9))
    dy = np.diff(ys).mean()
    rho_b = s.mass[0] / (dl * dl * dy)
    H = ys[-1] + 0.5 * dy  # the top of the top layer's cell
    w = 1.5 * R
    f = coarse_grain(s, [0, 0, 0], [L, H + 4 * w, L], [dl / 2, R / 2, dl / 2], w)
    y = f.centres(1)
    pv = -f.profile(f.stress[..., 1, 1], 1)
    bulk = (y > 3 * w) & (y < H - 3 * w)
    assert bulk.sum() >= 20
    err = np.abs(pv[bulk] / (rho_b * G * (H - y[bulk])) - 1)
    assert err.max() < 0.01  # measured 3.5e-4
    assert np.abs(f.profile(f.density, 1)[bulk] / rho_b - 1).max() < 0.005  # truncation ripple 2.2e-3
    assert np.abs(f.kinetic_stress).max() < 1e-6 * pv.max()
    # the edges: the floor's cells get part of the kernel (open), the correction restores them
    assert f.profile(f.density, 1)[0] < 0.7 * rho_b
    g = coarse_grain(s, [0, 0, 0], [L, H + 4 * w, L], [dl / 2, R / 2, dl / 2], w, edges="correct")
    assert abs(g.profile(g.density, 1)[0] / rho_b - 1) < 0.05
    # Janssen with no wall friction is the hydrostatic line
    jz = janssen(y, H, rho_b * G, L, L, 0.5, 1e-9, 1e-9)
    assert np.allclose(jz[bulk], rho_b * G * (H - y[bulk]), rtol=1e-6)


def test_janssen_limits():
    K = lateral_pressure_ratio(np.tan(np.radians(30)))
    assert abs(K - 1 / 3) < 1e-12
    W, T, mu_s, mu_f, gamma = 0.15, 0.04, 0.3, 0.2, 5000.0
    zc = W * T / (2 * K * (mu_s * T + mu_f * W))
    deep = janssen(np.array([-100.0]), 0.3, gamma, W, T, K, mu_s, mu_f)
    assert abs(deep[0] / (gamma * zc) - 1) < 1e-12  # the asymptote
    assert janssen(np.array([0.31]), 0.3, gamma, W, T, K, mu_s, mu_f)[0] == 0.0


def test_bad_input_names_the_key():
    s = _pair_system()
    with pytest.raises(CaseError, match="width"):
        coarse_grain(s, [0.0] * 3, [0.04] * 3, 0.004, 0.0005)
    with pytest.raises(CaseError, match="edges"):
        coarse_grain(s, [0.0] * 3, [0.04] * 3, 0.002, R, edges="mirror")
    with pytest.raises(CaseError, match="lo/hi"):
        coarse_grain(s, [0.0] * 3, [0.04, 0.0, 0.04], 0.002, R)


def test_command_on_a_run_checkpoint(tmp_path, root):
    import h5py

    from cfddem.cli import main
    from cfddem.config import load_case
    from cfddem.simulation import run_case

    case = load_case(root / "cases" / "box_small", overrides=["checkpoint.interval=0.01"])
    run_case(case, out_dir=tmp_path / "run", echo=False, progress=False)
    out = tmp_path / "cg"
    assert main(["coarse-grain", str(tmp_path / "run"), "--width", "0.002", "--spacing", "0.001",
                 "--out", str(out), "--janssen", "0.3,0.2", "--phi", "30"]) == 0
    with h5py.File(out / "coarse.h5", "r") as f:
        m = f["density"][()].sum() * np.prod(f.attrs["spacing"])
        assert abs(m / f.attrs["total_mass"] - 1) < 1e-10
        assert f["stress"].shape[-2:] == (3, 3)
    for name in ("coarse.vtu", "vertical_profile.csv", "vertical_stress.png"):
        assert (out / name).stat().st_size > 0
    # bad input: one line, exit code 2
    assert main(["coarse-grain", str(tmp_path), "--out", str(out)]) == 2
    assert main(["coarse-grain", str(tmp_path / "run"), "--spacing", "1,2", "--out", str(out)]) == 2


def test_janssen_frictionless_walls_is_hydrostatic():
    from cfddem.measure.coarse import janssen, janssen_length

    assert janssen_length(0.08, 0.04, 0.5, 0.0, 0.0) == math.inf
    z = np.array([0.0, 0.05, 0.1, 0.2])
    np.testing.assert_allclose(janssen(z, 0.1, 5000.0, 0.08, 0.04, 0.5, 0.0, 0.0), [500.0, 250.0, 0.0, 0.0], rtol=1e-14)
    assert janssen_length(0.08, 0.04, 0.5, 0.17, 0.2) == pytest.approx(0.08 * 0.04 / (2 * 0.5 * (0.17 * 0.04 + 0.2 * 0.08)))
