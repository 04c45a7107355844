"""Walls: one-sided infinite planes, bounded planar rectangles and finite cylinders (rings).

A wall is described to kernels by one float64 row of ``WALL_NGEOM`` numbers (geometry) and one
contact-parameter row (:mod:`cfddem.particles.contact`).  Geometry row layout::

    [kind, p(3), n(3), a1(3), a2(3), h1, h2, (unused), v(3), spin]

``kind`` 0 = infinite plane through p with unit normal n; 1 = rectangle centred at p spanned by
unit in-plane axes a1, a2 with half-extents h1, h2; a negative kind (``KIND_OFF``) is a wall
switched off (no contact; :meth:`ParticleSystem.set_wall_active`, e.g. a silo gate); 2 = the
surface of a finite cylinder: axis n through p, radius h1, axial extent -h2 <= s <= h2 about p,
a1[0] = -1 for the inside surface (particles inside the ring), +1 for the outside.  v is the
wall velocity: it enters the relative contact velocity, and :class:`ParticleSystem` translates a
wall with non-zero v by v dt every step (its position p(t) = p(t0) + v (t - t0), and the
reference point moves with it).  ``spin`` is an angular speed (rad/s) of the surface about the
wall's own axis n through p (right-handed): the surface velocity at the contact point q is
v + spin n x (q - p) while the geometry stays put (exact for surfaces of revolution about n: a
rotating drum, its end plates, a turntable).  The reference points about which the torque
exerted on each wall is accumulated are packed separately (:func:`pack_walls`).  New kinds (e.g. hopper cones) add a branch in :func:`wall_contact_s` that
returns the same (overlap, outward normal, contact point).

One-sided: particles live on the +n side.  For a plane the contact exists while the centre
height h = (x - p).n satisfies -R < h < R (overlap R - h).  The overlap exceeds R only for a
contact that began on the front and was pushed in: a contact that would *begin* with the centre
behind the face (overlap > R, a sphere arriving from the back of a rectangle or annulus, e.g.
over a ring's rim) is no contact; the engine marks the particle behind that wall until the
overlap ends and counts the event
(:func:`cfddem.particles.integrate.wall_forces`; the run log names the particle and wall).  For a rectangle the nearest point q
of the rectangle to the centre is used: inside the face (|u1| <= h1, |u2| <= h2) this is the
plane contact; outside, q lies on an edge or corner, the normal is (x - q)/|x - q| and the
overlap R - |x - q|, for centres on the +n side only (h >= 0).

Cylinder (inside): with s = (x - p).n the axial coordinate and rho = |x - p - s n| the distance
from the axis, the contact exists for centres inside the ring (rho < R_c).  Within the ends
(|s| <= h2) the normal points radially inwards, n_c = -(x - p - s n)/rho, the overlap is
r + rho - R_c and the contact point q = p + s n + R_c (x - p - s n)/rho.  Beyond an end the
sphere can only touch the rim circle: q = p + sign(s) h2 n + R_c (x - p - s n)/rho, normal
(x - q)/|x - q|, overlap r - |x - q| (continuous with the face at |s| = h2).  Centres outside the
ring (rho > R_c) or exactly on the axis (no defined normal; only possible with r > R_c) get no
contact.  The outside surface mirrors this (rho > R_c, normal radially outwards).

Annulus (kind 3; the top face of a ring's wall, e.g. the ledges of a shear cell): the plane
through p with normal n, restricted to inner radius h1 <= rho <= outer radius h2 about p.
Over the face it is the plane contact; otherwise the nearest point q lies on the inner or outer
rim circle, normal (x - q)/|x - q|, overlap R - |x - q|, for centres on the +n side only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cfddem._jit import kernel, parallel_kernel, prange
from cfddem.errors import CaseError
from cfddem.particles._twin import serial_twin
from cfddem.particles.contact.base import NPARAM, ContactLaw

WALL_NGEOM = 20
KIND_PLANE = 0
KIND_RECT = 1
KIND_CYLINDER = 2
KIND_ANNULUS = 3
KIND_OFF = -1.0


def _unit(key, v):
    v = np.asarray(v, dtype=float).reshape(3)
    nrm = float(np.linalg.norm(v))
    if not nrm > 0 or not np.isfinite(nrm):
        raise CaseError(key, f"needs a non-zero finite vector, got {v.tolist()}")
    return v / nrm


@dataclass
class Wall:
    """Base wall: contact parameters, velocity, reference point for the torque on the wall."""

    contact: ContactLaw  # LinearContact, HertzMindlinContact, ... (cfddem.particles.contact)
    velocity: tuple = (0.0, 0.0, 0.0)
    ref_point: tuple | None = None
    name: str = ""
    spin: float = 0.0  # rad/s about the wall's axis / normal through its point (module docstring)

    def geometry(self) -> np.ndarray:  # pragma: no cover - overridden
        raise NotImplementedError

    def _row(self, kind: int) -> np.ndarray:
        """A geometry row with the entries every kind shares: kind, p (``point``), v."""
        g = np.zeros(WALL_NGEOM)
        g[0] = kind
        g[1:4] = np.asarray(self.point, float)
        g[16:19] = np.asarray(self.velocity, float)
        if not math.isfinite(self.spin):
            raise CaseError("wall.spin", f"must be finite, got {self.spin}")
        g[19] = float(self.spin)
        return g


@dataclass
class PlaneWall(Wall):
    """Infinite one-sided plane through ``point`` with normal ``normal`` (towards the particles)."""

    point: tuple = (0.0, 0.0, 0.0)
    normal: tuple = (0.0, 1.0, 0.0)

    def geometry(self) -> np.ndarray:
        g = self._row(KIND_PLANE)
        g[4:7] = _unit("wall.normal", self.normal)
        g[14] = g[15] = np.inf
        # ref stored separately (see pack_walls)
        return g


@dataclass
class RectangleWall(Wall):
    """Bounded one-sided rectangle: centre ``point``, ``normal``, in-plane ``axis1`` (``axis2`` =
    normal x axis1), half-extents ``half1``, ``half2``."""

    point: tuple = (0.0, 0.0, 0.0)
    normal: tuple = (0.0, 1.0, 0.0)
    axis1: tuple = (1.0, 0.0, 0.0)
    half1: float = 1.0
    half2: float = 1.0

    def geometry(self) -> np.ndarray:
        n = _unit("wall.normal", self.normal)
        a1 = np.asarray(self.axis1, float)
        a1 = a1 - np.dot(a1, n) * n
        a1 = _unit("wall.axis1 (in-plane part)", a1)
        a2 = np.cross(n, a1)
        if not (self.half1 > 0 and self.half2 > 0):
            raise CaseError("wall.half", f"half-extents must be positive, got {self.half1}, {self.half2}")
        g = self._row(KIND_RECT)
        g[4:7] = n
        g[7:10] = a1
        g[10:13] = a2
        g[13] = self.half1
        g[14] = self.half2
        return g


@dataclass
class CylinderWall(Wall):
    """Surface of a finite cylinder (a ring): axis ``axis`` through ``point``, radius ``radius``,
    axial extent +-``half_height`` about ``point``.  ``inside=True``: the inner surface, particles
    live inside the ring (a shear cell, a silo barrel); ``inside=False``: the outer surface.
    Geometry kind 2 (module docstring)."""

    point: tuple = (0.0, 0.0, 0.0)
    axis: tuple = (0.0, 0.0, 1.0)
    radius: float = 1.0
    half_height: float = 1.0
    inside: bool = True

    def geometry(self) -> np.ndarray:
        a = _unit("wall.axis", self.axis)
        if not (self.radius > 0 and math.isfinite(self.radius)):
            raise CaseError("wall.radius", f"cylinder radius must be positive, got {self.radius}")
        if not (self.half_height > 0 and math.isfinite(self.half_height)):
            raise CaseError("wall.half_height", f"cylinder half-height must be positive, got {self.half_height}")
        g = self._row(KIND_CYLINDER)
        g[4:7] = a
        g[7] = -1.0 if self.inside else 1.0
        g[13] = self.radius
        g[14] = self.half_height
        return g


@dataclass
class AnnulusWall(Wall):
    """One-sided flat ring (kind 3): centre ``point``, ``normal`` (towards the particles), radii
    ``r_in`` < ``r_out`` (module docstring).  The shear cell's ledges (the rings' wall faces)."""

    point: tuple = (0.0, 0.0, 0.0)
    normal: tuple = (0.0, 1.0, 0.0)
    r_in: float = 0.5
    r_out: float = 1.0

    def geometry(self) -> np.ndarray:
        if not (0.0 <= self.r_in < self.r_out and math.isfinite(self.r_out)):
            raise CaseError("wall.radius", f"annulus needs 0 <= r_in < r_out, got {self.r_in}, {self.r_out}")
        g = self._row(KIND_ANNULUS)
        g[4:7] = _unit("wall.normal", self.normal)
        g[13] = self.r_in
        g[14] = self.r_out
        return g


def pack_walls(walls: list[Wall]):
    """(geometry rows (nw, WALL_NGEOM), reference points (nw, 3), contact rows (nw, NPARAM))."""
    nw = len(walls)
    geom = np.zeros((max(nw, 1), WALL_NGEOM))
    ref = np.zeros((max(nw, 1), 3))
    par = np.zeros((max(nw, 1), NPARAM))
    for k, w in enumerate(walls):
        geom[k] = w.geometry()
        ref[k] = np.asarray(w.ref_point if w.ref_point is not None else w.point, float)
        par[k] = w.contact.params()
    return geom, ref, par


@kernel(inline="always")
def _point_contact(x, y, z, r, qx, qy, qz, nx, ny, nz):
    """Contact of a sphere with the point q of a wall's edge, corner or rim: normal (x - q)/|x - q|,
    overlap r - |x - q| (none if |x - q| >= r or 0; n is returned unchanged then)."""
    dx = x - qx
    dy = y - qy
    dz = z - qz
    d = math.sqrt(dx * dx + dy * dy + dz * dz)
    if d >= r or d == 0.0:
        return -1.0, nx, ny, nz, 0.0, 0.0, 0.0
    return r - d, dx / d, dy / d, dz / d, qx, qy, qz


@kernel(inline="always")
def wall_contact_s(kind, g1, g2, g3, g4, g5, g6, g7, g8, g9, g10, g11, g12, g13, g14, x, y, z, r):
    """Contact of a sphere (centre x, y, z, radius r) with wall ``w`` of the geometry table ``G``
    (rows indexed in place: no array views inside parallel loops).

    Scalar arguments: the geometry row's entries 0..14 (see the module docstring).
    Returns (overlap, nx, ny, nz, qx, qy, qz): overlap > 0 means contact, n the unit normal from
    the wall towards the sphere centre, q the contact point on the wall.
    """
    if kind < 0.0:  # switched off
        return -1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0
    px = x - g1
    py = y - g2
    pz = z - g3
    nx, ny, nz = g4, g5, g6
    h = px * nx + py * ny + pz * nz
    if kind == 0.0:
        if h <= -r or h >= r:
            return -1.0, nx, ny, nz, 0.0, 0.0, 0.0
        return r - h, nx, ny, nz, x - h * nx, y - h * ny, z - h * nz
    if kind == 2.0:
        # cylinder: n = axis, h = axial coordinate, g7 = -1 inside / +1 outside, g13 = R_c, g14 = h2
        ex = px - h * nx
        ey = py - h * ny
        ez = pz - h * nz
        rho = math.sqrt(ex * ex + ey * ey + ez * ez)
        sg = g7
        dist = sg * (rho - g13)  # distance from the surface, >= 0 on the particles' side
        if rho == 0.0 or dist < 0.0 or dist >= r:
            return -1.0, nx, ny, nz, 0.0, 0.0, 0.0
        ux = ex / rho
        uy = ey / rho
        uz = ez / rho
        if h >= -g14 and h <= g14:
            return (r - dist, sg * ux, sg * uy, sg * uz, g1 + h * nx + g13 * ux, g2 + h * ny + g13 * uy,
                    g3 + h * nz + g13 * uz)
        se = g14 if h > 0.0 else -g14
        qx = g1 + se * nx + g13 * ux
        qy = g2 + se * ny + g13 * uy
        qz = g3 + se * nz + g13 * uz
        return _point_contact(x, y, z, r, qx, qy, qz, nx, ny, nz)
    if kind == 3.0:
        # annulus: plane face for g13 <= rho <= g14, else the nearer rim circle (+n side only)
        if h >= r or h <= -r:
            return -1.0, nx, ny, nz, 0.0, 0.0, 0.0
        ex = px - h * nx
        ey = py - h * ny
        ez = pz - h * nz
        rho = math.sqrt(ex * ex + ey * ey + ez * ez)
        if rho >= g13 and rho <= g14:
            return r - h, nx, ny, nz, x - h * nx, y - h * ny, z - h * nz
        if h < 0.0 or rho == 0.0:
            return -1.0, nx, ny, nz, 0.0, 0.0, 0.0
        rc = g13 if rho < g13 else g14
        qx = g1 + rc * ex / rho
        qy = g2 + rc * ey / rho
        qz = g3 + rc * ez / rho
        return _point_contact(x, y, z, r, qx, qy, qz, nx, ny, nz)
    # rectangle
    if h >= r or h <= -r:
        return -1.0, nx, ny, nz, 0.0, 0.0, 0.0
    u1 = px * g7 + py * g8 + pz * g9
    u2 = px * g10 + py * g11 + pz * g12
    h1 = g13
    h2 = g14
    c1 = min(max(u1, -h1), h1)
    c2 = min(max(u2, -h2), h2)
    qx = g1 + c1 * g7 + c2 * g10
    qy = g2 + c1 * g8 + c2 * g11
    qz = g3 + c1 * g9 + c2 * g12
    if c1 == u1 and c2 == u2:
        return r - h, nx, ny, nz, qx, qy, qz
    if h < 0.0:
        return -1.0, nx, ny, nz, 0.0, 0.0, 0.0
    return _point_contact(x, y, z, r, qx, qy, qz, nx, ny, nz)


@kernel(inline="always")
def wall_contact(G, w, x, y, z, r):
    """:func:`wall_contact_s` with the geometry taken from row ``w`` of the table ``G``."""
    return wall_contact_s(G[w, 0], G[w, 1], G[w, 2], G[w, 3], G[w, 4], G[w, 5], G[w, 6], G[w, 7],
                          G[w, 8], G[w, 9], G[w, 10], G[w, 11], G[w, 12], G[w, 13], G[w, 14],
                          x, y, z, r)


@kernel
def wall_contact_py(g, x, r):
    """Test helper: :func:`wall_contact` for one sphere and one geometry row, returning a tuple."""
    G = g.reshape(1, g.size)
    return wall_contact(G, 0, x[0], x[1], x[2], r)


#: walls beyond this index are visited for every particle (the candidate masks are int64 bits)
MAX_FILTERED_WALLS = 62


@kernel(inline="always")
def wall_shift(G, w, dx, dy, dz):
    """How much the displacement (dx, dy, dz) can change the reach of wall ``w``
    (:func:`wall_reach`): |d.n| for a plane, rectangle or annulus, the part of d across the
    axis for a cylinder."""
    h = dx * G[w, 4] + dy * G[w, 5] + dz * G[w, 6]
    # both computed, then one selected (no early return): in the kick loop's rebuild test the
    # branches cost more than the few flops (the 30k chute, one thread: ~8 of 27 ns per particle)
    ex = dx - h * G[w, 4]
    ey = dy - h * G[w, 5]
    ez = dz - h * G[w, 6]
    across = math.sqrt(ex * ex + ey * ey + ez * ez)
    return across if G[w, 0] == 2.0 else abs(h)


@kernel(inline="always")
def wall_reach(G, w, x, y, z):
    """A lower bound of the distance from the point (x, y, z) to wall ``w``: |h| (height
    above the plane) for planes, rectangles and annuli, |rho - R_c| for cylinders, inf for a
    wall switched off.  Each wall kind's contact needs it below the sphere's radius (module
    docstring), and it changes by at most the distance the point moves.  (|h| and rho are
    :func:`wall_shift` of the point's offset from the wall's centre point.)"""
    kind = G[w, 0]
    if kind < 0.0:
        return np.inf
    s = wall_shift(G, w, x - G[w, 1], y - G[w, 2], z - G[w, 3])
    if kind == 2.0:
        return abs(s - G[w, 13])
    return s


@parallel_kernel
def wall_candidates(n, pos, radius, skin, G, nw, MAXF, wfilt, wmask, slack, won, wfn, whist, wfw, wtw):
    """At a neighbour rebuild: bit w of ``wmask[i]`` set when particle i may touch wall w before
    the next rebuild (its reach below r + skin; particles move less than skin/2 between
    rebuilds), for the walls with ``wfilt[w]`` = 1 (standing walls); a wall with ``wfilt[w]`` = 0
    (a moving one) has its bit set for every particle.  The force pass visits only the walls of
    a particle's bits.  A (particle, wall) left out can have no contact before the next rebuild:
    its contact state is cleared (a stale 'behind the wall' mark would otherwise outlive it).
    ``slack[i]`` = (s1, s2, w1): the particle's smallest reach minus r among the standing walls
    it is not a candidate of (at wall w1; -1 and inf if none) and the second smallest, s2: it
    cannot touch any of them while its displacement across wall w1 (:func:`wall_shift`) stays
    below s1 and its whole displacement below s2.
    ``MAXF``: :data:`MAX_FILTERED_WALLS` (walls from there on are always visited)."""
    for i in prange(n):
        x = pos[i, 0]
        y = pos[i, 1]
        z = pos[i, 2]
        reach = radius[i] + skin
        mk = 0
        s1 = np.inf
        s2 = np.inf
        w1 = -1.0
        for w in range(min(nw, MAXF)):
            if wfilt[w] == 0:
                mk |= 1 << w
                continue
            rw = wall_reach(G, w, x, y, z)
            if rw < reach:
                mk |= 1 << w
                continue
            sw = rw - radius[i]
            if sw < s1:
                s2 = s1
                s1 = sw
                w1 = w
            elif sw < s2:
                s2 = sw
            if won[i, w] != 0:
                won[i, w] = 0
                wfn[i, w] = 0.0
                for c in range(3):
                    whist[i, w, c] = 0.0
                    wfw[i, w, c] = 0.0
                    wtw[i, w, c] = 0.0
        wmask[i] = mk
        slack[i, 0] = s1
        slack[i, 1] = s2
        slack[i, 2] = w1


wall_candidates_s = serial_twin(wall_candidates)
