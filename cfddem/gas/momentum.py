"""Explicit part of the volume-averaged momentum equation on the staggered grid.

For the x-component on the x-face control volume (centred on the face, spanning the two
adjacent cell centres) the kernel returns, per unit volume and divided by rho_g,

    R_x = A_x + V_x + eps_f^{n+1} [ g_x - 2 (Omega x u)_x - (Omega x (Omega x r))_x ]

* advection, in the bounded non-conservative finite-volume form
  ``A = -(1/Vol) sum_faces F_f (q_f - u_P)`` with F_f the mass flux (eps^n u^n, averaged
  to the control-volume face) and q_f the advected velocity on that face.  It equals the
  conservative ``-div(eps u u)`` minus ``u`` times the discrete continuity residual, so it
  vanishes for a uniform flow whatever the porosity field, and with an upwind-biased q_f it is
  the standard bounded (positive-coefficient) form (Patankar 1980; Ferziger & Peric ch. 5).
  q_f: ``scheme=0`` central (second order, non-dissipative), ``scheme=1`` TVD van Leer
  (van Leer 1974): ``q_f = q_U + (1/2) phi(r) (q_D - q_U)`` with the upwind point U,
  ``phi(r) = (r + |r|)/(1 + |r|)``, i.e. the limited slope is the harmonic mean
  ``2 a b / (a + b)`` of the two one-sided differences (0 at extrema).  Second order in
  smooth monotone regions, first order at extrema, no new over/undershoots.
* viscous stress divergence ``-div(eps tau)/rho`` with
  ``tau = -[(lambda - 2/3 mu)(div u) I + mu (grad u + grad u^T)]`` (physics.md section 2):
  normal stress at cell centres, shear stress at cell edges with eps averaged over the
  four cells around the edge.  ``lam_ratio = lambda/mu - 2/3``.
* Coriolis ``-2 Omega x u`` with the other two components averaged to the face (4 points),
  centrifugal ``-Omega x (Omega x r) = |Omega|^2 r - Omega (Omega . r)`` with r measured
  from the axis point, gravity g; all weighted by the face porosity at the new time.

The y- and z-components reuse the same kernel on cyclically permuted views (axes
(y, z, x) and (z, x, y)); the cross products are invariant under cyclic permutation.
"""

from __future__ import annotations

import numpy as np

from cfddem._jit import kernel, parallel_kernel, prange  # noqa: I001
from numba import uint64 as U


@kernel
def face_value(qm1, q0, q1, q2, flux, scheme):
    """Velocity advected through a control-volume face between q0 and q1.

    scheme 0: central ``(q0 + q1)/2``; scheme 1: van Leer TVD, upwind by the sign of flux:
    ``q0 + s/2`` (flux >= 0, slopes a = q0 - qm1, b = q1 - q0) or ``q1 - s/2`` (flux < 0,
    a = q2 - q1), ``s = 2 a b/(a + b)`` if ``a b > 0`` else 0.  Written with selects instead
    of branches (the same values bit for bit), so that the stencil loop vectorises.
    """
    if scheme == 0:
        return 0.5 * (q0 + q1)
    pos = flux >= 0.0
    b = q1 - q0
    a = (q0 - qm1) if pos else (q2 - q1)
    ab = a * b
    mono = ab > 0.0
    s = (2.0 * ab / (a + b)) if mono else 0.0  # a + b != 0 where ab > 0
    return (q0 + 0.5 * s) if pos else (q1 - 0.5 * s)


@parallel_kernel
def momentum_rhs_kernel(u, v, w, eo, en, out, su, sv, sw, se, so, uA, uB, uC, vA, vB, wA, wC, eA, eB, eC,
                        dA, dB, dC, nu, lam_ratio, scheme, oA, oB, oC, gA, X, Y, Z, px, py, pz, cA, cB, cC,
                        i0, i1, j0, j1, k0, k1):
    """Explicit acceleration R_A of the velocity component along axis A (see module docstring)
    at the face-array indices [i0,i1) x [j0,j1) x [k0,k1), looping in memory order (k, the
    contiguous axis, innermost) whatever the component.

    All arrays are flat (raveled C-order arrays with halos); the same index triple (i, j, k)
    addresses the face of ``u`` (component A), the cell east of it in ``eo``/``en`` (centres)
    and the faces of ``v`` (component B) and ``w`` (component C) that share its indices, as in
    the staggered layout.  (A, B, C) is a cyclic permutation of the axes; the stencil is
    written in that frame (offsets ``p`` along A, ``q`` along B, ``r`` along C are
    ``p*xA + q*xB + r*xC`` with the strides of array x along A, B, C).  su, sv, sw, se, so:
    (i, j) strides of u, v, w, eo/en, out.  dA, dB, dC: spacings; oA, oB, oC: Omega in the
    frame; gA: gravity along A; X, Y, Z: physical coordinates of the faces of u (halos
    included); cA, cB, cC: the physical axis of A, B, C (0, 1, 2).  The arithmetic is that
    of the previous (index-permuted) kernel, operation for operation."""
    rdx = 1.0 / dA
    rdy = 1.0 / dB
    rdz = 1.0 / dC
    om2 = oA * oA + oB * oB + oC * oC
    for i in prange(i0, i1):
        for j in range(j0, j1):
            bu = i * su[0] + j * su[1]
            bv = i * sv[0] + j * sv[1]
            bw = i * sw[0] + j * sw[1]
            be = i * se[0] + j * se[1]
            bo = i * so[0] + j * so[1]
            xi = X[i] - px
            yj = Y[j] - py
            for k in range(k0, k1):
                cu = bu + k
                cv = bv + k
                cw = bw + k
                ce = be + k
                uP = u[U(cu)]
                uE = u[U(cu + uA)]
                uW = u[U(cu - uA)]
                eW = eo[U(ce - eA)]
                eE = eo[U(ce)]
                # ---- advection: mass fluxes through the control-volume faces --------------
                mP = 0.5 * (eW + eE) * uP
                mE = 0.5 * (eE + eo[U(ce + eA)]) * uE
                mW = 0.5 * (eo[U(ce - 2 * eA)] + eW) * uW
                Fe = 0.5 * (mP + mE)
                Fw = 0.5 * (mW + mP)
                qe = face_value(uW, uP, uE, u[U(cu + 2 * uA)], Fe, scheme)
                qw = face_value(u[U(cu - 2 * uA)], uW, uP, uE, Fw, scheme)
                uN = u[U(cu + uB)]
                uS = u[U(cu - uB)]
                vWn = v[U(cv - vA + vB)]
                vPn = v[U(cv + vB)]
                vWs = v[U(cv - vA)]
                vPs = v[U(cv)]
                eWn = eo[U(ce - eA + eB)]
                ePn = eo[U(ce + eB)]
                eWs = eo[U(ce - eA - eB)]
                ePs = eo[U(ce - eB)]
                Fn = 0.25 * ((eW + eWn) * vWn + (eE + ePn) * vPn)
                Fs = 0.25 * ((eWs + eW) * vWs + (ePs + eE) * vPs)
                qn = face_value(uS, uP, uN, u[U(cu + 2 * uB)], Fn, scheme)
                qs = face_value(u[U(cu - 2 * uB)], uS, uP, uN, Fs, scheme)
                uT = u[U(cu + uC)]
                uB_ = u[U(cu - uC)]
                wWt = w[U(cw - wA + wC)]
                wPt = w[U(cw + wC)]
                wWb = w[U(cw - wA)]
                wPb = w[U(cw)]
                eWt = eo[U(ce - eA + eC)]
                ePt = eo[U(ce + eC)]
                eWb = eo[U(ce - eA - eC)]
                ePb = eo[U(ce - eC)]
                Ft = 0.25 * ((eW + eWt) * wWt + (eE + ePt) * wPt)
                Fb = 0.25 * ((eWb + eW) * wWb + (ePb + eE) * wPb)
                qt = face_value(uB_, uP, uT, u[U(cu + 2 * uC)], Ft, scheme)
                qb = face_value(u[U(cu - 2 * uC)], uB_, uP, uT, Fb, scheme)
                adv = -((Fe * (qe - uP) - Fw * (qw - uP)) * rdx
                        + (Fn * (qn - uP) - Fs * (qs - uP)) * rdy
                        + (Ft * (qt - uP) - Fb * (qb - uP)) * rdz)
                # ---- viscous stresses ----------------------------------------------------
                dudx_e = (uE - uP) * rdx
                div_e = dudx_e + (vPn - vPs) * rdy + (wPt - wPb) * rdz
                dudx_w = (uP - uW) * rdx
                div_w = dudx_w + (vWn - vWs) * rdy + (wWt - wWb) * rdz
                sxx_e = eE * (2.0 * dudx_e + lam_ratio * div_e)
                sxx_w = eW * (2.0 * dudx_w + lam_ratio * div_w)
                en_ = 0.25 * (eW + eE + eWn + ePn)
                es_ = 0.25 * (eWs + ePs + eW + eE)
                txy_n = en_ * ((uN - uP) * rdy + (vPn - vWn) * rdx)
                txy_s = es_ * ((uP - uS) * rdy + (vPs - vWs) * rdx)
                et_ = 0.25 * (eW + eE + eWt + ePt)
                eb_ = 0.25 * (eWb + ePb + eW + eE)
                txz_t = et_ * ((uT - uP) * rdz + (wPt - wWt) * rdx)
                txz_b = eb_ * ((uP - uB_) * rdz + (wPb - wWb) * rdx)
                visc = nu * ((sxx_e - sxx_w) * rdx + (txy_n - txy_s) * rdy + (txz_t - txz_b) * rdz)
                # ---- body forces: gravity, Coriolis, centrifugal ------------------------
                efn = 0.5 * (en[U(ce - eA)] + en[U(ce)])
                vf = 0.25 * (vWs + vWn + vPs + vPn)
                wf = 0.25 * (wWb + wWt + wPb + wPt)
                cor = -2.0 * (oB * wf - oC * vf)
                zk = Z[k] - pz
                rx = xi if cA == 0 else (yj if cA == 1 else zk)
                ry = xi if cB == 0 else (yj if cB == 1 else zk)
                rz = xi if cC == 0 else (yj if cC == 1 else zk)
                cen = om2 * rx - oA * (oA * rx + oB * ry + oC * rz)
                out[U(bo + k)] = adv + visc + efn * (gA + cor + cen)


# cyclic permutations: component d is treated as "x" with axes PERM[d]
PERM = ((0, 1, 2), (1, 2, 0), (2, 0, 1))


_STRIDES: dict = {}
_COORDS: dict = {}


def _strides(a: np.ndarray) -> np.ndarray:
    """Element strides of a (cached per (shape, strides); the arrays returned are not written)."""
    key = (a.shape, a.strides, a.itemsize)
    s = _STRIDES.get(key)
    if s is None:
        s = np.array(a.strides, dtype=np.int64) // a.itemsize
        _STRIDES[key] = s
    return s


def _coords(grid, comp: int) -> tuple:
    """Coordinates with halos of component comp's faces along x, y, z (cached per grid)."""
    key = (grid.shape, grid.lengths, grid.origin, grid.halo, comp)
    c = _COORDS.get(key)
    if c is None:
        loc = ("fcc", "cfc", "ccf")[comp]
        c = tuple(grid.coords(loc, d, with_halo=True) for d in range(3))
        _COORDS[key] = c
    return c


def momentum_rhs(comp: int, vel: tuple, eps_old: np.ndarray, eps_new: np.ndarray, grid, *, nu: float,
                 lam_ratio: float, scheme: int, omega, gravity, axis_point, face_range, out: np.ndarray) -> None:
    """Fill ``out`` (array of component ``comp``'s faces) with R_comp at the faces that the
    momentum equation updates (``face_range`` along comp; all interior faces across).
    All arrays must be C-contiguous (the solver's are)."""
    A, B, C = PERM[comp]
    u, v, w = vel[A], vel[B], vel[C]
    if not (eps_old.shape == eps_new.shape and all(a.flags.c_contiguous for a in (u, v, w, eps_old, eps_new, out))):
        raise ValueError("momentum_rhs needs C-contiguous arrays, eps_old and eps_new of one shape")
    su, sv, sw, se, so = (_strides(a) for a in (u, v, w, eps_old, out))
    g = grid.halo
    sp = grid.spacing
    n = grid.shape
    X, Y, Z = _coords(grid, comp)
    lo, hi = face_range
    lim = [[g, g + n[0]], [g, g + n[1]], [g, g + n[2]]]
    lim[comp] = [g + lo, g + hi]
    momentum_rhs_kernel(
        u.ravel(), v.ravel(), w.ravel(), eps_old.ravel(), eps_new.ravel(), out.ravel(), su, sv, sw, se, so,
        su[A], su[B], su[C], sv[A], sv[B], sw[A], sw[C], se[A], se[B], se[C],
        sp[A], sp[B], sp[C], nu, lam_ratio, scheme,
        float(omega[A]), float(omega[B]), float(omega[C]), float(gravity[A]), X, Y, Z,
        float(axis_point[0]), float(axis_point[1]), float(axis_point[2]), A, B, C,
        lim[0][0], lim[0][1], lim[1][0], lim[1][1], lim[2][0], lim[2][1])


@parallel_kernel
def viscous_laplacian_kernel(u, eo, dx, dy, dz, nu, cn, i0, i1, j0, j1, k0, k1, out):
    """The part of the viscous term of R_x that the semi-implicit scheme treats implicitly:

        L(u) = nu [ cn d/dx(eps du/dx) + d/dy(eps_e du/dy) + d/dz(eps_e du/dz) ]

    with ``cn = 2 + lam_ratio`` (4/3 for lambda = 0) and the same porosity placement as the
    full stress divergence (centres for d/dx, edge means for d/dy, d/dz).  The rest of the
    viscous term (the cross derivatives dv/dx, dw/dx and lam_ratio (dv/dy + dw/dz)) stays
    explicit; it vanishes for constant eps and divergence-free u."""
    rdx2 = 1.0 / (dx * dx)
    rdy2 = 1.0 / (dy * dy)
    rdz2 = 1.0 / (dz * dz)
    for a in prange(i0, i1):
        for b in range(j0, j1):
            for c in range(k0, k1):
                uP = u[a, b, c]
                eW = eo[a - 1, b, c]
                eE = eo[a, b, c]
                en_ = 0.25 * (eW + eE + eo[a - 1, b + 1, c] + eo[a, b + 1, c])
                es_ = 0.25 * (eo[a - 1, b - 1, c] + eo[a, b - 1, c] + eW + eE)
                et_ = 0.25 * (eW + eE + eo[a - 1, b, c + 1] + eo[a, b, c + 1])
                eb_ = 0.25 * (eo[a - 1, b, c - 1] + eo[a, b, c - 1] + eW + eE)
                out[a, b, c] = nu * (cn * (eE * (u[a + 1, b, c] - uP) - eW * (uP - u[a - 1, b, c])) * rdx2
                                     + (en_ * (u[a, b + 1, c] - uP) - es_ * (uP - u[a, b - 1, c])) * rdy2
                                     + (et_ * (u[a, b, c + 1] - uP) - eb_ * (uP - u[a, b, c - 1])) * rdz2)


def viscous_laplacian(comp: int, arr: np.ndarray, eps_old: np.ndarray, grid, *, nu: float, cn: float,
                      face_range, out: np.ndarray) -> None:
    """Fill ``out`` with L(arr) (see :func:`viscous_laplacian_kernel`) for component ``comp``
    at the faces that the momentum equation updates."""
    p = PERM[comp]
    t = lambda a: np.transpose(a, p)  # noqa: E731
    g = grid.halo
    sp = grid.spacing
    n = grid.shape
    lo, hi = face_range
    viscous_laplacian_kernel(t(arr), t(eps_old), sp[p[0]], sp[p[1]], sp[p[2]], nu, cn,
                             g + lo, g + hi, g, g + n[p[1]], g, g + n[p[2]], t(out))
