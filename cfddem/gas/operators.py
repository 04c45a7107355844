"""Staggered-grid operators, named by where the result lives: written once here and used by
the gas solver, the particle-to-grid mapping and the momentum exchange.

Array conventions (see :mod:`cfddem.gas.grid`): a face array along direction d has one
more entry along d than a centre array; face array index ``I`` lies between centre array
indices ``I-1`` and ``I``; centre index ``i`` lies between face indices ``i`` and ``i+1``.

Point operators (compiled, inlined into the kernels that call them; the direction is the
unit vector ``(di, dj, dk)``, the indices are signed array indices and are cast to unsigned
where used, so that the calling loops vectorise):

===============================================  ====================================  ======
function                                         formula                               at
===============================================  ====================================  ======
``c2f_interp_at(a, i, j, k, di, dj, dk)``        ``(a[I-1] + a[I]) / 2``               face I
``c2f_diff_at(a, i, j, k, di, dj, dk)``          ``a[I] - a[I-1]``                     face I
``c2f_grad_at(a, i, j, k, di, dj, dk, h)``       ``(a[I] - a[I-1]) / h``               face I
``f2c_interp_at(f, i, j, k, di, dj, dk)``        ``(f[i] + f[i+1]) / 2``               centre i
``f2c_diff_at(f, i, j, k, di, dj, dk)``          ``f[i+1] - f[i]``                     centre i
``porous_divergence_at(u, v, w, e, i, j, k, ..)`` ``sum_d ((e_f f_d)[i+1] - (e_f f_d)[i]) / h_d``,
                                                 ``e_f = c2f_interp_at(e)``            centre i
===============================================  ====================================  ======

``c2f_grad_at`` is the face gradient of a centre field (the pressure gradient of the gas,
the mapping and the exchange); ``c2f_interp_at`` the face value of a centre field (the face
porosity ``eps_f`` everywhere).  The projection kernels fold 1/h into factors they
precompute (the predictor multiplies the face difference by ``1/h``, the correction by
``dt/(rho h)``) and so call ``c2f_diff_at``: dividing by h there instead would change their
results in the last bit.

Array operators (fields with halos, :class:`~cfddem.gas.grid.Field`): ``interp_to_face``,
``grad_to_face``, ``gradient``, ``interp_to_centre``, ``diff_to_centre``, ``divergence``,
``porous_divergence``, and :func:`c2f_gradient` on plain arrays.  Their kernels write only
the entries whose stencil lies inside the input array, and leave the rest of ``out``
untouched, so they can run on arrays with halos.  Second-order accurate on uniform grids and
exact for fields linear in the direction of the operation.  Compiled with
:func:`cfddem._jit.parallel_kernel` (one ``prange`` loop over the first array axis; every
iteration writes its own entries, so the result does not depend on the thread count).
"""

from __future__ import annotations

import numpy as np

from cfddem._jit import kernel, parallel_kernel, prange  # noqa: I001  (before numba: it sets the threading layer)
from numba import uint64 as U

from cfddem.gas.grid import Field


def _offsets(d: int):
    return (1 if d == 0 else 0, 1 if d == 1 else 0, 1 if d == 2 else 0)


# ---- point operators ------------------------------------------------------------------
@kernel(inline="always")
def c2f_interp_at(a, i, j, k, di, dj, dk):
    """Centre field a at the face (i, j, k) normal to (di, dj, dk): ``(a[I-1] + a[I]) / 2``."""
    return 0.5 * (a[U(i - di), U(j - dj), U(k - dk)] + a[U(i), U(j), U(k)])


@kernel(inline="always")
def c2f_diff_at(a, i, j, k, di, dj, dk):
    """Difference of the centre field a across the face (i, j, k): ``a[I] - a[I-1]``."""
    return a[U(i), U(j), U(k)] - a[U(i - di), U(j - dj), U(k - dk)]


@kernel(inline="always")
def c2f_grad_at(a, i, j, k, di, dj, dk, h):
    """Derivative of the centre field a along (di, dj, dk) at the face (i, j, k), spacing h:
    ``(a[I] - a[I-1]) / h``."""
    return c2f_diff_at(a, i, j, k, di, dj, dk) / h


@kernel(inline="always")
def f2c_interp_at(f, i, j, k, di, dj, dk):
    """Face field f (normal to (di, dj, dk)) at the centre (i, j, k): ``(f[i] + f[i+1]) / 2``."""
    return 0.5 * (f[U(i), U(j), U(k)] + f[U(i + di), U(j + dj), U(k + dk)])


@kernel(inline="always")
def f2c_diff_at(f, i, j, k, di, dj, dk):
    """Difference of the face field f across the centre (i, j, k): ``f[i+1] - f[i]``."""
    return f[U(i + di), U(j + dj), U(k + dk)] - f[U(i), U(j), U(k)]


@kernel(inline="always")
def porous_divergence_at(u, v, w, eps, i, j, k, rdx, rdy, rdz):
    """div(e_f u) at the cell centre (i, j, k) (array indices, at least 1: a halo cell on
    each side): the six face fluxes with the face porosity e_f = :func:`c2f_interp_at` of the
    two cells beside the face.  Indices are cast to unsigned where used (no negative-index
    test, so that the loops calling this vectorise; the same values)."""
    iu, ju, ku = U(i), U(j), U(k)
    fxp = c2f_interp_at(eps, i + 1, j, k, 1, 0, 0) * u[U(i + 1), ju, ku]
    fxm = c2f_interp_at(eps, i, j, k, 1, 0, 0) * u[iu, ju, ku]
    fyp = c2f_interp_at(eps, i, j + 1, k, 0, 1, 0) * v[iu, U(j + 1), ku]
    fym = c2f_interp_at(eps, i, j, k, 0, 1, 0) * v[iu, ju, ku]
    fzp = c2f_interp_at(eps, i, j, k + 1, 0, 0, 1) * w[iu, ju, U(k + 1)]
    fzm = c2f_interp_at(eps, i, j, k, 0, 0, 1) * w[iu, ju, ku]
    return (fxp - fxm) * rdx + (fyp - fym) * rdy + (fzp - fzm) * rdz


# ---- array kernels --------------------------------------------------------------------
@parallel_kernel
def _c2f_interp(a, di, dj, dk, out):
    """out[I] = c2f_interp_at(a, I) wherever face I has both centres in a."""
    n0, n1, n2 = a.shape
    for iu in prange(di, n0):
        i = np.int64(iu)  # (a prange index may be unsigned; mixed with signed ints it types as float)
        for j in range(dj, n1):
            for k in range(dk, n2):
                out[i, j, k] = c2f_interp_at(a, i, j, k, di, dj, dk)


@parallel_kernel
def _c2f_grad(a, di, dj, dk, h, out):
    """out[I] = c2f_grad_at(a, I, h) wherever face I has both centres in a."""
    n0, n1, n2 = a.shape
    for iu in prange(di, n0):
        i = np.int64(iu)
        for j in range(dj, n1):
            for k in range(dk, n2):
                out[i, j, k] = c2f_grad_at(a, i, j, k, di, dj, dk, h)


@parallel_kernel
def _f2c(f, di, dj, dk, scale, mode, out):
    # mode 0: f2c_interp_at; mode 1: f2c_diff_at * scale
    n0, n1, n2 = out.shape
    for iu in prange(n0):
        i = np.int64(iu)
        for j in range(n1):
            for k in range(n2):
                if mode == 0:
                    out[i, j, k] = f2c_interp_at(f, i, j, k, di, dj, dk)
                else:
                    out[i, j, k] = f2c_diff_at(f, i, j, k, di, dj, dk) * scale


@parallel_kernel
def porous_divergence_kernel(u, v, w, eps, rdx, rdy, rdz, g, nx, ny, nz, out):
    """out[c] = div(e_f u) at interior centres (array indices g..g+n-1); e_f arithmetic mean
    (:func:`porous_divergence_at`)."""
    for iu in prange(g, g + nx):
        i = np.int64(iu)
        for j in range(g, g + ny):
            for k in range(g, g + nz):
                out[i, j, k] = porous_divergence_at(u, v, w, eps, i, j, k, rdx, rdy, rdz)


@parallel_kernel
def divergence_kernel(u, v, w, rdx, rdy, rdz, out):
    """out[i,j,k] = div u at every centre whose faces lie inside the arrays."""
    n0, n1, n2 = out.shape
    for iu in prange(n0):
        i = np.int64(iu)
        for j in range(n1):
            for k in range(n2):
                out[i, j, k] = (f2c_diff_at(u, i, j, k, 1, 0, 0) * rdx + f2c_diff_at(v, i, j, k, 0, 1, 0) * rdy
                                + f2c_diff_at(w, i, j, k, 0, 0, 1) * rdz)


def c2f_gradient(a: np.ndarray, d: int, h: float, out: np.ndarray | None = None) -> np.ndarray:
    """The face gradient along d of a centre array a (any halo), :func:`c2f_grad_at` on every
    face with both centres in a: ``out`` has the shape of a plus one along d, and entry I
    along d (1 <= I < a.shape[d]) is ``(a[I] - a[I-1]) / h``; entries 0 and a.shape[d] are
    left as they are (zero in a new array)."""
    a = np.ascontiguousarray(a, dtype=np.float64)
    shape = list(a.shape)
    shape[d] += 1
    if out is None:
        out = np.zeros(shape)
    elif out.shape != tuple(shape):
        raise ValueError(f"c2f_gradient: out has shape {out.shape}, expected {tuple(shape)}")
    _c2f_grad(a, *_offsets(d), float(h), _view_c2f(out, d))
    return out


def _face_loc(d: int) -> str:
    return ("fcc", "cfc", "ccf")[d]


def _require(f: Field, loc: str, what: str) -> None:
    if f.location != loc:
        raise ValueError(f"{what} needs a {loc} field, got {f.location}")


def interp_to_face(a: Field, d: int) -> Field:
    """Centre field -> faces normal to d, (a[I-1] + a[I]) / 2."""
    _require(a, "ccc", "interp_to_face")
    out = a.grid.zeros(_face_loc(d))
    _c2f_interp(a.data, *_offsets(d), _view_c2f(out.data, d))
    return out


def _view_c2f(out: np.ndarray, d: int) -> np.ndarray:
    # the face array has one more entry along d; kernel loops over the centre-array extent
    s = [slice(None)] * 3
    s[d] = slice(0, out.shape[d] - 1)
    return out[tuple(s)]


def grad_to_face(a: Field, d: int) -> Field:
    """Centre field -> derivative along d on the faces normal to d, (a[I] - a[I-1]) / h."""
    _require(a, "ccc", "grad_to_face")
    out = a.grid.zeros(_face_loc(d))
    c2f_gradient(a.data, d, a.grid.spacing[d], out.data)
    return out


def gradient(p: Field) -> tuple:
    """Gradient of a centre field: three face fields (fcc, cfc, ccf)."""
    return tuple(grad_to_face(p, d) for d in range(3))


def interp_to_centre(f: Field, d: int) -> Field:
    """Face field normal to d -> centres, (f[i] + f[i+1]) / 2."""
    _require(f, _face_loc(d), "interp_to_centre")
    out = f.grid.zeros("ccc")
    _f2c(f.data, *_offsets(d), 1.0, 0, out.data)
    return out


def diff_to_centre(f: Field, d: int) -> Field:
    """Face field normal to d -> derivative along d at centres, (f[i+1] - f[i]) / h."""
    _require(f, _face_loc(d), "diff_to_centre")
    out = f.grid.zeros("ccc")
    _f2c(f.data, *_offsets(d), 1.0 / f.grid.spacing[d], 1, out.data)
    return out


def divergence(u: Field, v: Field, w: Field) -> Field:
    """div (u, v, w) at centres (valid at every centre, halos included where faces exist)."""
    _require(u, "fcc", "divergence")
    _require(v, "cfc", "divergence")
    _require(w, "ccf", "divergence")
    g = u.grid
    out = g.zeros("ccc")
    dx, dy, dz = g.spacing
    divergence_kernel(u.data, v.data, w.data, 1.0 / dx, 1.0 / dy, 1.0 / dz, out.data)
    return out


def porous_divergence(u: Field, v: Field, w: Field, eps: Field) -> Field:
    """div(eps_f u) at interior centres with eps_f the arithmetic face mean of eps
    (eps halos must be filled)."""
    _require(eps, "ccc", "porous_divergence")
    g = u.grid
    out = g.zeros("ccc")
    dx, dy, dz = g.spacing
    nx, ny, nz = g.shape
    porous_divergence_kernel(u.data, v.data, w.data, eps.data, 1.0 / dx, 1.0 / dy, 1.0 / dz, g.halo, nx, ny, nz, out.data)
    return out
