"""Staggered grid, located fields and the tiny operators (cfddem.gas.grid / operators)."""

import numpy as np
import pytest

from cfddem.gas import StaggeredGrid
from cfddem.gas import operators as op
from cfddem.gas.grid import Field


pytestmark = [pytest.mark.usefixtures("one_numba_thread"),
              pytest.mark.nojit]  # also run as plain Python (tests/unit/test_nojit_tier.py)


def make_grid(shape=(5, 4, 3), halo=2):
    return StaggeredGrid(shape, (1.0, 0.8, 0.6), origin=(-0.3, 0.1, 2.0), halo=halo)


def test_coordinates_and_shapes():
    g = make_grid()
    assert g.spacing == pytest.approx((0.2, 0.2, 0.2))
    assert g.centres(0)[0] == pytest.approx(-0.2)
    assert g.faces(2)[-1] == pytest.approx(2.6)
    assert g.array_shape("fcc") == (10, 8, 7)
    assert g.array_shape("ccf") == (9, 8, 8)
    # halo coordinates continue the uniform spacing
    assert np.allclose(np.diff(g.coords("cfc", 1)), 0.2)
    assert g.coords("cfc", 1)[g.halo] == pytest.approx(0.1)
    assert g.coords("ccc", 0)[g.halo] == pytest.approx(-0.2)


def test_field_location_mismatch_raises():
    g = make_grid()
    u, p = g.zeros("fcc"), g.zeros("ccc")
    with pytest.raises(ValueError, match="location mismatch"):
        u + p
    with pytest.raises(ValueError, match="location mismatch"):
        p -= u
    with pytest.raises(ValueError, match="location"):
        Field(g, "xyz")
    with pytest.raises(ValueError, match="array shape"):
        Field(g, "fcc", np.zeros(g.array_shape("ccc")))
    s = u + u * 2.0
    assert s.location == "fcc"
    other = StaggeredGrid((5, 4, 4), (1.0, 0.8, 0.6))
    with pytest.raises(ValueError):
        other.zeros("ccc") + p


def _fill(g, loc, f):
    X, Y, Z = g.mesh(loc, with_halo=True)
    return Field(g, loc, f(X, Y, Z))


@pytest.mark.parametrize("d", [0, 1, 2])
def test_operators_exact_for_linear_fields(d):
    g = make_grid()
    coef = (1.3, -0.7, 2.1)
    lin = lambda X, Y, Z: 0.4 + coef[0] * X + coef[1] * Y + coef[2] * Z  # noqa: E731
    p = _fill(g, "ccc", lin)
    floc = ("fcc", "cfc", "ccf")[d]
    exact_face = _fill(g, floc, lin)
    sl = g.interior(floc)
    assert np.allclose(op.interp_to_face(p, d).data[sl], exact_face.data[sl], atol=1e-13, rtol=0)
    assert np.allclose(op.grad_to_face(p, d).data[sl], coef[d], atol=1e-12, rtol=0)
    f = _fill(g, floc, lin)
    ci = g.interior("ccc")
    assert np.allclose(op.interp_to_centre(f, d).data[ci], p.data[ci], atol=1e-13, rtol=0)
    assert np.allclose(op.diff_to_centre(f, d).data[ci], coef[d], atol=1e-12, rtol=0)


def test_divergence_and_porous_divergence_exact_for_linear_fields():
    g = make_grid()
    u = _fill(g, "fcc", lambda X, Y, Z: 1.0 + 2.0 * X - Y)
    v = _fill(g, "cfc", lambda X, Y, Z: 0.5 - 3.0 * Y + Z)
    w = _fill(g, "ccf", lambda X, Y, Z: 4.0 * Z + X)
    ci = g.interior("ccc")
    assert np.allclose(op.divergence(u, v, w).data[ci], 2.0 - 3.0 + 4.0, atol=1e-12, rtol=0)
    # div(eps U) with constant U and linear eps: U . grad(eps)
    U = (0.3, -1.1, 0.7)
    uc, vc, wc = (_fill(g, loc, lambda X, Y, Z, c=c: 0 * X + c) for loc, c in zip(("fcc", "cfc", "ccf"), U))
    eps = _fill(g, "ccc", lambda X, Y, Z: 0.6 + 0.1 * X - 0.2 * Y + 0.05 * Z)
    expect = U[0] * 0.1 - U[1] * 0.2 + U[2] * 0.05
    assert np.allclose(op.porous_divergence(uc, vc, wc, eps).data[ci], expect, atol=1e-12, rtol=0)
    with pytest.raises(ValueError):
        op.divergence(v, u, w)


def test_gradient_second_order_for_smooth_field():
    errs = []
    for n in (8, 16, 32):
        g = StaggeredGrid((n, 2, 2), (1.0, 1.0, 1.0))
        p = _fill(g, "ccc", lambda X, Y, Z: np.sin(2 * np.pi * X))
        gx = op.gradient(p)[0]
        X = g.mesh("fcc")[0]
        errs.append(np.max(np.abs(gx.interior - 2 * np.pi * np.cos(2 * np.pi * X))))
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(np.abs(orders - 2.0) < 0.1), orders


def _buf(nz):
    """The work rows of step_diagnostics_kernel and their int64 view."""
    b = np.zeros((3, nz))
    return b, b.view(np.int64)


def test_one_pass_defect_equals_divergence_then_defect():
    """The one-pass mass-balance defect of the step diagnostics equals the porous divergence
    kernel followed by the defect kernel, bit for bit, and keeps a NaN."""
    from cfddem.gas.operators import porous_divergence_kernel
    from cfddem.gas.projection import mass_defect_kernel, step_diagnostics_kernel

    rng = np.random.default_rng(7)
    g, (nx, ny, nz) = 1, (5, 4, 6)
    shp = (nx + 2 * g, ny + 2 * g, nz + 2 * g)
    u, v, w = (rng.normal(size=(shp[0] + (c == 0), shp[1] + (c == 1), shp[2] + (c == 2))) for c in range(3))
    en, eo, p = rng.uniform(0.4, 1.0, shp), rng.uniform(0.4, 1.0, shp), np.zeros(shp)
    div = np.zeros(shp)
    porous_divergence_kernel(u, v, w, en, 1 / 0.1, 1 / 0.2, 1 / 0.3, g, nx, ny, nz, div)
    ref = mass_defect_kernel(div, en, eo, 1e-3, g, nx, ny, nz)
    d = step_diagnostics_kernel(u, v, w, p, en, eo, 1 / 0.1, 1 / 0.2, 1 / 0.3, 1e-3, g, nx, ny, nz, *_buf(nz))[0]
    assert ref > 0 and d == ref
    w[2, 2, 3] = np.nan
    assert np.isnan(step_diagnostics_kernel(u, v, w, p, en, eo, 10.0, 5.0, 1 / 0.3, 1e-3, g, nx, ny, nz, *_buf(nz))[0])


def test_local_advective_rate_takes_each_cell_own_faces():
    """The local rate is the largest per-cell sum of the larger of each axis' two face speeds
    over h; it is below the sum of the per-axis maxima when those sit in different cells."""
    from cfddem.gas.projection import local_advective_rate_kernel

    g, (nx, ny, nz) = 1, (3, 4, 5)
    u = np.zeros((nx + 3, ny + 2, nz + 2))
    v = np.zeros((nx + 2, ny + 3, nz + 2))
    w = np.zeros((nx + 2, ny + 2, nz + 3))
    u[2, 1, 1] = -1.0           # x-face between cells (0,0,0) and (1,0,0)
    w[3, 4, 5] = 3.0            # z-face between cells (2,3,3) and (2,3,4)
    v[3, 4, 5] = 0.5            # y-face between cells (2,2,4) and (2,3,4)
    rdx, rdy, rdz = 1 / 0.1, 1 / 0.2, 1 / 0.3
    r = local_advective_rate_kernel(u, v, w, rdx, rdy, rdz, g, nx, ny, nz)
    assert r == pytest.approx(3.0 * rdz + 0.5 * rdy)  # cell (2,3,4) holds w and v: 12.5 > 10 (u)
    assert r < 1.0 * rdx + 0.5 * rdy + 3.0 * rdz
    u[0, 0, 0] = 1e9            # halo entries do not count
    assert local_advective_rate_kernel(u, v, w, rdx, rdy, rdz, g, nx, ny, nz) == r
    w[2, 2, 2] = np.nan
    assert np.isnan(local_advective_rate_kernel(u, v, w, rdx, rdy, rdz, g, nx, ny, nz))


def test_fused_step_kernels_equal_the_separate_ones():
    """The gas step's one-pass kernels give the numbers of the separate ones bit for bit: the
    pressure right-hand side from the velocity (= porous divergence, then the formula), and
    the end-of-step diagnostics (= mass defect, local advective rate, max |p|), NaN kept."""
    from cfddem.gas.operators import porous_divergence_kernel
    from cfddem.gas.projection import (local_advective_rate_kernel, mass_defect_kernel, pressure_rhs_kernel,
                                       step_diagnostics_kernel)

    rng = np.random.default_rng(8)
    g, (nx, ny, nz) = 2, (5, 4, 7)
    shp = (nx + 2 * g, ny + 2 * g, nz + 2 * g)
    u, v, w = (rng.normal(size=(shp[0] + (c == 0), shp[1] + (c == 1), shp[2] + (c == 2))) for c in range(3))
    en, eo, p = rng.uniform(0.4, 1.0, shp), rng.uniform(0.4, 1.0, shp), rng.normal(size=shp)
    p[0, 0, 0] = 1e9  # a halo entry: not counted
    r = (1 / 0.1, 1 / 0.2, 1 / 0.3)
    dt, rho = 1e-3, 1.2
    div = np.zeros(shp)
    porous_divergence_kernel(u, v, w, en, *r, g, nx, ny, nz, div)
    ci = (slice(g, g + nx), slice(g, g + ny), slice(g, g + nz))
    ref = (-rho / dt) * (div[ci] + (en[ci] - eo[ci]) / dt)
    b = np.zeros((nx, ny, nz))
    pressure_rhs_kernel(u, v, w, en, eo, *r, dt, rho, g, b)
    assert np.array_equal(b, ref)
    d, rate, pm = step_diagnostics_kernel(u, v, w, p, en, eo, *r, dt, g, nx, ny, nz, *_buf(nz))
    assert d == mass_defect_kernel(div, en, eo, dt, g, nx, ny, nz) and d > 0
    assert rate == local_advective_rate_kernel(u, v, w, *r, g, nx, ny, nz) and rate > 0
    assert pm == np.max(np.abs(p[ci]))
    w[3, 3, 4] = np.nan
    p[3, 3, 3] = np.nan
    d, rate, pm = step_diagnostics_kernel(u, v, w, p, en, eo, *r, dt, g, nx, ny, nz, *_buf(nz))
    assert np.isnan(d) and np.isnan(rate) and np.isnan(pm)
    w[3, 3, 4] = -np.inf  # infinite, not NaN: inf (the maxima are taken on the bit patterns)
    p[3, 3, 3] = -np.inf
    d, rate, pm = step_diagnostics_kernel(u, v, w, p, en, eo, *r, dt, g, nx, ny, nz, *_buf(nz))
    assert np.isinf(d) and rate == np.inf and pm == np.inf
