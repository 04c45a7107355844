"""Fused compiled kernels of the projection step (cfddem.gas.solver.GasSolver.step).

One pass per velocity component replaces a dozen numpy temporaries (measured: the numpy
version of predictor and correction cost ~4 ms per chute step, as much as the momentum
kernels).  The formulas are those of :mod:`cfddem.gas.solver`; with eps_f the arithmetic
face mean of the new cell porosity and ``dk = dt K / rho``:

* predictor, on the faces the momentum equation updates::

      u* = [eps_f u^n + dt (R - eps_f grad p^n / rho + S / rho + K U_p / rho)] / (eps_f + dk)

* on every interior face: the pressure coefficient ``a_f = eps_f^2 / (eps_f + dk)`` and the
  correction ratio ``eps_f / (eps_f + dk)``;
* correction: ``u^{n+1} = u* - (dt/rho) ratio grad phi`` on the updated faces.

The component's axis is given as a unit vector (di, dj, dk); loops follow the memory
layout.  Arrays with halos carry ``g`` ghost layers; face arrays without halos (S, K, U_p,
a_f, ratio) have n+1 faces along the component's axis.  Each face writes only its own
entries: no races, thread-independent.
"""

from __future__ import annotations

import numpy as np

from cfddem._jit import kernel, parallel_kernel, prange  # noqa: I001
from numba import uint64 as U

from cfddem.gas.operators import c2f_diff_at, c2f_interp_at, porous_divergence_at


@kernel(inline="always")
def _coef_at(en, K, dt, irho, i, j, k, ia, ja, ka, di, dj, dk):
    """(eps_f, eps_f + dt K / rho) of the face (i, j, k) (array indices ia, ja, ka with halos)."""
    ef = c2f_interp_at(en, ia, ja, ka, di, dj, dk)
    return ef, ef + dt * K[U(i), U(j), U(k)] * irho


@kernel(inline="always")
def _coef_run(en, K, dt, irho, i, j, ka, kb, g, di, dj, dk, coef, ratio):
    """coef = eps_f^2 / (eps_f + dt K/rho) and ratio = eps_f / (eps_f + dt K/rho) on the faces
    k in [ka, kb) of the z row (i, j) (face-array indices)."""
    for k in range(ka, kb):
        ef, d = _coef_at(en, K, dt, irho, i, j, k, g + i, g + j, g + k, di, dj, dk)
        coef[U(i), U(j), U(k)] = ef * ef / d
        ratio[U(i), U(j), U(k)] = ef / d


@parallel_kernel
def predictor_kernel(u, en, p, rhs, S, K, Up, dt, rho, rh, g, di, dj, dk, lo, hi, explicit, coef, ratio, numer, den):
    """Fill coef and ratio on all faces of component (di, dj, dk) (the unit vector of its
    axis); on the faces [lo, hi) along that axis either update u to u* (``explicit``) or store
    the numerator and denominator of u* (semi-implicit viscosity, solved afterwards).
    numer/den start at face lo.  Loops follow the memory layout (k fastest); indices are cast
    to unsigned where used (no negative-index test: the loops vectorise).  A z row is done in
    up to three runs (faces below, inside and above [k0, k1)), each one branch-free loop, so
    that the faces updated compute eps_f and the denominator once for both uses."""
    n0, n1, n2 = coef.shape
    irho = 1.0 / rho
    i0, j0, k0 = lo * di, lo * dj, lo * dk
    i1 = hi if di else n0
    j1 = hi if dj else n1
    k1 = hi if dk else n2
    for i in prange(n0):
        for j in range(n1):
            upd = i >= i0 and i < i1 and j >= j0 and j < j1
            ka0 = k0 if upd else n2
            kb0 = k1 if upd else n2
            _coef_run(en, K, dt, irho, i, j, 0, ka0, g, di, dj, dk, coef, ratio)
            for k in range(ka0, kb0):
                ia, ja, ka = g + i, g + j, g + k
                ef, d = _coef_at(en, K, dt, irho, i, j, k, ia, ja, ka, di, dj, dk)
                coef[U(i), U(j), U(k)] = ef * ef / d
                ratio[U(i), U(j), U(k)] = ef / d
                gradp = c2f_diff_at(p, ia, ja, ka, di, dj, dk) * rh  # (1/h folded into rh: operators.py)
                num = ef * u[U(ia), U(ja), U(ka)] + dt * (rhs[U(ia), U(ja), U(ka)] - ef * gradp * irho)
                num += dt * S[U(i), U(j), U(k)] * irho
                num += dt * K[U(i), U(j), U(k)] * Up[U(i), U(j), U(k)] * irho
                if explicit:
                    u[U(ia), U(ja), U(ka)] = num / d
                else:
                    numer[U(i - i0), U(j - j0), U(k - k0)] = num
                    den[U(i - i0), U(j - j0), U(k - k0)] = d
            _coef_run(en, K, dt, irho, i, j, kb0, n2, g, di, dj, dk, coef, ratio)


@parallel_kernel
def correction_kernel(u, phi, ratio, fac, g, di, dj, dk, lo, hi):
    """u -= fac ratio (phi - phi_minus) on the faces [lo, hi) along the axis (di, dj, dk);
    fac = dt / (rho h)."""
    n0, n1, n2 = ratio.shape
    i0, j0, k0 = lo * di, lo * dj, lo * dk
    i1 = hi if di else n0
    j1 = hi if dj else n1
    k1 = hi if dk else n2
    for i in prange(i0, i1):
        for j in range(j0, j1):
            for k in range(k0, k1):
                ia, ja, ka = g + i, g + j, g + k
                u[U(ia), U(ja), U(ka)] -= fac * ratio[U(i), U(j), U(k)] * c2f_diff_at(phi, ia, ja, ka, di, dj, dk)


@kernel
def porosity_copy_kernel(e, out, g, lim):
    """Returns the number of values of e outside (0, lim], NaN included (``not (0 < v <= lim)``
    holds for NaN and +-inf); if there are none, copies e into the interior of the centre
    array ``out`` (g halo layers): out[g + i, g + j, g + k] = e[i, j, k].  Replaces numpy's
    validation (isfinite, min, max: three passes and a temporary) and the strided copy; out is
    left untouched by an invalid e."""
    nx, ny, nz = e.shape
    bad = 0
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                v = e[U(i), U(j), U(k)]
                bad += 0 if (v > 0.0 and v <= lim) else 1
    if bad:
        return bad
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                out[U(i + g), U(j + g), U(k + g)] = e[U(i), U(j), U(k)]
    return 0


@kernel
def pressure_rhs_kernel(u, v, w, en, eo, rdx, rdy, rdz, dt, rho, g, b):
    """Right-hand side of the pressure equation ``b = -(rho/dt) [div(eps_f u*) + (eps^{n+1} -
    eps^n)/dt]`` at the cells (b without halos), the divergence from
    :func:`cfddem.gas.operators.porous_divergence_at` (no divergence array: the same numbers
    as :func:`cfddem.gas.operators.porous_divergence_kernel` followed by this formula)."""
    nx, ny, nz = b.shape
    f = -rho / dt
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                ia, ja, ka = g + i, g + j, g + k
                d = porous_divergence_at(u, v, w, en, ia, ja, ka, rdx, rdy, rdz)
                b[U(i), U(j), U(k)] = f * (d + (en[U(ia), U(ja), U(ka)] - eo[U(ia), U(ja), U(ka)]) / dt)


@kernel
def mass_defect_kernel(div, en, eo, dt, g, nx, ny, nz):
    """max over cells of |div(eps_f u) + (eps^{n+1} - eps^n)/dt| * dt."""
    m = 0.0
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                v = abs(div[g + i, g + j, g + k] + (en[g + i, g + j, g + k] - eo[g + i, g + j, g + k]) / dt)
                if v > m or v != v:  # a NaN is kept (nothing compares greater than it)
                    m = v
    return m * dt


@kernel(inline="always")
def _defect_at(u, v, w, en, eo, i, j, k, rdx, rdy, rdz, dt):
    """|div(eps_f u) + (eps^{n+1} - eps^n)/dt| at cell (i, j, k) (array indices)."""
    d = porous_divergence_at(u, v, w, en, i, j, k, rdx, rdy, rdz)
    return abs(d + (en[U(i), U(j), U(k)] - eo[U(i), U(j), U(k)]) / dt)


@kernel(inline="always")
def _rate_at(u, v, w, i, j, k, rdx, rdy, rdz):
    """``max(|u_W|, |u_E|)/dx + max(|v_S|, |v_N|)/dy + max(|w_B|, |w_T|)/dz`` of cell (i, j, k);
    NaN (``np.nan``) if one of its six face velocities is NaN.  Written with selects, no
    early return, so that a loop over k vectorises (signed indices, cast to unsigned where
    used)."""
    ip, jp, kp = U(i + 1), U(j + 1), U(k + 1)
    iu, ju, ku = U(i), U(j), U(k)
    u0, u1 = u[iu, ju, ku], u[ip, ju, ku]
    v0, v1 = v[iu, ju, ku], v[iu, jp, ku]
    w0, w1 = w[iu, ju, ku], w[iu, ju, kp]
    bad = (u0 != u0) | (u1 != u1) | (v0 != v0) | (v1 != v1) | (w0 != w0) | (w1 != w1)
    a = max(abs(u0), abs(u1)) * rdx
    b = max(abs(v0), abs(v1)) * rdy
    c = max(abs(w0), abs(w1)) * rdz
    return np.nan if bad else a + b + c


@kernel
def local_advective_rate_kernel(u, v, w, rdx, rdy, rdz, g, nx, ny, nz):
    """max over cells of ``max(|u_W|, |u_E|)/dx + max(|v_S|, |v_N|)/dy + max(|w_B|, |w_T|)/dz``
    (the face velocities on the cell's own faces; NaN if one of them is NaN).

    Times dt this is the local Courant number of the cell, the quantity the positivity (TVD)
    condition of the explicit bounded advection acts on: the outflow of a cell in one step is
    at most this fraction of its content. It bounds OpenFOAM's per-cell Courant number
    (0.5 sum_f |phi_f| dt / V) from above and is bounded by the sum of the per-axis maxima
    max|u|/dx + max|v|/dy + max|w|/dz, which takes its three terms from different cells.
    """
    m = 0.0
    for i in range(g, g + nx):
        for j in range(g, g + ny):
            for k in range(g, g + nz):
                r = _rate_at(u, v, w, i, j, k, rdx, rdy, rdz)
                if r != r:
                    return np.nan
                if r > m:
                    m = r
    return m


@kernel(inline="always")
def _row_max(ibuf, q, n, m):
    """max(m, ibuf[q, 0:n]) (integers: a maximum that vectorises)."""
    for kk in range(n):
        x = ibuf[U(q), U(kk)]
        m = x if x > m else m
    return m


@kernel
def step_diagnostics_kernel(u, v, w, p, en, eo, rdx, rdy, rdz, dt, g, nx, ny, nz, buf, ibuf):
    """The end-of-step numbers in one pass over the cells: (max over cells of
    |div(eps_f u) + (eps^{n+1} - eps^n)/dt| * dt, the divergence from
    :func:`cfddem.gas.operators.porous_divergence_at` (the same number as
    :func:`cfddem.gas.operators.porous_divergence_kernel` followed by
    :func:`mass_defect_kernel`, no divergence array written), the local advective rate as
    :func:`local_advective_rate_kernel`, max |p| over the interior); each NaN if one of its
    inputs is NaN (inf if one is infinite).

    ``buf``: a work array of shape (3, nz) (float64), ``ibuf`` the same memory viewed as
    int64.  Per z row the three values of every cell go to ``buf`` (a loop without branches
    or reductions, which vectorises), then their maxima are taken on the integer view: the
    three values are >= 0 or NaN with the sign bit clear (``abs``; the rate's NaN is
    ``np.nan``), and for such floats the order of the bit patterns as integers is the order
    of the values, with NaN above +inf.  An integer maximum vectorises; the float one with
    its NaN test did not (3x slower).  The results are the same numbers as a float
    maximum that keeps the first NaN."""
    m0 = 0
    m1 = 0
    m2 = 0
    for i in range(g, g + nx):
        for j in range(g, g + ny):
            for kk in range(nz):
                buf[0, U(kk)] = _defect_at(u, v, w, en, eo, i, j, g + kk, rdx, rdy, rdz, dt)
            for kk in range(nz):
                buf[1, U(kk)] = _rate_at(u, v, w, i, j, g + kk, rdx, rdy, rdz)
            for kk in range(nz):
                buf[2, U(kk)] = abs(p[U(i), U(j), U(g + kk)])
            m0 = _row_max(ibuf, 0, nz, m0)
            m1 = _row_max(ibuf, 1, nz, m1)
            m2 = _row_max(ibuf, 2, nz, m2)
    ibuf[0, 0] = m0
    ibuf[1, 0] = m1
    ibuf[2, 0] = m2
    return buf[0, 0] * dt, buf[1, 0], buf[2, 0]
