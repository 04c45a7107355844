"""Neighbour search: O(N) cell list (counting sort) and a Verlet half list with skin.

Pairs (i, j), i < j in the cell-sorted particle order, with |r_j - r_i| < R_i + R_j + skin
(minimum image along periodic axes).  The list is rebuilt when the largest displacement since
the last build exceeds skin/2, so that no pair closer than R_i + R_j can be missing.

Build (all deterministic, identical for any thread count):

1. cell geometry (:func:`cell_grid`): along a periodic axis the fixed box (lo, hi); along
   other axes the particles' bounding box.  Cell edge >= 2 R_max + skin; the total number of
   cells is capped at a few times N so that one particle far away cannot allocate a huge grid.
2. counting sort of particles by linear cell index (:func:`cell_sort`, stable) -- the caller
   reorders the particle arrays in this order, which gives cache locality.  After the sort,
   cell c holds particles ``cell_start[c] .. cell_start[c+1]-1``.
3. one search pass (:func:`pair_search`, ``prange`` over particles): particle i scans the
   (up to) 27 neighbouring cells with index >= its own cell and keeps j > i (as rows of
   cells contiguous in memory: one or two ranges of j per row), into slots of a
   size taken from the last build (more slots and a second pass when a particle has more
   partners; a counting and a filling pass where the slots would be too many).  The pairs of
   particle i are stored contiguously from ``first_start[i]`` (:func:`pair_compact`), so the
   list is ordered by i, then by scan order.  Nothing is written out of bounds; Python grows
   the arrays.
4. :func:`second_csr`: for each particle the pairs in which it is the second member (ascending
   pair index).  The force gather uses both ranges in a fixed order (exact Newton's third law).
5. :func:`remap_history`: each new pair looks its old tangential history up by the particles'
   old indices (``old_index``, -1 for particles inserted since) in the old lists.
"""

from __future__ import annotations

import math

import numpy as np

from cfddem._jit import kernel, parallel_kernel, prange
from cfddem.particles._twin import serial_twin


@parallel_kernel
def bounding_box(pos, n):
    """Per-axis min and max of pos[:n] (exact, order independent)."""
    x0 = np.inf
    y0 = np.inf
    z0 = np.inf
    x1 = -np.inf
    y1 = -np.inf
    z1 = -np.inf
    for i in prange(n):
        x0 = min(x0, pos[i, 0])
        y0 = min(y0, pos[i, 1])
        z0 = min(z0, pos[i, 2])
        x1 = max(x1, pos[i, 0])
        y1 = max(y1, pos[i, 1])
        z1 = max(z1, pos[i, 2])
    return x0, y0, z0, x1, y1, z1


def cell_grid(pos, n, rmax, skin, plo, phi, periodic, max_cells=None, serial=False):
    """Cell geometry: (lo (3), cell size (3), counts (3) int64).

    ``periodic[a]`` True: the axis spans [plo[a], phi[a]) and needs at least 3 cells.
    """
    cut = 2.0 * rmax + skin
    if n > 0:
        bb = (bounding_box_s if serial else bounding_box)(pos, n)
    else:
        bb = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    lo = np.zeros(3)
    length = np.zeros(3)
    for a in range(3):
        if periodic[a]:
            lo[a] = plo[a]
            length[a] = phi[a] - plo[a]
        else:
            lo[a] = bb[a] - 1e-9 * max(1.0, abs(bb[a]))
            length[a] = max(bb[a + 3] - lo[a], 0.0) * (1 + 1e-12) + 1e-300
    if max_cells is None:
        max_cells = max(4 * n, 4096)
    c = cut
    while True:
        nc = np.ones(3, dtype=np.int64)
        for a in range(3):
            nc[a] = max(1, int(math.floor(length[a] / c)))
        if int(nc[0]) * int(nc[1]) * int(nc[2]) <= max_cells:
            break
        c *= 1.25
    size = np.where(nc > 0, length / nc, 1.0)
    size = np.maximum(size, 1e-300)
    return lo, size, grid_strides(nc, int(np.argmax(nc)))


def grid_strides(nc, major: int = 0) -> np.ndarray:
    """The cell counts ``nc`` (3) followed by the strides of the linear cell index
    ``c = cx * nc[3] + cy * nc[4] + cz * nc[5]`` (6 int64 in all): axis ``major`` varies
    slowest, the other two in their order.  With the axis of most cells as the major one, a
    layer of cells across it is a contiguous range of cells (and of cell-sorted particles): the
    slabs of the force pass (:func:`slab_starts`), and neighbours that sit close in memory."""
    nc = np.asarray(nc, np.int64)[:3]
    rest = [a for a in range(3) if a != major]
    st = np.zeros(3, np.int64)
    st[rest[1]] = 1
    st[rest[0]] = nc[rest[1]]
    st[major] = nc[rest[0]] * nc[rest[1]]
    return np.concatenate([nc, st])


def slab_starts(nc, cell_start, periodic) -> np.ndarray:
    """Particle ranges of the slabs of the force pass: layers of cells across the major axis
    (the axis of most cells, the first of equals, as :func:`cell_grid` chose it), cell-sorted particles ``out[s] .. out[s + 1] - 1``.

    A pair of the list joins two particles of the same or of neighbouring layers, so slabs
    three apart never share a particle: the force pass runs the slabs s = 0, 3, 6, ... in
    parallel, then 1, 4, ..., then 2, 5, ... (:func:`cfddem.particles.integrate.pair_forces`).
    Along a periodic major axis the last slab neighbours the first, so the number of slabs is
    made a multiple of three (adjacent layers merged).  The slabs depend on the cells only,
    never on the thread count: the order in which each particle's forces are summed, and so
    the result, is the same for any number of threads."""
    major = int(np.argmax(nc[:3]))
    nl = int(nc[major])
    stride = int(nc[3 + major])
    ns = nl
    if periodic[major] and nl >= 3:
        ns = 3 * (nl // 3)
    layers = (np.arange(ns + 1, dtype=np.int64) * nl) // ns
    return np.ascontiguousarray(cell_start[layers * stride], dtype=np.int64)


@kernel
def cell_sort(pos, n, lo, size, nc, cell_of, order, cell_start):
    """Stable counting sort of particles by linear cell index.

    Fills ``cell_of[i]`` (cell of particle i), ``order`` (new position -> old index) and
    ``cell_start`` (length ncell + 1, prefix sums of the counts in the new order).
    """
    ncell = nc[0] * nc[1] * nc[2]
    for c in range(ncell + 1):
        cell_start[c] = 0
    for i in range(n):
        cx = int((pos[i, 0] - lo[0]) / size[0])
        cy = int((pos[i, 1] - lo[1]) / size[1])
        cz = int((pos[i, 2] - lo[2]) / size[2])
        cx = min(max(cx, 0), nc[0] - 1)
        cy = min(max(cy, 0), nc[1] - 1)
        cz = min(max(cz, 0), nc[2] - 1)
        c = cx * nc[3] + cy * nc[4] + cz * nc[5]
        cell_of[i] = c
        cell_start[c + 1] += 1
    for c in range(ncell):
        cell_start[c + 1] += cell_start[c]
    # stable placement: use a running cursor per cell (reuse cell_of as storage is not possible)
    for i in range(n):
        c = cell_of[i]
        order[cell_start[c]] = i
        cell_start[c] += 1
    for c in range(ncell, 0, -1):
        cell_start[c] = cell_start[c - 1]
    cell_start[0] = 0
    return ncell


@kernel(inline="always")
def _min_image(d, plen):
    """Minimum image of a coordinate difference along an axis of period ``plen`` (0: not
    periodic).  Positions are kept wrapped into the box, so |d| < plen and one shift suffices
    (comparisons instead of a division and a floor: this sits in the innermost loops)."""
    if plen > 0.0:
        if d > 0.5 * plen:
            d -= plen
        elif d < -0.5 * plen:
            d += plen
    return d


@kernel(inline="always")
def _wrap(x, lo, plen):
    """Wrap a coordinate into [lo, lo + plen) (plen 0: not periodic); one period at most per
    call (a particle moves far less than a box length in one step), else a floor."""
    if plen > 0.0:
        if x >= lo + plen:
            x -= plen
            if x >= lo + plen:
                x = lo + (x - lo) - plen * math.floor((x - lo) / plen)
        elif x < lo:
            x += plen
            if x < lo:
                x = lo + (x - lo) - plen * math.floor((x - lo) / plen)
    return x


@kernel
def affine_moments(pos, vel, n, free, nf, row, out_xx, out_xv):
    """The normal equations of the least-squares fit v ~ c + G (x - x_0) over the ``nf`` axes
    ``free``: ``out_xx`` ((nf+1) x (nf+1)) = A^T A and ``out_xv`` ((nf+1) x 3) = A^T V with
    A = [1, x - x_0], x_0 the first particle's position (a shift that keeps the sums well
    scaled).  ``row``: scratch of 4.  One serial pass (the same sums for any thread count)."""
    m = nf + 1
    for a in range(m):
        for b in range(m):
            out_xx[a, b] = 0.0
        for c in range(3):
            out_xv[a, c] = 0.0
    if n == 0:
        return
    for i in range(n):
        row[0] = 1.0
        for a in range(nf):
            row[a + 1] = pos[i, free[a]] - pos[0, free[a]]
        for a in range(m):
            ra = row[a]
            for b in range(a, m):
                out_xx[a, b] += ra * row[b]
            for c in range(3):
                out_xv[a, c] += ra * vel[i, c]
    for a in range(m):
        for b in range(a):
            out_xx[a, b] = out_xx[b, a]


@kernel(inline="always")
def _axis_cell(o, c, nc, per):
    """The cell ``c + o`` along an axis of ``nc`` cells (``per``: periodic, wrapped when the
    axis has 3 cells or more, else no neighbour across the seam), -1 where there is none."""
    a = c + o
    if per and nc >= 3:
        if a < 0:
            a += nc
        elif a >= nc:
            a -= nc
    elif a < 0 or a >= nc:
        a = -1
    return a


@parallel_kernel
def pair_search(pos, radius, n, skin, lo, size, nc, periodic_len, cell_start, starts, slots, tmp, counts):
    """The partners j > i of particle i within R_i + R_j + skin, in scan order, into ``tmp``:

    * ``slots`` > 0: at most ``slots`` of them from ``tmp[i * slots]`` (one pass; then
      :func:`pair_compact` writes the list);
    * ``slots`` = 0: from ``tmp[starts[i]]``, at most ``starts[i + 1] - starts[i]`` of them (a
      counting pass with all ``starts`` zero, then a filling pass with their prefix sums: for
      neighbourhoods too dense for slots).

    The scan: the cells of the stencil with linear index >= i's own (and j > i in its own
    cell), visited as rows along the axis of stride 1 (:func:`grid_strides`: the cells of a
    row, and their cell-sorted particles, are contiguous, so a row is one or two ranges of j
    instead of three cells), the rows in the order of the slowest axis, then the middle one.
    A whole row lies above or below i's cell (its offset from i's row is a multiple of the
    row length), so only i's own row is cut.  ``counts[i]`` gets the number of partners, also
    beyond the room.  Returns the largest count: above ``slots`` the caller gives more slots
    and searches again."""
    # the axes by stride: A slowest, C of stride 1 (the later axis of equal strides), B between
    st0 = nc[3]
    st1 = nc[4]
    st2 = nc[5]
    axa = 0
    if st1 > st0:
        axa = 1
    if st2 > st0 and st2 > st1:
        axa = 2
    r0 = 1 if axa == 0 else 0
    r1 = 2 if axa != 2 else 1
    axc = r1
    axb = r0
    if nc[3 + r0] < nc[3 + r1]:
        axc = r0
        axb = r1
    nca = nc[axa]
    ncb = nc[axb]
    ncc = nc[axc]
    sta = nc[3 + axa]
    stb = nc[3 + axb]
    pera = periodic_len[axa] > 0.0
    perb = periodic_len[axb] > 0.0
    perc = periodic_len[axc] > 0.0
    pl0 = periodic_len[0]
    pl1 = periodic_len[1]
    pl2 = periodic_len[2]
    nc0 = nc[0]
    nc1 = nc[1]
    nc2 = nc[2]
    lo0 = lo[0]
    lo1 = lo[1]
    lo2 = lo[2]
    sz0 = size[0]
    sz1 = size[1]
    sz2 = size[2]
    most = 0
    for i in prange(n):
        xi = pos[i, 0]
        yi = pos[i, 1]
        zi = pos[i, 2]
        ri = radius[i]
        cx = min(max(int((xi - lo0) / sz0), 0), nc0 - 1)
        cy = min(max(int((yi - lo1) / sz1), 0), nc1 - 1)
        cz = min(max(int((zi - lo2) / sz2), 0), nc2 - 1)
        ca = cx if axa == 0 else (cy if axa == 1 else cz)
        cb = cx if axb == 0 else (cy if axb == 1 else cz)
        cc = cx if axc == 0 else (cy if axc == 1 else cz)
        own = ca * sta + cb * stb  # the base of i's row
        if slots > 0:
            base = i * slots
            room = slots
        else:
            base = starts[i]
            room = starts[i + 1] - base
        cnt = 0
        for oa in range(-1, 2):
            aa = _axis_cell(oa, ca, nca, pera)
            if aa < 0:
                continue
            for ob in range(-1, 2):
                ab = _axis_cell(ob, cb, ncb, perb)
                if ab < 0:
                    continue
                row = aa * sta + ab * stb
                if row < own:
                    continue  # every cell of the row below i's cell
                # the row's cells in offset order, merged into at most two contiguous runs
                nr = 0
                lo_a = 0
                hi_a = -1
                lo_b = 0
                hi_b = -1
                for oc in range(-1, 2):
                    ac = _axis_cell(oc, cc, ncc, perc)
                    if ac < 0 or (row == own and ac < cc):
                        continue
                    c = row + ac
                    if nr == 1 and c == hi_a + 1:
                        hi_a = c
                    elif nr == 2 and c == hi_b + 1:
                        hi_b = c
                    elif nr == 0:
                        lo_a = c
                        hi_a = c
                        nr = 1
                    else:
                        lo_b = c
                        hi_b = c
                        nr = 2
                for r in range(nr):
                    clo = lo_a if r == 0 else lo_b
                    chi = hi_a if r == 0 else hi_b
                    for j in range(max(cell_start[clo], i + 1), cell_start[chi + 1]):
                        dx = _min_image(pos[j, 0] - xi, pl0)
                        dy = _min_image(pos[j, 1] - yi, pl1)
                        dz = _min_image(pos[j, 2] - zi, pl2)
                        cut = ri + radius[j] + skin
                        if dx * dx + dy * dy + dz * dz < cut * cut:
                            if cnt < room:
                                tmp[base + cnt] = j
                            cnt += 1
        counts[i] = cnt
        most = max(most, cnt)
    return most


@parallel_kernel
def pair_compact(n, slots, tmp, first_start, pi, pj):
    """The list from :func:`pair_search`'s results: the pairs of particle i at
    ``first_start[i] .. first_start[i + 1] - 1`` (the prefix sums of its counts); their
    partners from its slots (``slots`` > 0) or already in ``pj`` (``slots`` = 0)."""
    for i in prange(n):
        k = first_start[i]
        base = i * slots
        for q in range(first_start[i + 1] - k):
            pi[k + q] = i
            if slots > 0:
                pj[k + q] = tmp[base + q]


@kernel
def prefix_sum(counts, n, start):
    """start[0] = 0, start[i+1] = start[i] + counts[i]."""
    start[0] = 0
    for i in range(n):
        start[i + 1] = start[i] + counts[i]
    return start[n]


@kernel
def second_csr(pj, npairs, n, second_start, second_list):
    """For each particle j the pairs k with pj[k] == j, ascending k (counting sort)."""
    for i in range(n + 1):
        second_start[i] = 0
    for k in range(npairs):
        second_start[pj[k] + 1] += 1
    for i in range(n):
        second_start[i + 1] += second_start[i]
    for k in range(npairs):
        j = pj[k]
        second_list[second_start[j]] = k
        second_start[j] += 1
    for i in range(n, 0, -1):
        second_start[i] = second_start[i - 1]
    second_start[0] = 0


@parallel_kernel
def remap_history(pi, pj, npairs, hist, old_index, old_pi, old_pj, old_hist, old_first_start,
                  old_second_start, old_second_list, n_old):
    """hist[k] = tangential history of pair (pi[k], pj[k]) in the old list (sign-adjusted when
    the pair's orientation flipped), zero if the pair was not in the old list."""
    for k in prange(npairs):
        hist[k, 0] = 0.0
        hist[k, 1] = 0.0
        hist[k, 2] = 0.0
        oa = old_index[pi[k]]
        ob = old_index[pj[k]]
        if oa < 0 or ob < 0 or oa >= n_old or ob >= n_old:
            continue
        found = False
        for q in range(old_first_start[oa], old_first_start[oa + 1]):
            if old_pj[q] == ob:
                hist[k, 0] = old_hist[q, 0]
                hist[k, 1] = old_hist[q, 1]
                hist[k, 2] = old_hist[q, 2]
                found = True
                break
        if not found:
            for s in range(old_second_start[oa], old_second_start[oa + 1]):
                q = old_second_list[s]
                if old_pi[q] == ob:
                    hist[k, 0] = -old_hist[q, 0]
                    hist[k, 1] = -old_hist[q, 1]
                    hist[k, 2] = -old_hist[q, 2]
                    break


@parallel_kernel
def max_displacement2(pos, ref, n, periodic_len):
    """max_i |r_i - r_i(at last build)|^2, minimum image along periodic axes."""
    m = 0.0
    for i in prange(n):
        dx = _min_image(pos[i, 0] - ref[i, 0], periodic_len[0])
        dy = _min_image(pos[i, 1] - ref[i, 1], periodic_len[1])
        dz = _min_image(pos[i, 2] - ref[i, 2], periodic_len[2])
        m = max(m, dx * dx + dy * dy + dz * dz)
    return m


def brute_force_pairs(pos, radius, cutoff_extra, periodic_len):
    """Reference (numpy, O(N^2)): set of (min(id), max(id))-index pairs with
    |r_ij| < R_i + R_j + cutoff_extra (minimum image)."""
    n = len(pos)
    d = pos[None, :, :] - pos[:, None, :]
    for a in range(3):
        if periodic_len[a] > 0:
            d[..., a] -= periodic_len[a] * np.floor(d[..., a] / periodic_len[a] + 0.5)
    r2 = (d**2).sum(-1)
    cut = radius[:, None] + radius[None, :] + cutoff_extra
    ii, jj = np.nonzero((r2 < cut**2) & (np.arange(n)[:, None] < np.arange(n)[None, :]))
    return set(zip(ii.tolist(), jj.tolist()))


bounding_box_s = serial_twin(bounding_box)
pair_search_s = serial_twin(pair_search)
pair_compact_s = serial_twin(pair_compact)
remap_history_s = serial_twin(remap_history)


@parallel_kernel
def gather_rows(a, order, n, out):
    """out[k, :] = a[order[k], :] for k < n (row permutation into a scratch buffer)."""
    m = a.shape[1]
    for k in prange(n):
        src = order[k]
        for c in range(m):
            out[k, c] = a[src, c]


@parallel_kernel
def copy_rows(src, n, dst):
    """dst[k, :] = src[k, :] for k < n."""
    m = src.shape[1]
    for k in prange(n):
        for c in range(m):
            dst[k, c] = src[k, c]


gather_rows_s = serial_twin(gather_rows)
copy_rows_s = serial_twin(copy_rows)


def permute_rows(a, order, n, scratch, serial):
    """In-place a[:n] = a[order] for a C-contiguous array of float64, int64 (bitwise) or other
    dtypes (numpy fallback), using ``scratch`` (float64, flat) as the buffer."""
    if a.dtype == np.float64 or a.dtype == np.int64:
        cap = a.shape[0]
        a2 = a.reshape(cap, -1)
        if a.dtype == np.int64:
            a2 = a2.view(np.float64)
        m = a2.shape[1]
        out = scratch[: n * m].reshape(n, m)
        (gather_rows_s if serial else gather_rows)(a2, order, n, out)
        (copy_rows_s if serial else copy_rows)(out, n, a2)
    else:
        a[:n] = a[order]

