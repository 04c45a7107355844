"""Triangle-mesh walls (walls from CAD): reading, checking, packing and the contact kernels.

A :class:`MeshWall` is a one-sided surface made of triangles, read from STL (ASCII or binary) or
OBJ through meshio, or given as arrays.  It behaves like the analytic wall it approximates: a
sphere touching a face, an edge or a vertex gets exactly one contact however many triangles
share the point, and that contact is computed like the analytic plane / rectangle edge
(:mod:`cfddem.particles.walls`) and goes through the same pair law.

Contact of a sphere (centre x, radius r) with one triangle t (vertices P0, P1, P2, unit normal n
= (P1 - P0) x (P2 - P0) / |...| pointing towards the particles, h = (x - P0).n):

* face: the projection x - h n lies in the closed triangle.  Contact while -r < h < r, overlap
  r - h, normal n, contact point q = x - h n (the analytic plane, also from behind);
* otherwise the closest point q of the triangle lies on its boundary: on an edge (interior of
  the segment) or on a vertex.  Contact while |x - q| < r and h >= 0 (front side only, as the
  rectangle's edges), overlap r - |x - q|, normal (x - q)/|x - q|.

One contact per point (the contact is a local minimum of the distance from x to the surface).
The triangles of a mesh share welded vertices and edges (global ids).  An edge or vertex contact
of triangle t at feature f (an edge or a vertex) is kept only if every other triangle u incident
to f (sharing the edge, or the vertex's fan)

* does not see x over its own face (then u's closest point is strictly closer than q, so q is not
  a local minimum of the distance; u's face contact is the contact), and
* does not have its closest point strictly closer than q on another feature, and
* if u's closest point is the same feature f and u is in front (h_u >= 0), u has a larger index
  (the lowest-index triangle owns a shared edge or vertex contact).

Face contacts are always kept; two contacts at the same point (e.g. the projection on the seam
of two coplanar triangles, which both see x over their closed faces) are merged: a new contact
whose point lies within 1e-9 r of an accepted contact of the same mesh is dropped.  Consequences (tested): a flat seam or
a vertex shared by six coplanar triangles gives one contact, equal to the analytic plane's; a
sphere rolling across a seam of two coplanar triangles keeps the face contact of the triangle
under it (the neighbour's edge contact is dropped because the triangle under the sphere sees x
over its face), so the force is continuous; rolling over a convex edge passes from the face contact
through the edge contact (normal turning continuously) to the next face; a concave corner (two
faces at an angle, both seen from the front) gives the two face contacts that two analytic planes
give.

Tangential history follows a contact across triangles: each particle has ``K`` contact slots
(mesh index, last normal, last contact point, tangential spring).  A new contact takes over the
slot of the same mesh whose last normal is closest to its normal (n_new.n_old > 1/2) and whose
last contact point is within r of its point, best pairs first; the other new contacts take free
slots with zero history; slots not taken are released.

Moving meshes: a mesh translates at ``velocity`` and rotates at ``angular_velocity`` about an
axis through ``center`` (which moves with the translation).  The vertex positions are
c(t) + Rot(t) (X0 - c0), with c(t) = c0 + the accumulated translation and Rot(t) the
accumulated rotation (both stepped with the particles); the contact uses the surface velocity
v + w x (q - c(t)).  ``schedule`` switches a mesh on and off at set times (a gate).

Search (:func:`tri_cell_count`, :func:`mesh_cand_count`): at every neighbour rebuild the
triangles are binned into the particles' cell grid (a triangle goes into each cell whose
centre lies within (R_max + skin + half the cell diagonal) of it; only the cells of the slab
around its plane are examined), and each particle keeps the triangles of its own cell that
lie within r + skin of its centre (a candidate list, CSR).  The list is rebuilt when a particle or a mesh vertex has moved more than skin/2 since the build.
The force kernel visits only the particles that have candidates.
Through-the-mesh diagnosis (:meth:`MeshTables.crossings`, :func:`chord_grid`,
:func:`chord_crossings`; used by :mod:`cfddem.particles.crossing`): the chords from particle
centres at a check to the centres now, taken into each mesh's own frame, are tested against the
triangles of a grid built once per mesh.
Limits: meshes do not see periodic images; a particle has at most ``K`` mesh contacts at once
(the step stops with a clear message otherwise).
"""

from __future__ import annotations

import functools
import math
from pathlib import Path

import numpy as np

from cfddem._jit import kernel, parallel_kernel, prange
from cfddem.particles._twin import serial_twin
from cfddem.particles.neighbours import grid_strides
from cfddem.errors import CaseError
from cfddem.particles.contact import P_1, P_2, P_3, P_4, P_MODEL, P_MU, wall_contact_force

#: columns of the triangle table: P0 (0:3), e1 = P1 - P0 (3:6), e2 = P2 - P0 (6:9), unit normal
#: (9:12), e1.e1, e1.e2, e2.e2, 1/(e1.e1 e2.e2 - (e1.e2)^2), |e2 - e1|^2
NT = 17
FACE, EDGE, VERTEX = 0, 1, 2
#: length units of mesh files, in metres
UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6, "in": 0.0254, "ft": 0.3048}
#: contact-point distance (relative to the particle radius) below which two contacts of one mesh
#: are the same contact
MERGE_TOL = 1e-9
#: a slot's history goes to a new contact whose normal is within 60 degrees of the slot's
MATCH_COS = 0.5


def _vec3(key, v):
    a = np.asarray(v, dtype=float).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise CaseError(key, f"needs three finite numbers, got {np.asarray(v).tolist()}")
    return a


def rotation(axis, angle: float) -> np.ndarray:
    """Rotation matrix by ``angle`` (radians) about ``axis`` (Rodrigues)."""
    a = np.asarray(axis, float)
    w = float(np.linalg.norm(a))
    if w == 0.0 or angle == 0.0:
        return np.eye(3)
    k = a / w
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


def _weld(V, F, tol):
    """Merge vertices closer than ``tol``; drop unreferenced ones.  Returns (V, F)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    nv = len(V)
    pairs = cKDTree(V).query_pairs(tol, output_type="ndarray") if tol > 0 else np.zeros((0, 2), int)
    if len(pairs):
        g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(nv, nv))
        _, label = connected_components(g, directed=False)
        # representative: the first vertex of each group (keeps the file's order)
        first = np.full(label.max() + 1, nv, dtype=np.int64)
        np.minimum.at(first, label, np.arange(nv))
        F = first[label][F]
    used, F = np.unique(F, return_inverse=True)
    return V[used], F.reshape(-1, 3)


def triangle_rows(V, F) -> np.ndarray:
    """The triangle table (nt, NT) of vertices V (nv, 3) and triangles F (nt, 3)."""
    p0 = V[F[:, 0]]
    e1 = V[F[:, 1]] - p0
    e2 = V[F[:, 2]] - p0
    c = np.cross(e1, e2)
    n = c / np.linalg.norm(c, axis=1)[:, None]
    d11 = np.einsum("ij,ij->i", e1, e1)
    d12 = np.einsum("ij,ij->i", e1, e2)
    d22 = np.einsum("ij,ij->i", e2, e2)
    e3 = e2 - e1
    T = np.empty((len(F), NT))
    T[:, 0:3] = p0
    T[:, 3:6] = e1
    T[:, 6:9] = e2
    T[:, 9:12] = n
    T[:, 12] = d11
    T[:, 13] = d12
    T[:, 14] = d22
    T[:, 15] = 1.0 / (d11 * d22 - d12 * d12)
    T[:, 16] = np.einsum("ij,ij->i", e3, e3)
    return T


@functools.lru_cache(maxsize=8)
def _read_triangles(path: str, mtime_ns: int, size: int):
    """(points (nv, 3) in the file's units, triangles (nt, 3)) of a mesh file, read through meshio
    once per process for the same file, modification time and size (a case's mesh is needed by
    the validation, ``cfddem check``, the bounding box and the particle system; MeshWall.from_file
    applies the scale and transform to the cached points).  The arrays are read-only.  Errors
    are :class:`CaseError` with key "file" (not cached: a failed read is tried again)."""
    import meshio

    name = Path(path).name
    try:
        with np.errstate(over="ignore"):  # meshio's binary-size probe of ASCII files
            m = meshio.read(path)
    except Exception as exc:  # meshio raises many kinds for files that are not meshes
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise CaseError("file", f"cannot read {name} as a mesh ({msg})") from None
    tris = []
    for block in m.cells:
        c = np.asarray(block.data)
        if block.type == "triangle":
            tris.append(c)
        elif block.type == "quad" or block.type.startswith("polygon"):
            for j in range(1, c.shape[1] - 1):  # fan
                tris.append(c[:, [0, j, j + 1]])
    if not tris or sum(len(t) for t in tris) == 0:
        raise CaseError("file", f"{name} holds no triangles")
    P = np.array(np.asarray(m.points, dtype=float)[:, :3])
    F = np.concatenate(tris)
    P.flags.writeable = False
    F.flags.writeable = False
    return P, F


class MeshWall:
    """A one-sided wall made of triangles (module docstring).

    ``vertices`` (nv, 3) in metres, ``triangles`` (nt, 3) vertex indices; the normal of a
    triangle (P0, P1, P2) is (P1 - P0) x (P2 - P0) and must point towards the particles
    (``flip_normals=True`` reverses all of them).  ``contact``: its own contact law and
    material (:class:`LinearContact` or :class:`HertzMindlinContact`).  Motion: ``velocity``
    (m/s), ``angular_velocity`` (rad/s, a vector along the axis) about an axis through
    ``center`` (default: the centre of the bounding box); ``ref_point``: the point about which
    the torque on the mesh is reported (default ``center``; it moves with the translation).
    ``schedule``: ((time, on), ...) switches the mesh on (True) or off at those times;
    ``active``: the state at the start.  Vertices closer than ``weld_tol`` (default 1e-9 of the
    bounding-box diagonal) are merged; degenerate and duplicate triangles are dropped with a
    warning (:attr:`warnings`).  Bad input raises :class:`CaseError` (one line).
    """

    def __init__(self, vertices, triangles, contact, *, name: str = "", velocity=(0.0, 0.0, 0.0),
                 angular_velocity=(0.0, 0.0, 0.0), center=None, ref_point=None, schedule=(),
                 active: bool = True, flip_normals: bool = False, weld_tol: float | None = None,
                 source: str = ""):
        key = f"mesh {name!r}" if name else "mesh"
        self.name = name
        self.contact = contact
        self.source = source
        V = np.asarray(vertices, dtype=float)
        F = np.asarray(triangles)
        if V.size == 0 or F.size == 0:
            raise CaseError(key, f"empty mesh ({V.size // 3} vertices, {F.size // 3} triangles)")
        if V.ndim != 2 or V.shape[1] != 3:
            raise CaseError(key, f"vertices need shape (nv, 3), got {V.shape}")
        if F.ndim != 2 or F.shape[1] != 3 or not np.issubdtype(F.dtype, np.integer):
            raise CaseError(key, f"triangles need integer shape (nt, 3), got {F.dtype} {F.shape}")
        if not np.all(np.isfinite(V)):
            raise CaseError(key, "non-finite vertex coordinates")
        if F.min() < 0 or F.max() >= len(V):
            raise CaseError(key, f"triangle vertex index out of range 0..{len(V) - 1}")
        F = F.astype(np.int64)
        diag = float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))
        if not diag > 0:
            raise CaseError(key, "all vertices coincide (degenerate mesh)")
        tol = 1e-9 * diag if weld_tol is None else float(weld_tol)
        V, F = _weld(V, F, tol)
        self.warnings: list[str] = []
        # degenerate triangles: repeated vertices, or area below 1e-10 of the squared longest edge
        e1 = V[F[:, 1]] - V[F[:, 0]]
        e2 = V[F[:, 2]] - V[F[:, 0]]
        e3 = V[F[:, 2]] - V[F[:, 1]]
        a2 = np.linalg.norm(np.cross(e1, e2), axis=1)
        lmax2 = np.max([np.einsum("ij,ij->i", e, e) for e in (e1, e2, e3)], axis=0)
        bad = (a2 <= 1e-10 * lmax2) | (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 0] == F[:, 2])
        if bad.all():
            raise CaseError(key, f"all {len(F)} triangles are degenerate (zero area)")
        if bad.any():
            self.warnings.append(f"{int(bad.sum())} degenerate triangles (zero area) dropped")
            F = F[~bad]
        srt = np.sort(F, axis=1)
        _, first = np.unique(srt, axis=0, return_index=True)
        if len(first) < len(F):
            self.warnings.append(f"{len(F) - len(first)} duplicate triangles dropped")
            F = F[np.sort(first)]
        V, F = _weld(V, F, 0.0)  # drop vertices no triangle uses any more
        if flip_normals:
            F = F[:, [0, 2, 1]]
        self.vertices = V
        self.triangles = F
        self._topology()
        self.velocity = _vec3(f"{key}.velocity", velocity)
        self.angular_velocity = _vec3(f"{key}.angular_velocity", angular_velocity)
        self.center = (0.5 * (V.min(axis=0) + V.max(axis=0)) if center is None
                       else _vec3(f"{key}.center", center))
        self.ref_point = self.center.copy() if ref_point is None else _vec3(f"{key}.ref_point", ref_point)
        sched = []
        for item in schedule:
            try:
                t, on = item
                t = float(t)
            except (TypeError, ValueError):
                raise CaseError(f"{key}.schedule", f"needs (time, on) pairs, got {item!r}") from None
            if not math.isfinite(t):
                raise CaseError(f"{key}.schedule", f"switch time must be finite, got {t}")
            sched.append((t, bool(on)))
        self.schedule = sorted(sched, key=lambda s: s[0])
        self.active = bool(active)

    # ------------------------------------------------------------------ reading
    @classmethod
    def from_file(cls, path, contact, *, scale: float | None = None, units: str | None = None,
                  rotate=None, translate=(0.0, 0.0, 0.0), name: str | None = None, **kw) -> "MeshWall":
        """Read an STL (ASCII or binary) or OBJ file through meshio.

        Lengths in the file are multiplied by ``scale`` (or the factor of ``units``: one of
        :data:`UNITS`, e.g. "mm"; default metres), then rotated by ``rotate`` = (axis (3),
        angle in degrees) about the origin, then translated by ``translate`` (m).  Polygons
        (quads of OBJ files) are split into triangles (fans).  Other keywords go to
        :class:`MeshWall`.  Errors (missing file, not a mesh, no triangles) are one-line
        :class:`CaseError`.  The file is read once per process (:func:`_read_triangles`).
        """
        path = Path(path)
        name = path.stem if name is None else name
        key = f"mesh {name!r}"
        if units is not None:
            if units not in UNITS:
                raise CaseError(f"{key}.units", f"unknown unit {units!r} (one of {', '.join(UNITS)})")
            if scale is not None and scale != UNITS[units]:
                raise CaseError(f"{key}.scale", f"scale {scale} contradicts units {units!r}")
            scale = UNITS[units]
        scale = 1.0 if scale is None else float(scale)
        if not (scale > 0 and math.isfinite(scale)):
            raise CaseError(f"{key}.scale", f"must be positive, got {scale}")
        if not path.is_file():
            raise CaseError(f"{key}.file", f"no such file: {path}")
        st = path.stat()
        try:
            P, F = _read_triangles(str(path.resolve()), st.st_mtime_ns, st.st_size)
        except CaseError as e:
            raise CaseError(f"{key}.file", e.reason) from None
        V = P * scale
        if rotate is not None:
            try:
                axis, deg = rotate
                R = rotation(_vec3(f"{key}.rotate", axis), math.radians(float(deg)))
            except (TypeError, ValueError):
                raise CaseError(f"{key}.rotate", f"needs (axis (3), angle in degrees), got {rotate!r}") from None
            V = V @ R.T
        V = V + _vec3(f"{key}.translate", translate)
        return cls(V, F, contact, name=name, source=str(path), **kw)

    # ------------------------------------------------------------------ topology and checks
    def _topology(self):
        F = self.triangles
        nt = len(F)
        directed = np.stack([F, np.roll(F, -1, axis=1)], axis=2).reshape(-1, 2)  # edge k: v_k -> v_k+1
        und = np.sort(directed, axis=1)
        uniq, inv, counts = np.unique(und, axis=0, return_inverse=True, return_counts=True)
        inv = inv.reshape(-1)
        self.edges = uniq
        self.tri_edge = inv.reshape(nt, 3)
        self.n_open_edges = int(np.sum(counts == 1))
        self.n_nonmanifold_edges = int(np.sum(counts > 2))
        # orientation: on an edge shared by two triangles the two must run opposite ways
        fwd = directed[:, 0] < directed[:, 1]
        nfwd = np.bincount(inv, weights=fwd, minlength=len(uniq))
        self.n_inconsistent_edges = int(np.sum((counts == 2) & ((nfwd == 0) | (nfwd == 2))))
        self.closed = self.n_open_edges == 0 and self.n_nonmanifold_edges == 0
        # signed volume of a closed mesh: > 0 when the normals point outwards of the solid
        V = self.vertices
        self.signed_volume = float(np.einsum("ij,ij->i", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])).sum() / 6.0)
        if self.n_nonmanifold_edges:
            self.warnings.append(f"{self.n_nonmanifold_edges} non-manifold edges (shared by more than two triangles)")
        if self.n_inconsistent_edges:
            self.warnings.append(f"{self.n_inconsistent_edges} edges with inconsistent normals (neighbouring "
                                 "triangles face opposite ways; particles see only the front side of each)")
        if self.n_open_edges:
            self.warnings.append(f"{self.n_open_edges} open edges (the surface is not closed; particles can pass "
                                 "around its boundary)")

    @property
    def n_triangles(self) -> int:
        return len(self.triangles)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.vertices.min(axis=0), self.vertices.max(axis=0)

    def edge_lengths(self) -> np.ndarray:
        e = self.vertices[self.edges[:, 1]] - self.vertices[self.edges[:, 0]]
        return np.linalg.norm(e, axis=1)

    def check_lines(self, particle_diameter: float | None = None) -> list[str]:
        """One-line reports for ``cfddem check``: a summary, then each defect as a warning."""
        lo, hi = self.bounds()
        lmin = float(self.edge_lengths().min())
        size = f", smallest edge {lmin:.3g} m"
        if particle_diameter:
            size += f" = {lmin / particle_diameter:.3g} particle diameters"
        side = ""
        if self.closed and self.n_inconsistent_edges == 0:
            side = ("; closed, normals point outwards (particles outside the solid)" if self.signed_volume > 0
                    else "; closed, normals point inwards (particles inside)")
        name = self.name or self.source or "mesh"
        out = [f"mesh {name}: {self.n_triangles} triangles, bounds [{lo[0]:.4g}, {lo[1]:.4g}, {lo[2]:.4g}] .. "
               f"[{hi[0]:.4g}, {hi[1]:.4g}, {hi[2]:.4g}] m{size}{side}"]
        out += [f"warning: mesh {name}: {w}" for w in self.warnings]
        return out


# ---------------------------------------------------------------------- simple surfaces


def grid_surface(origin, u, v, nu: int, nv: int):
    """Parallelogram origin + a u + b v (0 <= a, b <= 1) split into nu x nv cells of two
    triangles each, every cell cut along the same diagonal (an interior vertex is shared by six
    triangles); normal u x v.  Returns (vertices, triangles)."""
    o, u, v = (np.asarray(a, float) for a in (origin, u, v))
    a, b = np.meshgrid(np.linspace(0, 1, nu + 1), np.linspace(0, 1, nv + 1), indexing="ij")
    V = o + a.reshape(-1, 1) * u + b.reshape(-1, 1) * v
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    p = (i * (nv + 1) + j).reshape(-1)
    F = np.concatenate([np.stack([p, p + nv + 2, p + 1], 1), np.stack([p, p + nv + 1, p + nv + 2], 1)])
    return V, F


def box_surface(lo, hi, n: int = 1, inward: bool = True):
    """Closed surface of the box lo..hi, each face split into n x n cells (12 n^2 triangles);
    normals point inwards (particles inside) unless ``inward=False``.  Returns (V, F), V with
    duplicate vertices along the box edges (MeshWall welds them)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    L = hi - lo
    Vs, Fs, off = [], [], 0
    for a in range(3):
        b, c = (a + 1) % 3, (a + 2) % 3
        eb, ec = np.zeros(3), np.zeros(3)
        eb[b], ec[c] = L[b], L[c]
        for side in (0, 1):
            o = lo.copy()
            o[a] = hi[a] if side else lo[a]
            # eb x ec points along +a: inwards on the low face
            V, F = grid_surface(o, eb, ec, n, n) if side == 0 else grid_surface(o, ec, eb, n, n)
            Vs.append(V)
            Fs.append(F + off)
            off += len(V)
    F = np.concatenate(Fs)
    return np.concatenate(Vs), (F if inward else F[:, [0, 2, 1]])


def cylinder_surface(center, axis, radius: float, length: float, n_around: int, n_along: int = 1,
                     caps: bool = True, inward: bool = True):
    """Closed (``caps``) or open surface of a cylinder of ``radius`` and ``length`` about
    ``axis`` through ``center``: a prism with n_around sides whose faces' mid-lines lie on the
    radius (vertices at radius / cos(pi / n_around)), caps as fans.  Normals point inwards
    (particles inside: a drum) unless ``inward=False``.  Returns (V, F)."""
    c = np.asarray(center, float)
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    e1 = np.cross(k, [1.0, 0, 0] if abs(k[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(k, e1)
    rv = radius / math.cos(math.pi / n_around)
    th = 2 * math.pi * np.arange(n_around) / n_around
    ring = rv * (np.cos(th)[:, None] * e1 + np.sin(th)[:, None] * e2)
    s = np.linspace(-0.5 * length, 0.5 * length, n_along + 1)
    V = (c + s[:, None, None] * k + ring[None]).reshape(-1, 3)
    F = []
    for a in range(n_along):
        for j in range(n_around):
            p, q = a * n_around + j, a * n_around + (j + 1) % n_around
            F += [[p, q, q + n_around], [p, q + n_around, p + n_around]]
    F = np.array(F)  # (ring j -> j+1) x axis points outwards: flip below for inward
    if caps:
        nv = len(V)
        V = np.vstack([V, c - 0.5 * length * k, c + 0.5 * length * k])
        j = np.arange(n_around)
        top = n_along * n_around
        bottom_fan = np.stack([np.full(n_around, nv), (j + 1) % n_around, j], 1)
        top_fan = np.stack([np.full(n_around, nv + 1), top + j, top + (j + 1) % n_around], 1)
        F = np.vstack([F, bottom_fan, top_fan])
    return V, (F[:, [0, 2, 1]] if inward else F)


# ---------------------------------------------------------------------- packed tables


class MeshTables:
    """Flat arrays of all mesh walls of a system (kernels' view), and their motion."""

    def __init__(self, meshes: list[MeshWall]):
        self.meshes = list(meshes)
        nm = len(meshes)
        self.nm = nm
        T, tmesh, tvert, tedge, tstart = [], [], [], [], [0]
        voff = eoff = 0
        for k, m in enumerate(meshes):
            T.append(triangle_rows(m.vertices, m.triangles))
            tmesh.append(np.full(m.n_triangles, k, np.int64))
            tvert.append(m.triangles + voff)
            tedge.append(m.tri_edge + eoff)
            voff += len(m.vertices)
            eoff += len(m.edges)
            tstart.append(tstart[-1] + m.n_triangles)
        self.tstart = np.array(tstart, np.int64)
        if nm:
            self.T0 = np.ascontiguousarray(np.concatenate(T))
            self.tmesh = np.concatenate(tmesh)
            self.tvert = np.ascontiguousarray(np.concatenate(tvert))
            self.tedge = np.ascontiguousarray(np.concatenate(tedge))
        else:
            self.T0 = np.zeros((0, NT))
            self.tmesh = np.zeros(0, np.int64)
            self.tvert = self.tedge = np.zeros((0, 3), np.int64)
        self.nt = len(self.T0)
        self.T = self.T0.copy()
        self.estart, self.etri = _csr(self.tedge, eoff)
        self.vstart, self.vtri = _csr(self.tvert, voff)
        self.par = np.zeros((max(nm, 1), 8))
        self.vel = np.zeros((max(nm, 1), 3))
        self.omg = np.zeros((max(nm, 1), 3))
        self.cen0 = np.zeros((max(nm, 1), 3))
        self.ref0 = np.zeros((max(nm, 1), 3))
        self.act = np.zeros(max(nm, 1), np.int64)
        self.rho = np.zeros(max(nm, 1))  # largest vertex distance from the rotation centre
        for k, m in enumerate(meshes):
            self.par[k] = m.contact.params()
            self.vel[k] = m.velocity
            self.omg[k] = m.angular_velocity
            self.cen0[k] = m.center
            self.ref0[k] = m.ref_point
            self.act[k] = 1 if m.active else 0
            self.rho[k] = float(np.max(np.linalg.norm(m.vertices - m.center, axis=1)))
        # motion state: offset of the centre, accumulated rotation
        self.offset = np.zeros((max(nm, 1), 3))
        self.rot = np.tile(np.eye(3), (max(nm, 1), 1, 1))
        self.cen = self.cen0.copy()
        self.ref = self.ref0.copy()
        self.disp = 0.0  # bound on any vertex's displacement since the last list build
        self.events = sorted((t, k, on) for k, m in enumerate(meshes) for t, on in m.schedule)
        self.next_event = 0
        self._chord_grids: dict = {}  # mesh -> its triangles binned for crossings() (built when first needed)
        self._moving = None

    def moving(self) -> np.ndarray:
        """Indices of the meshes that translate or rotate (cached: call :meth:`motion_changed`
        after changing ``vel`` or ``omg``)."""
        if self._moving is None:
            self._moving = np.flatnonzero(np.any(self.vel[: self.nm] != 0.0, axis=1)
                                          | np.any(self.omg[: self.nm] != 0.0, axis=1))
        return self._moving

    def motion_changed(self) -> None:
        self._moving = None

    def advance(self, dt: float) -> None:
        """Move every moving mesh by one step of length ``dt``."""
        for k in self.moving():
            w = float(np.linalg.norm(self.omg[k]))
            d = dt * self.vel[k]
            self.offset[k] += d
            if w > 0.0:
                self.rot[k] = rotation(self.omg[k], w * dt) @ self.rot[k]
            self.disp = max(self.disp, 0.0) + float(np.linalg.norm(d)) + w * dt * self.rho[k]
            self._place(k)

    def _place(self, k: int) -> None:
        self.cen[k] = self.cen0[k] + self.offset[k]
        self.ref[k] = self.ref0[k] + self.offset[k]
        lo, hi = int(self.tstart[k]), int(self.tstart[k + 1])
        place_rows(self.T0, self.T, lo, hi, self.rot[k], self.cen0[k], self.cen[k])

    def vertices_now(self, k: int) -> np.ndarray:
        m = self.meshes[k]
        return self.cen[k] + (m.vertices - self.cen0[k]) @ self.rot[k].T

    def placement(self) -> dict:
        """A copy of where the meshes are now and which are on (for :meth:`crossings`)."""
        return dict(cen=self.cen.copy(), rot=self.rot.copy(), act=self.act.copy(), next_event=self.next_event)

    def crossings(self, k: int, before: dict, old, new, radius):
        """Particles whose centre went through mesh k from its front to more than their radius
        behind it between two placements: ``before`` (:meth:`placement`, with the centres
        ``old``) and now (centres ``new``).  Both are taken into the mesh's own frame (its
        placement at the start), so a moving mesh is seen at rest; the chord old -> new is tested
        against the triangles (:func:`chord_crossings`) through a grid cached per mesh.
        Returns (triangle index in ``meshes[k].triangles`` or -1, depth behind it (m), number of
        triangle tests done): the first triangle the chord meets, when it meets it from the
        front and ends more than r behind its plane; -1 otherwise (no crossing, or the first
        triangle met from behind)."""
        a = self.cen0[k] + (np.asarray(old, float) - before["cen"][k]) @ before["rot"][k]
        b = self.cen0[k] + (np.asarray(new, float) - self.cen[k]) @ self.rot[k]
        grid = self._chord_grids.get(k)
        if grid is None:
            grid = self._chord_grids[k] = chord_grid(self.T0[int(self.tstart[k]): int(self.tstart[k + 1])])
        n = len(a)
        tri = np.empty(n, np.int64)
        s = np.empty(n)
        h = np.empty(n)
        tests = np.empty(n, np.int64)
        chord_crossings(n, np.ascontiguousarray(a), np.ascontiguousarray(b), *grid, tri, s, h, tests)
        hit = (tri >= 0) & (h < -np.asarray(radius, float))
        return np.where(hit, tri, -1), np.where(hit, -h, 0.0), int(tests.sum())

    def get_state(self) -> dict:
        return dict(m_offset=self.offset.copy(), m_rot=self.rot.copy(), m_act=self.act.copy(),
                    m_vel=self.vel.copy(), m_omg=self.omg.copy(), m_disp=self.disp, m_next_event=self.next_event)

    def set_state(self, st) -> None:
        self.offset[...] = st["m_offset"]
        self.rot[...] = st["m_rot"]
        self.act[...] = st["m_act"]
        self.vel[...] = st["m_vel"]
        self.omg[...] = st["m_omg"]
        self.motion_changed()
        self.disp = float(st["m_disp"])
        self.next_event = int(st["m_next_event"])
        for k in range(self.nm):
            self._place(k)


def _csr(tfeat, nfeat):
    """(start (nfeat+1), triangle list) of the triangles incident to each feature id."""
    nt = len(tfeat)
    flat = tfeat.reshape(-1)
    tri = np.repeat(np.arange(nt, dtype=np.int64), 3)
    order = np.argsort(flat, kind="stable")
    start = np.zeros(nfeat + 1, np.int64)
    np.cumsum(np.bincount(flat, minlength=nfeat), out=start[1:])
    # a degenerate-free triangle lists a feature once, so each (feature, triangle) is unique
    return start, np.ascontiguousarray(tri[order])


# ---------------------------------------------------------------------- kernels


@kernel
def place_rows(T0, T, lo, hi, R, c0, c):
    """Rows lo..hi of T = the rows of T0 rotated by R about c0 and moved to centre c."""
    for t in range(lo, hi):
        px = T0[t, 0] - c0[0]
        py = T0[t, 1] - c0[1]
        pz = T0[t, 2] - c0[2]
        for a in range(3):
            T[t, a] = c[a] + R[a, 0] * px + R[a, 1] * py + R[a, 2] * pz
        for b in (3, 6, 9):
            x = T0[t, b]
            y = T0[t, b + 1]
            z = T0[t, b + 2]
            for a in range(3):
                T[t, b + a] = R[a, 0] * x + R[a, 1] * y + R[a, 2] * z


@kernel(inline="always")
def _seg(ax, ay, az, ex, ey, ez, s):
    """Point a - s e (relative to the triangle's P0 frame) and its squared length."""
    rx = ax - s * ex
    ry = ay - s * ey
    rz = az - s * ez
    return rx, ry, rz, rx * rx + ry * ry + rz * rz


@kernel(inline="always")
def tri_closest(T, t, x, y, z):
    """Closest point of triangle t to (x, y, z).

    Returns (feature, k, qx, qy, qz, d2, h): feature FACE (0; the projection lies in the closed
    triangle), EDGE (1; interior of edge k, from vertex k to vertex k+1) or VERTEX (2; vertex k),
    the point q, the squared distance |x - q|^2 and the height h = (x - P0).n.
    """
    ax = x - T[t, 0]
    ay = y - T[t, 1]
    az = z - T[t, 2]
    e1x = T[t, 3]
    e1y = T[t, 4]
    e1z = T[t, 5]
    e2x = T[t, 6]
    e2y = T[t, 7]
    e2z = T[t, 8]
    nx = T[t, 9]
    ny = T[t, 10]
    nz = T[t, 11]
    h = ax * nx + ay * ny + az * nz
    d1 = ax * e1x + ay * e1y + az * e1z
    d2 = ax * e2x + ay * e2y + az * e2z
    d11 = T[t, 12]
    d12 = T[t, 13]
    d22 = T[t, 14]
    idet = T[t, 15]
    v = (d22 * d1 - d12 * d2) * idet
    w = (d11 * d2 - d12 * d1) * idet
    if v >= 0.0 and w >= 0.0 and v + w <= 1.0:
        return FACE, 0, x - h * nx, y - h * ny, z - h * nz, h * h, h
    # edge 0: P0 + s e1
    s0 = min(max(d1 / d11, 0.0), 1.0)
    rx, ry, rz, best = _seg(ax, ay, az, e1x, e1y, e1z, s0)
    k = 0
    s = s0
    # edge 1: P1 + s (e2 - e1), a - e1 relative to P1
    e3x = e2x - e1x
    e3y = e2y - e1y
    e3z = e2z - e1z
    bx = ax - e1x
    by = ay - e1y
    bz = az - e1z
    s1 = min(max((bx * e3x + by * e3y + bz * e3z) / T[t, 16], 0.0), 1.0)
    r1x, r1y, r1z, q1 = _seg(bx, by, bz, e3x, e3y, e3z, s1)
    if q1 < best:
        rx, ry, rz, best, k, s = r1x, r1y, r1z, q1, 1, s1
    # edge 2: P2 + s (P0 - P2) = P2 - s e2, a - e2 relative to P2
    cx = ax - e2x
    cy = ay - e2y
    cz = az - e2z
    s2 = min(max(-(cx * e2x + cy * e2y + cz * e2z) / d22, 0.0), 1.0)
    r2x, r2y, r2z, q2 = _seg(cx, cy, cz, -e2x, -e2y, -e2z, s2)
    if q2 < best:
        rx, ry, rz, best, k, s = r2x, r2y, r2z, q2, 2, s2
    feat = EDGE
    if s == 0.0:
        feat = VERTEX
    elif s == 1.0:
        feat = VERTEX
        k = (k + 1) % 3
    return feat, k, x - rx, y - ry, z - rz, best, h


@kernel(inline="always")
def _feature_kept(T, t, feat, fid, d2, x, y, z, tedge, tvert, fstart, ftri):
    """Is the edge/vertex contact of triangle t at feature ``fid`` the one kept (module
    docstring)?  ``fstart``/``ftri``: the incident triangles of the edges or of the vertices."""
    for j in range(fstart[fid], fstart[fid + 1]):
        u = ftri[j]
        if u == t:
            continue
        fu, ku, qx, qy, qz, du, hu = tri_closest(T, u, x, y, z)
        if fu == FACE:
            return False
        gid = tedge[u, ku] if fu == EDGE else tvert[u, ku]
        if fu == feat and gid == fid:
            if u < t and hu >= 0.0:
                return False
        elif du < d2:
            return False
    return True


@kernel(inline="always")
def mesh_contact_list(i, x, y, z, r, cstart, clist, T, tmesh, mact, tedge, tvert, estart, etri,
                      vstart, vtri, K, mc):
    """The contacts of particle i with the candidate triangles, one per point (module
    docstring), into mc[i, :, 0:8] = (overlap, n (3), q (3), mesh).  Returns (count, overflow)."""
    nnew = 0
    over = 0
    tol2 = (MERGE_TOL * r) ** 2
    for c in range(cstart[i], cstart[i + 1]):
        t = clist[c]
        m = tmesh[t]
        if mact[m] == 0:
            continue
        feat, k, qx, qy, qz, d2, h = tri_closest(T, t, x, y, z)
        if feat == FACE:
            if h >= r or h <= -r:
                continue
            ov = r - h
            nx = T[t, 9]
            ny = T[t, 10]
            nz = T[t, 11]
        else:
            if h < 0.0 or d2 >= r * r or d2 == 0.0:
                continue
            if feat == EDGE:
                if not _feature_kept(T, t, feat, tedge[t, k], d2, x, y, z, tedge, tvert, estart, etri):
                    continue
            elif not _feature_kept(T, t, feat, tvert[t, k], d2, x, y, z, tedge, tvert, vstart, vtri):
                continue
            d = math.sqrt(d2)
            ov = r - d
            nx = (x - qx) / d
            ny = (y - qy) / d
            nz = (z - qz) / d
        dup = False
        for p in range(nnew):
            if mc[i, p, 7] == m:
                dx = mc[i, p, 4] - qx
                dy = mc[i, p, 5] - qy
                dz = mc[i, p, 6] - qz
                if dx * dx + dy * dy + dz * dz <= tol2:
                    dup = True
                    break
        if dup:
            continue
        if nnew == K:
            over += 1
            continue
        mc[i, nnew, 0] = ov
        mc[i, nnew, 1] = nx
        mc[i, nnew, 2] = ny
        mc[i, nnew, 3] = nz
        mc[i, nnew, 4] = qx
        mc[i, nnew, 5] = qy
        mc[i, nnew, 6] = qz
        mc[i, nnew, 7] = m
        mc[i, nnew, 8] = -1.0
        nnew += 1
    return nnew, over


@kernel(inline="always")
def _match_slots(i, r, nnew, K, mc, ms_mesh, ms_n, ms_q, ms_h):
    """Give each new contact a slot (mc[i, p, 8]): the slot of the same mesh with the closest
    last normal (dot > MATCH_COS) and last point within r keeps its history, best pairs first;
    the others take the lowest free slots with zero history; untaken slots are released."""
    taken = 0
    r2 = r * r
    while True:
        best = MATCH_COS
        bp = -1
        bs = -1
        for p in range(nnew):
            if mc[i, p, 8] >= 0.0:
                continue
            for s in range(K):
                if ((taken >> s) & 1) != 0 or ms_mesh[i, s] != mc[i, p, 7]:
                    continue
                dx = mc[i, p, 4] - ms_q[i, s, 0]
                dy = mc[i, p, 5] - ms_q[i, s, 1]
                dz = mc[i, p, 6] - ms_q[i, s, 2]
                if dx * dx + dy * dy + dz * dz >= r2:
                    continue
                dot = mc[i, p, 1] * ms_n[i, s, 0] + mc[i, p, 2] * ms_n[i, s, 1] + mc[i, p, 3] * ms_n[i, s, 2]
                if dot > best:
                    best = dot
                    bp = p
                    bs = s
        if bp < 0:
            break
        mc[i, bp, 8] = bs
        taken |= 1 << bs
    for p in range(nnew):
        if mc[i, p, 8] < 0.0:
            for s in range(K):
                if ((taken >> s) & 1) == 0:
                    mc[i, p, 8] = s
                    taken |= 1 << s
                    ms_h[i, s, 0] = 0.0
                    ms_h[i, s, 1] = 0.0
                    ms_h[i, s, 2] = 0.0
                    break
    return taken


@parallel_kernel
def mesh_forces(nlist, plist, pos, vel, omg, radius, mass, cstart, clist, T, tmesh, tedge, tvert, estart, etri,
                vstart, vtri, mpar, mvel, momg, mcen, mref, mact, K, mc, ms_mesh, ms_n, ms_q, ms_h,
                ms_ov, ms_fn, ms_fw, ms_tw, mf, mt, mstat, dt_hist):
    """Contacts of every particle with the mesh walls (module docstring) and their forces.

    Only the particles ``plist[:nlist]`` are visited: those with candidate triangles (the others
    have no mesh contact and empty slots).  Per particle: mf[i], mt[i] = the summed contact force
    and torque (about the centre) from the meshes; per slot s: the mesh, normal, point, overlap, tangential spring, |F_n|, and the force
    and torque (about the mesh's reference point) on the mesh.  Rolling friction is added by the
    wall pass (:func:`cfddem.particles.integrate.wall_forces`), as for the analytic walls.
    Returns (particles with more than K contacts, max overlap ratio); mstat (nlist, 2) is scratch
    for these two per particle (reduced after the parallel loop: numba's reduction analysis
    fails on the inlined contact search).
    """
    for j in prange(nlist):
        i = plist[j]
        x = pos[i, 0]
        y = pos[i, 1]
        z = pos[i, 2]
        r = radius[i]
        nnew, o = mesh_contact_list(i, x, y, z, r, cstart, clist, T, tmesh, mact, tedge, tvert, estart,
                                    etri, vstart, vtri, K, mc)
        mstat[j, 0] = 1.0 if o > 0 else 0.0
        taken = _match_slots(i, r, nnew, K, mc, ms_mesh, ms_n, ms_q, ms_h)
        for s in range(K):
            if ((taken >> s) & 1) == 0 and ms_mesh[i, s] >= 0:  # a contact that ended
                ms_mesh[i, s] = -1
                ms_ov[i, s] = 0.0
                ms_fn[i, s] = 0.0
                for c in range(3):
                    ms_h[i, s, c] = 0.0
                    ms_fw[i, s, c] = 0.0
                    ms_tw[i, s, c] = 0.0
        fx = 0.0
        fy = 0.0
        fz = 0.0
        tx = 0.0
        ty = 0.0
        tz = 0.0
        vx = vel[i, 0]
        vy = vel[i, 1]
        vz = vel[i, 2]
        wx = omg[i, 0]
        wy = omg[i, 1]
        wz = omg[i, 2]
        m_i = mass[i]
        ovi = 0.0
        for p in range(nnew):
            s = int(mc[i, p, 8])
            m = int(mc[i, p, 7])
            ov = mc[i, p, 0]
            nx = mc[i, p, 1]
            ny = mc[i, p, 2]
            nz = mc[i, p, 3]
            qx = mc[i, p, 4]
            qy = mc[i, p, 5]
            qz = mc[i, p, 6]
            # surface velocity v + w x (q - c)
            lx = qx - mcen[m, 0]
            ly = qy - mcen[m, 1]
            lz = qz - mcen[m, 2]
            wvx = mvel[m, 0] + (momg[m, 1] * lz - momg[m, 2] * ly)
            wvy = mvel[m, 1] + (momg[m, 2] * lx - momg[m, 0] * lz)
            wvz = mvel[m, 2] + (momg[m, 0] * ly - momg[m, 1] * lx)
            cfx, cfy, cfz, ptx, pty, ptz, hx, hy, hz, fnabs, twx, twy, twz = wall_contact_force(
                mpar[m, P_MODEL], mpar[m, P_1], mpar[m, P_2], mpar[m, P_3], mpar[m, P_4],
                mpar[m, P_MU], m_i, r, ov, nx, ny, nz, qx, qy, qz, vx, vy, vz, wx, wy, wz, wvx, wvy, wvz,
                ms_h[i, s, 0], ms_h[i, s, 1], ms_h[i, s, 2], mref[m, 0], mref[m, 1], mref[m, 2], dt_hist)
            ms_mesh[i, s] = m
            ms_h[i, s, 0] = hx
            ms_h[i, s, 1] = hy
            ms_h[i, s, 2] = hz
            ms_n[i, s, 0] = nx
            ms_n[i, s, 1] = ny
            ms_n[i, s, 2] = nz
            ms_q[i, s, 0] = qx
            ms_q[i, s, 1] = qy
            ms_q[i, s, 2] = qz
            ms_ov[i, s] = ov
            ms_fn[i, s] = fnabs
            ms_fw[i, s, 0] = -cfx
            ms_fw[i, s, 1] = -cfy
            ms_fw[i, s, 2] = -cfz
            ms_tw[i, s, 0] = twx
            ms_tw[i, s, 1] = twy
            ms_tw[i, s, 2] = twz
            fx += cfx
            fy += cfy
            fz += cfz
            tx += ptx
            ty += pty
            tz += ptz
            ovi = max(ovi, ov / r)
        mf[i, 0] = fx
        mf[i, 1] = fy
        mf[i, 2] = fz
        mt[i, 0] = tx
        mt[i, 1] = ty
        mt[i, 2] = tz
        mstat[j, 1] = ovi
    over = 0
    ovmax = 0.0
    for j in range(nlist):
        if mstat[j, 0] != 0.0:
            over += 1
        ovmax = max(ovmax, mstat[j, 1])
    return over, ovmax


@kernel(inline="always")
def _cell_range(lo_a, size_a, nc_a, a0, a1):
    i0 = int(math.floor((a0 - lo_a) / size_a))
    i1 = int(math.floor((a1 - lo_a) / size_a))
    return min(max(i0, 0), nc_a - 1), min(max(i1, 0), nc_a - 1)


@kernel(inline="always")
def _tri_cells(T, t, lo, size, nc, cut, start, cells, tris, fill):
    """Count (fill=False) or write the cells of triangle t: those whose centre lies within
    lim = cut + half the cell diagonal of the triangle.  The cells are scanned over the
    triangle's bounding box (grown by cut) along the two axes other than the normal's largest
    component d, and along d only over the slab |n.(c - P0)| <= lim (at most about 3.5 lim
    long): a large tilted triangle costs its area in cells, not its bounding box's volume."""
    hd = 0.5 * math.sqrt(size[0] * size[0] + size[1] * size[1] + size[2] * size[2])
    lim = cut + hd
    lim2 = lim * lim
    d = 0
    if abs(T[t, 10]) > abs(T[t, 9 + d]):
        d = 1
    if abs(T[t, 11]) > abs(T[t, 9 + d]):
        d = 2
    a = (d + 1) % 3
    b = (d + 2) % 3
    ia0, ia1 = _cell_range(lo[a], size[a], nc[a], T[t, a] + min(0.0, min(T[t, 3 + a], T[t, 6 + a])) - cut,
                           T[t, a] + max(0.0, max(T[t, 3 + a], T[t, 6 + a])) + cut)
    ib0, ib1 = _cell_range(lo[b], size[b], nc[b], T[t, b] + min(0.0, min(T[t, 3 + b], T[t, 6 + b])) - cut,
                           T[t, b] + max(0.0, max(T[t, 3 + b], T[t, 6 + b])) + cut)
    dlo = T[t, d] + min(0.0, min(T[t, 3 + d], T[t, 6 + d])) - cut
    dhi = T[t, d] + max(0.0, max(T[t, 3 + d], T[t, 6 + d])) + cut
    na = T[t, 9 + a]
    nb_ = T[t, 9 + b]
    nd = T[t, 9 + d]
    cnt = 0
    for ia in range(ia0, ia1 + 1):
        ca = lo[a] + (ia + 0.5) * size[a]
        for ib in range(ib0, ib1 + 1):
            cb = lo[b] + (ib + 0.5) * size[b]
            base = na * (ca - T[t, a]) + nb_ * (cb - T[t, b])
            z1 = T[t, d] + (-lim - base) / nd
            z2 = T[t, d] + (lim - base) / nd
            zlo = max(min(z1, z2), dlo)
            zhi = min(max(z1, z2), dhi)
            if zlo > zhi:
                continue
            id0, id1 = _cell_range(lo[d], size[d], nc[d], zlo - 0.5 * size[d], zhi + 0.5 * size[d])
            for idd in range(id0, id1 + 1):
                if d == 0:
                    cx, cy, cz = idd, ia, ib
                elif d == 1:
                    cx, cy, cz = ib, idd, ia
                else:
                    cx, cy, cz = ia, ib, idd
                feat, k, qx, qy, qz, d2, h = tri_closest(T, t, lo[0] + (cx + 0.5) * size[0],
                                                         lo[1] + (cy + 0.5) * size[1],
                                                         lo[2] + (cz + 0.5) * size[2])
                if d2 < lim2:
                    if fill:
                        cells[start + cnt] = cx * nc[3] + cy * nc[4] + cz * nc[5]
                        tris[start + cnt] = t
                    cnt += 1
    return cnt


@parallel_kernel
def tri_cell_count(T, nt, lo, size, nc, cut, counts):
    """counts[t] = the number of cells of the particle grid that triangle t is binned into."""
    for t in prange(nt):
        counts[t] = _tri_cells(T, t, lo, size, nc, cut, 0, counts, counts, False)


@parallel_kernel
def tri_cell_fill(T, nt, lo, size, nc, cut, start, cells, tris):
    """(cell, triangle) entries of every triangle from ``start[t]`` (triangle order)."""
    for t in prange(nt):
        _tri_cells(T, t, lo, size, nc, cut, start[t], cells, tris, True)


@kernel(inline="always")
def _cell_of(x, y, z, lo, size, nc):
    cx = min(max(int((x - lo[0]) / size[0]), 0), nc[0] - 1)
    cy = min(max(int((y - lo[1]) / size[1]), 0), nc[1] - 1)
    cz = min(max(int((z - lo[2]) / size[2]), 0), nc[2] - 1)
    return cx * nc[3] + cy * nc[4] + cz * nc[5]


@parallel_kernel
def mesh_cand_count(n, pos, radius, skin, lo, size, nc, ctstart, ctri, T, counts):
    """counts[i] = triangles of particle i's cell within r_i + skin of its centre."""
    for i in prange(n):
        c = _cell_of(pos[i, 0], pos[i, 1], pos[i, 2], lo, size, nc)
        lim = radius[i] + skin
        cnt = 0
        for j in range(ctstart[c], ctstart[c + 1]):
            feat, k, qx, qy, qz, d2, h = tri_closest(T, ctri[j], pos[i, 0], pos[i, 1], pos[i, 2])
            if d2 < lim * lim:
                cnt += 1
        counts[i] = cnt


@parallel_kernel
def mesh_cand_fill(n, pos, radius, skin, lo, size, nc, ctstart, ctri, T, cstart, clist):
    """The candidate triangles of each particle (ascending triangle index) from cstart[i]."""
    for i in prange(n):
        c = _cell_of(pos[i, 0], pos[i, 1], pos[i, 2], lo, size, nc)
        lim = radius[i] + skin
        p = cstart[i]
        for j in range(ctstart[c], ctstart[c + 1]):
            t = ctri[j]
            feat, k, qx, qy, qz, d2, h = tri_closest(T, t, pos[i, 0], pos[i, 1], pos[i, 2])
            if d2 < lim * lim:
                clist[p] = t
                p += 1


def chord_grid(T) -> tuple:
    """Bin the triangle rows ``T`` (one mesh, in its own frame) into a uniform grid of cubes about
    the mean edge length (at most 4 million cells) for the chord test :func:`chord_crossings`:
    (T, lo, size, nc, ctstart, ctri); a triangle goes into every cell it may touch
    (:func:`tri_cell_count`)."""
    T = np.ascontiguousarray(T)
    nt = len(T)
    P = np.concatenate([T[:, 0:3], T[:, 0:3] + T[:, 3:6], T[:, 0:3] + T[:, 6:9]])
    lo, hi = P.min(axis=0), P.max(axis=0)
    L = hi - lo
    diag = float(np.linalg.norm(L))
    h = max(float(np.mean(np.sqrt(T[:, [12, 14, 16]]))), 1e-6 * diag)
    while np.prod(np.floor(L / h) + 1) > 4e6:
        h *= 1.25
    nc = grid_strides((np.floor(L / h) + 1).astype(np.int64))
    size = np.full(3, h)
    cut = 1e-9 * diag
    counts = np.zeros(nt, np.int64)
    tri_cell_count(T, nt, lo, size, nc, cut, counts)
    start = np.zeros(nt + 1, np.int64)
    np.cumsum(counts, out=start[1:])
    cells = np.empty(int(start[-1]), np.int64)
    tris = np.empty(int(start[-1]), np.int64)
    tri_cell_fill(T, nt, lo, size, nc, cut, start, cells, tris)
    order = np.argsort(cells, kind="stable")
    ncell = int(np.prod(nc[:3]))
    ctstart = np.zeros(ncell + 1, np.int64)
    np.cumsum(np.bincount(cells, minlength=ncell), out=ctstart[1:])
    return T, lo, size, nc, ctstart, np.ascontiguousarray(tris[order])


@parallel_kernel
def chord_crossings(n, a, b, T, lo, size, nc, ctstart, ctri, ftri, fs, fh, ntest):
    """The first triangle met by each chord a[i] -> b[i] (the triangles of the grid cells its
    bounding box covers, closed triangles: faces, edges and vertices): ftri[i] (-1: none),
    fs[i] (fraction of the chord), fh[i] = (b[i] - P0).n of that triangle (< 0: met from the
    front, since a chord crosses a plane once); ties go to the lowest triangle index.
    ntest[i]: triangles tested (the cost)."""
    for i in prange(n):
        ftri[i] = -1
        fs[i] = 2.0
        fh[i] = 0.0
        ntest[i] = 0
        ok = True
        for c in range(3):
            if not (math.isfinite(a[i, c]) and math.isfinite(b[i, c])):
                ok = False
            elif (max(a[i, c], b[i, c]) < lo[c] - 0.5 * size[c]
                  or min(a[i, c], b[i, c]) > lo[c] + (nc[c] + 0.5) * size[c]):
                ok = False
        if not ok:
            continue
        ix0, ix1 = _cell_range(lo[0], size[0], nc[0], min(a[i, 0], b[i, 0]), max(a[i, 0], b[i, 0]))
        iy0, iy1 = _cell_range(lo[1], size[1], nc[1], min(a[i, 1], b[i, 1]), max(a[i, 1], b[i, 1]))
        iz0, iz1 = _cell_range(lo[2], size[2], nc[2], min(a[i, 2], b[i, 2]), max(a[i, 2], b[i, 2]))
        dx = b[i, 0] - a[i, 0]
        dy = b[i, 1] - a[i, 1]
        dz = b[i, 2] - a[i, 2]
        cnt = 0
        for cx in range(ix0, ix1 + 1):
            for cy in range(iy0, iy1 + 1):
                for cz in range(iz0, iz1 + 1):
                    cell = cx * nc[3] + cy * nc[4] + cz * nc[5]
                    for j in range(ctstart[cell], ctstart[cell + 1]):
                        t = ctri[j]
                        cnt += 1
                        ax = a[i, 0] - T[t, 0]
                        ay = a[i, 1] - T[t, 1]
                        az = a[i, 2] - T[t, 2]
                        ha = ax * T[t, 9] + ay * T[t, 10] + az * T[t, 11]
                        hb = (b[i, 0] - T[t, 0]) * T[t, 9] + (b[i, 1] - T[t, 1]) * T[t, 10] + \
                            (b[i, 2] - T[t, 2]) * T[t, 11]
                        if not ((ha >= 0.0 and hb < 0.0) or (ha < 0.0 and hb >= 0.0)):
                            continue
                        s = ha / (ha - hb)
                        if s > fs[i] or (s == fs[i] and t > ftri[i]):
                            continue
                        px = ax + s * dx
                        py = ay + s * dy
                        pz = az + s * dz
                        d1 = px * T[t, 3] + py * T[t, 4] + pz * T[t, 5]
                        d2 = px * T[t, 6] + py * T[t, 7] + pz * T[t, 8]
                        v = (T[t, 14] * d1 - T[t, 13] * d2) * T[t, 15]
                        w = (T[t, 12] * d2 - T[t, 13] * d1) * T[t, 15]
                        if v >= -1e-9 and w >= -1e-9 and v + w <= 1.0 + 1e-9:
                            ftri[i] = t
                            fs[i] = s
                            fh[i] = hb
        ntest[i] = cnt


@kernel
def reduce_meshes(n, K, ms_mesh, ms_fw, ms_tw, fout, tout):
    """Ordered (particle, slot) reduction of the force and torque on each mesh."""
    fout[:] = 0.0
    tout[:] = 0.0
    for i in range(n):
        for s in range(K):
            m = ms_mesh[i, s]
            if m >= 0:
                for c in range(3):
                    fout[m, c] += ms_fw[i, s, c]
                    tout[m, c] += ms_tw[i, s, c]


@kernel
def mesh_closest_py(T, t, x):
    """Test helper: :func:`tri_closest` for one point."""
    return tri_closest(T, t, x[0], x[1], x[2])


mesh_forces_s = serial_twin(mesh_forces)
tri_cell_count_s = serial_twin(tri_cell_count)
tri_cell_fill_s = serial_twin(tri_cell_fill)
mesh_cand_count_s = serial_twin(mesh_cand_count)
mesh_cand_fill_s = serial_twin(mesh_cand_fill)
