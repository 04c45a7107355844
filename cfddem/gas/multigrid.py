"""Compiled geometric multigrid for the pressure equation on the regular cell-centred grid.

Solves the same system as :class:`cfddem.gas.pressure.PressureSolver`,

    (A phi)_c = sum_{faces f of c} a_f (phi_c - phi_nb(f)) / h_f^2 = b_c,

with Neumann (no term), Dirichlet on the boundary face (ghost ``-phi_c``: term ``2 a_f phi_c /
h^2``) and periodic sides, by conjugate gradients preconditioned with one symmetric
multigrid V-cycle.  Internally the operator is multiplied by the cell volume V (``W_f = a_f
A_f / d_f``: face area over centre distance), which makes the coarse-grid operators and the
restriction of residuals (sums) natural; the relative residual ``||b - A phi|| / ||b||`` is
the same.

Hierarchy (built once per grid, in Python):

* cell-centred coarsening by 2 along each axis whose cell width is at most
  ``coarsen_ratio`` (1.5) times the smallest one (semi-coarsening keeps the coarse cells
  roughly isotropic, so point Gauss-Seidel still smooths; on the chute, 5 x 3 x 6 mm cells,
  2.0 would coarsen all three axes at once: measured 5-10 % less solve time in the gas
  step, but 7.2 instead of 6 CG iterations with eps = 1 and 9 instead of 7 with the bed, a
  weaker preconditioner; not the default); coarse cell I covers fine cells 2I and 2I+1, and an odd
  count leaves the last coarse cell with one fine cell (ceil(n/2) coarse cells: coarse
  grids may be non-uniform, all widths and centre distances are tracked per axis);
* until at most ``coarse_max`` cells remain (or no axis can be coarsened); the coarsest
  system is solved exactly by a dense Cholesky factorisation (refactored at every set-up).
  A singular system (no Dirichlet side) gets ``c 1 1^T`` added on the coarsest level
  (c = mean diagonal / N), which gives the mean-free solution of a compatible system.

Coefficients (rebuilt at every :meth:`MGPressureSolver.set_coefficients`, O(N), compiled):
the coarse operator is the re-discretisation on the coarse cells, ``W_F = abar_F A_F / D_F``
with ``abar_F`` the **area-weighted arithmetic mean** of the fine coefficients on the coarse
face (faces in parallel: their conductances add) and D_F the coarse centre distance.  That
equals the piecewise-constant Galerkin sum ``sum_f W_f`` times ``d_f / D_F`` (d_f the fine
centre distance across the face), which is how it is computed; Dirichlet terms scale with
the boundary-cell widths in the same way.  (For a coefficient that jumps *along* the normal
inside a coarse cell a harmonic mean would be closer; on the chute the bed/air jump, up to a
factor ~6 in a with the drag, costs at most one CG iteration: 7 against 6-7 without it.)

Transfers: prolongation P is cell-centred (tri)linear interpolation along the coarsened axes
(piecewise constant along the others; at Neumann sides the ghost equals the coarse cell
value, at Dirichlet sides it is its negative, periodic sides wrap); restriction is P^T
(order 2 + 2 > 2, the condition of Mohr & Wienands (2004) for cell-centred multigrid).

Smoother (default): red-black Gauss-Seidel over-relaxed by ``omega``, ``nu`` sweeps
red-then-black before the coarse-grid correction and ``nu`` sweeps black-then-red in
reverse cell order after it, so the V-cycle
is a symmetric positive definite operator (R = P^T, adjoint pre/post smoothing, exact
coarsest solve) and a valid CG preconditioner.  With an odd periodic axis the two colours
touch across the wrap; the sweeps then are ordinary Gauss-Seidel sweeps in the red-black
order and the reverse order is still their adjoint.

Storage: level l occupies cells off..off+nx*ny*nz of every level array, x planes and y rows
in C order, but each z row stores its even k first, then its odd k (:func:`_pk`; red-black
order), so that the cells of one colour in a row are contiguous and their z neighbours sit
at fixed offsets: the smoother's interior loop is unit-stride and vectorises (1.8x per
sweep, measured).  :meth:`MGPressureSolver.solve`, ``apply`` and ``vcycle`` take and return
C-order arrays (permuted on entry and exit); ``storage_order`` gives the permutation.

Threads (opt-in, ``par_min``; serial by default, see MGPressureSolver): on every level of at
least ``par_min`` cells the smoother, the residual and
the transfers run with the x planes in parallel (one ``prange`` per kernel), and so do the
CG vector operations on the finest level.  Red-black Gauss-Seidel is deterministic per
colour: the rows of one colour are independent, except across an odd periodic x axis, where
row nx-1 is done after (forward) or before (reverse) the others, as in the serial order.
The restriction along x is parallel over y (each coarse entry is summed by one thread, in
increasing fine index).  Every inner product is a serial sum of per-plane partial sums
(:func:`_rowdot`, a fixed order).  So the iterates are bit-identical for any thread count
and for the serial path (tested with 1, 2, 3 threads).  Measured on the shared 2-core machine
(load 8-9): 2 threads are 7-10 % slower than 1 on the chute grid, up to 1.19x faster on
64^3 (docs/gas.md, "Threads").  The set-up's coarsening and the Chebyshev smoother are serial.

Precision (``precision``, default "single"): the V-cycle (its operator, transfer weights,
coarsest Cholesky factor and work arrays) runs in float32, converted from the float64 set-up
at every ``set_coefficients``; CG's operator, residual, iterate, direction and inner
products stay float64 and it stops on the float64 true residual, so the accuracy of the
solution is unchanged (only the preconditioner is approximated).  Half the memory traffic
and twice the SIMD lanes: on the chute (16 x 15 x 150) the gas step costs 15-18 % less CPU
with the same CG iterations (5.1 / 7.0) and defects.  The float32
V-cycle is symmetric only to its rounding (about 1e-8 relative, measured); plain CG with
it showed no loss of iterations, so no flexible (Polak-Ribiere) beta is used.
"double": the float64 V-cycle (exactly symmetric to rounding).

References: Trottenberg, Oosterlee & Schueller, *Multigrid* (2001), ch. 2-5; Mohr &
Wienands, Comput. Vis. Sci. 7 (2004) 129 (cell-centred transfers); Tatebe, Copper Mountain
Conf. (1993) (multigrid-preconditioned CG).
"""

from __future__ import annotations

import numpy as np

# cfddem._jit before numba: it selects numba's threading layer (OpenMP, passive waiting)
# through environment variables that numba reads when it is first imported
from cfddem._jit import kernel, parallel_kernel, prange  # noqa: I001
from numba import uint64 as U
from cfddem.gas.pressure import SolveInfo

_KIND = {"neumann": 0, "dirichlet": 1, "periodic": 2}
SIDES = ("x-", "x+", "y-", "y+", "z-", "z+")


# ------------------------------------------------------------------------------------------
# compiled kernels: level l occupies cells off..off+nx*ny*nz of every level array (z rows red-black)
# ------------------------------------------------------------------------------------------
@kernel
def _pk(k, n):
    """Storage position of z index k in a z row of n cells: the even k first (k/2), then
    the odd k (ceil(n/2) + (k-1)/2), so that the cells of one red-black colour in a row are
    contiguous and their z neighbours sit at fixed offsets (see "Storage" in the module doc)."""
    return (k >> 1) if (k & 1) == 0 else ((n + 1) >> 1) + (k >> 1)


@kernel(inline="always")
def _dirichlet_axes(dirich):
    """Whether each axis (x, y, z) has a Dirichlet side, from the six sides' flags."""
    return (dirich[0] == 1 or dirich[1] == 1, dirich[2] == 1 or dirich[3] == 1,
            dirich[4] == 1 or dirich[5] == 1)


@parallel_kernel
def _fine_coefficients(ax, ay, az, sc, dirich, periodic, cE, cN, cT, dX, dY, dZ):
    """Level-0 weights (volume-scaled): cE[U(c)] couples c to its +x neighbour (wrapping), zero
    at non-periodic +x sides; dX: Dirichlet boundary terms.  sc[d] = V / h_d^2.  x planes in
    parallel (each cell writes its own entries).  Red-black storage along z (:func:`_pk`):
    the even k, then the odd k, each a branch-free loop (the k = 0 and k = nz - 1 entries
    are fixed after them).  The Dirichlet arrays of an axis without a Dirichlet side are not
    written: they are zero from their allocation on and stay so (less memory traffic)."""
    nx, ny, nz = ax.shape[0] - 1, ay.shape[1] - 1, az.shape[2] - 1
    h = (nz + 1) // 2
    hx, hy, hz = _dirichlet_axes(dirich)
    for i in prange(nx):
        cutx = i == nx - 1 and (periodic[0] == 0 or nx == 1)
        for j in range(ny):
            cuty = j == ny - 1 and (periodic[1] == 0 or ny == 1)
            row = (i * ny + j) * nz
            for half in range(2):
                pb = row + (0 if half == 0 else h)
                for m in range(h if half == 0 else nz - h):
                    c = pb + m
                    k = 2 * m + half
                    cE[U(c)] = 0.0 if cutx else ax[U(i + 1), U(j), U(k)] * sc[0]
                    cN[U(c)] = 0.0 if cuty else ay[U(i), U(j + 1), U(k)] * sc[1]
                    cT[U(c)] = az[U(i), U(j), U(k + 1)] * sc[2]
            if hz:
                for c in range(row, row + nz):
                    dZ[U(c)] = 0.0
            if hx and (i == 0 or i == nx - 1):
                for k in range(nz):
                    d = 0.0
                    if i == 0 and dirich[0] == 1:
                        d += 2.0 * ax[U(0), U(j), U(k)] * sc[0]
                    if i == nx - 1 and dirich[1] == 1:
                        d += 2.0 * ax[U(nx), U(j), U(k)] * sc[0]
                    dX[U(row + _pk(k, nz))] = d
            elif hx:
                for k in range(nz):
                    dX[U(row + k)] = 0.0
            if hy and (j == 0 or j == ny - 1):
                for k in range(nz):
                    d = 0.0
                    if j == 0 and dirich[2] == 1:
                        d += 2.0 * ay[U(i), U(0), U(k)] * sc[1]
                    if j == ny - 1 and dirich[3] == 1:
                        d += 2.0 * ay[U(i), U(ny), U(k)] * sc[1]
                    dY[U(row + _pk(k, nz))] = d
            elif hy:
                for k in range(nz):
                    dY[U(row + k)] = 0.0
            last = row + _pk(nz - 1, nz)
            if periodic[2] == 0 or nz == 1:
                cT[U(last)] = 0.0
            if not hz:
                continue
            d = 0.0
            if dirich[4] == 1:
                d += 2.0 * az[U(i), U(j), U(0)] * sc[2]
            if nz == 1 and dirich[5] == 1:
                d += 2.0 * az[U(i), U(j), U(nz)] * sc[2]
            dZ[U(row)] = d
            if nz > 1:
                d = 0.0
                if dirich[5] == 1:
                    d += 2.0 * az[U(i), U(j), U(nz)] * sc[2]
                dZ[U(last)] = d


@kernel
def _diag_run(c0, c1, dz, dxm, dym, cE, cN, cT, dX, dY, dZ, dg, idg, omega, vE, vN, vT, vdg, vidg, copy, hx, hy, hz):
    """Diagonal (sum of the cell's weights) and omega / diagonal of the storage positions
    [c0, c1) of one z row whose z- neighbours sit at the fixed offset dz (x-, y- neighbours at
    dxm, dym).  ``copy``: the V-cycle runs on float32 copies: omega / diagonal goes to vidg
    only (the float64 idg, which only the float64 V-cycle reads, is not written: a smaller
    footprint, the same vidg), and the cell's entries are copied into vE, vN, vT, vdg.
    hx, hy, hz: whether the axis has a Dirichlet side; without one its Dirichlet array is all
    zero and not read (adding the zeros would give the same sum bit for bit)."""
    for c in range(c0, c1):
        d = (cE[U(c)] + cE[U(c + dxm)] + cN[U(c)] + cN[U(c + dym)]
             + cT[U(c)] + cT[U(c + dz)])
        if hx:
            d += dX[U(c)]
        if hy:
            d += dY[U(c)]
        if hz:
            d += dZ[U(c)]
        dg[U(c)] = d
        if copy:
            vidg[U(c)] = omega / d
        else:
            idg[U(c)] = omega / d
    if copy:
        for c in range(c0, c1):
            vE[U(c)] = cE[U(c)]
            vN[U(c)] = cN[U(c)]
            vT[U(c)] = cT[U(c)]
            vdg[U(c)] = dg[U(c)]


@kernel
def _coarsen_and_factor(LV, AOFF, AXI, AXF, ZP, ZF, cE, cN, cT, dX, dY, dZ, dg, idg, dense, singular, omega,
                        vE, vN, vT, vdg, vidg, vdense, copy, dirich):
    """Coarse weights of every level from level 0 (scaled Galerkin sums, see module doc),
    the diagonals of all levels, and the Cholesky factor of the coarsest level (lower
    triangle of ``dense``).  ZP, ZF: per fine z storage position (offsets AOFF[:, 2]), the
    storage position of its parent in the coarse row and its face and Dirichlet factors (the
    z rows are then run in storage order; every coarse entry still gets its contributions in
    the order of the fine (i, j, k)).  ``copy``: also write the V-cycle's float32 copies
    (vE ... vidg, vdense) of the operator.  ``dirich``: the six sides' Dirichlet flags; the
    Dirichlet array of an axis without a Dirichlet side is all zero and neither read nor
    written.  Returns 0, or 1 if the coarsest matrix is not positive definite."""
    L = LV.shape[0]
    hx, hy, hz = _dirichlet_axes(dirich)
    for l in range(L - 1):
        nx, ny, nz, off = LV[l, 0], LV[l, 1], LV[l, 2], LV[l, 3]
        mx, my, mz, offc = LV[l + 1, 0], LV[l + 1, 1], LV[l + 1, 2], LV[l + 1, 3]
        for c in range(offc, offc + mx * my * mz):
            cE[U(c)] = 0.0
            cN[U(c)] = 0.0
            cT[U(c)] = 0.0
        if hx:
            for c in range(offc, offc + mx * my * mz):
                dX[U(c)] = 0.0
        if hy:
            for c in range(offc, offc + mx * my * mz):
                dY[U(c)] = 0.0
        if hz:
            for c in range(offc, offc + mx * my * mz):
                dZ[U(c)] = 0.0
        ox, oy, oz = AOFF[l, 0], AOFF[l, 1], AOFF[l, 2]
        for i in range(nx):
            I = AXI[0, 0, U(ox + i)]
            fx = AXF[0, 0, U(ox + i)]
            gx = AXF[1, 0, U(ox + i)]
            for j in range(ny):
                J = AXI[0, 1, U(oy + j)]
                fy = AXF[0, 1, U(oy + j)]
                gy = AXF[1, 1, U(oy + j)]
                row = off + (i * ny + j) * nz
                crow = offc + (I * my + J) * mz
                for q in range(nz):  # q: fine storage position
                    c = row + q
                    C = crow + ZP[U(oz + q)]
                    fz = ZF[0, U(oz + q)]
                    gz = ZF[1, U(oz + q)]
                    # fx is nonzero only on the last fine child of I (the coarse +x face)
                    cE[U(C)] += fx * cE[U(c)]
                    cN[U(C)] += fy * cN[U(c)]
                    cT[U(C)] += fz * cT[U(c)]
                    if hx:
                        dX[U(C)] += gx * dX[U(c)]
                    if hy:
                        dY[U(C)] += gy * dY[U(c)]
                    if hz:
                        dZ[U(C)] += gz * dZ[U(c)]
    for l in range(L):
        nx, ny, nz, off = LV[l, 0], LV[l, 1], LV[l, 2], LV[l, 3]
        h = (nz + 1) // 2
        for i in range(nx):
            im = i - 1 if i > 0 else nx - 1
            for j in range(ny):
                jm = j - 1 if j > 0 else ny - 1
                row = off + (i * ny + j) * nz
                dxm = (im - i) * ny * nz
                dym = (jm - j) * nz
                # z- neighbour of storage position q: q = 0 (k = 0): k = nz - 1 (wrap);
                # 0 < q < h (even k = 2q): q + h - 1; q >= h (odd k): q - h
                _diag_run(row, row + 1, _pk(nz - 1, nz), dxm, dym, cE, cN, cT, dX, dY, dZ, dg, idg, omega,
                          vE, vN, vT, vdg, vidg, copy, hx, hy, hz)
                _diag_run(row + 1, row + h, h - 1, dxm, dym, cE, cN, cT, dX, dY, dZ, dg, idg, omega,
                          vE, vN, vT, vdg, vidg, copy, hx, hy, hz)
                _diag_run(row + h, row + nz, -h, dxm, dym, cE, cN, cT, dX, dY, dZ, dg, idg, omega,
                          vE, vN, vT, vdg, vidg, copy, hx, hy, hz)
    # coarsest level: dense matrix and its Cholesky factor
    nx, ny, nz, off = LV[L - 1, 0], LV[L - 1, 1], LV[L - 1, 2], LV[L - 1, 3]
    n = nx * ny * nz
    for a in range(n):
        for b in range(n):
            dense[a, b] = 0.0
    for i in range(nx):
        ip = i + 1 if i < nx - 1 else 0
        for j in range(ny):
            jp = j + 1 if j < ny - 1 else 0
            for k in range(nz):
                kp = k + 1 if k < nz - 1 else 0
                pk = _pk(k, nz)
                c = (i * ny + j) * nz + pk  # dense index = storage position
                dense[c, c] += dg[off + c]
                for dd in range(3):
                    if dd == 0:
                        nb, w = (ip * ny + j) * nz + pk, cE[off + c]
                    elif dd == 1:
                        nb, w = (i * ny + jp) * nz + pk, cN[off + c]
                    else:
                        nb, w = (i * ny + j) * nz + _pk(kp, nz), cT[off + c]
                    if w != 0.0:
                        dense[c, nb] -= w
                        dense[nb, c] -= w
    if singular:
        s = 0.0
        for a in range(n):
            s += dense[a, a]
        s /= n * n
        for a in range(n):
            for b in range(n):
                dense[a, b] += s
    for jj in range(n):  # in-place Cholesky, lower triangle
        s = dense[jj, jj]
        for kk in range(jj):
            s -= dense[jj, kk] * dense[jj, kk]
        if not s > 0.0:
            return 1
        d = np.sqrt(s)
        dense[jj, jj] = d
        for ii in range(jj + 1, n):
            s = dense[ii, jj]
            for kk in range(jj):
                s -= dense[ii, kk] * dense[jj, kk]
            dense[ii, jj] = s / d
    if copy:
        for a in range(n):
            for b in range(n):
                vdense[a, b] = dense[a, b]
    return 0


# Array indices are cast to unsigned (uint64) where they are used: numba then drops the
# negative-index wrap-around test on every access, which lets LLVM vectorise the stencil
# loops (measured 2-5x faster on these kernels).  All index arithmetic is in int64 before the
# cast (numba turns mixed int64/uint64 arithmetic into floats).


@kernel
def _ax(c, cm, cp, dxm, dxp, dym, dyp, cE, cN, cT, dg, x):
    """(A x)_c of the volume-scaled 7-point operator; cm, cp: the z neighbours of c, dxm...:
    offsets of the x and y neighbours from c (wrapped at periodic sides)."""
    return (dg[U(c)] * x[U(c)] - cE[U(c)] * x[U(c + dxp)] - cE[U(c + dxm)] * x[U(c + dxm)]
            - cN[U(c)] * x[U(c + dyp)] - cN[U(c + dym)] * x[U(c + dym)] - cT[U(c)] * x[U(cp)] - cT[U(cm)] * x[U(cm)])


@kernel
def _gs_row(i, nx, ny, nz, off, cE, cN, cT, dg, idg, x, b, col, reverse, zero):
    """Gauss-Seidel updates of the cells of colour ``col`` in the x-row (plane) i, in
    lexicographic (j, k) order or in exactly the reverse order.  Within one colour the rows
    are independent (x neighbours have the other colour) except across an odd periodic x
    wrap, which :func:`_gs_colour_par` orders explicitly.  ``zero``: x is zero on entry
    everywhere (the first colour of the first sweep from a zero guess), so the update is
    x = idg b, exactly what the full formula gives then.  Red-black storage (:func:`_pk`):
    the colour's cells of a z row are contiguous, in increasing k, and their z neighbours
    are at the fixed offsets (h - 1, h) for even k and (-h, 1 - h) for odd k, h = ceil(nz/2),
    so the interior loop is a unit-stride loop that vectorises."""
    im = i - 1 if i > 0 else nx - 1
    ip = i + 1 if i < nx - 1 else 0
    dxm = (im - i) * ny * nz
    dxp = (ip - i) * ny * nz
    h = (nz + 1) // 2
    for jj in range(ny):
        j = ny - 1 - jj if reverse else jj
        jm = j - 1 if j > 0 else ny - 1
        jp = j + 1 if j < ny - 1 else 0
        k0 = (i + j + col) & 1
        row = off + (i * ny + j) * nz
        dym = (jm - j) * nz
        dyp = (jp - j) * nz
        klast = k0 + 2 * ((nz - 1 - k0) // 2)  # last k of this colour (< k0: none)
        if klast < k0:
            continue
        if zero:
            base = row + (0 if k0 == 0 else h)
            for c in range(base, base + (klast - k0) // 2 + 1):
                x[U(c)] = b[U(c)] * idg[U(c)]
            continue
        dm = h - 1 if k0 == 0 else -h  # offsets of the z neighbours (interior cells)
        dp = h if k0 == 0 else 1 - h
        # interior cells of this colour: k in [kin0, kin1] (no z wrap), contiguous positions
        kin0 = k0 if k0 > 0 else 2
        kin1 = klast if klast < nz - 1 else klast - 2
        first_wrap = k0 == 0
        last_wrap = klast == nz - 1 and klast > 0
        for step in range(3):
            part = 2 - step if reverse else step
            if part == 0:
                if first_wrap:
                    c = row
                    cp = row + h if nz > 1 else row
                    x[U(c)] += (b[U(c)] - _ax(c, row + _pk(nz - 1, nz), cp, dxm, dxp, dym, dyp, cE, cN, cT, dg, x)) * idg[U(c)]
            elif part == 1:
                if kin1 >= kin0:
                    c0 = row + _pk(kin0, nz)
                    c1 = row + _pk(kin1, nz)
                    if reverse:
                        for c in range(c1, c0 - 1, -1):
                            x[U(c)] += (b[U(c)] - _ax(c, c + dm, c + dp, dxm, dxp, dym, dyp, cE, cN, cT, dg, x)) * idg[U(c)]
                    else:
                        for c in range(c0, c1 + 1):
                            x[U(c)] += (b[U(c)] - _ax(c, c + dm, c + dp, dxm, dxp, dym, dyp, cE, cN, cT, dg, x)) * idg[U(c)]
            else:
                if last_wrap:
                    c = row + _pk(nz - 1, nz)
                    x[U(c)] += (b[U(c)] - _ax(c, row + _pk(nz - 2, nz), row, dxm, dxp, dym, dyp, cE, cN, cT, dg, x)) * idg[U(c)]


@parallel_kernel
def _gs_colour_par(nx, ny, nz, off, cE, cN, cT, dg, idg, x, b, col, reverse, xdep, zero):
    """One colour of a Gauss-Seidel sweep, rows (x planes) in parallel.  ``xdep``: the x axis
    is periodic with an odd count, so rows nx-1 and 0 hold neighbours of the same colour; row
    nx-1 is then done last (forward) or first (reverse), as in the serial lexicographic
    order, so the result is that of the serial sweep whatever the thread count."""
    n = nx - 1 if xdep else nx
    if xdep and reverse:
        _gs_row(nx - 1, nx, ny, nz, off, cE, cN, cT, dg, idg, x, b, col, reverse, zero)
    for i in prange(n):
        _gs_row(i, nx, ny, nz, off, cE, cN, cT, dg, idg, x, b, col, reverse, zero)
    if xdep and not reverse:
        _gs_row(nx - 1, nx, ny, nz, off, cE, cN, cT, dg, idg, x, b, col, reverse, zero)


@kernel
def _gs_sweep(nx, ny, nz, off, cE, cN, cT, dg, idg, x, b, first, reverse, xdep, par, zero):
    """One red-black Gauss-Seidel sweep (over-relaxed by the omega folded into idg): colour
    ``first`` then the other, in lexicographic cell order, or in exactly the reverse cell
    order if ``reverse`` (its adjoint when called with the other ``first``).  Periodic
    neighbours wrap; non-periodic boundary weights are 0.  ``par``: rows in parallel
    (:func:`_gs_colour_par`, same result).  ``zero``: x = 0 on entry (the first colour then
    costs one multiplication per cell)."""
    for q in range(2):
        col = (first + q) & 1
        z = zero and q == 0
        if par:
            _gs_colour_par(nx, ny, nz, off, cE, cN, cT, dg, idg, x, b, col, reverse, xdep, z)
        else:
            for ii in range(nx):
                i = nx - 1 - ii if reverse else ii
                _gs_row(i, nx, ny, nz, off, cE, cN, cT, dg, idg, x, b, col, reverse, z)


@kernel
def _rowdot(a, b, o, n):
    """sum_{c=o}^{o+n-1} a_c b_c in a fixed order (four interleaved partial sums, added at the
    end: deterministic, and four independent chains instead of one)."""
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    s3 = 0.0
    n4 = n - n % 4
    for c in range(o, o + n4, 4):
        s0 += a[U(c)] * b[U(c)]
        s1 += a[U(c + 1)] * b[U(c + 1)]
        s2 += a[U(c + 2)] * b[U(c + 2)]
        s3 += a[U(c + 3)] * b[U(c + 3)]
    for c in range(o + n4, o + n):
        s0 += a[U(c)] * b[U(c)]
    return (s0 + s1) + (s2 + s3)


@kernel
def _apply_level(nx, ny, nz, off, cE, cN, cT, dg, x, b, y, mode):
    """mode 0: y = A x; mode 1: y = b - A x (the residual), on the level at offset off."""
    for i in range(nx):
        _apply_row(i, nx, ny, nz, off, cE, cN, cT, dg, x, b, y, mode)


@parallel_kernel
def _apply_par(nx, ny, nz, off, cE, cN, cT, dg, x, b, y, mode, want, part):
    """:func:`_apply_level` with the x planes in parallel; ``want`` 1: part[i] = sum of y^2
    over plane i, 2: sum of x y (partial sums of a fixed order: the same for any thread count)."""
    m = ny * nz
    for i in prange(nx):
        _apply_row(i, nx, ny, nz, off, cE, cN, cT, dg, x, b, y, mode)
        if want == 1:
            part[i] = _rowdot(y, y, off + i * m, m)
        elif want == 2:
            part[i] = _rowdot(x, y, off + i * m, m)


@kernel
def _apply_row(i, nx, ny, nz, off, cE, cN, cT, dg, x, b, y, mode):
    """The x plane i of :func:`_apply_level` (red-black storage along z, :func:`_pk`: the
    interior even k, then the interior odd k, each a unit-stride loop)."""
    im = i - 1 if i > 0 else nx - 1
    ip = i + 1 if i < nx - 1 else 0
    h = (nz + 1) // 2
    ne = (nz - 2) // 2  # interior even k: positions 1..ne
    no = (nz - 3) // 2 + 1  # interior odd k: positions h..h+no-1
    for j in range(ny):
        jm = j - 1 if j > 0 else ny - 1
        jp = j + 1 if j < ny - 1 else 0
        row = off + (i * ny + j) * nz
        dxm = (im - i) * ny * nz
        dxp = (ip - i) * ny * nz
        dym = (jm - j) * nz
        dyp = (jp - j) * nz
        if nz == 1:
            v = _ax(row, row, row, dxm, dxp, dym, dyp, cE, cN, cT, dg, x)
            y[U(row)] = b[U(row)] - v if mode == 1 else v
            continue
        cl = row + _pk(nz - 1, nz)
        v0 = _ax(row, cl, row + h, dxm, dxp, dym, dyp, cE, cN, cT, dg, x)
        v1 = _ax(cl, row + _pk(nz - 2, nz), row, dxm, dxp, dym, dyp, cE, cN, cT, dg, x)
        if mode == 1:
            for c in range(row + 1, row + 1 + ne):
                y[U(c)] = b[U(c)] - _ax(c, c + h - 1, c + h, dxm, dxp, dym, dyp, cE, cN, cT, dg, x)
            for c in range(row + h, row + h + no):
                y[U(c)] = b[U(c)] - _ax(c, c - h, c - h + 1, dxm, dxp, dym, dyp, cE, cN, cT, dg, x)
            y[U(row)] = b[U(row)] - v0
            y[U(cl)] = b[U(cl)] - v1
        else:
            for c in range(row + 1, row + 1 + ne):
                y[U(c)] = _ax(c, c + h - 1, c + h, dxm, dxp, dym, dyp, cE, cN, cT, dg, x)
            for c in range(row + h, row + h + no):
                y[U(c)] = _ax(c, c - h, c - h + 1, dxm, dxp, dym, dyp, cE, cN, cT, dg, x)
            y[U(row)] = v0
            y[U(cl)] = v1


@kernel
def _restrict_rows(src, dst, n0, n1, n2, m, axis, AXI, AXF, o, a0, a1):
    """dst = R_axis src for the outer indices [a0, a1): sum the cells of ``src`` (n0, n1, n2)
    along ``axis`` into the m coarse cells (dst shape with that extent replaced by m),
    weights of P^T.  The outer index is j for axis 0 (dst[:, j, :] is then owned by j) and i
    otherwise; every dst entry gets its contributions in increasing fine index."""
    if axis == 2:
        for i in range(a0, a1):
            for j in range(n1):
                rs = (i * n1 + j) * n2
                rd = (i * n1 + j) * m
                for K in range(m):
                    dst[U(rd + K)] = 0.0
                for k in range(n2):  # k: storage position (AXI/AXF rows 3-4 / 4-5 are in that order)
                    v = src[U(rs + k)]
                    dst[U(rd + AXI[3, 2, U(o + k)])] += AXF[4, 2, U(o + k)] * v
                    w2 = AXF[5, 2, U(o + k)]
                    if w2 != 0.0:
                        dst[U(rd + AXI[4, 2, U(o + k)])] += w2 * v
    elif axis == 1:
        for i in range(a0, a1):
            for c in range(i * m * n2, (i + 1) * m * n2):
                dst[U(c)] = 0.0
            for j in range(n1):
                rs = (i * n1 + j) * n2
                w1 = AXF[2, 1, U(o + j)]
                w2 = AXF[3, 1, U(o + j)]
                rd1 = (i * m + AXI[1, 1, U(o + j)]) * n2
                rd2 = (i * m + AXI[2, 1, U(o + j)]) * n2
                for k in range(n2):
                    dst[U(rd1 + k)] += w1 * src[U(rs + k)]
                if w2 != 0.0:
                    for k in range(n2):
                        dst[U(rd2 + k)] += w2 * src[U(rs + k)]
    else:
        for j in range(a0, a1):
            for I in range(m):
                rd = (I * n1 + j) * n2
                for k in range(n2):
                    dst[U(rd + k)] = 0.0
            for i in range(n0):
                w1 = AXF[2, 0, U(o + i)]
                w2 = AXF[3, 0, U(o + i)]
                rd1 = (AXI[1, 0, U(o + i)] * n1 + j) * n2
                rd2 = (AXI[2, 0, U(o + i)] * n1 + j) * n2
                rs = (i * n1 + j) * n2
                for k in range(n2):
                    dst[U(rd1 + k)] += w1 * src[U(rs + k)]
                if w2 != 0.0:
                    for k in range(n2):
                        dst[U(rd2 + k)] += w2 * src[U(rs + k)]


@parallel_kernel
def _restrict_par(src, dst, n0, n1, n2, m, axis, AXI, AXF, o):
    """:func:`_restrict_axis` with the outer index in parallel (no shared dst entries)."""
    n = n1 if axis == 0 else n0
    for a in prange(n):
        _restrict_rows(src, dst, n0, n1, n2, m, axis, AXI, AXF, o, a, a + 1)


@kernel
def _restrict_axis(src, dst, n0, n1, n2, m, axis, AXI, AXF, o, par):
    """dst = R_axis src (see :func:`_restrict_rows`); ``par``: in parallel (same result)."""
    if par:
        _restrict_par(src, dst, n0, n1, n2, m, axis, AXI, AXF, o)
    else:
        _restrict_rows(src, dst, n0, n1, n2, m, axis, AXI, AXF, o, 0, n1 if axis == 0 else n0)


@kernel
def _prolong_rows(src, dst, n0, n1, n2, axis, AXI, AXF, o, add, i0, i1):
    """dst (n0, n1, n2) (+)= P_axis src for the fine x planes [i0, i1), src having the
    coarse extent along ``axis``."""
    if axis == 2:
        m = src.size // (n0 * n1) if n0 * n1 > 0 else 0
        for ij in range(i0 * n1, i1 * n1):
            rs = ij * m
            rd = ij * n2
            for k in range(n2):  # k: storage position
                v = AXF[4, 2, U(o + k)] * src[U(rs + AXI[3, 2, U(o + k)])]
                w2 = AXF[5, 2, U(o + k)]
                if w2 != 0.0:
                    v += w2 * src[U(rs + AXI[4, 2, U(o + k)])]
                if add:
                    dst[U(rd + k)] += v
                else:
                    dst[U(rd + k)] = v
    elif axis == 1:
        mm = AXI[0, 1, U(o + n1 - 1)] + 1  # coarse extent
        for i in range(i0, i1):
            for j in range(n1):
                w1 = AXF[2, 1, U(o + j)]
                w2 = AXF[3, 1, U(o + j)]
                rd = (i * n1 + j) * n2
                r1 = (i * mm + AXI[1, 1, U(o + j)]) * n2
                r2 = (i * mm + AXI[2, 1, U(o + j)]) * n2
                if w2 != 0.0:
                    for k in range(n2):
                        v = w1 * src[U(r1 + k)] + w2 * src[U(r2 + k)]
                        if add:
                            dst[U(rd + k)] += v
                        else:
                            dst[U(rd + k)] = v
                else:
                    for k in range(n2):
                        if add:
                            dst[U(rd + k)] += w1 * src[U(r1 + k)]
                        else:
                            dst[U(rd + k)] = w1 * src[U(r1 + k)]
    else:
        for i in range(i0, i1):
            w1 = AXF[2, 0, U(o + i)]
            w2 = AXF[3, 0, U(o + i)]
            r1 = AXI[1, 0, U(o + i)] * n1 * n2
            r2 = AXI[2, 0, U(o + i)] * n1 * n2
            rd = i * n1 * n2
            for c in range(n1 * n2):
                v = w1 * src[U(r1 + c)]
                if w2 != 0.0:
                    v += w2 * src[U(r2 + c)]
                if add:
                    dst[U(rd + c)] += v
                else:
                    dst[U(rd + c)] = v


@parallel_kernel
def _prolong_par(src, dst, n0, n1, n2, axis, AXI, AXF, o, add):
    for i in prange(n0):
        _prolong_rows(src, dst, n0, n1, n2, axis, AXI, AXF, o, add, i, i + 1)


@kernel
def _prolong_axis(src, dst, n0, n1, n2, axis, AXI, AXF, o, add, par):
    """dst (n0, n1, n2) (+)= P_axis src (see :func:`_prolong_rows`); ``par``: x planes in
    parallel (each writes its own entries)."""
    if par:
        _prolong_par(src, dst, n0, n1, n2, axis, AXI, AXF, o, add)
    else:
        _prolong_rows(src, dst, n0, n1, n2, axis, AXI, AXF, o, add, 0, n0)


@kernel
def _chebyshev(nx, ny, nz, off, cE, cN, cT, dg, x, r, d, q, deg, lmin, lmax, keep_residual):
    """``deg`` steps of Chebyshev-accelerated Jacobi smoothing on one level (Adams, Brezina, Hu
    & Tuminaro, J. Comput. Phys. 188 (2003) 593): the error is multiplied by the Chebyshev
    polynomial of D^-1 A that is smallest on [lmin, lmax] (lmax = 2 bounds the spectrum of
    D^-1 A for this diagonally dominant operator).  On entry r = b - A x; on exit x is
    smoothed and, with ``keep_residual``, r = b - A x again.  A polynomial in D^-1 A is
    self-adjoint in the A inner product, so the same smoother before and after the
    coarse-grid correction keeps the V-cycle symmetric.  Every loop vectorises."""
    n = nx * ny * nz
    theta = 0.5 * (lmax + lmin)
    delta = 0.5 * (lmax - lmin)
    sigma = theta / delta
    rho = 1.0 / sigma
    for c in range(off, off + n):
        d[U(c)] = r[U(c)] / (dg[U(c)] * theta)
    for k in range(deg):
        for c in range(off, off + n):
            x[U(c)] += d[U(c)]
        if k == deg - 1 and not keep_residual:
            break
        _apply_level(nx, ny, nz, off, cE, cN, cT, dg, d, d, q, 0)
        for c in range(off, off + n):
            r[U(c)] -= q[U(c)]
        if k == deg - 1:
            break
        rho_new = 1.0 / (2.0 * sigma - rho)
        f1 = rho_new * rho
        f2 = 2.0 * rho_new / delta
        for c in range(off, off + n):
            d[U(c)] = f1 * d[U(c)] + f2 * r[U(c)] / dg[U(c)]
        rho = rho_new


@kernel
def _vcycle(LV, LF, AOFF, AXI, AXF, cE, cN, cT, dg, idg, dense, x, b, r, t1, t2, dw, qw, nu, deg, lmin, rin, zout, part):
    """zout = M rin: one symmetric V-cycle from a zero initial guess (rin, zout: level 0).
    t1, t2: work arrays of level-0 size for the axis-by-axis transfers.  deg = 0: ``nu``
    red-black Gauss-Seidel sweeps; deg > 0: Chebyshev smoothing of degree deg on
    [lmin, 2] (dw, qw: its work arrays).  LF[l] = (par, xdep, oddp): level l's smoother,
    residual and transfers run with the x planes in parallel (par = 1; results do not depend
    on it), its x axis is periodic with an odd count (xdep, see :func:`_gs_colour_par`), some
    axis is (then the first colour of the first sweep gets no zero-guess shortcut)."""
    L = LV.shape[0]
    n0 = LV[0, 0] * LV[0, 1] * LV[0, 2]
    for c in range(n0):
        b[c] = rin[c]
    for l in range(L - 1):
        nx, ny, nz, off = LV[l, 0], LV[l, 1], LV[l, 2], LV[l, 3]
        mx, my, mz, offc = LV[l + 1, 0], LV[l + 1, 1], LV[l + 1, 2], LV[l + 1, 3]
        for c in range(off, off + nx * ny * nz):
            x[c] = 0.0
        if deg > 0:
            for c in range(off, off + nx * ny * nz):
                r[c] = b[c]
            _chebyshev(nx, ny, nz, off, cE, cN, cT, dg, x, r, dw, qw, deg, lmin, 2.0, True)
        else:
            par, xdep = LF[l, 0] == 1, LF[l, 1] == 1
            for s in range(nu):
                _gs_sweep(nx, ny, nz, off, cE, cN, cT, dg, idg, x, b, 0, False, xdep, par, s == 0 and LF[l, 2] == 0)
            if par:
                _apply_par(nx, ny, nz, off, cE, cN, cT, dg, x, b, r, 1, 0, part)
            else:
                _apply_level(nx, ny, nz, off, cE, cN, cT, dg, x, b, r, 1)
        # restriction b_{l+1} = P^T r_l, one axis at a time (z, y, x)
        par = LF[l, 0] == 1
        ox, oy, oz = AOFF[l, 0], AOFF[l, 1], AOFF[l, 2]
        # an axis that is not coarsened (m = n) has the identity transfer: skipped (exact)
        cx, cy, cz = mx != nx, my != ny, mz != nz
        last = 0 if cx else (1 if cy else 2)  # the last coarsened axis writes b_{l+1}
        bc = b[offc:offc + mx * my * mz]
        src = r[off:off + nx * ny * nz]
        if cz:
            dst = bc if last == 2 else t1[:nx * ny * mz]
            _restrict_axis(src, dst, nx, ny, nz, mz, 2, AXI, AXF, oz, par)
            src = dst
        if cy:
            dst = bc if last == 1 else t2[:nx * my * mz]
            _restrict_axis(src, dst, nx, ny, mz, my, 1, AXI, AXF, oy, par)
            src = dst
        if cx:
            _restrict_axis(src, bc, nx, my, mz, mx, 0, AXI, AXF, ox, par)
    # coarsest: Cholesky solve
    nx, ny, nz, off = LV[L - 1, 0], LV[L - 1, 1], LV[L - 1, 2], LV[L - 1, 3]
    n = nx * ny * nz
    for a in range(n):
        s = b[off + a]
        for kk in range(a):
            s -= dense[a, kk] * x[off + kk]
        x[off + a] = s / dense[a, a]
    for a in range(n - 1, -1, -1):
        s = x[off + a]
        for kk in range(a + 1, n):
            s -= dense[kk, a] * x[off + kk]
        x[off + a] = s / dense[a, a]
    for l in range(L - 2, -1, -1):
        nx, ny, nz, off = LV[l, 0], LV[l, 1], LV[l, 2], LV[l, 3]
        mx, my, mz, offc = LV[l + 1, 0], LV[l + 1, 1], LV[l + 1, 2], LV[l + 1, 3]
        ox, oy, oz = AOFF[l, 0], AOFF[l, 1], AOFF[l, 2]
        par, xdep = LF[l, 0] == 1, LF[l, 1] == 1
        # prolongation x_l += P x_{l+1}, one axis at a time (x, y, z)
        # (identity transfers of axes that are not coarsened skipped; the last one adds)
        cx, cy, cz = mx != nx, my != ny, mz != nz
        last = 2 if cz else (1 if cy else 0)
        xl = x[off:off + nx * ny * nz]
        src = x[offc:offc + mx * my * mz]
        if cx:
            dst = xl if last == 0 else t2[:nx * my * mz]
            _prolong_axis(src, dst, nx, my, mz, 0, AXI, AXF, ox, last == 0, par)
            src = dst
        if cy:
            dst = xl if last == 1 else t1[:nx * ny * mz]
            _prolong_axis(src, dst, nx, ny, mz, 1, AXI, AXF, oy, last == 1, par)
            src = dst
        if cz:
            _prolong_axis(src, xl, nx, ny, nz, 2, AXI, AXF, oz, True, par)
        if deg > 0:
            _apply_level(nx, ny, nz, off, cE, cN, cT, dg, x, b, r, 1)
            _chebyshev(nx, ny, nz, off, cE, cN, cT, dg, x, r, dw, qw, deg, lmin, 2.0, False)
        else:
            for s in range(nu):
                _gs_sweep(nx, ny, nz, off, cE, cN, cT, dg, idg, x, b, 1, True, xdep, par, False)
    for c in range(n0):
        zout[c] = x[c]


@kernel
def _matvec(nx, ny, nz, cE, cN, cT, dg, x, y):
    """y = A x on level 0 (volume-scaled)."""
    _apply_level(nx, ny, nz, 0, cE, cN, cT, dg, x, x, y, 0)


@parallel_kernel
def _pdot(a, b, nx, m, part):
    """part[i] = sum over x plane i (m cells) of a b."""
    for i in prange(nx):
        part[i] = _rowdot(a, b, i * m, m)


@parallel_kernel
def _pupdate(x, r, p, q, alpha, nx, m, part):
    """x += alpha p, r -= alpha q; part[i] = sum over plane i of r^2."""
    for i in prange(nx):
        for c in range(i * m, (i + 1) * m):
            x[U(c)] += alpha * p[U(c)]
            r[U(c)] -= alpha * q[U(c)]
        part[i] = _rowdot(r, r, i * m, m)


@parallel_kernel
def _pxpby(y, x, b, nx, m):
    """y = x + b y (the CG direction update p = z + beta p)."""
    for i in prange(nx):
        for c in range(i * m, (i + 1) * m):
            y[U(c)] = x[U(c)] + b * y[U(c)]


@parallel_kernel
def _pscale(x, a, nx, m):
    """x = a x."""
    for i in prange(nx):
        for c in range(i * m, (i + 1) * m):
            x[U(c)] *= a


@parallel_kernel
def _pshift(z, s, nx, m):
    for i in prange(nx):
        for c in range(i * m, (i + 1) * m):
            z[U(c)] -= s


@parallel_kernel
def _presid(nx, ny, nz, cE, cN, cT, dg, x, b, r, part):
    """r = b - A x on level 0, part[i] = sum over plane i of r^2."""
    m = ny * nz
    for i in prange(nx):
        _apply_row(i, nx, ny, nz, 0, cE, cN, cT, dg, x, b, r, 1)
        part[i] = _rowdot(r, r, i * m, m)


@kernel
def _psum(part, n):
    """Serial sum of the plane partial sums in index order (thread-count independent)."""
    s = 0.0
    for i in range(n):
        s += part[i]
    return s


@kernel
def _pcg(LV, LF, AOFF, AXI, AXF, cE, cN, cT, dg, vE, vN, vT, vdg, vidg, dense, xl, bl, rl, t1, t2, dw, qw, nu, deg,
         lmin, singular, tol, maxiter,
         bvec, xvec, r, z, p, q, part, ones, atol, scale_x0):
    """Multigrid-preconditioned CG on level 0: A xvec = bvec, from the initial xvec
    (``scale_x0``: from ``a xvec``, a = xvec.b / xvec.A xvec, the multiple of xvec closest to
    the solution in the A-norm, 0 if xvec.A xvec is not positive).

    Stops when the true residual ``||b - A x|| <= max(tol ||b||, atol)`` (the recursive residual is
    checked each iteration; on apparent convergence the true one is computed and CG
    restarted from it if it is still too large).  Returns (iterations, relative residual).
    Vector operations and the residual run with the x planes in parallel; every inner
    product is a serial sum of per-plane partial sums (:func:`_rowdot`), so the iterates are
    the same for any thread count.  ``part``: nx work entries, ``ones``: a vector of ones."""
    nx, ny, nz = LV[0, 0], LV[0, 1], LV[0, 2]
    n = nx * ny * nz
    m = ny * nz
    _pdot(bvec, bvec, nx, m, part)
    bn = np.sqrt(_psum(part, nx))
    if bn == 0.0:
        for c in range(n):
            xvec[c] = 0.0
        return 0, 0.0
    if scale_x0:
        _apply_par(nx, ny, nz, 0, cE, cN, cT, dg, xvec, xvec, q, 0, 2, part)
        xax = _psum(part, nx)
        _pdot(xvec, bvec, nx, m, part)
        a = _psum(part, nx) / xax if xax > 0.0 else 0.0
        if not np.isfinite(a):
            a = 0.0
        _pscale(xvec, a, nx, m)
    its = 0
    rel = 0.0
    thr = max(tol * bn, atol)
    while True:
        _presid(nx, ny, nz, cE, cN, cT, dg, xvec, bvec, r, part)
        rn = _psum(part, nx)
        rel = np.sqrt(rn) / bn
        if np.sqrt(rn) <= thr or its >= maxiter or not np.isfinite(rel):
            return its, rel
        _vcycle(LV, LF, AOFF, AXI, AXF, vE, vN, vT, vdg, vidg, dense, xl, bl, rl, t1, t2, dw, qw, nu, deg, lmin, r, z,
                part)
        if singular:
            _pdot(z, ones, nx, m, part)
            _pshift(z, _psum(part, nx) / n, nx, m)
        _pdot(r, z, nx, m, part)
        rz = _psum(part, nx)
        for c in range(n):
            p[c] = z[c]
        while its < maxiter:
            its += 1
            _apply_par(nx, ny, nz, 0, cE, cN, cT, dg, p, p, q, 0, 2, part)
            pq = _psum(part, nx)
            alpha = rz / pq
            _pupdate(xvec, r, p, q, alpha, nx, m, part)
            rn = _psum(part, nx)
            if np.sqrt(rn) <= thr or not np.isfinite(rn):
                break
            _vcycle(LV, LF, AOFF, AXI, AXF, vE, vN, vT, vdg, vidg, dense, xl, bl, rl, t1, t2, dw, qw, nu, deg, lmin,
                    r, z, part)
            if singular:
                _pdot(z, ones, nx, m, part)
                _pshift(z, _psum(part, nx) / n, nx, m)
            _pdot(r, z, nx, m, part)
            rz2 = _psum(part, nx)
            beta = rz2 / rz
            rz = rz2
            _pxpby(p, z, beta, nx, m)


@kernel
def _to_storage(src, dst, nrows, nz, scale):
    """dst = scale * src from C order to the red-black storage order of level 0 (each z row:
    the even k, then the odd k; :func:`_pk`), without an index array."""
    h = (nz + 1) // 2
    for r in range(nrows):
        o = r * nz
        for m in range(h):
            dst[U(o + m)] = src[U(o + 2 * m)] * scale
        for m in range(nz - h):
            dst[U(o + h + m)] = src[U(o + 2 * m + 1)] * scale


@kernel
def _from_storage(src, dst, nrows, nz):
    """The inverse of :func:`_to_storage` (scale 1); returns whether every entry is finite."""
    h = (nz + 1) // 2
    finite = True
    for r in range(nrows):
        o = r * nz
        for m in range(h):
            v = src[U(o + m)]
            dst[U(o + 2 * m)] = v
            finite &= v - v == 0.0
        for m in range(nz - h):
            v = src[U(o + h + m)]
            dst[U(o + 2 * m + 1)] = v
            finite &= v - v == 0.0
    return finite


@kernel
def _compare_store(a, last):
    """last[:] = a; returns whether any entry differed (NaN always differs)."""
    changed = False
    for c in range(a.size):
        v = a[c]
        if not v == last[c]:
            changed = True
        last[c] = v
    return changed


# ------------------------------------------------------------------------------------------
# hierarchy (Python, once per grid)
# ------------------------------------------------------------------------------------------
def _axis_transfer(widths, kinds, coarsen):
    """1D data of one axis between a level (cell widths ``widths``) and the next.

    Returns (coarse widths, par, i1, i2, facf, dfac, w1, w2) per fine cell: parent index,
    the two interpolation sources and weights (w2 = 0: one source), the face factor d_f/D_F
    on the last child of each coarse cell (0 elsewhere, or for a non-periodic last face) and
    the Dirichlet factor w_child / W_parent."""
    n = widths.size
    lo, hi = kinds  # 0 neumann, 1 dirichlet, 2 periodic
    per = lo == 2
    if not coarsen:
        par = np.arange(n)
        facf = np.ones(n)
        dfac = np.ones(n)
        return widths.copy(), par, par.copy(), par.copy(), facf, dfac, np.ones(n), np.zeros(n)
    m = (n + 1) // 2
    par = np.arange(n) // 2
    W = np.bincount(par, weights=widths, minlength=m)
    L = widths.sum()
    xf = np.cumsum(widths) - 0.5 * widths
    xc = np.cumsum(W) - 0.5 * W
    first = 2 * np.arange(m)
    last = np.minimum(first + 1, n - 1)
    facf = np.zeros(n)
    for I in range(m):
        J = I + 1
        if J == m:
            if not per or m == 1:
                continue
            J = 0
        d_f = 0.5 * (widths[last[I]] + widths[first[J]])
        D = 0.5 * (W[I] + W[J])
        facf[last[I]] = d_f / D
    dfac = widths / W[par]
    i1 = par.copy()
    i2 = par.copy()
    w1 = np.ones(n)
    w2 = np.zeros(n)
    for i in range(n):
        I = par[i]
        if abs(xf[i] - xc[I]) <= 1e-12 * L:
            continue
        J = I - 1 if xf[i] < xc[I] else I + 1
        if 0 <= J < m:
            XJ, src, sgn = xc[J], J, 1.0
        else:
            kind = lo if J < 0 else hi
            if kind == 2:
                src = J % m
                XJ = xc[src] - L if J < 0 else xc[src] + L
                sgn = 1.0
            elif kind == 1:
                face = 0.0 if J < 0 else L
                XJ, src, sgn = 2.0 * face - xc[I], I, -1.0
            else:
                XJ, src, sgn = 2.0 * (0.0 if J < 0 else L) - xc[I], I, 1.0
        t = (xf[i] - xc[I]) / (XJ - xc[I])
        if src == I:
            w1[i] = (1.0 - t) + sgn * t
        else:
            i2[i] = src
            w1[i] = 1.0 - t
            w2[i] = t
    return W, par, i1, i2, facf, dfac, w1, w2


def _rb_order(n: int) -> np.ndarray:
    """z index k held at each storage position of a z row of n cells: the even k, then the
    odd k (red-black storage, :func:`_pk` is its inverse)."""
    return np.concatenate([np.arange(0, n, 2), np.arange(1, n, 2)])


class MGPressureSolver:
    """``A = -div(a grad)`` on a grid's cells, solved by multigrid-preconditioned CG.

    Same interface as :class:`~cfddem.gas.pressure.PressureSolver` (``set_coefficients``,
    ``solve``, ``apply``).  Parameters: grid, pressure_bc (side -> "neumann" | "dirichlet" |
    "periodic"), tol (relative residual), maxiter, nu (red-black Gauss-Seidel sweeps before
    and after the coarse-grid correction), coarse_max (cells of the coarsest level, solved
    densely), coarsen_ratio (an axis is coarsened while its cell width is at most this times
    the smallest), omega (over-relaxation of the Gauss-Seidel sweeps), chebyshev (0: the
    Gauss-Seidel smoother; k > 0: Chebyshev-Jacobi smoothing of degree k on the spectral
    interval [2/cheb_ratio, 2] of D^-1 A instead, every loop vectorised; measured on the
    chute 13-18 % cheaper solves with ``chebyshev=3, cheb_ratio=15, coarsen_ratio=2``, on
    64^3 9 % dearer, so not the default), par_min (levels with at least this many cells run
    their kernels with the x planes in parallel; the result does not depend on it; default:
    none, serial: in the coupled 16 rpm chute on an idle 2-core machine with 2 numba threads a
    solve took 26.7 ms threaded with par_min = 4096 against 11.3 ms serial, as every one of the
    hundreds of parallel regions per solve wakes the sleeping OpenMP threads), precision
    ("single", default: the V-cycle in float32 inside the float64 CG, same stopping criteria,
    15-18 % cheaper gas steps on the chute; "double": the float64 V-cycle; module doc).
    There is no set-up to reuse: the whole hierarchy's coefficients are refreshed from the
    current face coefficients at every ``set_coefficients`` (about 0.4-0.5 ms on the chute
    grid), except when they equal those of the last successful set-up bit for bit (then
    nothing is done; counted in ``n_setups_skipped``).
    """

    def __init__(self, grid, pressure_bc: dict, *, tol: float = 1e-8, maxiter: int = 200,
                 nu: int = 2, coarse_max: int = 128, coarsen_ratio: float = 1.5, omega: float = 1.2,
                 chebyshev: int = 0, cheb_ratio: float = 6.0, par_min: int = 1 << 40,
                 precision: str = "single"):
        if precision not in ("single", "double"):
            raise ValueError(f"precision must be 'single' or 'double', got {precision!r}")
        self.precision = precision
        self.grid = grid
        self.pressure_bc = dict(pressure_bc)
        self.tol = float(tol)
        self.maxiter = int(maxiter)
        self.nu = int(nu)
        self.omega = float(omega)
        self.chebyshev = int(chebyshev)
        self.cheb_ratio = float(cheb_ratio)
        self.singular = not any(v == "dirichlet" for v in self.pressure_bc.values())
        self.n_rebuilds = 0
        nx, ny, nz = grid.shape
        self.N = nx * ny * nz
        self._fshapes = [(nx + 1, ny, nz), (nx, ny + 1, nz), (nx, ny, nz + 1)]
        kinds = []
        for d in range(3):
            kinds.append((_KIND[self.pressure_bc[SIDES[2 * d]]], _KIND[self.pressure_bc[SIDES[2 * d + 1]]]))
        self._dirich = np.array([1 if self.pressure_bc[s] == "dirichlet" else 0 for s in SIDES], dtype=np.int64)
        self._periodic = np.array([1 if k[0] == 2 else 0 for k in kinds], dtype=np.int64)
        h = grid.spacing
        V = h[0] * h[1] * h[2]
        self._vol = V
        self._sc = np.array([V / h[d] ** 2 for d in range(3)])
        # --- levels ---
        widths = [np.full(grid.shape[d], float(h[d])) for d in range(3)]
        shapes = [tuple(grid.shape)]
        trans = []  # per level: three axis tuples
        while shapes[-1][0] * shapes[-1][1] * shapes[-1][2] > coarse_max:
            cand = [d for d in range(3) if widths[d].size > 1]
            if not cand:
                break
            wmin = min(widths[d].max() for d in cand)
            co = [d in cand and widths[d].max() <= coarsen_ratio * wmin * (1 + 1e-9) for d in range(3)]
            axes = [_axis_transfer(widths[d], kinds[d], co[d]) for d in range(3)]
            trans.append(axes)
            widths = [a[0] for a in axes]
            shapes.append(tuple(w.size for w in widths))
        self.shapes = shapes
        L = len(shapes)
        sizes = [a * b * c for a, b, c in shapes]
        offs = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        self._LV = np.array([[s[0], s[1], s[2], offs[l]] for l, s in enumerate(shapes)], dtype=np.int64)
        # per level: x planes in parallel (enough cells to pay for a parallel region), and an
        # odd periodic x axis (the smoother then orders row nx-1 explicitly)
        self.par_min = int(par_min)
        # and whether any axis is periodic with an odd count (the colours then touch across the
        # wrap: no shortcut for the first colour from a zero guess)
        oddp = [[kinds[d][0] == 2 and s[d] % 2 == 1 and s[d] > 1 for d in range(3)] for s in shapes]
        self._LF = np.array([[1 if sz >= self.par_min else 0, int(o[0]), int(any(o))] for sz, o in zip(sizes, oddp)],
                            dtype=np.int64)
        tot = int(offs[-1])
        # axis data, concatenated over levels per axis
        lens = [[shapes[l][d] for l in range(L - 1)] for d in range(3)]
        M = max(1, max(sum(x) for x in lens))
        # [par, i1, i2, i1s, i2s][axis][fine cell]: i1s, i2s (z axis only) are i1, i2 as coarse
        # storage positions, listed in fine storage order (red-black along z), likewise
        # [facf, dfac, w1, w2, w1s, w2s]: the z transfers then run in storage order
        self._AXI = np.zeros((5, 3, M), dtype=np.int64)
        self._AXF = np.zeros((6, 3, M))
        self._AOFF = np.zeros((max(L - 1, 1), 3), dtype=np.int64)
        # per fine z storage position: the parent's coarse storage position, and the face and
        # Dirichlet factors (rows 0, 1 of AXF along z, in storage order), for the set-up
        self._ZP = np.zeros(M, dtype=np.int64)
        self._ZF = np.zeros((2, M))
        for d in range(3):
            o = 0
            for l in range(L - 1):
                W, par, i1, i2, facf, dfac, w1, w2 = trans[l][d]
                n = par.size
                self._AOFF[l, d] = o
                self._AXI[0, d, o:o + n] = par
                self._AXI[1, d, o:o + n] = i1
                self._AXI[2, d, o:o + n] = i2
                self._AXF[0, d, o:o + n] = facf
                self._AXF[1, d, o:o + n] = dfac
                self._AXF[2, d, o:o + n] = w1
                self._AXF[3, d, o:o + n] = w2
                if d == 2:
                    m = W.size
                    kf = _rb_order(n)  # k at each position
                    pos_c = _rb_order(m)
                    cpos = np.empty(m, dtype=np.int64)
                    cpos[pos_c] = np.arange(m)  # coarse K -> its storage position
                    self._AXI[3, d, o:o + n] = cpos[i1[kf]]
                    self._AXI[4, d, o:o + n] = cpos[i2[kf]]
                    self._AXF[4, d, o:o + n] = w1[kf]
                    self._AXF[5, d, o:o + n] = w2[kf]
                    self._ZP[o:o + n] = cpos[par[kf]]
                    self._ZF[0, o:o + n] = facf[kf]
                    self._ZF[1, o:o + n] = dfac[kf]
                o += n
        self._cE, self._cN, self._cT = np.zeros(tot), np.zeros(tot), np.zeros(tot)
        self._dX, self._dY, self._dZ = np.zeros(tot), np.zeros(tot), np.zeros(tot)
        self._dg = np.zeros(tot)
        self._idg = np.zeros(tot if precision == "double" else 0)  # omega/diagonal, float64 V-cycle only
        nc = sizes[-1]
        self._dense = np.zeros((nc, nc))
        # the V-cycle's operator, transfer weights, coarsest factor and work arrays: the
        # set-up's float64 arrays themselves, or float32 copies (precision="single", refreshed
        # at every set_coefficients); CG's vectors and operator stay float64 either way
        vt = np.float32 if precision == "single" else np.float64
        if precision == "single":
            self._v = [np.zeros(tot, dtype=vt) for _ in range(5)]
            self._vAXF = self._AXF.astype(vt)
            self._vdense = np.zeros((nc, nc), dtype=vt)
        else:
            self._v = [self._cE, self._cN, self._cT, self._dg, self._idg]
            self._vAXF = self._AXF
            self._vdense = self._dense
        self._t1, self._t2 = np.zeros(self.N, dtype=vt), np.zeros(self.N, dtype=vt)
        self._xl, self._bl, self._rl = np.zeros(tot, dtype=vt), np.zeros(tot, dtype=vt), np.zeros(tot, dtype=vt)
        self._dw, self._qw = np.zeros(tot, dtype=vt), np.zeros(tot, dtype=vt)
        self._vec = [np.zeros(self.N) for _ in range(6)]  # b, x, r, z, p, q
        self._part = np.zeros(max(nx, 1))  # per-plane partial sums
        self._ones = np.ones(self.N)
        self._ready = False
        self._last = [np.empty(sh) for sh in self._fshapes]  # coefficients of the last set-up
        self._last_valid = False  # _last holds them (False after a set-up with compare=False)
        self.n_setups_skipped = 0

    def storage_order(self, level: int) -> np.ndarray:
        """C-order (natural) index of the cell stored at each position of a level's arrays:
        every z row holds its even k first, then its odd k (module doc, "Storage")."""
        nx, ny, nz = self.shapes[level]
        h = (nz + 1) // 2
        k = _rb_order(nz)
        assert k.size == nz and (nz == 0 or np.count_nonzero(k % 2 == 0) == h)
        rows = np.arange(nx * ny, dtype=np.int64)[:, None] * nz
        return (rows + k[None, :]).ravel()

    def level_array(self, name: str, level: int) -> np.ndarray:
        """A copy of one of the level's coefficient arrays (``"cE"``, ``"cN"``, ``"cT"``, ``"dX"``,
        ``"dY"``, ``"dZ"``, ``"dg"``) in natural order, shape (nx, ny, nz) of the level."""
        nx, ny, nz, off = (int(v) for v in self._LV[level])
        a = getattr(self, "_" + name)[off:off + nx * ny * nz]
        out = np.empty(nx * ny * nz)
        out[self.storage_order(level)] = a
        return out.reshape(nx, ny, nz)

    @property
    def levels(self) -> list:
        """Cell counts (nx, ny, nz) of the levels, finest first."""
        return list(self.shapes)

    def set_coefficients(self, ax: np.ndarray, ay: np.ndarray, az: np.ndarray, *, compare: bool = True) -> None:
        """Face coefficients a_f on all faces, shapes (nx+1,ny,nz), (nx,ny+1,nz), (nx,ny,nz+1);
        at a periodic side face n is face 0 (give them equal).

        ``compare`` (default): skip the set-up if the coefficients equal those of the last
        set-up bit for bit.  ``compare=False``: always set up, without the comparison and
        without storing a copy for the next one (for callers whose coefficients change at
        every call: the coupled gas step, where the copy's memory traffic cost about 3 % of
        the step)."""
        for a, s in zip((ax, ay, az), self._fshapes):
            if a.shape != s:
                raise ValueError(f"coefficient shape {a.shape}, expected {s}")
        A = [np.ascontiguousarray(a, dtype=np.float64) for a in (ax, ay, az)]
        if compare:
            # the same coefficients as the last successful set-up (a particle-free or frozen
            # porosity at a fixed dt): nothing to rebuild (NaN never compares equal); the
            # comparison also stores the new coefficients (one compiled pass per array)
            changed = [_compare_store(a.reshape(-1), o.reshape(-1)) for a, o in zip(A, self._last)]
            if self._ready and self._last_valid and not any(changed):
                self.n_setups_skipped += 1
                return
        self._last_valid = compare
        _fine_coefficients(A[0], A[1], A[2], self._sc, self._dirich, self._periodic,
                           self._cE, self._cN, self._cT, self._dX, self._dY, self._dZ)
        flag = _coarsen_and_factor(self._LV, self._AOFF, self._AXI, self._AXF, self._ZP, self._ZF, self._cE,
                                   self._cN, self._cT, self._dX, self._dY, self._dZ, self._dg, self._idg,
                                   self._dense, self.singular, self.omega, *self._v, self._vdense,
                                   self.precision == "single", self._dirich)
        self._ready = flag == 0

    # interface of PressureSolver's hierarchy reuse (nothing to reuse here)
    def needs_rebuild(self) -> bool:
        return False

    def rebuild(self) -> None:
        pass

    @property
    def reference_coefficients(self):
        return None

    def reuse_state(self) -> dict:
        return {}

    def set_reuse_state(self, d: dict) -> None:
        pass

    def apply(self, phi: np.ndarray) -> np.ndarray:
        """A phi (not volume-scaled: the operator of PressureSolver) for phi of shape (nx, ny, nz)."""
        nx, ny, nz = self.grid.shape
        xs, y = np.empty(self.N), np.empty(self.N)
        _to_storage(np.ascontiguousarray(phi, dtype=np.float64).reshape(-1), xs, nx * ny, nz, 1.0)
        _matvec(nx, ny, nz, self._cE, self._cN, self._cT, self._dg, xs, y)
        out = np.empty(self.N)
        _from_storage(y, out, nx * ny, nz)
        return (out / self._vol).reshape(self.grid.shape)

    def vcycle(self, r: np.ndarray) -> np.ndarray:
        """One V-cycle applied to a (volume-scaled) residual r: the preconditioner M r."""
        nx, ny, nz = self.grid.shape
        rs, z = np.empty(self.N), np.empty(self.N)
        _to_storage(np.ascontiguousarray(r, dtype=np.float64).reshape(-1), rs, nx * ny, nz, 1.0)
        _vcycle(self._LV, self._LF, self._AOFF, self._AXI, self._vAXF, *self._v, self._vdense, self._xl, self._bl,
                self._rl, self._t1, self._t2, self._dw, self._qw, self.nu, self.chebyshev, 2.0 / self.cheb_ratio,
                rs, z, self._part)
        out = np.empty(self.N)
        _from_storage(z, out, nx * ny, nz)
        return out

    def solve(self, b: np.ndarray, x0: np.ndarray | None = None, atol: float = 0.0, scale_x0: bool = False) -> tuple:
        """Solve A phi = b (b of shape (nx,ny,nz)); returns (phi, SolveInfo).

        Converged when ``||b - A phi||_2 <= max(tol ||b||_2, atol)`` (true residual, the
        operator of :meth:`apply`; ``atol`` an absolute bound in the units of b, 0 by
        default: the relative criterion alone).  CG starts from x0 (zero if None), or with
        ``scale_x0`` from the multiple ``a x0`` closest to the solution in the A-norm
        (``a = x0.b / x0.A x0``: one matrix-vector product)."""
        if not self._ready:
            return np.full(self.grid.shape, np.nan), SolveInfo(0, np.inf, False, False, 0.0)
        bv, xv, r, z, p, q = self._vec
        nx, ny, nz = self.grid.shape
        b = np.ascontiguousarray(b, dtype=np.float64).reshape(-1)
        compat = 0.0
        if self.singular:
            _to_storage(b, bv, nx * ny, nz, 1.0)  # to the solver's storage order
            compat = float(bv.mean())
            bv -= compat
            bv *= self._vol
        else:
            _to_storage(b, bv, nx * ny, nz, self._vol)
        if x0 is None:
            xv[:] = 0.0
        else:
            _to_storage(np.ascontiguousarray(x0, dtype=np.float64).reshape(-1), xv, nx * ny, nz, 1.0)
        its, rel = _pcg(self._LV, self._LF, self._AOFF, self._AXI, self._vAXF, self._cE, self._cN, self._cT,
                        self._dg, *self._v, self._vdense, self._xl, self._bl, self._rl, self._t1, self._t2, self._dw,
                        self._qw, self.nu, self.chebyshev, 2.0 / self.cheb_ratio, self.singular, self.tol,
                        self.maxiter, bv, xv, r, z, p, q, self._part, self._ones, float(atol) * self._vol,
                        bool(scale_x0 and x0 is not None))
        x = np.empty(self.N)
        finite = _from_storage(xv, x, nx * ny, nz)  # back to C order
        if self.singular:
            x -= x.mean()
        bnorm = float(np.sqrt(np.dot(bv, bv))) / self._vol
        converged = bool(np.isfinite(rel) and (rel <= self.tol or rel * bnorm <= atol * (1.0 + 1e-12)) and finite)
        return x.reshape(self.grid.shape), SolveInfo(int(its), float(rel), converged, False, compat)
