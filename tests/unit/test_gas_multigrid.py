"""Geometric multigrid pressure solver (cfddem.gas.multigrid): V-cycle convergence factor,
symmetry, agreement with a direct solve for every boundary type (both smoothers), singular
systems, thread independence, the coarse operators."""

import numba
import numpy as np
import pytest
import scipy.sparse.linalg as spla

from cfddem.gas import StaggeredGrid
from cfddem.gas.multigrid import MGPressureSolver
from cfddem.gas.pressure import PressureSolver

pytestmark = pytest.mark.usefixtures("one_numba_thread")

N, D, P = "neumann", "dirichlet", "periodic"


def bcs(x, y, z):
    return {"x-": x[0], "x+": x[1], "y-": y[0], "y+": y[1], "z-": z[0], "z+": z[1]}


def face_coefficients(eps, pbc):
    """Arithmetic face mean of a cell field (the gas solver's eps_f); periodic faces n = 0."""
    out = []
    for d, side in enumerate(("x-", "y-", "z-")):
        if pbc[side] == P:
            e = np.concatenate([np.take(eps, [-1], axis=d), eps, np.take(eps, [0], axis=d)], axis=d)
        else:
            e = np.concatenate([np.take(eps, [0], axis=d), eps, np.take(eps, [-1], axis=d)], axis=d)
        n = e.shape[d]
        out.append(0.5 * (np.take(e, range(n - 1), axis=d) + np.take(e, range(1, n), axis=d)))
    return out


def random_system(shape, lengths, pbc, seed):
    rng = np.random.default_rng(seed)
    g = StaggeredGrid(shape, lengths)
    co = face_coefficients(rng.uniform(0.35, 1.0, shape), pbc)
    return g, co, rng


CASES = [
    ((10, 9, 14), bcs((N, N), (N, N), (N, D))),  # chute: walls, outlet at z+
    ((8, 7, 9), bcs((D, N), (N, D), (N, N))),  # Dirichlet on two sides, odd sizes
    ((9, 8, 10), bcs((P, P), (N, N), (D, D))),  # odd periodic axis with Dirichlet
    ((9, 7, 11), bcs((P, P), (P, P), (P, P))),  # fully periodic, odd: singular
    ((8, 6, 10), bcs((N, N), (N, N), (N, N))),  # closed box: singular
    ((12, 10, 1), bcs((P, P), (N, D), (P, P))),  # 2D (one cell thick, periodic)
    ((2, 13, 3), bcs((N, N), (D, N), (P, P))),  # thin, periodic axis of 3
]


CHEB = {"chebyshev": 3, "cheb_ratio": 15.0, "coarsen_ratio": 2.0}


@pytest.mark.parametrize("shape,pbc,smoother", [c + ({},) for c in CASES] + [CASES[0] + (CHEB,), CASES[3] + (CHEB,)])
def test_agrees_with_direct_solve(shape, pbc, smoother):
    g, co, rng = random_system(shape, (0.05, 0.04, 0.07), pbc, seed=sum(shape))
    ref = PressureSolver(g, pbc)
    ref.set_coefficients(*co)  # the independent CSR assembly (singular: cell 0 pinned)
    mg = MGPressureSolver(g, pbc, tol=1e-11, maxiter=100, **smoother)
    mg.set_coefficients(*co)
    b = rng.standard_normal(shape)
    if mg.singular:
        b -= b.mean()
    exact = spla.spsolve(ref.A.tocsc(), b.ravel()).reshape(shape)
    if mg.singular:
        exact -= exact.mean()
    x0 = rng.standard_normal(shape)
    phi, info = mg.solve(b, x0=x0)
    assert info.converged and info.residual <= 1e-11 and 0 < info.iterations < 40
    assert np.max(np.abs(phi - exact)) <= 1e-8 * np.max(np.abs(exact))
    if mg.singular:
        assert abs(phi.mean()) < 1e-12 * np.max(np.abs(phi))
    else:  # the operator itself matches the CSR assembly
        y = rng.standard_normal(shape)
        np.testing.assert_allclose(mg.apply(y), ref.apply(y), rtol=1e-12, atol=1e-12 * np.abs(ref.apply(y)).max())


def test_singular_rhs_mean_is_reported_and_removed():
    pbc = bcs((P, P), (N, N), (P, P))
    g, co, rng = random_system((8, 6, 8), (1.0, 1.0, 1.0), pbc, seed=3)
    mg = MGPressureSolver(g, pbc, tol=1e-10)
    mg.set_coefficients(*co)
    b = rng.standard_normal(g.shape)
    phi, info = mg.solve(b + 0.25)
    phi0, _ = mg.solve(b - b.mean())
    assert info.compatibility == pytest.approx(b.mean() + 0.25, abs=1e-14)
    assert np.max(np.abs(phi - phi0)) < 1e-8 * np.max(np.abs(phi0))


def chute_like(shape=(16, 15, 40), lengths=(0.08, 0.045, 0.24)):
    """A bed of eps 0.45 along the floor (1 cm deep) under free air, plus noise; drag-modified
    coefficients a = eps_f^2/(eps_f + dt K/rho) as the gas solver passes them."""
    pbc = bcs((N, N), (N, N), (N, D))
    g = StaggeredGrid(shape, lengths)
    X, Y, Z = g.mesh("ccc")
    rng = np.random.default_rng(7)
    eps = np.where(Y < 0.01, 0.45, 1.0) + np.where(Y < 0.01, 0.05, 0.0) * rng.uniform(-1, 1, shape)
    co = [e * e / (e + 0.025) for e in face_coefficients(eps, pbc)]
    return g, pbc, co


@pytest.mark.parametrize("ratio,bound", [(1.5, 0.2), (2.0, 0.3)])
def test_vcycle_convergence_factor_on_a_known_solution(ratio, bound):
    """Stationary iteration x <- x + M (b - A x) with one V-cycle as M: the error (against a
    known smooth-plus-rough solution, b from the independent CSR assembly) drops by a factor
    below 0.2 per cycle on the variable-coefficient chute-like problem with the y-only first
    coarsening (coarsen_ratio 1.5, the default; measured 0.17), below 0.3 when all axes of the
    5 x 3 x 6 mm cells are coarsened at once (2.0; measured 0.28, cheaper cycles)."""
    g, pbc, co = chute_like()
    ref = PressureSolver(g, pbc)
    ref.set_coefficients(*co)
    X, Y, Z = g.mesh("ccc")
    exact = np.cos(40 * X) * np.sin(70 * Y) * np.cos(13 * Z) + 0.1 * np.random.default_rng(1).standard_normal(g.shape)
    b = ref.apply(exact)
    mg = MGPressureSolver(g, pbc, coarsen_ratio=ratio)
    mg.set_coefficients(*co)
    x = np.zeros(g.shape)
    errs = []
    for _ in range(8):
        r = (b - mg.apply(x)).ravel() * mg._vol  # the V-cycle works on volume-scaled residuals
        x = x + mg.vcycle(r).reshape(g.shape)
        errs.append(np.linalg.norm(x - exact))
    factors = [errs[i + 1] / errs[i] for i in range(2, 7)]
    assert max(factors) < bound, factors
    assert errs[-1] < 1e-4 * np.linalg.norm(exact)


@pytest.mark.parametrize("precision, sym_tol", [("double", 1e-12), ("single", 1e-6)])
@pytest.mark.parametrize("smoother", [{}, {"chebyshev": 3, "cheb_ratio": 15.0, "coarsen_ratio": 2.0}])
def test_vcycle_is_symmetric_positive_definite(smoother, precision, sym_tol):
    """<M u, v> = <u, M v> and <M u, u> > 0: the V-cycle is a valid CG preconditioner (also
    with an odd periodic axis, where red and black cells touch across the wrap), with the
    red-black Gauss-Seidel and with the Chebyshev smoother.  In float64 symmetric to
    rounding (1e-12 relative); the float32 V-cycle (precision="single") is symmetric only to
    its rounding, about 1e-8 relative measured (float32 epsilon 6e-8), bound 1e-6."""
    for shape, pbc in ((((16, 15, 40), bcs((N, N), (N, N), (N, D)))), ((9, 8, 10), bcs((P, P), (N, N), (D, D)))):
        g, co, rng = random_system(shape, (0.08, 0.045, 0.24), pbc, seed=2)
        mg = MGPressureSolver(g, pbc, precision=precision, **smoother)
        mg.set_coefficients(*co)
        assert len(mg.levels) >= 2
        for _ in range(3):
            u, v = rng.standard_normal(mg.N), rng.standard_normal(mg.N)
            Mu, Mv = mg.vcycle(u), mg.vcycle(v)
            assert abs(Mu @ v - u @ Mv) <= sym_tol * np.linalg.norm(Mu) * np.linalg.norm(v)
            assert Mu @ u > 0


def test_hierarchy_handles_odd_sizes_and_rediscretises():
    """The chute grid (cells 5 x 3 x 6 mm): with coarsen_ratio 1.5 it first coarsens only its
    finest axis (semi-coarsening to 5 x 5.6 x 6 mm), then all three: 16x15x150 -> 16x8x150 ->
    8x4x75 -> 4x2x38 -> 2x1x19 (ceil(n/2) for odd counts), the default; with 2.0 all three at
    once; for a constant coefficient the coarse weights are the re-discretisation a A_F / D_F."""
    g = StaggeredGrid((16, 15, 150), (0.08, 0.045, 0.9))
    mg = MGPressureSolver(g, bcs((N, N), (N, N), (N, D)))
    assert mg.levels == [(16, 15, 150), (16, 8, 150), (8, 4, 75), (4, 2, 38), (2, 1, 19)]
    mg = MGPressureSolver(g, bcs((N, N), (N, N), (N, D)), coarsen_ratio=2.0)
    assert mg.levels == [(16, 15, 150), (8, 8, 75), (4, 4, 38), (2, 2, 19)]
    g = StaggeredGrid((8, 8, 8), (1.0, 1.0, 1.0))
    mg = MGPressureSolver(g, bcs((N, N), (N, N), (D, D)))
    mg.set_coefficients(*(np.full(s, 0.7) for s in mg._fshapes))
    assert mg.levels == [(8, 8, 8), (4, 4, 4)]
    lv = mg._LV
    for l in range(len(mg.levels)):
        nx, ny, nz, off = lv[l]
        H = 1.0 / nx
        cT = mg.level_array("cT", l)
        dZ = mg.level_array("dZ", l)
        np.testing.assert_allclose(cT[:, :, :-1], 0.7 * H, rtol=1e-13)  # a H^2 / H
        assert np.all(cT[:, :, -1] == 0.0)
        np.testing.assert_allclose(dZ[:, :, 0], 0.7 * H * H / (H / 2), rtol=1e-13)  # Dirichlet: a A / (H/2)


@pytest.mark.parametrize("case", [0, 2, 3])
def test_thread_count_does_not_change_the_solution(case):
    """The threaded kernels (smoother, residual, transfers, CG vector operations with
    per-plane partial sums) give bit-identical solutions for 1, 2 and 3 threads, and the same
    as the serial path (par_min above the cell count); case 2 and 3 have an odd periodic x
    axis (red and black cells touch across the wrap)."""
    if case == 0:
        g, pbc, co = chute_like()
    else:
        shape, pbc = CASES[case]
        g, co, _ = random_system(shape, (0.05, 0.04, 0.07), pbc, seed=11)
    b = np.random.default_rng(4).standard_normal(g.shape)
    if not any(v == D for v in pbc.values()):
        b -= b.mean()
    out = []
    for par_min, threads in ((10**9, (1,)), (1, (1, 2, 3))):
        for nt in threads:
            numba.set_num_threads(min(nt, numba.config.NUMBA_NUM_THREADS))
            mg = MGPressureSolver(g, pbc, tol=1e-10, par_min=par_min)
            mg.set_coefficients(*co)
            phi, info = mg.solve(b)
            assert info.converged
            out.append(phi)
    numba.set_num_threads(1)
    for o in out[1:]:
        assert np.array_equal(out[0], o)


def test_agrees_with_amg_on_the_chute_like_problem_and_reports_non_convergence():
    g, pbc, co = chute_like()
    b = np.random.default_rng(5).standard_normal(g.shape)
    amg = PressureSolver(g, pbc, tol=1e-10)
    amg.set_coefficients(*co)
    mg = MGPressureSolver(g, pbc, tol=1e-10)
    mg.set_coefficients(*co)
    pa, ia = amg.solve(b)
    pm, im = mg.solve(b)
    assert ia.converged and im.converged and im.iterations <= ia.iterations
    assert np.max(np.abs(pa - pm)) < 1e-8 * np.max(np.abs(pa))
    mg1 = MGPressureSolver(g, pbc, tol=1e-10, maxiter=1)
    mg1.set_coefficients(*co)
    _, bad = mg1.solve(b)
    assert not bad.converged and bad.iterations == 1 and bad.residual > 1e-10


def test_single_precision_vcycle_meets_the_same_criteria_as_double():
    """precision="single" (float32 V-cycle inside the float64 CG) on the chute-like bed
    problem: the same true relative residual criterion is met, in at most one more
    iteration than with the float64 V-cycle, and the two solutions agree to the tolerance;
    the V-cycles themselves agree to float32 rounding (1e-5 relative)."""
    g, pbc, co = chute_like()
    b = np.random.default_rng(6).standard_normal(g.shape)
    res = {}
    for prec in ("double", "single"):
        mg = MGPressureSolver(g, pbc, tol=1e-10, precision=prec)
        mg.set_coefficients(*co)
        phi, info = mg.solve(b)
        assert info.converged and info.residual <= 1e-10
        r = b - mg.apply(phi)
        assert np.linalg.norm(r) <= 1e-10 * np.linalg.norm(b) * (1 + 1e-9)
        res[prec] = (phi, info.iterations, mg.vcycle(b.ravel()))
    (p2, i2, m2), (p1, i1, m1) = res["double"], res["single"]
    assert i1 <= i2 + 1
    assert np.linalg.norm(p1 - p2) <= 1e-8 * np.linalg.norm(p2)
    assert np.linalg.norm(m1 - m2) <= 1e-5 * np.linalg.norm(m2)
    with pytest.raises(ValueError):
        MGPressureSolver(g, pbc, precision="half")


def test_setup_is_skipped_only_for_identical_coefficients():
    """set_coefficients with the coefficients of the last set-up does nothing (counted); any
    change (one face) rebuilds the whole hierarchy, equal bit for bit to a fresh solver's, in
    both precisions; a NaN coefficient is never taken as unchanged."""
    g, pbc, co = chute_like(shape=(8, 7, 20), lengths=(0.04, 0.021, 0.12))
    for prec in ("double", "single"):
        mg = MGPressureSolver(g, pbc, precision=prec)
        mg.set_coefficients(*co)
        mg.set_coefficients(*[c.copy() for c in co])
        assert mg.n_setups_skipped == 1
        co2 = [c.copy() for c in co]
        co2[1][3, 2, 5] *= 1.5
        mg.set_coefficients(*co2)
        assert mg.n_setups_skipped == 1
        fresh = MGPressureSolver(g, pbc, precision=prec)
        fresh.set_coefficients(*co2)
        for name in ("cE", "cN", "cT", "dX", "dY", "dZ", "dg"):
            for lev in range(len(mg.levels)):
                assert np.array_equal(mg.level_array(name, lev), fresh.level_array(name, lev))
        assert all(np.array_equal(a, b) for a, b in zip(mg._v, fresh._v))
        assert not np.array_equal(mg.level_array("cN", 1), MGPressureSolver(g, pbc).level_array("cN", 1))
        co3 = [c.copy() for c in co2]
        co3[0][3, 2, 5] = np.nan  # an interior x face
        mg.set_coefficients(*co3)
        mg.set_coefficients(*co3)
        assert mg.n_setups_skipped == 1
        phi, info = mg.solve(np.ones(g.shape))
        assert not info.converged


def test_setup_without_comparison_always_rebuilds_and_invalidates_the_stored_copy():
    """``compare=False`` (the coupled gas step) sets up every time, with the same operator as a
    compared set-up; it leaves no stored copy behind, so the next compared call with the
    same coefficients rebuilds too (it must not compare against the older copy), and only the
    call after that is skipped."""
    g, pbc, co = chute_like(shape=(8, 7, 20), lengths=(0.04, 0.021, 0.12))
    co2 = [c.copy() for c in co]
    co2[2][2, 3, 4] *= 2.0
    mg = MGPressureSolver(g, pbc)
    mg.set_coefficients(*co)
    mg.set_coefficients(*co2, compare=False)
    mg.set_coefficients(*co2, compare=False)
    assert mg.n_setups_skipped == 0
    fresh = MGPressureSolver(g, pbc)
    fresh.set_coefficients(*co2)
    assert all(np.array_equal(a, b) for a, b in zip(mg._v, fresh._v))
    for name in ("cE", "cN", "cT", "dZ", "dg"):
        assert np.array_equal(mg.level_array(name, 1), fresh.level_array(name, 1))
    mg.set_coefficients(*co)  # the stored copy is still co's: it must not be trusted
    assert mg.n_setups_skipped == 0
    assert not np.array_equal(mg.level_array("cT", 0), fresh.level_array("cT", 0))
    mg.set_coefficients(*[c.copy() for c in co])
    assert mg.n_setups_skipped == 1


@pytest.mark.parametrize("solver,case", [("mg", 0), ("mg", 4), ("amg", 0)])  # amg solves case 4 (480 cells) at once
def test_scaled_initial_guess_is_the_best_multiple_of_x0(solver, case):
    """``scale_x0``: CG starts from a x0 with a = x0.b / x0.A x0.  A multiple of the solution
    (-2 phi) is then scaled back to phi itself, so the solve stops at once, where the
    unscaled start needs iterations; from an unrelated x0 the scaled start is never farther
    from the solution in the A-norm than x0 or zero, and the result is the same solution."""
    shape, pbc = CASES[case]
    g, co, rng = random_system(shape, (0.05, 0.04, 0.07), pbc, seed=11)
    s = (MGPressureSolver(g, pbc, tol=1e-9) if solver == "mg" else PressureSolver(g, pbc, tol=1e-9))
    s.set_coefficients(*co)
    b = rng.standard_normal(shape)
    if s.singular:
        b -= b.mean()
    phi, info = s.solve(b)
    assert info.converged and info.iterations > 2
    _, plain = s.solve(b, x0=-2.0 * phi)
    again, scaled = s.solve(b, x0=-2.0 * phi, scale_x0=True)
    assert plain.iterations > 2 and scaled.iterations <= 1 and scaled.converged
    np.testing.assert_allclose(again, phi, atol=1e-7 * np.abs(phi).max())

    def a_err(x):  # A-norm of the error (A phi = b)
        e = (x - phi).ravel()
        return float(e @ s.apply(x - phi).ravel())

    x0 = rng.standard_normal(shape)
    a = float(x0.ravel() @ b.ravel()) / float(x0.ravel() @ s.apply(x0).ravel())
    assert a_err(a * x0) <= min(a_err(x0), a_err(np.zeros(shape)))
    out, info = s.solve(b, x0=x0, scale_x0=True)
    assert info.converged
    np.testing.assert_allclose(out, phi, atol=1e-6 * np.abs(phi).max())
