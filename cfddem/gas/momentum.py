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

from cfddem._jit import kernel, parallel_kernel, prange


@kernel
def face_value(qm1, q0, q1, q2, flux, scheme):
    """Velocity advected through a control-volume face between q0 and q1.

    scheme 0: central ``(q0 + q1)/2``; scheme 1: van Leer TVD, upwind by the sign of flux.
    """
    if scheme == 0:
        return 0.5 * (q0 + q1)
    if flux >= 0.0:
        a = q0 - qm1
        b = q1 - q0
        s = 0.0
        if a * b > 0.0:
            s = 2.0 * a * b / (a + b)
        return q0 + 0.5 * s
    a = q2 - q1
    b = q1 - q0
    s = 0.0
    if a * b > 0.0:
        s = 2.0 * a * b / (a + b)
    return q1 - 0.5 * s


@parallel_kernel
def momentum_rhs_kernel(u, v, w, eo, en, dx, dy, dz, nu, lam_ratio, scheme,
                        ox, oy, oz, gx, xf, yc, zc, px, py, pz,
                        i0, i1, j0, j1, k0, k1, out):
    """Explicit acceleration R_x (see module docstring) at x-face array indices
    [i0,i1) x [j0,j1) x [k0,k1).  u: x-faces, v: y-faces, w: z-faces, eo/en: porosity at
    centres at the old/new time (halos filled).  xf, yc, zc: coordinates incl. halos."""
    rdx = 1.0 / dx
    rdy = 1.0 / dy
    rdz = 1.0 / dz
    om2 = ox * ox + oy * oy + oz * oz
    for a in prange(i0, i1):
        for b in range(j0, j1):
            for c in range(k0, k1):
                uP = u[a, b, c]
                eW = eo[a - 1, b, c]
                eE = eo[a, b, c]
                # ---- advection: mass fluxes through the control-volume faces --------------
                mP = 0.5 * (eW + eE) * uP
                mE = 0.5 * (eE + eo[a + 1, b, c]) * u[a + 1, b, c]
                mW = 0.5 * (eo[a - 2, b, c] + eW) * u[a - 1, b, c]
                Fe = 0.5 * (mP + mE)
                Fw = 0.5 * (mW + mP)
                qe = face_value(u[a - 1, b, c], uP, u[a + 1, b, c], u[a + 2, b, c], Fe, scheme)
                qw = face_value(u[a - 2, b, c], u[a - 1, b, c], uP, u[a + 1, b, c], Fw, scheme)
                Fn = 0.25 * ((eo[a - 1, b, c] + eo[a - 1, b + 1, c]) * v[a - 1, b + 1, c]
                             + (eo[a, b, c] + eo[a, b + 1, c]) * v[a, b + 1, c])
                Fs = 0.25 * ((eo[a - 1, b - 1, c] + eo[a - 1, b, c]) * v[a - 1, b, c]
                             + (eo[a, b - 1, c] + eo[a, b, c]) * v[a, b, c])
                qn = face_value(u[a, b - 1, c], uP, u[a, b + 1, c], u[a, b + 2, c], Fn, scheme)
                qs = face_value(u[a, b - 2, c], u[a, b - 1, c], uP, u[a, b + 1, c], Fs, scheme)
                Ft = 0.25 * ((eo[a - 1, b, c] + eo[a - 1, b, c + 1]) * w[a - 1, b, c + 1]
                             + (eo[a, b, c] + eo[a, b, c + 1]) * w[a, b, c + 1])
                Fb = 0.25 * ((eo[a - 1, b, c - 1] + eo[a - 1, b, c]) * w[a - 1, b, c]
                             + (eo[a, b, c - 1] + eo[a, b, c]) * w[a, b, c])
                qt = face_value(u[a, b, c - 1], uP, u[a, b, c + 1], u[a, b, c + 2], Ft, scheme)
                qb = face_value(u[a, b, c - 2], u[a, b, c - 1], uP, u[a, b, c + 1], Fb, scheme)
                adv = -((Fe * (qe - uP) - Fw * (qw - uP)) * rdx
                        + (Fn * (qn - uP) - Fs * (qs - uP)) * rdy
                        + (Ft * (qt - uP) - Fb * (qb - uP)) * rdz)
                # ---- viscous stresses ----------------------------------------------------
                dudx_e = (u[a + 1, b, c] - uP) * rdx
                div_e = dudx_e + (v[a, b + 1, c] - v[a, b, c]) * rdy + (w[a, b, c + 1] - w[a, b, c]) * rdz
                dudx_w = (uP - u[a - 1, b, c]) * rdx
                div_w = (dudx_w + (v[a - 1, b + 1, c] - v[a - 1, b, c]) * rdy
                         + (w[a - 1, b, c + 1] - w[a - 1, b, c]) * rdz)
                sxx_e = eE * (2.0 * dudx_e + lam_ratio * div_e)
                sxx_w = eW * (2.0 * dudx_w + lam_ratio * div_w)
                en_ = 0.25 * (eW + eE + eo[a - 1, b + 1, c] + eo[a, b + 1, c])
                es_ = 0.25 * (eo[a - 1, b - 1, c] + eo[a, b - 1, c] + eW + eE)
                txy_n = en_ * ((u[a, b + 1, c] - uP) * rdy + (v[a, b + 1, c] - v[a - 1, b + 1, c]) * rdx)
                txy_s = es_ * ((uP - u[a, b - 1, c]) * rdy + (v[a, b, c] - v[a - 1, b, c]) * rdx)
                et_ = 0.25 * (eW + eE + eo[a - 1, b, c + 1] + eo[a, b, c + 1])
                eb_ = 0.25 * (eo[a - 1, b, c - 1] + eo[a, b, c - 1] + eW + eE)
                txz_t = et_ * ((u[a, b, c + 1] - uP) * rdz + (w[a, b, c + 1] - w[a - 1, b, c + 1]) * rdx)
                txz_b = eb_ * ((uP - u[a, b, c - 1]) * rdz + (w[a, b, c] - w[a - 1, b, c]) * rdx)
                visc = nu * ((sxx_e - sxx_w) * rdx + (txy_n - txy_s) * rdy + (txz_t - txz_b) * rdz)
                # ---- body forces: gravity, Coriolis, centrifugal ------------------------
                efn = 0.5 * (en[a - 1, b, c] + en[a, b, c])
                vf = 0.25 * (v[a - 1, b, c] + v[a - 1, b + 1, c] + v[a, b, c] + v[a, b + 1, c])
                wf = 0.25 * (w[a - 1, b, c] + w[a - 1, b, c + 1] + w[a, b, c] + w[a, b, c + 1])
                cor = -2.0 * (oy * wf - oz * vf)
                rx = xf[a] - px
                ry = yc[b] - py
                rz = zc[c] - pz
                cen = om2 * rx - ox * (ox * rx + oy * ry + oz * rz)
                out[a, b, c] = adv + visc + efn * (gx + cor + cen)


# cyclic permutations: component d is treated as "x" with axes PERM[d]
PERM = ((0, 1, 2), (1, 2, 0), (2, 0, 1))


def momentum_rhs(comp: int, vel: tuple, eps_old: np.ndarray, eps_new: np.ndarray, grid, *, nu: float,
                 lam_ratio: float, scheme: int, omega, gravity, axis_point, face_range, out: np.ndarray) -> None:
    """Fill ``out`` (array of component ``comp``'s faces) with R_comp at the faces that the
    momentum equation updates (``face_range`` along comp; all interior faces across)."""
    p = PERM[comp]
    t = lambda a: np.transpose(a, p)  # noqa: E731
    uu, vv, ww = t(vel[p[0]]), t(vel[p[1]]), t(vel[p[2]])
    g = grid.halo
    sp = grid.spacing
    n = grid.shape
    coords = [grid.coords(("fcc", "cfc", "ccf")[comp], d, with_halo=True) for d in range(3)]
    lo, hi = face_range
    momentum_rhs_kernel(
        uu, vv, ww, t(eps_old), t(eps_new), sp[p[0]], sp[p[1]], sp[p[2]], nu, lam_ratio, scheme,
        float(omega[p[0]]), float(omega[p[1]]), float(omega[p[2]]), float(gravity[p[0]]),
        coords[p[0]], coords[p[1]], coords[p[2]],
        float(axis_point[p[0]]), float(axis_point[p[1]]), float(axis_point[p[2]]),
        g + lo, g + hi, g, g + n[p[1]], g, g + n[p[2]], t(out))


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
