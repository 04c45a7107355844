"""Boundary conditions of the gas box: the one boundary model of cfddem, and the halo fills.

One condition per side of the box: ``"x-", "x+", "y-", "y+", "z-", "z+"``.  Each condition
(a :class:`BC`) declares its rules once: the halo fills below, the gas solver, the
particle-to-grid mapping and the momentum exchange read them (see :class:`BC` and
docs/gas.md, "The boundary model").  Filling the halos makes every interior stencil
branch-free.  With ``g`` the halo width, ``n`` the cell count along the side's normal
direction and indices counted in the array (interior index ``i`` is array index ``i+g``),
the lower-side fills are (upper side mirrored):

normal component (the face field whose faces are parallel to the side, boundary face ``g``),
by ``normal_rule``
    * ``"prescribed"`` (``NoSlip``, ``FreeSlip``: u_b = 0; ``Velocity``/``Inlet``/
      ``LidCrossWind``: u_b given): ``a[g] = u_b``, ``a[g-m] = 2 u_b - a[g+m]`` (odd
      reflection; exact for a field linear in the normal direction);
    * ``"solved"`` (``PressureOutlet``): the boundary face is an unknown; ``a[g-m] = a[g]``
      (zero gradient);
    * ``"periodic"``: face ``n`` is face ``0``; ``a[g+n] = a[g]``, ``a[g-m] = a[g+n-m]``.

tangential components (centred in the normal direction; the boundary lies half a cell
outside the first interior point), by ``tangential_rule``
    * ``"prescribed"``: ``a[g-m] = 2 u_b - a[g+m-1]`` (the wall value is the mean of the first
      interior and ghost values; second-order, exact for linear fields);
    * ``"slip"``: ``a[g-m] = a[g+m-1]`` (zero normal gradient, zero shear stress);
    * ``"zero_gradient"``: ``a[g-m] = a[g]``;
    * ``"periodic"``: ``a[g-m] = a[g+n-m]``.

cell-centred pressure, by ``pressure_rule``: ``"neumann"`` zero normal gradient (at
prescribed normal faces: the projection never corrects them), ``"dirichlet"``
``p_ghost = 2 p_b - p_interior`` (the value ``p_b`` of :meth:`BC.pressure` on the boundary
face), ``"periodic"`` wrap.  Porosity: zero gradient (wrap at periodic sides).

Halos are filled direction by direction (x, then y, then z) over the full extent of the
other directions, so edges and corners take consistent values.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from cfddem._jit import kernel
from cfddem.errors import CaseError
from cfddem.gas.grid import StaggeredGrid

SIDES = ("x-", "x+", "y-", "y+", "z-", "z+")
_COMPONENT_LOC = ("fcc", "cfc", "ccf")


class BC:
    """Base class of a side's boundary condition: what every part of the code needs to know
    about a side, declared once here (docs/gas.md, "The boundary model").

    A kind of boundary is a subclass that sets the five rules below (and overrides
    :meth:`velocity` / :meth:`pressure` if it prescribes values); the gas halo fill
    (:class:`BoundarySet`), the gas solver (updated faces, pressure equation, periodic faces),
    the particle-to-grid mapping (:mod:`cfddem.coupling.mapping`) and the momentum exchange
    (:mod:`cfddem.coupling.exchange`) read these rules and never the class or its ``kind``.

    ``normal_rule``: the boundary face of the velocity component normal to the side:
        ``"prescribed"`` (the value of :meth:`velocity`; not a gas unknown, the projection
        never corrects it; odd reflection into the halo), ``"solved"`` (a gas unknown that the
        momentum equation updates; zero-gradient halo beyond it; needs halo 2), ``"periodic"``
        (face n is face 0).
    ``tangential_rule``: the two tangential components in the halo: ``"prescribed"`` (the
        side's value is the mean of ghost and first interior point: no-slip, moving wall,
        inlet), ``"slip"`` (mirror image: zero normal gradient, no shear stress),
        ``"zero_gradient"`` (copies of the first interior point: outflow), ``"periodic"``.
    ``pressure_rule``: the cell-centred pressure: ``"neumann"`` (zero normal gradient in the
        halo and in the pressure equation: a prescribed normal face), ``"dirichlet"`` (the
        value of :meth:`pressure` on the boundary face: a solved normal face), ``"periodic"``.
    ``particle_rule``: the particle-to-grid mapping across the side: ``"fold"`` (a particle
        keeps its whole volume and force inside the box: weight on nodes beyond the first
        interior node the mapping uses folds onto it, centres outside are clamped onto the
        side), ``"wrap"`` (periodic: node n is node 0).
    ``half_cell_source``: the momentum exchange's boundary half-cell (exchange step 5b): True
        where the boundary face is not a gas unknown, so the half cell between the side and
        the first interior face lies outside every gas control volume and the boundary
        supplies its pressure force (to the particles in the first cell layer and, as an
        explicit source, to the gas on the first interior face).

    The porosity halo is zero-gradient on every side that is not periodic.
    """

    kind = "base"
    normal_rule = "prescribed"
    tangential_rule = "prescribed"
    pressure_rule = "neumann"
    particle_rule = "fold"
    half_cell_source = True

    @property
    def prescribes_velocity(self) -> bool:
        """Whether the side prescribes a velocity component (its :meth:`velocity` is read)."""
        return self.normal_rule == "prescribed" or self.tangential_rule == "prescribed"

    @property
    def periodic(self) -> bool:
        return self.normal_rule == "periodic"

    def velocity(self, side: str, x, y, z):
        """Prescribed velocity (u, v, w) at the boundary points (arrays broadcast together)."""
        zero = np.zeros(np.broadcast(x, y, z).shape)
        return zero, zero.copy(), zero.copy()

    def pressure(self, side: str, x, y, z):
        """Pressure on the boundary face at the points (``pressure_rule`` "dirichlet" only)."""
        raise NotImplementedError(f"{type(self).__name__} prescribes no pressure")


#: the allowed values of each rule; BoundarySet checks every BC against them
RULES = {
    "normal_rule": ("prescribed", "solved", "periodic"),
    "tangential_rule": ("prescribed", "slip", "zero_gradient", "periodic"),
    "pressure_rule": ("neumann", "dirichlet", "periodic"),
    "particle_rule": ("fold", "leave", "wrap"),
    "half_cell_source": (True, False),
}


def check_rules(side: str, bc: BC) -> None:
    """CaseError unless bc's rules take allowed values and fit together: periodic in all of
    them or in none; a solved normal face with a Dirichlet pressure, a prescribed one with a
    Neumann pressure; the half-cell source exactly where the normal face is prescribed."""
    key = f"gas.bcs.{side}"
    if isinstance(bc, Patched):
        bc.check(side)
        return
    for name, allowed in RULES.items():
        if getattr(bc, name) not in allowed:
            raise CaseError(key, f"{type(bc).__name__}.{name} = {getattr(bc, name)!r}; allowed: {allowed}")
    per = bc.normal_rule == "periodic"
    if (per != (bc.tangential_rule == "periodic") or per != (bc.pressure_rule == "periodic")
            or per != (bc.particle_rule == "wrap")):
        raise CaseError(key, f"{type(bc).__name__}: periodic must be the rule of all four fields or of none")
    pairs = {"prescribed": "neumann", "solved": "dirichlet", "periodic": "periodic"}
    if pairs[bc.normal_rule] != bc.pressure_rule:
        raise CaseError(key, f"{type(bc).__name__}: a {bc.normal_rule} normal face needs pressure_rule "
                        f"{pairs[bc.normal_rule]!r}, not {bc.pressure_rule!r}")
    if bc.half_cell_source != (bc.normal_rule == "prescribed"):
        raise CaseError(key, f"{type(bc).__name__}: half_cell_source must be True exactly where the normal "
                        "face is prescribed")


@dataclass(frozen=True)
class NoSlip(BC):
    """Wall at rest: u = 0 on the wall (normal and tangential)."""

    kind = "noslip"


@dataclass(frozen=True)
class FreeSlip(BC):
    """Impermeable wall without shear stress: u.n = 0, d(u_t)/dn = 0."""

    kind = "freeslip"
    tangential_rule = "slip"


@dataclass(frozen=True)
class Velocity(BC):
    """Prescribed velocity: a constant vector or a function ``f(x, y, z) -> (u, v, w)``.

    Also a moving wall (tangential velocity only) or an open boundary with given inflow.
    """

    value: tuple | Callable = (0.0, 0.0, 0.0)
    kind = "velocity"

    def velocity(self, side, x, y, z):
        shape = np.broadcast(x, y, z).shape
        if callable(self.value):
            out = self.value(x, y, z)
        else:
            out = self.value
        return tuple(np.broadcast_to(np.asarray(c, dtype=float), shape).copy() for c in out)


@dataclass(frozen=True)
class Inlet(BC):
    """Velocity inlet: inflow speed (m/s, into the box, along the side's normal), uniform or
    a profile ``f(x, y, z) -> speed``; optional tangential velocity vector ``tangential``."""

    speed: float | Callable = 0.0
    tangential: tuple = (0.0, 0.0, 0.0)
    kind = "inlet"

    def velocity(self, side, x, y, z):
        shape = np.broadcast(x, y, z).shape
        d = "xyz".index(side[0])
        sign = 1.0 if side[1] == "-" else -1.0
        s = self.speed(x, y, z) if callable(self.speed) else self.speed
        out = [np.broadcast_to(np.asarray(t, dtype=float), shape).copy() for t in self.tangential]
        out[d] = sign * np.broadcast_to(np.asarray(s, dtype=float), shape).copy()
        return tuple(out)


@dataclass(frozen=True)
class LidCrossWind(BC):
    """Open top of a rotating chute: the lab-frame air at rest seen from the rotating frame,
    ``u = -Omega x (r - r_axis)`` (physics.md section 2)."""

    omega: tuple = (0.0, 0.0, 0.0)
    axis_point: tuple = (0.0, 0.0, 0.0)
    kind = "velocity"

    def velocity(self, side, x, y, z):
        shape = np.broadcast(x, y, z).shape
        r = [np.broadcast_to(np.asarray(c, dtype=float), shape) - a for c, a in zip((x, y, z), self.axis_point)]
        ox, oy, oz = (float(o) for o in self.omega)
        # Omega x r = (oy rz - oz ry, oz rx - ox rz, ox ry - oy rx)
        return (-(oy * r[2] - oz * r[1]), -(oz * r[0] - ox * r[2]), -(ox * r[1] - oy * r[0]))


@dataclass(frozen=True)
class PressureOutlet(BC):
    """Constant-pressure outlet: p = p_out on the boundary face (a number or a function
    ``f(x, y, z)``, e.g. hydrostatic), zero-gradient velocity.

    Particles near it are mapped as near a wall (``particle_rule = "fold"``): a particle within
    half a cell of the outlet gives its weight to the last interior face, not to the outlet
    face that the gas solves for, and a particle centre past the outlet is clamped onto it
    (docs/gas.md, "The boundary model").  With ``particle_rule = "leave"`` a particle centre
    past the outlet has left the gas: no volume, drag or pressure force."""

    p: float | Callable = 0.0
    particle_rule: str = "fold"
    kind = "outlet"
    normal_rule = "solved"
    tangential_rule = "zero_gradient"
    pressure_rule = "dirichlet"
    half_cell_source = False

    def pressure(self, side, x, y, z):
        return self.p(x, y, z) if callable(self.p) else self.p


@dataclass(frozen=True)
class Periodic(BC):
    """Periodic pair: both sides of the direction must be periodic."""

    kind = "periodic"
    normal_rule = "periodic"
    tangential_rule = "periodic"
    pressure_rule = "periodic"
    particle_rule = "wrap"
    half_cell_source = False


@dataclass(frozen=True)
class Patched(BC):
    """One side carrying different conditions on different face cells: ``default`` everywhere
    except on the face cells whose centres lie in a patch's box, which take that patch's
    condition (a later patch wins where patches overlap).

    ``patches``: a sequence of ``(box, bc)``, ``box = (lo, hi)`` two 3-vectors (m; the
    coordinate along the side's normal is ignored, +-inf for unbounded), ``bc`` any condition
    that is not periodic and not itself patched.  Every rule of the side becomes per face cell
    (:meth:`BoundarySet.parts`): the halo fill, the momentum update (the boundary faces of
    the solved part are gas unknowns, those of the prescribed part keep their value), the
    pressure equation (Dirichlet on the faces of the Dirichlet part, Neumann elsewhere), the
    exchange's boundary half-cell (where the part declares one).  A tangential velocity point
    on the edge between two parts takes the rule of the part listed first (the default, then
    the patches in order).  ``particle_rule`` is one for the whole side (the mapping's
    weights are per side): "fold" or "leave".

    Example: the silo's bottom, no-slip plates with a pressure outlet over the slot::

        Patched(default=NoSlip(), patches=[((xa, -inf, -inf), (xb, inf, inf)), PressureOutlet(p=p0))])
    """

    default: BC = field(default_factory=lambda: NoSlip())
    patches: tuple = ()
    particle_rule: str = "fold"
    kind = "patched"
    # per face cell (BoundarySet.parts); these class values are never read for a Patched side
    normal_rule = "per cell"
    tangential_rule = "per cell"
    pressure_rule = "per cell"
    half_cell_source = "per cell"

    def bcs(self) -> list:
        """The conditions of the side, the default first."""
        return [self.default] + [bc for _, bc in self.patches]

    @property
    def prescribes_velocity(self) -> bool:
        return any(bc.prescribes_velocity for bc in self.bcs())

    @property
    def periodic(self) -> bool:
        return False

    def check(self, side: str) -> None:
        """CaseError unless every part is a valid non-periodic, non-patched condition, the boxes
        are pairs of 3-vectors and the side's particle rule is "fold" or "leave"."""
        key = f"gas.bcs.{side}"
        for i, item in enumerate(self.patches):
            try:
                box, bc = item
                lo, hi = (np.asarray(v, dtype=float) for v in box)
            except (TypeError, ValueError):
                raise CaseError(key, f"patch {i}: need ((lo, hi), bc), got {item!r}") from None
            if lo.shape != (3,) or hi.shape != (3,):
                raise CaseError(key, f"patch {i}: the box corners must be 3-vectors, got {box!r}")
        for bc in self.bcs():
            if not isinstance(bc, BC) or isinstance(bc, Patched):
                raise CaseError(key, f"a patched side's parts must be plain conditions, got {bc!r}")
            if bc.periodic:
                raise CaseError(key, "a patched side cannot have a periodic part")
            check_rules(side, bc)
        if self.particle_rule not in ("fold", "leave"):
            raise CaseError(key, f"Patched.particle_rule = {self.particle_rule!r}; allowed: ('fold', 'leave')")

    def labels(self, side: str, grid: StaggeredGrid) -> np.ndarray:
        """The part index (0 the default, k the k-th patch) of each face cell of the side, an
        int array over the two tangential axes in increasing order (the last patch wins)."""
        d = "xyz".index(side[0])
        e1, e2 = (e for e in range(3) if e != d)
        c1 = grid.coords("ccc", e1, with_halo=False)[:, None]
        c2 = grid.coords("ccc", e2, with_halo=False)[None, :]
        lab = np.zeros((c1.size, c2.size), dtype=np.int64)
        for k, ((lo, hi), _) in enumerate(self.patches, start=1):
            inside = (c1 >= lo[e1]) & (c1 <= hi[e1]) & (c2 >= lo[e2]) & (c2 <= hi[e2])
            lab[inside] = k
        return lab


def _sl(d: int, idx) -> tuple:
    s = [slice(None)] * 3
    s[d] = idx
    return tuple(s)


def _ix(d: int, idx, blk) -> tuple:
    """``_sl(d, idx)`` restricted to the block ``blk`` (slices of the other two axes in
    increasing order; None: all)."""
    if blk is None:
        return _sl(d, idx)
    s = [None, None, None]
    s[d] = idx
    s[[e for e in range(3) if e != d][0]], s[[e for e in range(3) if e != d][1]] = blk
    return tuple(s)


def _cut(a, d: int, blk):
    """The block ``blk`` of a boundary-value array (axis d of size 1); a itself for None."""
    if a is None or blk is None:
        return a
    return a[_ix(d, slice(None), blk)]


@dataclass
class BoundarySet:
    """The six boundary conditions of a grid, with their boundary values precomputed.

    Everything here is read from the rules each BC declares (:class:`BC`).  Attributes used
    by the solver and the coupling: ``kinds[side]`` (names, for messages), ``periodic[d]``,
    ``face_range[d]`` (first and one-past-last interior face index of component d that the
    momentum equation updates: the boundary face is included where its ``normal_rule`` is
    "solved"),
    ``pressure_bc[side]`` in {"neumann", "dirichlet", "periodic"}, ``particle_rules``
    (the six ``particle_rule`` values in the order of ``SIDES``, for the mapping) and
    ``half_cell[d]`` (whether the lower and the upper side of axis d carry a boundary
    half-cell, for the exchange).
    """

    grid: StaggeredGrid
    bcs: dict
    kinds: dict = field(init=False)
    periodic: tuple = field(init=False)

    def __post_init__(self):
        g = self.grid
        missing = [s for s in SIDES if s not in self.bcs]
        extra = [s for s in self.bcs if s not in SIDES]
        if missing or extra:
            raise CaseError("gas.bcs", f"need one condition for each of {SIDES}; missing {missing}, unknown {extra}")
        for s, bc in self.bcs.items():
            if not isinstance(bc, BC):
                raise CaseError(f"gas.bcs.{s}", f"not a boundary condition: {bc!r}")
            check_rules(s, bc)
        self.kinds = {s: self.bcs[s].kind for s in SIDES}
        # per side: [(label, bc)] and the part label of each face cell (None: one part)
        self._parts = {}
        self._labels = {}
        for s in SIDES:
            bc = self.bcs[s]
            if isinstance(bc, Patched):
                lab = bc.labels(s, g)
                present = set(int(k) for k in np.unique(lab))  # parts that cover no face cell are left out
                self._parts[s] = [(k, b) for k, b in enumerate(bc.bcs()) if k in present]
                self._labels[s] = lab
            else:
                self._parts[s] = [(0, bc)]
                self._labels[s] = None
        per = []
        for d in range(3):
            lo, hi = self.bcs[SIDES[2 * d]].periodic, self.bcs[SIDES[2 * d + 1]].periodic
            if lo != hi:
                raise CaseError(f"gas.bcs.{SIDES[2 * d]}", "periodic must be set on both sides of a direction")
            per.append(lo)
        self.periodic = tuple(per)
        self.face_range = []
        for d in range(3):
            n = g.shape[d]
            lo_side, hi_side = SIDES[2 * d], SIDES[2 * d + 1]
            if self.periodic[d]:
                self.face_range.append((0, n))
            else:
                lo = 0 if self._any(lo_side, "normal_rule", "solved") else 1
                hi = n + 1 if self._any(hi_side, "normal_rule", "solved") else n
                self.face_range.append((lo, hi))
        self.pressure_bc = {s: ("dirichlet" if self._any(s, "pressure_rule", "dirichlet")
                                else self._parts[s][0][1].pressure_rule) for s in SIDES}
        self.particle_rules = tuple(self.bcs[s].particle_rule for s in SIDES)
        self.half_cell = tuple((self._any(SIDES[2 * d], "half_cell_source", True),
                                self._any(SIDES[2 * d + 1], "half_cell_source", True)) for d in range(3))
        self._precompute()

    def _any(self, side: str, rule: str, value) -> bool:
        """Whether some part of the side has ``rule == value``."""
        return any(getattr(bc, rule) == value for _, bc in self._parts[side])

    def parts(self, side: str) -> list:
        """The conditions on the side as ``[(mask, bc)]``: ``mask`` a boolean array over the
        side's face cells (the two tangential axes in increasing order) where ``bc`` holds, None
        for a side with one condition."""
        lab = self._labels[side]
        if lab is None:
            return [(None, self.bcs[side])]
        return [(lab == k, bc) for k, bc in self._parts[side] if np.any(lab == k)]

    def cell_mask(self, side: str, rule: str, value):
        """Boolean array over the side's face cells: where the side's rule ``rule`` has
        ``value`` (a patched side), or a plain bool for a side with one condition."""
        lab = self._labels[side]
        if lab is None:
            return getattr(self.bcs[side], rule) == value
        out = np.zeros(lab.shape, dtype=bool)
        for k, bc in self._parts[side]:
            if getattr(bc, rule) == value:
                out |= lab == k
        return out

    @property
    def patched_sides(self) -> list:
        """The sides whose normal rule differs between face cells (some faces solved, some
        prescribed): the solver keeps their prescribed faces (:meth:`close_prescribed_faces`)."""
        return [s for s in SIDES if self._labels[s] is not None
                and len({bc.normal_rule for _, bc in self._parts[s]}) > 1]

    @property
    def needs_wide_halo(self) -> bool:
        """A solved boundary face (an outlet) needs halo 2: its momentum stencil reaches two
        faces beyond it."""
        return any(self.bcs[s].normal_rule == "solved" for s in SIDES)

    def copy_periodic_faces(self, a: np.ndarray, c: int, offset: int) -> None:
        """Face n := face 0 of the component-c face array ``a`` if axis c is periodic (the first
        statement of the periodic fill; ``offset``: the array's halo width, 0 for an array of
        interior faces).  Nothing on other axes."""
        if self.periodic[c]:
            n = self.grid.shape[c]
            a[_sl(c, offset + n)] = a[_sl(c, offset)]

    @property
    def has_dirichlet_pressure(self) -> bool:
        return any(v == "dirichlet" for v in self.pressure_bc.values())

    def _boundary_points(self, side: str, loc: str):
        """Coordinates (broadcastable, axis d of size 1) on the side's plane for ``loc``."""
        g = self.grid
        d = "xyz".index(side[0])
        xb = g.origin[d] + (0.0 if side[1] == "-" else g.lengths[d])
        cs = []
        for e in range(3):
            if e == d:
                cs.append(np.full((1, 1, 1), xb))
            else:
                shape = [1, 1, 1]
                c = g.coords(loc, e, with_halo=True)
                shape[e] = c.size
                cs.append(c.reshape(shape))
        return cs

    def _loc_labels(self, side: str, loc: str) -> np.ndarray:
        """The part label of every boundary point of ``loc`` on a patched side, over the two
        tangential axes of the array (halos included, axis d of size 1 inserted): halo points
        take the label of the nearest face cell; a face point between two cells of different
        parts takes the lower label (the default, then the patches in order)."""
        g = self.grid.halo
        d = "xyz".index(side[0])
        lab = np.pad(self._labels[side], g, mode="edge")
        for k, e in enumerate(e for e in range(3) if e != d):
            if loc[e] == "f":
                m = lab.shape[k]
                left = np.take(lab, np.clip(np.arange(m + 1) - 1, 0, m - 1), axis=k)
                right = np.take(lab, np.clip(np.arange(m + 1), 0, m - 1), axis=k)
                lab = np.minimum(left, right)
        return np.expand_dims(lab, d)

    def _blocks(self, side: str, loc: str) -> list:
        """A patched side's boundary points of ``loc`` as rectangular blocks of one part each:
        ``[(blk, bc)]``, ``blk`` the slices of the two tangential axes (consecutive rows with
        the same runs of labels merged); ``[(None, bc)]`` for a side with one condition."""
        if self._labels[side] is None:
            return [(None, self.bcs[side])]
        d = "xyz".index(side[0])
        lab = np.squeeze(self._loc_labels(side, loc), axis=d)
        bcs = dict(self._parts[side])
        rows = []
        for r in lab:
            cuts = [0] + [int(i) + 1 for i in np.flatnonzero(np.diff(r))] + [r.size]
            rows.append(tuple((a, b, int(r[a])) for a, b in zip(cuts[:-1], cuts[1:])))
        out = []
        i0 = 0
        for i in range(1, len(rows) + 1):
            if i == len(rows) or rows[i] != rows[i0]:
                out.extend(((slice(i0, i), slice(a, b)), bcs[k]) for a, b, k in rows[i0])
                i0 = i
        return out

    def _precompute(self):
        self._ub = {}
        self._pout = {}
        self._ops = {}
        for s in SIDES:
            bc = self.bcs[s]
            d = "xyz".index(s[0])
            if bc.prescribes_velocity:
                for c in range(3):
                    shape = list(self.grid.array_shape(_COMPONENT_LOC[c]))
                    shape[d] = 1
                    x, y, z = self._boundary_points(s, _COMPONENT_LOC[c])
                    if self._labels[s] is None:
                        vals = bc.velocity(s, x, y, z)[c]
                    else:  # each prescribing part's values on its points, 0 elsewhere
                        lab = self._loc_labels(s, _COMPONENT_LOC[c])
                        vals = np.zeros(shape)
                        for k, b in self._parts[s]:
                            if b.prescribes_velocity:
                                vals = np.where(lab == k, np.broadcast_to(b.velocity(s, x, y, z)[c], shape), vals)
                    self._ub[(s, c)] = np.ascontiguousarray(np.broadcast_to(vals, shape))
            if self.pressure_bc[s] == "dirichlet":
                x, y, z = self._boundary_points(s, "ccc")
                shape = list(self.grid.array_shape("ccc"))
                shape[d] = 1
                if self._labels[s] is None:
                    pv = bc.pressure(s, x, y, z)
                else:
                    lab = self._loc_labels(s, "ccc")
                    pv = np.zeros(shape)
                    for k, b in self._parts[s]:
                        if b.pressure_rule == "dirichlet":
                            pv = np.where(lab == k, np.broadcast_to(np.asarray(b.pressure(s, x, y, z), float), shape), pv)
                self._pout[s] = np.ascontiguousarray(np.broadcast_to(np.asarray(pv, dtype=float), shape))
        self._closed = {}
        g = self.grid.halo
        for s in self.patched_sides:  # the prescribed boundary faces of a partly solved side
            d = "xyz".index(s[0])
            n = self.grid.shape[d]
            mask = self.cell_mask(s, "normal_rule", "prescribed")
            i1, i2 = np.nonzero(mask)
            e1, e2 = (e for e in range(3) if e != d)
            fi = [None, None, None]
            fi[d] = np.full(i1.size, 0 if s[1] == "-" else n)
            fi[e1], fi[e2] = i1, i2
            face = tuple(fi)
            arr = tuple(a + g for a in face)
            self._closed[s] = (d, face, arr, self._ub[(s, d)][tuple(np.zeros_like(a) if e == d else a
                                                                     for e, a in enumerate(arr))])

    def close_prescribed_faces(self, vel, coefs, ratios) -> None:
        """On a side whose boundary faces are partly solved (a patched side with an outlet
        part): give the prescribed faces their value again after the predictor wrote them
        (``vel``: the three face arrays with halos) and zero their pressure coefficient and
        correction ratio (interior face arrays), so that the pressure equation sees a Neumann
        face there and the correction leaves it alone.  Nothing on other sides."""
        for d, face, arr, ub in self._closed.values():
            vel[d][arr] = ub
            coefs[d][face] = 0.0
            ratios[d][face] = 0.0

    def boundary_velocity(self, side: str, comp: int) -> np.ndarray | None:
        """Prescribed value of component ``comp`` on ``side`` (None where not prescribed)."""
        return self._ub.get((side, comp))

    # --- halo filling -------------------------------------------------------------------
    # Every fill is a fixed, ordered list of elementwise assignments on the flat array,
    #     mode 0: a[dst] = a[src]; mode 1: a[dst] = cst - a[src]; mode 2: a[dst] = cst,
    # recorded once per (array kind) from the slice statements of the ``_*_statements``
    # methods (the reference numpy implementation, ``compiled=False``) as runs (one per line
    # of a statement's block: start, stride and length, not one index per entry: the index
    # arrays made the fills memory-bound, 0.1 ms each on the chute grid) and run by one
    # compiled loop (:func:`_run_fill`).  The same operations in the same order, so the
    # compiled fill equals the numpy fill bit for bit (cst = 2 u_b, and ``cst - a`` is the
    # numpy expression ``2.0 * u_b - a``).
    def fill_velocity(self, u: np.ndarray, v: np.ndarray, w: np.ndarray, compiled: bool = True) -> None:
        """Fill halos (and prescribed boundary faces) of the three velocity arrays in place."""
        for c, a in enumerate((u, v, w)):
            self.fill_component(a, c, compiled)

    def fill_component(self, a: np.ndarray, c: int, compiled: bool = True) -> None:
        """Fill the halos (and prescribed boundary faces) of velocity component c only."""
        self._fill(a, ("velocity", c), lambda: self._component_statements(c), compiled)

    def fill_pressure(self, p: np.ndarray, homogeneous: bool = False, compiled: bool = True) -> None:
        """Fill the halos of a centre pressure array.  ``homogeneous``: outlet value 0
        (for the pressure increment of the projection)."""
        self._fill(p, ("pressure", homogeneous), lambda: self._pressure_statements(homogeneous), compiled)

    def fill_scalar(self, a: np.ndarray, compiled: bool = True) -> None:
        """Zero-gradient halos (wrap at periodic sides) for a centre scalar (porosity)."""
        self._fill(a, ("scalar",), self._scalar_statements, compiled)

    def _fill(self, a, key, statements, compiled):
        if not compiled or not (a.flags.c_contiguous and a.dtype == np.float64):
            for dst, src, mode, cst in statements():
                if mode == 0:
                    a[dst] = a[src]
                elif mode == 1:
                    a[dst] = cst - a[src]
                else:
                    a[dst] = cst
            return
        ops = self._ops.get(key)
        if ops is None or ops[-1] != a.shape:
            ops = self._record(a.shape, statements())
            self._ops[key] = ops
        _run_fill(a.reshape(-1), ops[0], ops[1])

    @staticmethod
    def _record(shape, statements):
        """The statements as runs for :func:`_run_fill`: ``runs[r] = (dst0, src0, n, dst
        stride, src stride, mode, offset into cst)``, one per line of a statement's block
        (its last axis longer than 1; flat indices), in the statements' order, and ``cst``
        the constants of the entries of mode 1 and 2 in that order."""
        idx = np.arange(int(np.prod(shape)), dtype=np.int64).reshape(shape)
        R, C = [], []
        nc = 0
        for dst, src, mode, cst in statements:
            d = np.squeeze(idx[dst])
            sq = np.squeeze(idx[src]) if mode != 2 else np.zeros_like(d)
            if d.ndim == 0:
                d, sq = d.reshape(1, 1), sq.reshape(1, 1)
            d, sq = d.reshape(-1, d.shape[-1]), sq.reshape(-1, d.shape[-1])
            rows, n = d.shape
            sd = int(d[0, 1] - d[0, 0]) if n > 1 else 0
            ss = int(sq[0, 1] - sq[0, 0]) if n > 1 else 0
            r = np.empty((rows, 7), dtype=np.int64)
            r[:, 0], r[:, 1], r[:, 2], r[:, 3], r[:, 4], r[:, 5] = d[:, 0], sq[:, 0], n, sd, ss, mode
            r[:, 6] = nc + n * np.arange(rows) if mode != 0 else 0
            R.append(r)
            if mode != 0:
                C.append(np.broadcast_to(np.asarray(cst, dtype=np.float64), idx[dst].shape).ravel())
                nc += rows * n
        runs = np.concatenate(R) if R else np.zeros((0, 7), dtype=np.int64)
        cst = np.concatenate(C) if C else np.zeros(0)
        return (runs, cst, tuple(shape))

    def _component_statements(self, c: int) -> list:
        out = []
        for d in range(3):
            out.extend(self._component_axis(c, d))
        return out

    def _component_axis(self, c: int, d: int) -> list:
        """The fill of component c along direction d as (dst, src, mode, cst) slice statements."""
        g = self.grid.halo
        n = self.grid.shape[d]
        lo, hi = SIDES[2 * d], SIDES[2 * d + 1]
        st = []
        if self.periodic[d]:
            if c == d:
                st.append((_sl(d, g + n), _sl(d, g), 0, 0.0))
                for m in range(1, g + 1):
                    st.append((_sl(d, g - m), _sl(d, g + n - m), 0, 0.0))
                    st.append((_sl(d, g + n + m), _sl(d, g + m), 0, 0.0))
            else:
                for m in range(1, g + 1):
                    st.append((_sl(d, g - m), _sl(d, g + n - m), 0, 0.0))
                    st.append((_sl(d, g + n - 1 + m), _sl(d, g - 1 + m), 0, 0.0))
            return st
        for side, lower in ((lo, True), (hi, False)):
            for blk, bc in self._blocks(side, _COMPONENT_LOC[c]):
                st.extend(self._side_component(c, d, side, lower, bc, blk))
        return st

    def _side_component(self, c: int, d: int, side: str, lower: bool, bc: BC, blk) -> list:
        """The fill of component c on one side by the rules of ``bc``, on the block ``blk`` of
        the side's points (None: all of them)."""
        g = self.grid.halo
        n = self.grid.shape[d]
        st = []
        if c == d:  # normal component, boundary face at g (lower) or g+n (upper)
            ub = _cut(self._ub.get((side, c)), d, blk)
            b = g if lower else g + n
            sgn = -1 if lower else 1
            if bc.normal_rule == "solved":
                for m in range(1, g + 1):
                    st.append((_ix(d, b + sgn * m, blk), _ix(d, b, blk), 0, 0.0))
            else:
                st.append((_ix(d, slice(b, b + 1), blk), None, 2, ub))
                for m in range(1, g + 1):
                    st.append((_ix(d, slice(b + sgn * m, b + sgn * m + 1), blk),
                               _ix(d, slice(b - sgn * m, b - sgn * m + 1), blk), 1, 2.0 * ub))
        else:  # tangential component, first interior point half a cell from the side
            rule = bc.tangential_rule
            ub = _cut(self._ub.get((side, c)), d, blk) if rule == "prescribed" else None
            for m in range(1, g + 1):
                if lower:
                    gi, mi, fi = g - m, g + m - 1, g
                else:
                    gi, mi, fi = g + n - 1 + m, g + n - m, g + n - 1
                if rule == "zero_gradient":
                    st.append((_ix(d, gi, blk), _ix(d, fi, blk), 0, 0.0))
                elif rule == "slip":
                    st.append((_ix(d, gi, blk), _ix(d, mi, blk), 0, 0.0))
                else:
                    st.append((_ix(d, slice(gi, gi + 1), blk), _ix(d, slice(mi, mi + 1), blk), 1, 2.0 * ub))
        return st

    def _pressure_statements(self, homogeneous: bool) -> list:
        g = self.grid.halo
        st = []
        for d in range(3):
            n = self.grid.shape[d]
            if self.periodic[d]:
                for m in range(1, g + 1):
                    st.append((_sl(d, g - m), _sl(d, g + n - m), 0, 0.0))
                    st.append((_sl(d, g + n - 1 + m), _sl(d, g - 1 + m), 0, 0.0))
                continue
            for side, lower in ((SIDES[2 * d], True), (SIDES[2 * d + 1], False)):
                for blk, bc in self._blocks(side, "ccc"):
                    for m in range(1, g + 1):
                        gi, mi = (g - m, g + m - 1) if lower else (g + n - 1 + m, g + n - m)
                        if bc.pressure_rule == "dirichlet":
                            pb = 0.0 if homogeneous else _cut(self._pout[side], d, blk)
                            st.append((_ix(d, slice(gi, gi + 1), blk), _ix(d, slice(mi, mi + 1), blk), 1, 2.0 * pb))
                        else:
                            st.append((_ix(d, gi, blk), _ix(d, mi, blk), 0, 0.0))
        return st

    def _scalar_statements(self) -> list:
        g = self.grid.halo
        st = []
        for d in range(3):
            n = self.grid.shape[d]
            for m in range(1, g + 1):
                if self.periodic[d]:
                    st.append((_sl(d, g - m), _sl(d, g + n - m), 0, 0.0))
                    st.append((_sl(d, g + n - 1 + m), _sl(d, g - 1 + m), 0, 0.0))
                else:
                    st.append((_sl(d, g - m), _sl(d, g + m - 1), 0, 0.0))
                    st.append((_sl(d, g + n - 1 + m), _sl(d, g + n - m), 0, 0.0))
        return st


@kernel
def _run_fill(a, runs, cst):
    """Run a recorded halo fill on the flat array a, run after run and each run in order
    (see :meth:`BoundarySet._record`): mode 0 ``a[dst] = a[src]``, 1 ``a[dst] = cst - a[src]``,
    2 ``a[dst] = cst``."""
    for r in range(runs.shape[0]):
        d0, s0, n, sd, ss, m, co = runs[r, 0], runs[r, 1], runs[r, 2], runs[r, 3], runs[r, 4], runs[r, 5], runs[r, 6]
        if m == 0:
            for t in range(n):
                a[d0 + t * sd] = a[s0 + t * ss]
        elif m == 1:
            for t in range(n):
                a[d0 + t * sd] = cst[co + t] - a[s0 + t * ss]
        else:
            for t in range(n):
                a[d0 + t * sd] = cst[co + t]
