"""Tiny staggered-grid operators, named by where the result lives.

Array conventions (see :mod:`cfddem.gas.grid`): a face array along direction d has one
more entry along d than a centre array; face array index ``I`` lies between centre array
indices ``I-1`` and ``I``; centre index ``i`` lies between face indices ``i`` and ``i+1``.
All kernels write only the entries whose stencil lies inside the input array, and leave
the rest of ``out`` untouched, so they can run on arrays with halos.

=======================  =====================================================  =========
function                 formula                                                result at
=======================  =====================================================  =========
``c2f_interp(a,d,out)``  ``(a[I-1] + a[I]) / 2``                                faces d
``c2f_diff(a,d,h,out)``  ``(a[I] - a[I-1]) / h``                                faces d
``f2c_interp(f,d,out)``  ``(f[i] + f[i+1]) / 2``                                centres
``f2c_diff(f,d,h,out)``  ``(f[i+1] - f[i]) / h``                                centres
``divergence``           ``sum_d (f_d[i+1] - f_d[i]) / h_d``                    centres
``porous_divergence``    ``sum_d (e_f f_d)[i+1] - (e_f f_d)[i]) / h_d``,
                         ``e_f = (e[I-1] + e[I]) / 2``                          centres
=======================  =====================================================  =========

Second-order accurate on uniform grids and exact for fields linear in the direction of the
operation.  Compiled with :func:`cfddem._jit.parallel_kernel` (one ``prange`` loop over the
first array axis; every iteration writes its own entries, so the result does not depend
on the thread count).
"""

from __future__ import annotations

import numpy as np

from cfddem._jit import kernel, parallel_kernel, prange  # noqa: I001  (before numba: it sets the threading layer)
from numba import uint64 as U

from cfddem.gas.grid import Field


def _offsets(d: int):
    return (1 if d == 0 else 0, 1 if d == 1 else 0, 1 if d == 2 else 0)


@parallel_kernel
def _c2f(a, di, dj, dk, scale, mode, out):
    # mode 0: interpolation 0.5*(a[I-1] + a[I]); mode 1: difference (a[I] - a[I-1]) * scale
    n0, n1, n2 = a.shape
    for i in prange(di, n0):
        for j in range(dj, n1):
            for k in range(dk, n2):
                lo = a[i - di, j - dj, k - dk]
                hi = a[i, j, k]
                if mode == 0:
                    out[i, j, k] = 0.5 * (lo + hi)
                else:
                    out[i, j, k] = (hi - lo) * scale


@parallel_kernel
def _f2c(f, di, dj, dk, scale, mode, out):
    # mode 0: 0.5*(f[i] + f[i+1]); mode 1: (f[i+1] - f[i]) * scale
    n0, n1, n2 = out.shape
    for i in prange(n0):
        for j in range(n1):
            for k in range(n2):
                lo = f[i, j, k]
                hi = f[i + di, j + dj, k + dk]
                if mode == 0:
                    out[i, j, k] = 0.5 * (lo + hi)
                else:
                    out[i, j, k] = (hi - lo) * scale


@kernel
def porous_divergence_at(u, v, w, eps, i, j, k, rdx, rdy, rdz):
    """div(e_f u) at the cell centre (i, j, k) (array indices, at least 1: a halo cell on
    each side): the six face fluxes with the face porosity e_f the arithmetic mean of the two
    cells beside the face.  Indices are cast to unsigned where used (no negative-index test,
    so that the loops calling this vectorise; the same values)."""
    im, jm, km = U(i - 1), U(j - 1), U(k - 1)
    ip, jp, kp = U(i + 1), U(j + 1), U(k + 1)
    iu, ju, ku = U(i), U(j), U(k)
    e = eps[iu, ju, ku]
    fxp = 0.5 * (e + eps[ip, ju, ku]) * u[ip, ju, ku]
    fxm = 0.5 * (eps[im, ju, ku] + e) * u[iu, ju, ku]
    fyp = 0.5 * (e + eps[iu, jp, ku]) * v[iu, jp, ku]
    fym = 0.5 * (eps[iu, jm, ku] + e) * v[iu, ju, ku]
    fzp = 0.5 * (e + eps[iu, ju, kp]) * w[iu, ju, kp]
    fzm = 0.5 * (eps[iu, ju, km] + e) * w[iu, ju, ku]
    return (fxp - fxm) * rdx + (fyp - fym) * rdy + (fzp - fzm) * rdz


@parallel_kernel
def porous_divergence_kernel(u, v, w, eps, rdx, rdy, rdz, g, nx, ny, nz, out):
    """out[c] = div(e_f u) at interior centres (array indices g..g+n-1); e_f arithmetic mean
    (:func:`porous_divergence_at`)."""
    for i in prange(g, g + nx):
        for j in range(g, g + ny):
            for k in range(g, g + nz):
                out[i, j, k] = porous_divergence_at(u, v, w, eps, i, j, k, rdx, rdy, rdz)


@parallel_kernel
def divergence_kernel(u, v, w, rdx, rdy, rdz, out):
    """out[i,j,k] = div u at every centre whose faces lie inside the arrays."""
    n0, n1, n2 = out.shape
    for i in prange(n0):
        for j in range(n1):
            for k in range(n2):
                out[i, j, k] = ((u[i + 1, j, k] - u[i, j, k]) * rdx + (v[i, j + 1, k] - v[i, j, k]) * rdy
                                + (w[i, j, k + 1] - w[i, j, k]) * rdz)


def _face_loc(d: int) -> str:
    return ("fcc", "cfc", "ccf")[d]


def _require(f: Field, loc: str, what: str) -> None:
    if f.location != loc:
        raise ValueError(f"{what} needs a {loc} field, got {f.location}")


def interp_to_face(a: Field, d: int) -> Field:
    """Centre field -> faces normal to d, (a[I-1] + a[I]) / 2."""
    _require(a, "ccc", "interp_to_face")
    out = a.grid.zeros(_face_loc(d))
    _c2f(a.data, *_offsets(d), 1.0, 0, _view_c2f(out.data, d))
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
    _c2f(a.data, *_offsets(d), 1.0 / a.grid.spacing[d], 1, _view_c2f(out.data, d))
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
