"""Particles that went through a wall between two checks, analytic and mesh walls alike: the
diagnosis behind the run's "went through wall" error (:class:`cfddem.simulation.Simulation`).

:func:`crossing_mark` notes the particles' ids and centres and where every wall is (the
analytic walls' geometry rows, the meshes' placement and on/off state); :func:`find_crossing`
later compares the particles still present with that mark.  A particle went through a wall
when its centre was on the wall's contact side at the mark (h >= 0) and is now more than its
radius behind it (h < -r), both measured relative to the wall (a moving wall is seen at rest),
and the path crossed the wall itself, not the plane beyond its edges:

* analytic walls (``ParticleSystem.walls``): planes; rectangles and annuli with both centres
  over the face; cylinders (h = distance from the ring surface, > 0 on the particles' side)
  with both centres within the ends;
* mesh walls (``ParticleSystem.meshes``): the straight chord from the old centre to the new
  one, in the mesh's frame, meets a triangle (its face, an edge or a vertex), the first
  triangle it meets is met from the front, and the new centre is more than r behind that
  triangle's plane (:meth:`cfddem.particles.mesh.MeshTables.crossings`).  A particle that flies
  over an open edge of a mesh is not a crossing; one that came from behind the mesh neither.

A wall switched on or off since the mark (a gate) is not checked.  Cost per check: O(n) array
work per wall; for a mesh, the triangles in the grid cells covered by each chord's bounding
box (a few cells for the usual chord shorter than a triangle; the count is returned as
``mesh_tests``), the grid being built once per mesh.
"""

from __future__ import annotations

from dataclasses import dataclass

import math

import numpy as np

from cfddem._jit import kernel
from cfddem.particles.walls import KIND_ANNULUS, KIND_CYLINDER, KIND_RECT


@dataclass
class Crossing:
    """A particle that went through a wall: its index now and id, the wall's name, the mesh
    triangle (index into ``MeshWall.triangles``; -1 for an analytic wall), how far behind the
    wall its centre is now (m), and the step of the mark."""

    index: int
    pid: int
    wall: str
    triangle: int
    depth: float
    since_step: int


def crossing_mark(system) -> dict:
    """What :func:`find_crossing` compares with later (copies)."""
    return dict(ids=system.ids.copy(), pos=system.pos.copy(), step=int(system.step_count),
                wgeom=system._wgeom.copy(), mesh=system._mt.placement())


@kernel
def _analytic_crossing(n, ids, pos, rad, table, old_pos, wg, wg_old, nw, k_cyl, k_ann, k_rect):
    """The first particle that went through an analytic wall (module docstring), walls in order
    and particles in row order: (row, wall, depth of the centre behind it now), (-1, -1, 0) if
    none.  ``table[id]``: the particle's row in ``old_pos`` (-1: not there at the mark).
    Planes, rectangles and annuli: on the contact side at the mark (h >= 0), more than r
    behind now, both centres over the face; cylinders: h the distance from the ring surface
    (> 0 on the particles' side), both centres within the ends."""
    for w in range(nw):
        if wg[w, 0] < 0.0 or wg_old[w, 0] < 0.0:  # a gate open now or at the mark
            continue
        kind = int(wg[w, 0])
        nx, ny, nz = wg[w, 4], wg[w, 5], wg[w, 6]
        px, py, pz = wg[w, 1], wg[w, 2], wg[w, 3]
        ox, oy, oz = wg_old[w, 1], wg_old[w, 2], wg_old[w, 3]
        for i in range(n):
            k = table[ids[i]]
            if k < 0:
                continue
            r = rad[i]
            cx, cy, cz = pos[i, 0] - px, pos[i, 1] - py, pos[i, 2] - pz
            qx, qy, qz = old_pos[k, 0] - ox, old_pos[k, 1] - oy, old_pos[k, 2] - oz
            h_now = cx * nx + cy * ny + cz * nz
            h_old = qx * nx + qy * ny + qz * nz
            if kind == k_cyl:
                hh = wg[w, 14]
                if abs(h_now) > hh or abs(h_old) > hh:
                    continue
                sg = 1.0 if wg[w, 7] < 0.0 else -1.0
                rc = wg[w, 13]
                a_now = math.sqrt((cx - h_now * nx) ** 2 + (cy - h_now * ny) ** 2 + (cz - h_now * nz) ** 2)
                a_old = math.sqrt((qx - h_old * nx) ** 2 + (qy - h_old * ny) ** 2 + (qz - h_old * nz) ** 2)
                h_now = sg * (rc - a_now)
                h_old = sg * (rc - a_old)
                if h_old >= 0.0 and h_now < -r:
                    return i, w, -h_now
                continue
            if not (h_old >= 0.0 and h_now < -r):
                continue
            if kind == k_ann:
                a_now = math.sqrt((cx - h_now * nx) ** 2 + (cy - h_now * ny) ** 2 + (cz - h_now * nz) ** 2)
                a_old = math.sqrt((qx - h_old * nx) ** 2 + (qy - h_old * ny) ** 2 + (qz - h_old * nz) ** 2)
                if not (wg[w, 13] <= a_now <= wg[w, 14] and wg[w, 13] <= a_old <= wg[w, 14]):
                    continue
            elif kind == k_rect:
                if (abs(cx * wg[w, 7] + cy * wg[w, 8] + cz * wg[w, 9]) > wg[w, 13]
                        or abs(cx * wg[w, 10] + cy * wg[w, 11] + cz * wg[w, 12]) > wg[w, 14]
                        or abs(qx * wg[w, 7] + qy * wg[w, 8] + qz * wg[w, 9]) > wg[w, 13]
                        or abs(qx * wg[w, 10] + qy * wg[w, 11] + qz * wg[w, 12]) > wg[w, 14]):
                    continue
            return i, w, -h_now
    return -1, -1, 0.0


def find_crossing(system, mark: dict, stats: dict | None = None) -> Crossing | None:
    """The first particle (analytic walls in order, then the meshes) that went through a wall
    since ``mark`` (:func:`crossing_mark`; module docstring), or None.  ``stats`` (a dict), if
    given, receives ``mesh_tests``: the triangle tests done."""
    ids, rad = system.ids, system.radius
    pid = mark["ids"]
    if not len(ids) or not len(pid):
        return None
    # each id's row at the mark: a dense table over the ids (they are below the next id to
    # give), O(n) where a sort was O(n log n)
    top = int(max(pid.max(), ids.max())) + 1
    table = np.full(top, -1, np.int64)
    table[pid] = np.arange(len(pid))
    if stats is not None:
        stats["mesh_tests"] = 0
    nw = len(system.walls)
    if nw:
        i, w, depth = _analytic_crossing(len(ids), ids, system.pos, rad, table, mark["pos"], system._wgeom,
                                         mark["wgeom"], nw, KIND_CYLINDER, KIND_ANNULUS, KIND_RECT)
        if i >= 0:
            return Crossing(int(i), int(ids[i]), system.walls[w].name, -1, float(depth), mark["step"])
    if not system.meshes:
        return None
    k = table[ids]
    known = k >= 0
    if not known.any():
        return None
    at = np.flatnonzero(known)
    cur = system.pos[known]
    old = mark["pos"][k[known]]  # one gather (no full reordered copy)
    r = rad[known]

    def found(i, wall, tri, depth):
        return Crossing(int(at[i]), int(ids[at[i]]), wall, int(tri), float(depth), mark["step"])

    mt = system._mt
    before = mark["mesh"]
    switched = {e[1] for e in mt.events[before["next_event"]: mt.next_event]}
    tests = 0
    for km, m in enumerate(system.meshes):
        if not (mt.act[km] and before["act"][km]) or km in switched:
            continue
        tri, depth, nt = mt.crossings(km, before, old, cur, r)
        tests += nt
        hit = np.flatnonzero(tri >= 0)
        if len(hit):
            i = int(hit[0])
            return found(i, m.name, tri[i], depth[i])
    if stats is not None:
        stats["mesh_tests"] = tests
    return None
