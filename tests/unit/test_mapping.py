"""Particle-grid mapping: weights, exact interpolation, conservation, adjointness, walls,
porosity reporting, thread independence."""

import numba
import numpy as np
import pytest

from cfddem.coupling import mapping as M
from cfddem.errors import CaseError

SPEC = M.GridSpec((-0.02, 0.0, 0.1), (0.01, 0.0075, 0.0125), (4, 3, 5))
LO = np.array(SPEC.origin)
L = np.array(SPEC.spacing) * np.array(SPEC.shape)
PERIODICS = [(False, False, False), (True, False, False), (False, True, True), (True, True, True)]


def random_points(rng, n, margin=0.0):
    return LO + margin + rng.uniform(size=(n, 3)) * (L - 2 * margin)


def node_coords(location, axis, spec=SPEC):
    n, h, o = spec.shape[axis], spec.spacing[axis], spec.origin[axis]
    if location[axis] == "f":
        return o + np.arange(n + 1) * h
    return o + (np.arange(n) + 0.5) * h


def test_hand_computed_weights():
    spec = M.GridSpec((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), (4, 4, 4))
    # centres at 0.5, 1.5, ...: point (1.0, 1.75, 2.5) -> x: cells 0,1 (0.5, 0.5);
    # y: cells 1,2 (0.75, 0.25); z: cells 2 only (1.0, 0.0)
    idx, w = M.trilinear_weights(spec, np.array([[1.0, 1.75, 2.5]]))
    got = {}
    for c in range(8):
        got[tuple(idx[0, c])] = got.get(tuple(idx[0, c]), 0.0) + w[0, c]
    expect = {(0, 1, 2): 0.375, (0, 2, 2): 0.125, (1, 1, 2): 0.375, (1, 2, 2): 0.125,
              (0, 1, 3): 0.0, (0, 2, 3): 0.0, (1, 1, 3): 0.0, (1, 2, 3): 0.0}
    assert got == pytest.approx(expect, abs=1e-15)
    # x-faces at 0, 1, 2, ...: same point -> x face 1 only; y,z centres as before
    idx, w = M.trilinear_weights(spec, np.array([[1.0, 1.75, 2.5]]), "fcc")
    mask = w[0] > 0
    assert set(map(tuple, idx[0][mask])) == {(1, 1, 2), (1, 2, 2)}
    assert w[0][mask].sum() == pytest.approx(1.0, abs=1e-15)


@pytest.mark.parametrize("periodic", PERIODICS)
@pytest.mark.parametrize("location", M.LOCATIONS)
def test_weights_sum_to_one_and_stay_on_updated_nodes(location, periodic):
    rng = np.random.default_rng(1)
    pts = random_points(rng, 500)
    # add points on and near the walls and slightly outside
    edge = LO + rng.integers(0, 2, size=(200, 3)) * L + rng.uniform(-1e-3, 1e-3, size=(200, 3))
    pts = np.vstack([pts, edge])
    idx, w = M.trilinear_weights(SPEC, pts, location, periodic)
    assert np.all(w >= 0)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, rtol=0, atol=4e-16)
    for a in range(3):
        n = SPEC.shape[a]
        if periodic[a]:
            lo, hi = 0, n - 1
        elif location[a] == "f":
            lo, hi = 1, n - 1  # boundary faces never get weight
        else:
            lo, hi = 0, n - 1
        assert idx[:, :, a].min() >= lo and idx[:, :, a].max() <= hi


@pytest.mark.parametrize("location", M.LOCATIONS)
def test_linear_field_interpolated_exactly_inside(location):
    rng = np.random.default_rng(2)
    X, Y, Z = np.meshgrid(*(node_coords(location, a) for a in range(3)), indexing="ij")
    c = (0.3, -1.7, 2.9, 0.8)
    field = c[0] + c[1] * X + c[2] * Y + c[3] * Z
    # interior points: no fold active (half a cell from walls for centres, a cell for faces)
    margin = np.array([SPEC.spacing[a] * (1.0 if location[a] == "f" else 0.5) for a in range(3)])
    pts = LO + margin + rng.uniform(size=(400, 3)) * (L - 2 * margin)
    got = M.interpolate(SPEC, field, pts, location)
    exact = c[0] + pts @ np.array(c[1:])
    np.testing.assert_allclose(got, exact, rtol=1e-13, atol=1e-15)


@pytest.mark.parametrize("periodic", PERIODICS)
def test_pressure_gradient_exact_for_linear_pressure(periodic):
    rng = np.random.default_rng(3)
    X, Y, Z = np.meshgrid(*(node_coords("ccc", a) for a in range(3)), indexing="ij")
    g = np.array([120.0, -45.0, 9.81])
    for a in range(3):
        if periodic[a]:
            g[a] = 0.0  # a periodic pressure cannot have a mean gradient
    p = 1e5 + X * g[0] + Y * g[1] + Z * g[2]
    pts = random_points(rng, 300)  # everywhere, walls included: the fold keeps it exact
    got = M.gradient_at_particles(SPEC, p, pts, periodic)
    np.testing.assert_allclose(got, np.broadcast_to(g, got.shape), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("periodic", PERIODICS)
def test_deposit_conserves_momentum(periodic):
    rng = np.random.default_rng(4)
    pts = np.vstack([random_points(rng, 3000), LO + rng.uniform(size=(50, 3)) * L * np.array([1e-3, 1, 1])])
    f = rng.normal(size=(pts.shape[0], 3)) * 1e-3
    su, sv, sw = M.deposit_faces(SPEC, pts, f, periodic)
    assert su.shape == (5, 3, 5) and sv.shape == (4, 4, 5) and sw.shape == (4, 3, 6)
    tot = np.array([su.sum(), sv.sum(), sw.sum()])
    ref = f.sum(axis=0)
    assert np.all(np.abs(tot - ref) <= 1e-13 * np.abs(f).sum(axis=0))
    # walls: boundary faces receive nothing; periodic: face n stays empty
    for s, a in ((su, 0), (sv, 1), (sw, 2)):
        n = SPEC.shape[a]
        first = np.take(s, 0, axis=a)
        last = np.take(s, n, axis=a)
        assert np.all(last == 0.0)
        if not periodic[a]:
            assert np.all(first == 0.0)


@pytest.mark.parametrize("periodic", PERIODICS)
def test_deposit_and_interpolate_are_adjoint(periodic):
    rng = np.random.default_rng(5)
    pts = random_points(rng, 700)
    f = rng.normal(size=(700, 3))
    fields = [rng.normal(size=M.node_shape(SPEC, loc)) for loc in ("fcc", "cfc", "ccf")]
    dep = M.deposit_faces(SPEC, pts, f, periodic)
    lhs = sum(float(np.sum(d * u)) for d, u in zip(dep, fields))
    up = M.interpolate_faces(SPEC, *fields, pts, periodic)
    rhs = float(np.sum(f * up))
    assert abs(lhs - rhs) <= 1e-12 * np.sum(np.abs(f)) * max(np.abs(u).max() for u in fields)
    # centres too
    val = rng.normal(size=700)
    cf = rng.normal(size=SPEC.shape)
    lhs = float(np.sum(M.deposit(SPEC, pts, val, "ccc", periodic) * cf))
    rhs = float(np.sum(val * M.interpolate_centres(SPEC, cf, pts, periodic)))
    assert abs(lhs - rhs) <= 1e-12 * np.sum(np.abs(val)) * np.abs(cf).max()


def test_deposit_equals_numpy_scatter():
    """The serial scatter kernel gives what numpy's add.at with the same weights gives."""
    rng = np.random.default_rng(6)
    pts = random_points(rng, 2000)
    val = rng.uniform(size=2000)
    for loc in M.LOCATIONS:
        for per in PERIODICS:
            idx, w = M.trilinear_weights(SPEC, pts, loc, per)
            ref = np.zeros(M.node_shape(SPEC, loc))
            np.add.at(ref, (idx[..., 0].ravel(), idx[..., 1].ravel(), idx[..., 2].ravel()), (w * val[:, None]).ravel())
            got = M.deposit(SPEC, pts, val, loc, per)
            np.testing.assert_allclose(got, ref, rtol=1e-13, atol=1e-15)


def test_periodic_wrap():
    spec = M.GridSpec((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), (4, 2, 2))
    # x = 0.1: centre grid, between cell 3 (image at -0.5) and cell 0 (0.5): 0.4 / 0.6
    pt = np.array([[0.1, 0.5, 0.5]])
    s = M.deposit(spec, pt, np.array([1.0]), "ccc", (True, False, False))
    assert s[3].sum() == pytest.approx(0.4, abs=1e-15) and s[0].sum() == pytest.approx(0.6, abs=1e-15)
    # same point shifted by a period lands on the same nodes
    s2 = M.deposit(spec, pt + [[4.0, 0, 0]], np.array([1.0]), "ccc", (True, False, False))
    np.testing.assert_allclose(s2, s, atol=1e-15)
    # x-faces, periodic: x = 3.75 -> faces 3 (0.25) and 4 == 0 (0.75), face 4 stays empty
    su = M.deposit(spec, np.array([[3.75, 0.5, 0.5]]), np.array([1.0]), "fcc", (True, False, False))
    assert su[0].sum() == pytest.approx(0.75) and su[3].sum() == pytest.approx(0.25) and su[4].sum() == 0.0
    # interpolation reads face 0 for face 4
    u = np.zeros((5, 2, 2))
    u[0] = 2.0
    u[3] = 1.0
    assert M.interpolate(spec, u, np.array([[3.75, 0.5, 0.5]]), "fcc", (True, False, False))[0] == pytest.approx(1.75)


def test_particle_against_wall_keeps_whole_volume():
    spec = M.GridSpec((0.0, 0.0, 0.0), (0.01, 0.01, 0.01), (3, 3, 3))
    r = 0.0015
    # touching the x = 0 wall, in the y = 0 / z = 0 corner, and at the top corner
    pts = np.array([[r, 0.015, 0.015], [r, r, r], [0.03 - r, 0.03 - r, 0.03 - r], [0.015, 0.015, 0.015]])
    res = M.porosity(spec, pts, r)
    vol = 4.0 / 3.0 * np.pi * r**3
    assert res.solid_volume == pytest.approx(4 * vol, rel=1e-14)
    assert np.sum((1.0 - res.eps) * spec.cell_volume) == pytest.approx(4 * vol, rel=1e-12)
    # the corner particle's whole volume is in cell (0, 0, 0)
    one = M.porosity(spec, pts[1:2], r)
    assert (1.0 - one.eps[0, 0, 0]) * spec.cell_volume == pytest.approx(vol, rel=1e-12)
    assert np.count_nonzero(one.eps < 1.0) == 1
    assert one.n_outside == 0
    # centre outside the box (e.g. about to be removed at the exit): clamped, counted
    out = M.porosity(spec, np.array([[0.015, 0.015, 0.0305]]), r)
    assert out.n_outside == 1 and out.solid_volume == pytest.approx(vol, rel=1e-14)
    # drag reaction next to the wall: the whole force reaches interior faces
    su, sv, sw = M.deposit_faces(spec, pts, np.ones((4, 3)))
    assert su[1:3].sum() == pytest.approx(4.0, rel=1e-14) and su[0].sum() == 0 and su[3].sum() == 0


def random_dilute(rng, spec, n, r):
    lo = np.array(spec.origin)
    hi = lo + np.array(spec.spacing) * np.array(spec.shape)
    pts = []
    while len(pts) < n:
        p = lo + r + rng.uniform(size=3) * (hi - lo - 2 * r)
        if all(np.sum((p - q) ** 2) >= (2 * r) ** 2 for q in pts):
            pts.append(p)
    return np.array(pts)


def test_porosity_small_cells_dilute_and_reported_dense():
    rng = np.random.default_rng(7)
    d = 3e-3
    spec = M.GridSpec((0.0, 0.0, 0.0), (2.5e-3, 2.5e-3, 2.5e-3), (8, 8, 8))  # cells < d
    pts = random_dilute(rng, spec, 150, d / 2)  # ~ 8 % solid
    res = M.porosity(spec, pts, d / 2)
    vols = 150 * np.pi * d**3 / 6
    assert res.solid_volume == pytest.approx(vols, rel=1e-13)
    assert np.all(res.eps > 0.0) and np.all(res.eps <= 1.0)
    assert res.n_negative == 0 and res.eps_min_found == res.eps.min()
    assert res.n_low == np.count_nonzero(res.eps < 0.3)
    assert 0.0 < res.eps_min_found < 0.95  # really small cells: noisy, but positive
    # dense clump of particles in cells much smaller than a particle: reported, not clipped
    tiny = M.GridSpec((0.0, 0.0, 0.0), (1e-3, 1e-3, 1e-3), (8, 8, 8))
    clump = 4e-3 + np.array([[0, 0, 0], [d, 0, 0], [0, d, 0], [0, 0, d]]) * 0.999
    res = M.porosity(tiny, clump, d / 2, eps_min=0.3)
    assert res.n_negative > 0 and res.eps_min_found < 0.0
    assert res.eps_min_found == res.eps.min() and res.eps[res.where] == res.eps_min_found
    assert res.n_low == np.count_nonzero(res.eps < 0.3) >= res.n_negative
    assert res.solid_volume == pytest.approx(4 * np.pi * d**3 / 6, rel=1e-13)


def test_one_cell_wall_axis_drops_normal_component():
    spec = M.GridSpec((0.0, 0.0, 0.0), (0.01, 0.01, 0.01), (3, 3, 1))  # quasi-2D in z
    pts = np.array([[0.012, 0.017, 0.004]])
    su, sv, sw = M.deposit_faces(spec, pts, np.array([[1.0, 2.0, 3.0]]))
    assert su.sum() == pytest.approx(1.0) and sv.sum() == pytest.approx(2.0) and np.all(sw == 0)
    up = M.interpolate_faces(spec, np.ones((4, 3, 1)), np.ones((3, 4, 1)), np.ones((3, 3, 2)), pts)
    np.testing.assert_allclose(up, [[1.0, 1.0, 0.0]])


def test_grid_spec_input_and_errors():
    class G:  # duck-typed like cfddem.gas.grid.StaggeredGrid
        origin, spacing, shape = SPEC

    rng = np.random.default_rng(8)
    pts = random_points(rng, 20)
    a = M.porosity(G(), pts, 1e-3).eps
    b = M.porosity((SPEC.origin, SPEC.spacing, SPEC.shape), pts, 1e-3).eps
    c = M.porosity(dict(origin=SPEC.origin, spacing=SPEC.spacing, shape=SPEC.shape), pts, 1e-3).eps
    assert np.array_equal(a, b) and np.array_equal(a, c)
    with pytest.raises(CaseError):
        M.as_grid_spec(((0, 0, 0), (0.1, -1, 0.1), (2, 2, 2)))
    with pytest.raises(CaseError, match="not finite"):
        M.porosity(SPEC, np.array([[0.0, np.nan, 0.1]]), 1e-3)
    with pytest.raises(CaseError, match="interior shape"):
        M.interpolate_centres(SPEC, np.zeros((3, 3, 3)), pts)
    with pytest.raises(CaseError, match="unknown location"):
        M.deposit(SPEC, pts, np.ones(20), "cff")
    # empty particle set
    e = M.porosity(SPEC, np.zeros((0, 3)), 1e-3)
    assert np.all(e.eps == 1.0) and e.solid_volume == 0.0


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs 2 numba threads")
def test_thread_independence_bit_identical():
    rng = np.random.default_rng(9)
    spec = M.GridSpec((0.0, 0.0, 0.0), (0.005, 0.003, 0.006), (16, 15, 30))
    lo = np.zeros(3)
    hi = np.array(spec.spacing) * np.array(spec.shape)
    pts = lo + rng.uniform(size=(40000, 3)) * hi
    f = rng.normal(size=(40000, 3))
    u = [rng.normal(size=M.node_shape(spec, loc)) for loc in ("fcc", "cfc", "ccf")]
    prev = numba.get_num_threads()
    results = []
    try:
        for nt in (1, 2):
            numba.set_num_threads(nt)
            por = M.porosity(spec, pts, 1.5e-3, (True, False, False))
            dep = M.deposit_faces(spec, pts, f, (True, False, False))
            itp = M.interpolate_faces(spec, *u, pts, (True, False, False))
            results.append((por.eps, *dep, itp))
    finally:
        numba.set_num_threads(prev)
    for a, b in zip(*results):
        assert np.array_equal(a, b)


def test_plan_reuses_weights_and_matches_functions():
    rng = np.random.default_rng(10)
    pts = random_points(rng, 500)
    per = (True, False, False)
    f = rng.normal(size=(500, 3))
    u = [rng.normal(size=M.node_shape(SPEC, loc)) for loc in ("fcc", "cfc", "ccf")]
    p = rng.normal(size=SPEC.shape)
    plan = M.MappingPlan(SPEC, pts, per)
    a = plan.porosity(1e-3)
    b = M.porosity(SPEC, pts, 1e-3, per)
    assert np.array_equal(a.eps, b.eps) and a[1:] == b[1:]
    for x, y in zip(plan.deposit_faces(f), M.deposit_faces(SPEC, pts, f, per)):
        assert np.array_equal(x, y)
    assert np.array_equal(plan.interpolate_faces(*u), M.interpolate_faces(SPEC, *u, pts, per))
    assert np.array_equal(plan.gradient(p), M.gradient_at_particles(SPEC, p, pts, per))
    w_before = plan.weights("fcc")
    plan.deposit_faces(f)
    assert plan.weights("fcc") is w_before  # cached, not recomputed


@pytest.mark.parametrize("periodic", [(False, False, False), (True, False, True)])
def test_fused_coupling_kernels_match_single_field_methods_and_threads(periodic):
    """interpolate_slip, deposit_drag and particle_forces: the same numbers as the single-field
    methods with the numpy formulas (interpolations bit-identical, deposits to round-off),
    bit-identical for 1 and 2 threads, also when reusing a workspace."""
    rng = np.random.default_rng(11)
    n = 3000
    pts = random_points(rng, n)
    vel = rng.normal(size=(n, 3))
    d = rng.uniform(1e-3, 3e-3, n)
    keff = rng.uniform(0.0, 1e-3, n)
    vol = np.pi * d**3 / 6.0
    eps = rng.uniform(0.3, 1.0, SPEC.shape)
    u = [rng.normal(size=M.node_shape(SPEC, loc)) for loc in ("fcc", "cfc", "ccf")]
    G = [rng.normal(size=SPEC.shape) for _ in range(3)]
    Gb = []
    for c in range(3):  # boundary fields: nonzero in the first and last layers only
        g = np.zeros(SPEC.shape)
        sl = [slice(None)] * 3
        sl[c] = [0, SPEC.shape[c] - 1]
        g[tuple(sl)] = rng.normal(size=g[tuple(sl)].shape)
        Gb.append(g)
    Gb[1] = None
    rho, mu = 1.2, 1.8e-5
    plan = M.MappingPlan(SPEC, pts, periodic)
    eps_ref = np.clip(plan.interpolate(eps, "ccc"), 1e-12, 1.0)
    ua = plan.interpolate_faces(*u)
    re_ref = eps_ref * rho * np.sqrt(np.sum((ua - vel) ** 2, axis=1)) * d / mu
    dk_ref = plan.deposit_faces(np.repeat(keff[:, None], 3, axis=1))
    dkv_ref = plan.deposit_faces(keff[:, None] * vel)
    fd_ref = keff[:, None] * (ua - vel)
    fp_ref = np.stack([-vol * plan.interpolate(G[c], "ccc") for c in range(3)], axis=1)
    fb_ref = np.stack([-vol * plan.interpolate(Gb[c], "ccc") if Gb[c] is not None else np.zeros(n)
                       for c in range(3)], axis=1)
    prev = numba.get_num_threads()
    runs = []
    ws = {}
    try:
        for nt in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
            numba.set_num_threads(nt)
            p = M.MappingPlan(SPEC, pts, periodic, workspace=ws)
            e_a, re = (x.copy() for x in p.interpolate_slip(eps, *u, vel, d, rho, mu))
            dk, dkv = (tuple(a.copy() for a in t) for t in p.deposit_drag(keff, vel))
            f = {k: v.copy() for k, v in p.particle_forces(*u, vel, keff, vol, G, Gb).items()}
            out = np.full((n, 3), np.nan)
            sums = p.apply_forces(*u, vel, keff, vol, G, Gb, out)
            f["applied"] = out
            for key in ("fd", "fp", "fb"):
                f["sum_" + key] = sums[key]
            f["sum_power"] = np.array(sums["power"])
            f["max_magnitude"] = np.array(sums["max_magnitude"])
            runs.append((e_a, re, dk, dkv, f))
    finally:
        numba.set_num_threads(prev)
    e_a, re, dk, dkv, f = runs[0]
    assert np.array_equal(e_a, eps_ref)
    np.testing.assert_allclose(re, re_ref, rtol=1e-14, atol=0.0)
    for a, b in zip(dk + dkv, dk_ref + dkv_ref):
        np.testing.assert_allclose(a, b, rtol=1e-13, atol=1e-13 * np.abs(b).max())
    assert np.array_equal(f["fd"], fd_ref) and np.array_equal(f["fp"], fp_ref) and np.array_equal(f["fb"], fb_ref)
    assert np.array_equal(f["total"], fd_ref + fp_ref + fb_ref)
    np.testing.assert_allclose(f["power"].sum(), np.sum(fd_ref * (ua - vel)), rtol=1e-12)
    np.testing.assert_allclose(f["magnitude"], np.linalg.norm(fd_ref, axis=1), rtol=1e-14)
    # apply_forces: the same total, written into the caller's array, and block sums
    assert np.array_equal(f["applied"], f["total"])
    for key, ref in (("fd", fd_ref), ("fp", fp_ref), ("fb", fb_ref)):
        np.testing.assert_allclose(f["sum_" + key], ref.sum(axis=0), rtol=0, atol=1e-13 * np.abs(ref).sum())
    np.testing.assert_allclose(f["sum_power"], np.sum(fd_ref * (ua - vel)), rtol=1e-12)
    assert f["max_magnitude"] == pytest.approx(np.linalg.norm(fd_ref, axis=1).max(), rel=1e-14)
    with pytest.raises(CaseError):
        p.apply_forces(*u, vel, keff, vol, G, Gb, np.zeros((n, 3))[:, ::1].T.copy().T)
    r1, r2 = runs
    assert np.array_equal(r1[0], r2[0]) and np.array_equal(r1[1], r2[1])
    for a, b in zip(r1[2] + r1[3], r2[2] + r2[3]):
        assert np.array_equal(a, b)
    for k in r1[4]:
        assert np.array_equal(r1[4][k], r2[4][k])
