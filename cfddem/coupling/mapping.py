"""Particle <-> grid mapping on the staggered (MAC) gas grid (physics.md section 4).

The distribution function ``delta`` of physics.md is trilinear: a particle at ``r`` gives
each of the 8 grid nodes around it the weight

    w = (1 - |s_x - i|)(1 - |s_y - j|)(1 - |s_z - k|),   s = (r - node_0)/h  (node units),

so the weights are non-negative and sum to 1.  The same weights serve four purposes:

* ``porosity``: solid volume V_a spread to cell centres, eps_c = 1 - sum_a V_a w_ac / V_cell;
* ``deposit_faces``: each component of a per-particle force spread to its own staggered
  face grid (x-component to the x-faces at (x_i, y_j+1/2, z_k+1/2), etc.);
* ``interpolate_faces`` / ``interpolate_centres``: gas velocity (each component from its
  own faces) and centre fields to the particle; exactly the transpose of the deposition, so
  ``<deposit(f), u> = <f, interpolate(u)>`` and the momentum given to the gas is exactly
  the opposite of the momentum taken from it;
* ``gradient_at_particles``: grad p on the faces by central differences, interpolated like
  the velocity.

Node locations (names as in :mod:`cfddem.gas.grid`: ``ccc`` centres, ``fcc`` x-faces,
``cfc`` y-faces, ``ccf`` z-faces).  Arrays are *interior* arrays (no halo): a centre field
is ``(nx, ny, nz)``, an x-face field ``(nx+1, ny, nz)`` and so on.  ``Field`` objects (with
an ``.interior`` attribute) are accepted where an array is read.

Boundary rules.  What a particle near a side of the box sees and deposits is the
``particle_rule`` that the side's boundary condition declares (:class:`cfddem.gas.BC`; the
mapping takes the gas's :class:`~cfddem.gas.BoundarySet`, a dict side -> BC, or, for a box
of walls and periodic axes, three periodic flags):

* ``"fold"`` (walls, inlets, and the pressure outlet): a particle keeps its whole volume
  (and its whole force) inside the domain.  Weight that would fall on a node outside the set
  of nodes the gas solver updates is folded onto the adjacent one:

  - centre nodes: a point within half a cell of the side would give weight to the halo cell
    -1 (or n); that weight goes to cell 0 (or n-1);
  - face nodes along the face normal: the boundary faces 0 and n carry prescribed (wall)
    velocities and are not updated by the momentum equation, so their weight goes to faces 1
    (and n-1).  A force deposited there would be lost; instead the whole force reaches the
    gas.  Interpolation uses the same folded weights (it is the transpose), so within half a
    cell of a wall the particle sees the first interior face's velocity.  (At a pressure
    outlet the boundary face is a gas unknown, but the outlet declares the same rule: its
    weight goes to face n-1 as well.)
  - particle centres outside the box are clamped onto the side (the count is reported by
    :func:`porosity` as ``n_outside``).

* ``"leave"`` (a side that particles leave the gas through, e.g. the silo's outlet plane):
  mapped as "fold"; the exchange (:class:`cfddem.coupling.exchange.CoupledGas`) gives a
  particle whose centre lies beyond the side no volume, no drag and no pressure force: it has
  left the gas domain.

* ``"wrap"`` (periodic sides, in pairs): node n is node 0.  Face grids keep their ``n+1``
  entries along a periodic normal axis; deposition writes faces 0..n-1 only (face n stays 0)
  and interpolation reads face 0 for face n, so the pair stays exactly adjoint.

A folding axis with a single cell has no interior face; the normal component is then
dropped (deposited and interpolated as zero).

:class:`MappingPlan` computes the weights and the particle sort once per location for one
particle configuration and reuses them for every field of a coupling step; the module
functions build a plan per call.

Thread-independent deposition: the single-field methods (:func:`deposit`,
:meth:`MappingPlan.deposit`) scatter *serially* over the particles (in index order, the 8
corners of each in a fixed order), so no two threads ever add to the same node and the sums
are bit-identical for 1 and N threads.  The weights (per particle and axis) are computed in
parallel, each particle writing only its own slot, and the interpolations are parallel over
particles for the same reason.

Fused kernels for the coupling step (:class:`cfddem.coupling.exchange.CoupledGas`) read
*compact weights* computed once per plan in one parallel pass (:func:`_compact_weights_kernel`:
per particle and axis the centre and the face node pair as int32 and their upper weights
``f``, the lower being ``1 - f``: the numbers of :func:`_axis_weights`, 96 bytes per
particle), one pass each: :meth:`MappingPlan.porosity` (deposit and the outside count),
:meth:`MappingPlan.interpolate_slip` (eps, the three face velocities, slip and Re per
particle), :meth:`MappingPlan.deposit_drag_pairs` (K and K v_c on each face grid) and
:meth:`MappingPlan.apply_forces` (drag from the new face velocities plus the pressure forces,
written into the caller's array, with thread-independent block sums).

Their deposits are parallel and still thread-independent: a serial counting sort
(:func:`_chunk_sort_kernel`) splits the z nodes into a fixed number of chunks (16, or fewer
on short grids: even, or 1; it depends on the grid only) of consecutive nodes holding about
equally many particles, by each particle's lower z node (the centre nodes for the porosity
and the x- and y-face grids, the z-face nodes for the z-face grid).  A particle of chunk b
writes only to z nodes in [start_b, start_{b+1}], so the even chunks run in parallel
without sharing a node, then the odd ones; each chunk adds its particles in index order.
The order of the additions to a node thus depends on the positions and the grid, never on
the thread count (it differs from the serial index order in round-off only).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from cfddem._jit import kernel, parallel_kernel, prange
from cfddem.errors import CaseError
from cfddem.gas.operators import c2f_gradient

__all__ = [
    "GridSpec",
    "MappingPlan",
    "as_grid_spec",
    "LOCATIONS",
    "node_shape",
    "trilinear_weights",
    "deposit",
    "porosity",
    "PorosityResult",
    "deposit_faces",
    "interpolate",
    "interpolate_faces",
    "interpolate_centres",
    "face_gradient",
    "gradient_at_particles",
]

LOCATIONS = ("ccc", "fcc", "cfc", "ccf")
FACE_LOCATIONS = ("fcc", "cfc", "ccf")
_FORCE_BLOCK = 512  # particles per block of the thread-independent force sums
_Z_CHUNKS = 16  # z chunks of the parallel deposits (fixed: the sums do not depend on the thread count)


class GridSpec(NamedTuple):
    """origin (x0, y0, z0), spacing (dx, dy, dz), shape (nx, ny, nz) of the cell grid."""

    origin: tuple
    spacing: tuple
    shape: tuple

    @property
    def cell_volume(self) -> float:
        return float(self.spacing[0] * self.spacing[1] * self.spacing[2])


def as_grid_spec(grid) -> GridSpec:
    """A :class:`GridSpec` from a GridSpec, an object with ``origin``/``spacing``/``shape``
    (e.g. :class:`cfddem.gas.grid.StaggeredGrid`), a mapping with those keys, or a tuple
    ``(origin, spacing, shape)``."""
    if isinstance(grid, GridSpec):
        spec = grid
    elif isinstance(grid, dict):
        spec = GridSpec(grid["origin"], grid["spacing"], grid["shape"])
    elif all(hasattr(grid, a) for a in ("origin", "spacing", "shape")):
        spec = GridSpec(grid.origin, grid.spacing, grid.shape)
    elif isinstance(grid, (tuple, list)) and len(grid) == 3:
        spec = GridSpec(*grid)
    else:
        raise CaseError("coupling.grid", f"cannot read a grid spec (origin, spacing, shape) from {grid!r}")
    try:
        origin = tuple(float(v) for v in spec.origin)
        spacing = tuple(float(v) for v in spec.spacing)
        shape = tuple(int(v) for v in spec.shape)
    except (TypeError, ValueError) as exc:
        raise CaseError("coupling.grid", f"bad grid spec {spec!r}: {exc}") from None
    if len(origin) != 3 or len(spacing) != 3 or len(shape) != 3:
        raise CaseError("coupling.grid", "origin, spacing and shape need three entries each")
    if any(not (h > 0.0) for h in spacing) or any(n < 1 for n in shape):
        raise CaseError("coupling.grid", f"spacing must be > 0 and shape >= 1, got {spacing}, {shape}")
    return GridSpec(origin, spacing, shape)


SIDES = ("x-", "x+", "y-", "y+", "z-", "z+")
PARTICLE_RULES = ("fold", "leave", "wrap")


def _side_rules(boundaries) -> tuple:
    """The mapping rule of each side (``"fold"`` or ``"wrap"``, in the order of ``SIDES``) from
    ``boundaries``: the gas's boundary conditions (an object with ``particle_rules``, e.g. a
    :class:`cfddem.gas.BoundarySet`, or a dict side -> BC, whose ``particle_rule`` is read,
    or side -> rule; or the six rules), or periodic flags (None: none periodic; a bool for all
    three axes; three flags): wrap on the periodic axes, fold on the others."""
    if boundaries is None:
        rules = ("fold",) * 6
    elif hasattr(boundaries, "particle_rules"):
        rules = tuple(boundaries.particle_rules)
    elif isinstance(boundaries, dict):
        missing = [s for s in SIDES if s not in boundaries]
        if missing:
            raise CaseError("coupling.boundaries", f"need a rule for each of {SIDES}; missing {missing}")
        rules = tuple(getattr(boundaries[s], "particle_rule", boundaries[s]) for s in SIDES)
    elif isinstance(boundaries, (bool, np.bool_)):
        rules = ("wrap" if boundaries else "fold",) * 6
    elif len(boundaries) == 6 and all(isinstance(r, str) for r in boundaries):
        rules = tuple(boundaries)
    else:
        flags = tuple(bool(v) for v in boundaries)
        if len(flags) != 3:
            raise CaseError("coupling.periodic", f"need three flags, got {boundaries!r}")
        rules = tuple("wrap" if flags[a] else "fold" for a in range(3) for _ in range(2))
    for s, r in zip(SIDES, rules):
        if r not in PARTICLE_RULES:
            raise CaseError("coupling.boundaries", f"side {s}: particle rule {r!r}, expected one of {PARTICLE_RULES}")
    for a in range(3):
        if (rules[2 * a] == "wrap") != (rules[2 * a + 1] == "wrap"):
            raise CaseError("coupling.boundaries", f"side {SIDES[2 * a]}: wrap must be the rule of both sides or of none")
    return rules


def _periodic(rules: tuple) -> tuple:
    """Per axis: whether the side rules wrap."""
    return tuple(rules[2 * a] == "wrap" for a in range(3))


def node_shape(grid, location="ccc") -> tuple:
    """Interior array shape of the nodes of ``location`` (centres or one face grid)."""
    spec = as_grid_spec(grid)
    if location not in LOCATIONS:
        raise CaseError("coupling.location", f"unknown location {location!r}; expected one of {LOCATIONS}")
    return _node_shape(spec.shape, location)


def _node_shape(shape, location) -> tuple:
    """:func:`node_shape` of cell counts ``shape`` and a valid location, unchecked."""
    return tuple(n + (1 if location[a] == "f" else 0) for a, n in enumerate(shape))


class _Axes(NamedTuple):
    x0: np.ndarray  # position of node 0
    h: np.ndarray
    n: np.ndarray  # cells (period for periodic axes)
    per: np.ndarray  # 1 periodic
    lo: np.ndarray  # fold limits (wall axes)
    hi: np.ndarray
    bmin: np.ndarray  # smallest lower-node index (bin offset)
    nbin: np.ndarray
    smin: np.ndarray  # clamp range in node units (wall axes)
    smax: np.ndarray
    shape: tuple  # node array shape
    dead: bool  # a face grid on a one-cell wall axis: no interior face


def _axes(spec: GridSpec, location: str, rules: tuple) -> _Axes:
    """The axis parameters of the weights of ``location`` under the side rules (:func:`_side_rules`).

    "wrap" (both sides): node n is node 0.  "fold": a particle centre beyond the side is
    clamped onto it (node units: 0 or n on a face axis, -0.5 or n - 0.5 on a centre axis), and
    weight beyond the first node that the gas solver updates next to the side folds onto that
    node: the first cell centre, or on the face grid along the side's normal the first
    interior face (the boundary face carries the boundary's value)."""
    x0 = np.empty(3)
    h = np.empty(3)
    n = np.empty(3, np.int64)
    per = np.empty(3, np.int64)
    lo = np.empty(3, np.int64)
    hi = np.empty(3, np.int64)
    bmin = np.empty(3, np.int64)
    nbin = np.empty(3, np.int64)
    smin = np.empty(3)
    smax = np.empty(3)
    dead = False
    for a in range(3):
        na, ha, oa = spec.shape[a], spec.spacing[a], spec.origin[a]
        face = location[a] == "f"
        h[a] = ha
        n[a] = na
        wrap = rules[2 * a] == "wrap"
        per[a] = 1 if wrap else 0
        x0[a] = oa if face else oa + 0.5 * ha
        if wrap:
            lo[a], hi[a], bmin[a], nbin[a] = 0, na - 1, 0, na
            smin[a], smax[a] = 0.0, float(na)
            continue
        # "fold" on both sides ("leave" maps as "fold": the exchange gives no volume or force
        # to a particle beyond a "leave" side)
        if face:
            lo[a], hi[a], bmin[a], nbin[a] = 1, na - 1, 0, na
            smin[a], smax[a] = 0.0, float(na)
            if na < 2:
                dead = True
        else:
            lo[a], hi[a], bmin[a], nbin[a] = 0, na - 1, -1, na + 1
            smin[a], smax[a] = -0.5, na - 0.5
    shape = tuple(int(spec.shape[a]) + (1 if location[a] == "f" else 0) for a in range(3))
    return _Axes(x0, h, n, per, lo, hi, bmin, nbin, smin, smax, shape, dead)


# --------------------------------------------------------------------------------------
# kernels
# --------------------------------------------------------------------------------------


@kernel(inline="always")
def _axis_weights(x, x0, h, n, per, lo, hi, bmin, smin, smax):
    """Lower node a0, upper node a1 (after wrap/fold), their weights and the bin index."""
    s = (x - x0) / h
    if per == 1:
        s = s - n * np.floor(s / n)
        if s >= n:
            s -= n
        if s < 0.0:
            s = 0.0
    else:
        if s < smin:
            s = smin
        if s > smax:
            s = smax
    i0 = int(np.floor(s))
    if i0 > n - 1:
        i0 = n - 1
    f = s - i0
    a0 = i0
    a1 = i0 + 1
    if per == 1:
        if a1 >= n:
            a1 -= n
        b = i0
    else:
        if a0 < lo:
            a0 = lo
        if a0 > hi:
            a0 = hi
        if a1 < lo:
            a1 = lo
        if a1 > hi:
            a1 = hi
        b = i0 - bmin
    return b, a0, a1, 1.0 - f, f


@parallel_kernel
def _weights_kernel(pos, x0, h, n, per, lo, hi, bmin, smin, smax, a0, a1, w0, w1):
    """Per particle and axis: nodes a0, a1 and weights w0, w1 (each particle its own slot)."""
    for p in prange(pos.shape[0]):
        for a in range(3):
            b, i0, i1, v0, v1 = _axis_weights(pos[p, a], x0[a], h[a], n[a], per[a], lo[a], hi[a], bmin[a], smin[a], smax[a])
            a0[p, a] = i0
            a1[p, a] = i1
            w0[p, a] = v0
            w1[p, a] = v1
    return 0


@parallel_kernel
def _weights4_kernel(pos, x0, h, n, per, lo, hi, bmin, smin, smax, a0, a1, w0, w1):
    """The weights of the four locations (index l of ``LOCATIONS``; parameters (4, 3),
    outputs (4, n, 3)) in one pass: along axis a the centre variant (shared by the three
    locations centred on a) and the face variant (location a + 1) are evaluated once each."""
    for p in prange(pos.shape[0]):
        for a in range(3):
            x = pos[p, a]
            bc, c0, c1, v0, v1 = _axis_weights(x, x0[0, a], h[0, a], n[0, a], per[0, a], lo[0, a], hi[0, a],
                                               bmin[0, a], smin[0, a], smax[0, a])
            f = a + 1
            bf, f0, f1, u0, u1 = _axis_weights(x, x0[f, a], h[f, a], n[f, a], per[f, a], lo[f, a], hi[f, a],
                                               bmin[f, a], smin[f, a], smax[f, a])
            for loc in range(4):
                if loc == f:
                    a0[loc, p, a] = f0
                    a1[loc, p, a] = f1
                    w0[loc, p, a] = u0
                    w1[loc, p, a] = u1
                else:
                    a0[loc, p, a] = c0
                    a1[loc, p, a] = c1
                    w0[loc, p, a] = v0
                    w1[loc, p, a] = v1
    return 0


@kernel(inline="always")
def _interp_at(a0, a1, w0, w1, p, field):
    """sum over the 8 corner nodes of (wx wy wz) field[node], corners in the order
    (cx, cy, cz) = (0,0,0), (0,0,1), ..., (1,1,1)."""
    acc = 0.0
    for cx in range(2):
        ix = a0[p, 0] if cx == 0 else a1[p, 0]
        wx = w0[p, 0] if cx == 0 else w1[p, 0]
        for cy in range(2):
            iy = a0[p, 1] if cy == 0 else a1[p, 1]
            wxy = wx * (w0[p, 1] if cy == 0 else w1[p, 1])
            for cz in range(2):
                iz = a0[p, 2] if cz == 0 else a1[p, 2]
                acc += wxy * (w0[p, 2] if cz == 0 else w1[p, 2]) * field[ix, iy, iz]
    return acc


@kernel
def _scatter_kernel(a0, a1, w0, w1, val, out):
    """out[t] += w_pt val[p]: serial over particles (index order), so the same sums in the
    same order for any thread count."""
    for p in range(a0.shape[0]):
        v = val[p]
        for cx in range(2):
            ix = a0[p, 0] if cx == 0 else a1[p, 0]
            wx = w0[p, 0] if cx == 0 else w1[p, 0]
            for cy in range(2):
                iy = a0[p, 1] if cy == 0 else a1[p, 1]
                wxy = wx * (w0[p, 1] if cy == 0 else w1[p, 1])
                for cz in range(2):
                    iz = a0[p, 2] if cz == 0 else a1[p, 2]
                    out[ix, iy, iz] += wxy * (w0[p, 2] if cz == 0 else w1[p, 2]) * v
    return 0


@parallel_kernel
def _interp_kernel(a0, a1, w0, w1, field, out):
    """out[p] = sum over the 8 corner nodes of w * field[node] (each particle its own slot)."""
    for p in prange(a0.shape[0]):
        out[p] = _interp_at(a0, a1, w0, w1, p, field)
    return 0


# ---- fused kernels of the coupling step ----
#
# The per-axis weights are computed once per plan (``fpar (4, 3, 4)`` = (x0, h, smin, smax)
# and ``ipar (4, 3, 5)`` = (n, per, lo, hi, bmin) per location (index of ``LOCATIONS``) and
# axis, read into locals outside the particle loop) and stored compactly (2.9 MB for 30k
# particles).  Why: storing the full weights of all four locations ((4, n, 3) int64 node
# indices and float64 weights, 11.6 MB for 30k particles) made every kernel that read them
# back memory-bound, and recomputing them inline in each kernel cost about 0.67 ms per kernel.


@kernel(inline="always")
def _i8(i0, i1, j0, j1, k0, k1, wx0, wx1, wy0, wy1, wz0, wz1, field):
    """sum over the 8 corners of (wx wy wz) field[node], in the order and with the
    arithmetic of :func:`_interp_at` (bit-identical results)."""
    acc = 0.0
    for cx in range(2):
        ix = i0 if cx == 0 else i1
        wx = wx0 if cx == 0 else wx1
        for cy in range(2):
            iy = j0 if cy == 0 else j1
            wxy = wx * (wy0 if cy == 0 else wy1)
            for cz in range(2):
                iz = k0 if cz == 0 else k1
                acc += wxy * (wz0 if cz == 0 else wz1) * field[ix, iy, iz]
    return acc


@kernel(inline="always")
def _cw(idx, wf, p, a, face):
    """Stored compact weights of particle p along axis a (face 0: the centre variant, 1: the
    face variant of that axis): nodes i0, i1 and weights 1 - f, f (the numbers of
    :func:`_axis_weights`, whose lower weight is computed as 1 - f as well)."""
    j = 4 * a + 2 * face
    f = wf[p, 2 * a + face]
    return idx[p, j], idx[p, j + 1], 1.0 - f, f


@kernel(inline="always")
def _store_axis(idx, wf, p, a, x, x0c, hc, nc, pc, loc, hic, bc, smic, smac, x0f, hf, nf, pf, lof, hif, bf, smif,
                smaf):
    """Store particle p's compact weights along axis a at coordinate x, in the layout that
    :func:`_cw` reads: ``idx[p, 4a:4a+4]`` = (centre i0, centre i1, face i0, face i1) and
    ``wf[p, 2a:2a+2]`` = (centre f, face f), from :func:`_axis_weights` with the centre
    (``*c``) and the face (``*f``) axis parameters."""
    b, i0, i1, v0, v1 = _axis_weights(x, x0c, hc, nc, pc, loc, hic, bc, smic, smac)
    b, j0, j1, u0, u1 = _axis_weights(x, x0f, hf, nf, pf, lof, hif, bf, smif, smaf)
    idx[p, 4 * a] = i0
    idx[p, 4 * a + 1] = i1
    idx[p, 4 * a + 2] = j0
    idx[p, 4 * a + 3] = j1
    wf[p, 2 * a] = v1
    wf[p, 2 * a + 1] = u1


@parallel_kernel
def _compact_weights_kernel(pos, fpar, ipar, idx, wf):
    """Per particle (each its own slot), for each axis a: ``idx[p, 4a:4a+4]`` = (centre i0,
    centre i1, face i0, face i1) as int32 and ``wf[p, 2a:2a+2]`` = (centre f, face f), the
    upper weights of :func:`_axis_weights` for the centre location and for the face location
    normal to a (``fpar``/``ipar`` rows 0 and a + 1).  96 bytes per particle, written once
    per coupling step and read by the porosity, slip, drag-deposit and force kernels.  The
    axis parameters are read into locals outside the particle loop."""
    x0c0 = fpar[0, 0, 0]; hc0 = fpar[0, 0, 1]; smic0 = fpar[0, 0, 2]; smac0 = fpar[0, 0, 3]
    x0c1 = fpar[0, 1, 0]; hc1 = fpar[0, 1, 1]; smic1 = fpar[0, 1, 2]; smac1 = fpar[0, 1, 3]
    x0c2 = fpar[0, 2, 0]; hc2 = fpar[0, 2, 1]; smic2 = fpar[0, 2, 2]; smac2 = fpar[0, 2, 3]
    x0f0 = fpar[1, 0, 0]; hf0 = fpar[1, 0, 1]; smif0 = fpar[1, 0, 2]; smaf0 = fpar[1, 0, 3]
    x0f1 = fpar[2, 1, 0]; hf1 = fpar[2, 1, 1]; smif1 = fpar[2, 1, 2]; smaf1 = fpar[2, 1, 3]
    x0f2 = fpar[3, 2, 0]; hf2 = fpar[3, 2, 1]; smif2 = fpar[3, 2, 2]; smaf2 = fpar[3, 2, 3]
    nc0 = ipar[0, 0, 0]; pc0 = ipar[0, 0, 1]; loc0 = ipar[0, 0, 2]; hic0 = ipar[0, 0, 3]; bc0 = ipar[0, 0, 4]
    nc1 = ipar[0, 1, 0]; pc1 = ipar[0, 1, 1]; loc1 = ipar[0, 1, 2]; hic1 = ipar[0, 1, 3]; bc1 = ipar[0, 1, 4]
    nc2 = ipar[0, 2, 0]; pc2 = ipar[0, 2, 1]; loc2 = ipar[0, 2, 2]; hic2 = ipar[0, 2, 3]; bc2 = ipar[0, 2, 4]
    nf0 = ipar[1, 0, 0]; pf0 = ipar[1, 0, 1]; lof0 = ipar[1, 0, 2]; hif0 = ipar[1, 0, 3]; bf0 = ipar[1, 0, 4]
    nf1 = ipar[2, 1, 0]; pf1 = ipar[2, 1, 1]; lof1 = ipar[2, 1, 2]; hif1 = ipar[2, 1, 3]; bf1 = ipar[2, 1, 4]
    nf2 = ipar[3, 2, 0]; pf2 = ipar[3, 2, 1]; lof2 = ipar[3, 2, 2]; hif2 = ipar[3, 2, 3]; bf2 = ipar[3, 2, 4]
    for p in prange(pos.shape[0]):
        _store_axis(idx, wf, p, 0, pos[p, 0], x0c0, hc0, nc0, pc0, loc0, hic0, bc0, smic0, smac0,
                    x0f0, hf0, nf0, pf0, lof0, hif0, bf0, smif0, smaf0)
        _store_axis(idx, wf, p, 1, pos[p, 1], x0c1, hc1, nc1, pc1, loc1, hic1, bc1, smic1, smac1,
                    x0f1, hf1, nf1, pf1, lof1, hif1, bf1, smif1, smaf1)
        _store_axis(idx, wf, p, 2, pos[p, 2], x0c2, hc2, nc2, pc2, loc2, hic2, bc2, smic2, smac2,
                    x0f2, hf2, nf2, pf2, lof2, hif2, bf2, smif2, smaf2)
    return 0


@kernel(inline="always")
def _chunk_bounds(n, nnodes, count, nstart, pstart):
    """From the particles per node ``count``: chunk boundaries ``nstart`` (nodes) and
    ``pstart`` (slots), and ``count`` overwritten with the chunk of each node."""
    nb = nstart.shape[0] - 1
    nstart[0] = 0
    node = 0
    cum = 0
    for b in range(nb - 1):
        target = (b + 1) * n / nb
        # at least one node per chunk, and one left for each later chunk
        cum += count[node]
        node += 1
        while node < nnodes - (nb - 1 - b) and cum + count[node] <= target:
            cum += count[node]
            node += 1
        nstart[b + 1] = node
    nstart[nb] = nnodes
    pstart[0] = 0
    for b in range(nb):
        s = 0
        for t in range(nstart[b], nstart[b + 1]):
            s += count[t]
            count[t] = b
        pstart[b + 1] = pstart[b] + s


@kernel
def _chunk_sort_kernel(idx, nn0, nn1, count0, count1, nstart0, nstart1, pstart0, pstart1, fill0, fill1,
                       perm0, perm1):
    """Two sorts of the particles into z chunks, by the lower centre z node ``idx[p, 8]``
    (suffix 0) and by the lower z-face node ``idx[p, 10]`` (suffix 1), in one serial pass
    each for counting and placing.  Per sort: the ``nn`` distinct z nodes are split into
    ``nb = nstart.shape[0] - 1`` chunks of consecutive nodes (each at least one node wide)
    holding about equally many particles; ``nstart[b]`` = first node of chunk b,
    ``pstart[b]`` = its first slot in ``perm``, which lists the particles chunk by chunk in
    index order (a stable counting sort; ``count`` and ``fill`` are scratch).  The result
    depends on the positions and the grid only, not on the thread count.  A particle of
    chunk b writes to z nodes in [nstart[b], nstart[b+1]] (its upper node is its lower node
    + 1, the same node at a wall fold, or node 0 after the periodic wrap of the last node),
    so chunks of equal parity never share a node when nb is even (the wrap reaches chunk 0
    from the odd chunk nb - 1) or nb is 1."""
    n = idx.shape[0]
    for t in range(nn0):
        count0[t] = 0
    for t in range(nn1):
        count1[t] = 0
    for p in range(n):
        count0[idx[p, 8]] += 1
        count1[idx[p, 10]] += 1
    _chunk_bounds(n, nn0, count0, nstart0, pstart0)
    _chunk_bounds(n, nn1, count1, nstart1, pstart1)
    for b in range(nstart0.shape[0] - 1):
        fill0[b] = pstart0[b]
    for b in range(nstart1.shape[0] - 1):
        fill1[b] = pstart1[b]
    for p in range(n):
        b = count0[idx[p, 8]]
        perm0[fill0[b]] = p
        fill0[b] += 1
        b = count1[idx[p, 10]]
        perm1[fill1[b]] = p
        fill1[b] += 1
    return 0


@kernel(inline="always")
def _face_interp(idx, wf, p, live, u, v, w):
    """(I_fcc(u), I_cfc(v), I_ccf(w)) at particle p from the stored weights (0 for a dead
    face grid)."""
    cx0, cx1, vx0, vx1 = _cw(idx, wf, p, 0, 0)
    cy0, cy1, vy0, vy1 = _cw(idx, wf, p, 1, 0)
    cz0, cz1, vz0, vz1 = _cw(idx, wf, p, 2, 0)
    ua = 0.0
    va = 0.0
    wa = 0.0
    if live[0] == 1:
        f0, f1, u0, u1 = _cw(idx, wf, p, 0, 1)
        ua = _i8(f0, f1, cy0, cy1, cz0, cz1, u0, u1, vy0, vy1, vz0, vz1, u)
    if live[1] == 1:
        f0, f1, u0, u1 = _cw(idx, wf, p, 1, 1)
        va = _i8(cx0, cx1, f0, f1, cz0, cz1, vx0, vx1, u0, u1, vz0, vz1, v)
    if live[2] == 1:
        f0, f1, u0, u1 = _cw(idx, wf, p, 2, 1)
        wa = _i8(cx0, cx1, cy0, cy1, f0, f1, vx0, vx1, vy0, vy1, u0, u1, w)
    return ua, va, wa


@parallel_kernel
def _porosity_chunks_kernel(parity, pstart, perm, idx, wf, pos, vol, lo, hi, wall, solid, nout):
    """solid[c] += w_pc vol[p] on the centre grid for the particles of the z chunks of the
    given parity (:func:`_chunk_sort_kernel` on the centre z node), one chunk per prange
    index, its particles in index order; ``nout[b]``: particle centres of chunk b outside
    [lo, hi] on a wall axis (``wall[a]`` = 1).  Called for parity 0, then 1: chunks of one
    parity touch disjoint nodes, so the sums are race-free and, the chunks depending on the
    positions only, the same for any thread count."""
    nb = pstart.shape[0] - 1
    nq = (nb - parity + 1) // 2
    for q in prange(nq):
        b = 2 * q + parity
        n_out = 0
        for t in range(pstart[b], pstart[b + 1]):
            p = perm[t]
            i0, i1, wx0, wx1 = _cw(idx, wf, p, 0, 0)
            j0, j1, wy0, wy1 = _cw(idx, wf, p, 1, 0)
            k0, k1, wz0, wz1 = _cw(idx, wf, p, 2, 0)
            out = False
            for a in range(3):
                if wall[a] == 1 and (pos[p, a] < lo[a] or pos[p, a] > hi[a]):
                    out = True
            if out:
                n_out += 1
            val = vol[p]
            for cx in range(2):
                ix = i0 if cx == 0 else i1
                wx = wx0 if cx == 0 else wx1
                for cy in range(2):
                    iy = j0 if cy == 0 else j1
                    wxy = wx * (wy0 if cy == 0 else wy1)
                    for cz in range(2):
                        iz = k0 if cz == 0 else k1
                        solid[ix, iy, iz] += wxy * (wz0 if cz == 0 else wz1) * val
        nout[b] = n_out
    return 0


@parallel_kernel
def _slip_kernel(idx, wf, live, eps, u, v, w, vel, diam, rho, mu, eps_a, re):
    """Per particle (each its own slot): eps_a = clip(I_ccc(eps), 1e-12, 1), u_a from the face
    grids, Re = eps_a rho |u_a - v_a| d / mu.  (The drag closure is applied afterwards by
    numpy: its SIMD pow/expm1 on 30k values took 0.75 ms against 1.9 ms for the compiled
    scalar twin called here, measured on the chute.)"""
    for p in prange(idx.shape[0]):
        i0, i1, wx0, wx1 = _cw(idx, wf, p, 0, 0)
        j0, j1, wy0, wy1 = _cw(idx, wf, p, 1, 0)
        k0, k1, wz0, wz1 = _cw(idx, wf, p, 2, 0)
        e = _i8(i0, i1, j0, j1, k0, k1, wx0, wx1, wy0, wy1, wz0, wz1, eps)
        if e < 1e-12:
            e = 1e-12
        if e > 1.0:
            e = 1.0
        ua, va, wa = _face_interp(idx, wf, p, live, u, v, w)
        d0 = ua - vel[p, 0]
        d1 = va - vel[p, 1]
        d2 = wa - vel[p, 2]
        slip = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        r = e * rho * slip * diam[p] / mu
        eps_a[p] = e
        re[p] = r
    return 0


@kernel(inline="always")
def _scatter_pair(i0, i1, j0, j1, k0, k1, wx0, wx1, wy0, wy1, wz0, wz1, k, kv, o):
    """o[t, 0] += w_t k, o[t, 1] += w_t kv over the 8 corners (order and arithmetic of
    :func:`_scatter_kernel`)."""
    for cx in range(2):
        ix = i0 if cx == 0 else i1
        wx = wx0 if cx == 0 else wx1
        for cy in range(2):
            iy = j0 if cy == 0 else j1
            wxy = wx * (wy0 if cy == 0 else wy1)
            for cz in range(2):
                iz = k0 if cz == 0 else k1
                wc = wxy * (wz0 if cz == 0 else wz1)
                o[ix, iy, iz, 0] += wc * k
                o[ix, iy, iz, 1] += wc * kv


@parallel_kernel
def _deposit_drag_chunks_kernel(parity, pstart0, perm0, pstart1, perm1, idx, wf, live, keff, vel, ox, oy, oz):
    """o_c[t, 0] += w_pt K[p], o_c[t, 1] += w_pt (K[p] vel[p, c]) on face grid c (skipped
    where ``live[c]`` is 0; node arrays with a trailing pair axis, so that both sums of a
    node share a cache line), for the particles of the z chunks of the given parity: the
    x- and y-face grids share the centre z nodes (chunks of the centre sort ``pstart0,
    perm0``), the z-face grid has its own (chunks of the face sort ``pstart1, perm1``); the
    chunks of both sorts in one prange (they write different grids).  Race-free and
    thread-independent as :func:`_porosity_chunks_kernel`."""
    nq0 = (pstart0.shape[0] - 1 - parity + 1) // 2
    nq1 = (pstart1.shape[0] - 1 - parity + 1) // 2
    for qu in prange(nq0 + nq1):
        q = np.int64(qu)  # (a prange index may be unsigned; mixed with signed ints it types as float)
        zface = 0 if q < nq0 else 1
        b = 2 * (q if q < nq0 else q - nq0) + parity
        t0 = pstart0[b] if zface == 0 else pstart1[b]
        t1 = pstart0[b + 1] if zface == 0 else pstart1[b + 1]
        for t in range(t0, t1):
            p = perm0[t] if zface == 0 else perm1[t]
            k = keff[p]
            cx0, cx1, vx0, vx1 = _cw(idx, wf, p, 0, 0)
            cy0, cy1, vy0, vy1 = _cw(idx, wf, p, 1, 0)
            if zface == 0:
                cz0, cz1, vz0, vz1 = _cw(idx, wf, p, 2, 0)
                if live[0] == 1:
                    f0, f1, u0, u1 = _cw(idx, wf, p, 0, 1)
                    _scatter_pair(f0, f1, cy0, cy1, cz0, cz1, u0, u1, vy0, vy1, vz0, vz1, k, k * vel[p, 0], ox)
                if live[1] == 1:
                    f0, f1, u0, u1 = _cw(idx, wf, p, 1, 1)
                    _scatter_pair(cx0, cx1, f0, f1, cz0, cz1, vx0, vx1, u0, u1, vz0, vz1, k, k * vel[p, 1], oy)
            elif live[2] == 1:
                f0, f1, u0, u1 = _cw(idx, wf, p, 2, 1)
                _scatter_pair(cx0, cx1, cy0, cy1, f0, f1, vx0, vx1, vy0, vy1, u0, u1, k, k * vel[p, 2], oz)
    return 0


@parallel_kernel
def _forces_kernel(idx, wf, live, u, v, w, G, B, has_b, vel, keff, vol, store,
                   fd, fp, fb, ext, power, fmag, chunk, part):
    """Per particle: drag fd = K (u_a - v_a) with u_a from the face grids, pressure forces
    fp_c = -V I_ccc(G[..., c]), fb_c = -V I_ccc(B[..., c]) (0 where has_b[c] is 0; B[..., c] is
    zero except in the first and last cell layers along axis c, and only particles touching
    those layers read it; G and B (nx, ny, nz, 3), the components of a node in one cache
    line), ext = fd + fp + fb, power = fd . (u_a - v_a), fmag = |fd|; fd, fp, fb, power,
    fmag are stored only if ``store`` is 1.  Sums: ``part[b]`` = (sum fd (3), sum fp (3),
    sum fb (3), sum power, max fmag) over the particles of block b = [b chunk, (b+1) chunk),
    each block summed serially in index order; the prange runs over blocks (whose size does
    not depend on the thread count), so the sums are the same for any thread count."""
    nb0 = G.shape[0] - 1
    nb1 = G.shape[1] - 1
    nb2 = G.shape[2] - 1
    n = idx.shape[0]
    nblk = part.shape[0]
    for b in prange(nblk):
        sf0 = sf1 = sf2 = sp0 = sp1 = sp2 = sb0 = sb1 = sb2 = spw = 0.0
        fmax = 0.0
        p_end = min(n, (b + 1) * chunk)
        for p in range(b * chunk, p_end):
            ua, va, wa = _face_interp(idx, wf, p, live, u, v, w)
            i0, i1, wx0, wx1 = _cw(idx, wf, p, 0, 0)
            j0, j1, wy0, wy1 = _cw(idx, wf, p, 1, 0)
            k0, k1, wz0, wz1 = _cw(idx, wf, p, 2, 0)
            s0 = 0.0
            s1 = 0.0
            s2 = 0.0
            t0 = 0.0
            t1 = 0.0
            t2 = 0.0
            rb0 = has_b[0] == 1 and (i0 == 0 or i1 == 0 or i0 == nb0 or i1 == nb0)
            rb1 = has_b[1] == 1 and (j0 == 0 or j1 == 0 or j0 == nb1 or j1 == nb1)
            rb2 = has_b[2] == 1 and (k0 == 0 or k1 == 0 or k0 == nb2 or k1 == nb2)
            for cx in range(2):
                ix = i0 if cx == 0 else i1
                wx = wx0 if cx == 0 else wx1
                for cy in range(2):
                    iy = j0 if cy == 0 else j1
                    wxy = wx * (wy0 if cy == 0 else wy1)
                    for cz in range(2):
                        iz = k0 if cz == 0 else k1
                        wc = wxy * (wz0 if cz == 0 else wz1)
                        s0 += wc * G[ix, iy, iz, 0]
                        s1 += wc * G[ix, iy, iz, 1]
                        s2 += wc * G[ix, iy, iz, 2]
                        if rb0:
                            t0 += wc * B[ix, iy, iz, 0]
                        if rb1:
                            t1 += wc * B[ix, iy, iz, 1]
                        if rb2:
                            t2 += wc * B[ix, iy, iz, 2]
            k = keff[p]
            mv = -vol[p]
            d0 = ua - vel[p, 0]
            d1 = va - vel[p, 1]
            d2 = wa - vel[p, 2]
            f0 = k * d0
            f1 = k * d1
            f2 = k * d2
            p0 = mv * s0
            p1 = mv * s1
            p2 = mv * s2
            q0 = mv * t0 if has_b[0] == 1 else 0.0
            q1 = mv * t1 if has_b[1] == 1 else 0.0
            q2 = mv * t2 if has_b[2] == 1 else 0.0
            pw = f0 * d0 + f1 * d1 + f2 * d2
            fm = np.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
            ext[p, 0] = f0 + p0 + q0
            ext[p, 1] = f1 + p1 + q1
            ext[p, 2] = f2 + p2 + q2
            if store == 1:
                fd[p, 0] = f0
                fd[p, 1] = f1
                fd[p, 2] = f2
                fp[p, 0] = p0
                fp[p, 1] = p1
                fp[p, 2] = p2
                fb[p, 0] = q0
                fb[p, 1] = q1
                fb[p, 2] = q2
                power[p] = pw
                fmag[p] = fm
            sf0 += f0
            sf1 += f1
            sf2 += f2
            sp0 += p0
            sp1 += p1
            sp2 += p2
            sb0 += q0
            sb1 += q1
            sb2 += q2
            spw += pw
            if fm > fmax:
                fmax = fm
        part[b, 0] = sf0
        part[b, 1] = sf1
        part[b, 2] = sf2
        part[b, 3] = sp0
        part[b, 4] = sp1
        part[b, 5] = sp2
        part[b, 6] = sb0
        part[b, 7] = sb1
        part[b, 8] = sb2
        part[b, 9] = spw
        part[b, 10] = fmax
    return 0



@parallel_kernel
def _sphere_volumes_kernel(radius, out):
    """``out[a] = 4/3 pi radius[a]^3`` (r r r: one pass, where numpy's ``r**3`` is a libm pow
    per value and two temporaries: 0.03 against 0.7 ms on 30k radii)."""
    c = 4.0 / 3.0 * np.pi
    for a in prange(out.shape[0]):
        r = radius[a]
        out[a] = c * (r * r * r)
    return 0


def sphere_volumes(radius, out=None) -> np.ndarray:
    """The volumes 4/3 pi r^3 of spheres of radii ``radius`` (n,), into ``out`` if given:
    the volumes every porosity deposit of this module uses."""
    r = np.ascontiguousarray(radius, dtype=np.float64).reshape(-1)
    if out is None:
        out = np.empty(r.shape[0])
    _sphere_volumes_kernel(r, out)
    return out


# --------------------------------------------------------------------------------------
# Python orchestration
# --------------------------------------------------------------------------------------


def _positions(pos) -> np.ndarray:
    pos = np.ascontiguousarray(pos, dtype=np.float64)
    if pos.ndim != 2 or pos.shape[1] != 3:
        raise CaseError("coupling.positions", f"positions must be an (n, 3) array, got shape {pos.shape}")
    if pos.size and not np.all(np.isfinite(pos)):
        bad = int(np.count_nonzero(~np.all(np.isfinite(pos), axis=1)))
        raise CaseError("coupling.positions", f"{bad} particle position(s) are not finite")
    return pos


class _Weights(NamedTuple):
    ax: _Axes
    a0: np.ndarray
    a1: np.ndarray
    w0: np.ndarray
    w1: np.ndarray


def _weights(spec: GridSpec, location: str, pos: np.ndarray, rules: tuple) -> _Weights:
    ax = _axes(spec, location, rules)
    m = pos.shape[0]
    a0 = np.empty((m, 3), np.int64)
    a1 = np.empty((m, 3), np.int64)
    w0 = np.empty((m, 3))
    w1 = np.empty((m, 3))
    _weights_kernel(pos, ax.x0, ax.h, ax.n, ax.per, ax.lo, ax.hi, ax.bmin, ax.smin, ax.smax, a0, a1, w0, w1)
    return _Weights(ax, a0, a1, w0, w1)


class MappingPlan:
    """Weights and the bin sort of one particle configuration, computed once per location
    and reused: in a coupling step porosity, velocity and grad p interpolation and the force
    deposition all use the same positions.  Results are bit-identical to the module
    functions (which build a plan per call).

        plan = MappingPlan(grid, pos, boundaries)
        res = plan.porosity(radius); uvw = plan.interpolate_faces(u, v, w)
        su, sv, sw = plan.deposit_faces(force)

    ``boundaries``: the side rules (module docstring, "Boundary rules"): the gas's
    BoundarySet, a dict side -> BC, or periodic flags (None: a box of walls); the plan keeps
    them as ``rules`` (six strings) and ``periodic`` (per axis).

    The plan holds references to nothing but its own arrays; build a new one when the
    particles move.  ``workspace``: a dict kept by the caller and handed to every plan; the
    plan's weights and the outputs of the fused methods (``interpolate_slip``,
    ``deposit_drag``, ``particle_forces``) then live in it and are overwritten by the next
    plan with the same workspace (copy what must outlive it).
    """

    def __init__(self, grid, pos, boundaries=None, workspace=None):
        self.spec = as_grid_spec(grid)
        self.pos = _positions(pos)
        self.rules = _side_rules(boundaries)
        self.periodic = _periodic(self.rules)
        self._w = {}
        self._cw = None  # compact weights (idx, wf), computed on first use
        self._sorted = {}  # z-chunk sorts of the particles, per column of idx
        # arrays kept by the caller between plans (a coupling step builds one plan per step):
        # first-touch page faults of fresh multi-megabyte arrays cost more than the kernels
        self._ws = workspace if workspace is not None else {}

    def _buf(self, key, shape, dtype=np.float64, zero=False):
        """A work array from the workspace (reused when the shape matches)."""
        arr = self._ws.get(key)
        if arr is None or arr.shape != tuple(shape) or arr.dtype != dtype:
            arr = np.empty(shape, dtype)
            self._ws[key] = arr
        if zero:
            arr.fill(0.0)
        return arr

    def _nshape(self, location):
        """:func:`node_shape` of the plan's (already validated) grid."""
        return _node_shape(self.spec.shape, location)

    @property
    def n(self) -> int:
        return self.pos.shape[0]

    def weights(self, location) -> _Weights:
        """Per-axis nodes and weights of ``location``; the first call computes all four
        locations in one parallel pass (:func:`_weights4_kernel`), later calls reuse them."""
        _check_location(location)
        if not self._w:
            axes = [_axes(self.spec, loc, self.rules) for loc in LOCATIONS]
            m = self.n
            a0 = self._buf("a0", (4, m, 3), np.int64)
            a1 = self._buf("a1", (4, m, 3), np.int64)
            w0 = self._buf("w0", (4, m, 3))
            w1 = self._buf("w1", (4, m, 3))
            if m:
                par = [np.ascontiguousarray(np.stack([getattr(ax, k) for ax in axes]))
                       for k in ("x0", "h", "n", "per", "lo", "hi", "bmin", "smin", "smax")]
                _weights4_kernel(self.pos, *par, a0, a1, w0, w1)
            for i, (loc, ax) in enumerate(zip(LOCATIONS, axes)):
                self._w[loc] = _Weights(ax, a0[i], a1[i], w0[i], w1[i])
        return self._w[location]

    def deposit(self, values, location="ccc") -> np.ndarray:
        """Node sums S[t] = sum_a w_at values[a] on ``location`` (see :func:`deposit`)."""
        values = np.ascontiguousarray(values, dtype=np.float64).reshape(-1)
        if values.shape[0] != self.n:
            raise CaseError("coupling.values", f"{values.shape[0]} values for {self.n} particles")
        wt = self.weights(location)
        ax = wt.ax
        out = np.zeros(ax.shape)
        if ax.dead or self.n == 0:
            return out
        _scatter_kernel(wt.a0, wt.a1, wt.w0, wt.w1, values, out)
        return out

    def interpolate(self, field, location="ccc") -> np.ndarray:
        """sum_t w_at field[t] at each particle (see :func:`interpolate`)."""
        wt = self.weights(location)
        arr = _array(field, wt.ax.shape, location + " field")
        out = np.zeros(self.n)
        if wt.ax.dead or self.n == 0:
            return out
        _interp_kernel(wt.a0, wt.a1, wt.w0, wt.w1, arr, out)
        return out

    def _params(self):
        """Per-location axis parameters for the fused kernels: ``fpar (4, 3, 4)`` (x0, h, smin,
        smax), ``ipar (4, 3, 5)`` (n, per, lo, hi, bmin) and the live flags of the three face
        grids (kept in the workspace for the same grid)."""
        key = (self.spec, self.rules)
        cached = self._ws.get("_params")
        if cached is not None and cached[0] == key:
            return cached[1]
        axes = [_axes(self.spec, loc, self.rules) for loc in LOCATIONS]
        fpar = np.empty((4, 3, 4))
        ipar = np.empty((4, 3, 5), np.int64)
        for i, ax in enumerate(axes):
            for j, name in enumerate(("x0", "h", "smin", "smax")):
                fpar[i, :, j] = getattr(ax, name)
            for j, name in enumerate(("n", "per", "lo", "hi", "bmin")):
                ipar[i, :, j] = getattr(ax, name)
        live = np.array([0 if ax.dead else 1 for ax in axes[1:]], np.int64)
        val = (fpar, ipar, live)
        self._ws["_params"] = (key, val)
        return val

    def _compact(self):
        """Compact weights of the fused kernels, computed once per plan in one parallel pass
        (:func:`_compact_weights_kernel`): ``idx (n, 12)`` int32 and ``wf (n, 6)``
        (workspace arrays)."""
        if self._cw is None:
            idx = self._buf("cw_idx", (self.n, 12), np.int32)
            wf = self._buf("cw_wf", (self.n, 6))
            if self.n:
                fpar, ipar, _ = self._params()
                _compact_weights_kernel(self.pos, fpar, ipar, idx, wf)
            self._cw = (idx, wf)
        return self._cw

    def _chunks(self, face):
        """``(pstart, perm)`` of the z-chunk sort (:func:`_chunk_sort_kernel`, both sorts in
        one call) by the lower centre z node (``face`` 0) or the lower z-face node (1).  The
        number of chunks depends on the grid only: ``min(16, distinct nodes along z)`` rounded
        down to an even number (1 if that is below 2), so the deposits are the same for any
        thread count."""
        if not self._sorted:
            idx, _ = self._compact()
            arrays = []
            for f in (0, 1):
                # distinct z nodes: a periodic face grid's node n is node 0 (never written)
                nnodes = self.spec.shape[2] + (f if not self.periodic[2] else 0)
                nb = min(_Z_CHUNKS, nnodes) // 2 * 2
                if nb < 2:
                    nb = 1
                arrays.append((nnodes, self._buf("cs_count%d" % f, (nnodes,), np.int64),
                               self._buf("cs_nstart%d" % f, (nb + 1,), np.int64),
                               self._buf("cs_pstart%d" % f, (nb + 1,), np.int64),
                               self._buf("cs_fill%d" % f, (nb,), np.int64),
                               self._buf("cs_perm%d" % f, (self.n,), np.int64)))
            a, b = arrays
            _chunk_sort_kernel(idx, a[0], b[0], a[1], b[1], a[2], b[2], a[3], b[3], a[4], b[4], a[5], b[5])
            self._sorted = {0: (a[3], a[5]), 1: (b[3], b[5])}
        return self._sorted[face]

    def porosity(self, radius, eps_min=0.3, volume=None) -> "PorosityResult":
        """See :func:`porosity`.  ``volume``: the particle volumes if already computed (they
        must be ``4/3 pi radius^3``); one pass, parallel over z chunks (module docstring),
        deposits them and counts the particle centres outside the box.  The same sums as
        :meth:`deposit` to round-off (another order of the additions), the same for any
        thread count."""
        spec, per = self.spec, self.periodic
        if volume is None:
            vol = sphere_volumes(np.broadcast_to(np.asarray(radius, dtype=np.float64), (self.n,)))
        else:
            vol = self._per_particle(volume, "volume")
        solid = np.zeros(spec.shape)
        n_out = 0
        if self.n:
            idx, wf = self._compact()
            pstart, perm = self._chunks(0)
            lo = np.array(spec.origin, dtype=np.float64)
            hi = np.array([spec.origin[a] + spec.shape[a] * spec.spacing[a] for a in range(3)])
            wall = np.array([0 if per[a] else 1 for a in range(3)], np.int64)
            nout = np.zeros(pstart.shape[0] - 1, np.int64)
            for parity in (0, 1):
                _porosity_chunks_kernel(parity, pstart, perm, idx, wf, self.pos, vol, lo, hi, wall, solid, nout)
            n_out = int(nout.sum())
        eps = 1.0 - solid / spec.cell_volume
        k = int(np.argmin(eps))
        where = tuple(int(v) for v in np.unravel_index(k, eps.shape))
        return PorosityResult(
            eps,
            int(np.count_nonzero(eps < eps_min)),
            int(np.count_nonzero(eps < 0.0)),
            float(eps.flat[k]),
            where,
            float(solid.sum()),
            n_out,
        )

    def deposit_faces(self, values):
        """See :func:`deposit_faces`."""
        values = np.ascontiguousarray(values, dtype=np.float64)
        if values.shape != self.pos.shape:
            raise CaseError("coupling.values", f"values must have shape {self.pos.shape}, got {values.shape}")
        return tuple(self.deposit(np.ascontiguousarray(values[:, c]), loc) for c, loc in enumerate(FACE_LOCATIONS))

    def interpolate_faces(self, u, v, w) -> np.ndarray:
        """See :func:`interpolate_faces`."""
        out = np.empty((self.n, 3))
        for c, (loc, f) in enumerate(zip(FACE_LOCATIONS, (u, v, w))):
            out[:, c] = self.interpolate(f, loc)
        return out

    def gradient(self, p) -> np.ndarray:
        """See :func:`gradient_at_particles`."""
        return self.interpolate_faces(*face_gradient(self.spec, p, self.rules))

    # ---------------------------------------------------------------- fused (coupling step)
    def _vel(self, vel):
        vel = np.ascontiguousarray(vel, dtype=np.float64)
        if vel.shape != self.pos.shape:
            raise CaseError("coupling.values", f"velocities must have shape {self.pos.shape}, got {vel.shape}")
        return vel

    def _per_particle(self, values, name):
        arr = np.asarray(values, dtype=np.float64)
        if arr.ndim > 1 or (arr.ndim == 1 and arr.shape[0] != self.n):
            raise CaseError("coupling.values", f"{name}: need a scalar or {self.n} values, got shape {arr.shape}")
        return np.ascontiguousarray(np.broadcast_to(arr, (self.n,)))

    def _fields(self, eps, u, v, w):
        spec = self.spec
        e = None if eps is None else _array(eps, spec.shape, "ccc field")
        fu, fv, fw = (_array(f, self._nshape(loc), loc + " field") for f, loc in zip((u, v, w), FACE_LOCATIONS))
        return e, fu, fv, fw

    def interpolate_slip(self, eps, u, v, w, vel, diameter, rho, mu):
        """Porosity and slip Reynolds number at the particles, one parallel pass:
        ``eps_a = clip(I_ccc(eps)_a, 1e-12, 1)``, ``u_a = (I_fcc(u), I_cfc(v), I_ccf(w))_a``,
        ``Re_a = eps_a rho |u_a - vel_a| d_a / mu``.  ``eps`` a centre field, ``u, v, w`` face
        fields (arrays or Fields), ``vel (n, 3)``, ``diameter`` (n,) or scalar.  Returns
        ``(eps_a, re)``, each (n,); the same numbers as :meth:`interpolate` and
        :meth:`interpolate_faces` followed by the numpy formulas."""
        return self._slip(eps, u, v, w, vel, diameter, rho, mu)

    def _slip(self, eps, u, v, w, vel, diameter, rho, mu):
        eps, fu, fv, fw = self._fields(eps, u, v, w)
        vel = self._vel(vel)
        d = self._per_particle(diameter, "diameter")
        eps_a = self._buf("eps_a", (self.n,))
        re = self._buf("re", (self.n,))
        if self.n:
            _, _, live = self._params()
            idx, wf = self._compact()
            _slip_kernel(idx, wf, live, eps, fu, fv, fw, vel, d, float(rho), float(mu), eps_a, re)
        return eps_a, re

    def deposit_drag(self, keff, vel):
        """Face deposits of a drag coefficient and of its momentum, one pass over the particles
        for the three face grids, parallel over z chunks (module docstring):
        ``(D_c(K), D_c(K vel_c))`` for c = x, y, z (D_c as :meth:`deposit` on the component's
        face grid; dead face grids stay 0).  Returns two tuples of three face arrays, the same
        sums as ``deposit_faces`` of ``K`` repeated and of ``K[:, None] vel`` to round-off
        (another order of the additions), the same for any thread count."""
        pairs = self.deposit_drag_pairs(keff, vel)
        return tuple(a[..., 0].copy() for a in pairs), tuple(a[..., 1].copy() for a in pairs)

    def deposit_drag_pairs(self, keff, vel):
        """:meth:`deposit_drag` with both sums of a face grid in one array of shape
        ``node_shape + (2,)``: ``[..., 0] = D_c(K)``, ``[..., 1] = D_c(K vel_c)`` (the same
        numbers; the pair layout halves the cache lines the scatter touches).  Work arrays of
        the workspace."""
        k = self._per_particle(keff, "drag coefficient")
        vel = self._vel(vel)
        pairs = tuple(self._buf("dkp" + loc, self._nshape(loc) + (2,), zero=True) for loc in FACE_LOCATIONS)
        if self.n:
            _, _, live = self._params()
            idx, wf = self._compact()
            ps0, pm0 = self._chunks(0)  # x and y faces: centre z nodes
            ps1, pm1 = self._chunks(1)  # z faces
            for parity in (0, 1):
                _deposit_drag_chunks_kernel(parity, ps0, pm0, ps1, pm1, idx, wf, live, k, vel, *pairs)
        return pairs

    def _stacked(self, fields, key):
        """Three centre fields as one (nx, ny, nz, 3) array: a stacked array passes through, a
        sequence is copied into a work array (None entries as zeros)."""
        shape = tuple(self.spec.shape) + (3,)
        if isinstance(fields, np.ndarray) and fields.ndim == 4:
            return _array(fields, shape, "stacked centre fields")
        if len(fields) != 3:
            raise CaseError("coupling.field", f"need three centre fields, got {len(fields)}")
        out = self._buf(key, shape)
        for c, g in enumerate(fields):
            out[..., c] = 0.0 if g is None else _array(g, self.spec.shape, "centre field")
        return out

    def _forces(self, u, v, w, vel, keff, volume, centre, boundary, out, store, boundary_used=None):
        _, fu, fv, fw = self._fields(None, u, v, w)
        vel = self._vel(vel)
        k = self._per_particle(keff, "drag coefficient")
        vol = self._per_particle(volume, "volume")
        G = self._stacked(centre, "G3")
        if boundary is None:
            boundary = (None, None, None)
        if isinstance(boundary, np.ndarray) and boundary.ndim == 4:
            used = (True, True, True) if boundary_used is None else boundary_used
        else:
            used = [b is not None for b in boundary]
        has_b = np.array([1 if b else 0 for b in used], np.int64)
        B = self._stacked(boundary, "B3")
        n = self.n
        if store:
            res = {key: self._buf(key, (n, 3)) for key in ("fd", "fp", "fb")}
            res["power"] = self._buf("power", (n,))
            res["magnitude"] = self._buf("magnitude", (n,))
        else:
            empty = self._buf("empty3", (0, 3))
            res = {"fd": empty, "fp": empty, "fb": empty, "power": empty[:, 0].copy(), "magnitude": empty[:, 0].copy()}
        nblk = (n + _FORCE_BLOCK - 1) // _FORCE_BLOCK
        part = self._buf("force_sums", (nblk, 11))
        if n:
            _, _, live = self._params()
            idx, wf = self._compact()
            _forces_kernel(idx, wf, live, fu, fv, fw, G, B, has_b, vel, k, vol, 1 if store else 0,
                           res["fd"], res["fp"], res["fb"], out, res["power"], res["magnitude"], _FORCE_BLOCK, part)
        return res, part

    def particle_forces(self, u, v, w, vel, keff, volume, centre, boundary=None):
        """Forces on the particles from the gas, one parallel pass:
        ``fd = K (u_a - vel_a)`` (u_a from the face fields as in :meth:`interpolate_faces`),
        ``fp_c = -V I_ccc(centre[c])``, ``fb_c = -V I_ccc(boundary[c])`` (components whose
        ``boundary[c]`` is None, or all if ``boundary`` is None, give 0).  A ``boundary[c]``
        field must be zero outside the first and last cell layers along axis c (the boundary
        half-cell field of the exchange); only those layers are read.  Returns a dict of
        ``fd, fp, fb, total`` (each (n, 3); total = fd + fp + fb), ``power`` (n,) =
        fd . (u_a - vel_a) and ``magnitude`` (n,) = |fd|."""
        total = self._buf("total", (self.n, 3))
        res, _ = self._forces(u, v, w, vel, keff, volume, centre, boundary, total, True)
        res["total"] = total
        return res

    def apply_forces(self, u, v, w, vel, keff, volume, centre, boundary, out, boundary_used=None,
                     store: bool = False) -> dict:
        """:meth:`particle_forces` for the coupling step: writes only ``total`` into ``out``
        (a C-contiguous float64 (n, 3) array, e.g. ``system.ext_force``) and returns the sums
        ``fd, fp, fb`` ((3,) each, sum over the particles), ``power`` (sum of fd . (u_a - v_a))
        and ``max_magnitude`` (max |fd|).  The sums run serially over fixed blocks of
        particles and then over the blocks, so they are the same for any thread count (they
        differ from a plain sum in round-off only).  ``centre`` and ``boundary`` may also be
        stacked (nx, ny, nz, 3) arrays (no copy); ``boundary_used`` then gives the components
        of ``boundary`` that are used (default all).  With ``store`` the dict also holds the
        per-particle ``fd_each``, ``fp_each``, ``fb_each`` ((n, 3) each, copies; the same
        arithmetic, so ``out`` is the same)."""
        if (not isinstance(out, np.ndarray) or out.shape != (self.n, 3) or out.dtype != np.float64
                or not out.flags.c_contiguous or not out.flags.writeable):
            raise CaseError("coupling.values", f"out must be a writable C-contiguous float64 ({self.n}, 3) array")
        res, part = self._forces(u, v, w, vel, keff, volume, centre, boundary, out, bool(store), boundary_used)
        tot = part[:, :10].sum(axis=0)  # numpy, in one process: thread-independent
        d = {"fd": tot[0:3].copy(), "fp": tot[3:6].copy(), "fb": tot[6:9].copy(), "power": float(tot[9]),
             "max_magnitude": float(part[:, 10].max()) if part.shape[0] else 0.0}
        if store:
            d.update(fd_each=res["fd"].copy(), fp_each=res["fp"].copy(), fb_each=res["fb"].copy())
        return d


def _check_location(location):
    if location not in LOCATIONS:
        raise CaseError("coupling.location", f"unknown location {location!r}; expected one of {LOCATIONS}")


def trilinear_weights(grid, pos, location="ccc", boundaries=None):
    """Node indices ``(n, 8, 3)`` and weights ``(n, 8)`` of each particle on the nodes of
    ``location`` (after the wall fold and periodic wrap; a node may appear twice).

    Corner c = 4 cx + 2 cy + cz takes the lower (0) or upper (1) node along each axis.  For
    inspection and tests; the kernels use the same per-axis weights."""
    spec = as_grid_spec(grid)
    _check_location(location)
    pos = _positions(pos)
    wt = _weights(spec, location, pos, _side_rules(boundaries))
    m = pos.shape[0]
    idx = np.empty((m, 8, 3), np.int64)
    w = np.empty((m, 8))
    for c in range(8):
        bits = ((c >> 2) & 1, (c >> 1) & 1, c & 1)
        wc = np.ones(m)
        for a, bit in enumerate(bits):
            idx[:, c, a] = wt.a1[:, a] if bit else wt.a0[:, a]
            wc = wc * (wt.w1[:, a] if bit else wt.w0[:, a])
        w[:, c] = wc
    if wt.ax.dead:
        w[:] = 0.0
    return idx, w


def deposit(grid, pos, values, location="ccc", boundaries=None) -> np.ndarray:
    """Spread per-particle scalars ``values (n,)`` to the nodes of ``location`` with the
    trilinear weights: S[t] = sum_a w_at values[a] (a sum, not a density).  Race-free and
    bit-identical for any thread count; sum(S) = sum(values) up to round-off."""
    return MappingPlan(grid, pos, boundaries).deposit(values, location)


class PorosityResult(NamedTuple):
    """eps (nx, ny, nz); n_low: cells with eps < eps_min; n_negative: cells with eps < 0
    (more solid than the cell holds); eps_min_found and where (cell index) of the minimum;
    solid_volume: total deposited volume (= sum of particle volumes); n_outside: particle
    centres outside the box on a wall axis (clamped onto it)."""

    eps: np.ndarray
    n_low: int
    n_negative: int
    eps_min_found: float
    where: tuple
    solid_volume: float
    n_outside: int


def porosity(grid, pos, radius, boundaries=None, eps_min=0.3) -> PorosityResult:
    """Porosity eps_c = 1 - sum_a V_a w_ac / V_cell at the cell centres, V_a = 4/3 pi R_a^3.

    Never clipped: cells below ``eps_min`` (and below 0) are counted and the minimum and its
    cell are returned so that the caller can log where and how much.  Point-volume trilinear
    deposition: cells smaller than about 3 particle diameters give a noisy eps (and, if much
    smaller than a particle, eps < 0)."""
    return MappingPlan(grid, pos, boundaries).porosity(radius, eps_min)


def deposit_faces(grid, pos, values, boundaries=None):
    """Spread per-particle vectors ``values (n, 3)`` (e.g. the reaction of the drag force) to
    the staggered face grids: component 0 to the x-faces ``(nx+1, ny, nz)``, 1 to the
    y-faces, 2 to the z-faces, each with its own trilinear weights.  Returns (Su, Sv, Sw),
    sums per face [same unit as values]; divide by the cell volume for a density.  The sum
    over faces equals the sum over particles component by component (up to round-off),
    except for a component normal to a one-cell wall axis (dropped, see module doc)."""
    return MappingPlan(grid, pos, boundaries).deposit_faces(values)


def _array(field, shape, name):
    arr = getattr(field, "interior", field)
    arr = np.ascontiguousarray(arr, dtype=np.float64)
    if arr.shape != tuple(shape):
        raise CaseError("coupling.field", f"{name} must have interior shape {tuple(shape)}, got {arr.shape}")
    return arr


def interpolate(grid, field, pos, location="ccc", boundaries=None) -> np.ndarray:
    """Value of a node field of ``location`` at the particles (n,): sum_t w_at field[t]."""
    return MappingPlan(grid, pos, boundaries).interpolate(field, location)


def interpolate_centres(grid, field, pos, boundaries=None) -> np.ndarray:
    """A cell-centre field ``(nx, ny, nz)`` at the particles (n,)."""
    return interpolate(grid, field, pos, "ccc", boundaries)


def interpolate_faces(grid, u, v, w, pos, boundaries=None) -> np.ndarray:
    """Staggered velocity at the particles, (n, 3): u from the x-faces ``(nx+1, ny, nz)``, v
    from the y-faces, w from the z-faces, each with its own weights (the transpose of
    :func:`deposit_faces`)."""
    return MappingPlan(grid, pos, boundaries).interpolate_faces(u, v, w)


def face_gradient(grid, p, boundaries=None):
    """grad p on the faces: (gx, gy, gz) with gx[i] = (p[i] - p[i-1])/dx on x-face i
    (:func:`cfddem.gas.operators.c2f_gradient`).

    Interior faces 1..n-1 by the central difference; across a "wrap" side face 0 (and its
    image face n) uses p[0] - p[n-1]; across a "fold" side the boundary face is 0 (the fold
    never gives it weight).  ``boundaries`` as for :class:`MappingPlan`."""
    spec = as_grid_spec(grid)
    rules = _side_rules(boundaries)
    p = _array(p, spec.shape, "pressure (ccc)")
    grads = []
    for a in range(3):
        pad = [(0, 0)] * 3
        pad[a] = (1, 1)
        # one halo cell along a: the wrapped neighbour, or a copy of the boundary cell (fold:
        # a zero difference across the boundary face)
        pp = np.pad(p, pad, mode="wrap" if rules[2 * a] == "wrap" else "edge")
        g = c2f_gradient(pp, a, spec.spacing[a])  # faces 0..n of p are entries 1..n+1 of g
        sl = [slice(None)] * 3
        sl[a] = slice(1, spec.shape[a] + 2)
        grads.append(np.ascontiguousarray(g[tuple(sl)]))
    return tuple(grads)


def gradient_at_particles(grid, p, pos, boundaries=None) -> np.ndarray:
    """grad p at the particles (n, 3): face differences (:func:`face_gradient`) interpolated
    like the velocity.  Exact for a pressure field linear in x, y, z (away from walls within
    half a cell, where the fold uses the first interior face's value - also exact for
    linear p)."""
    return MappingPlan(grid, pos, boundaries).gradient(p)
