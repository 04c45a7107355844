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

import numpy as np

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


def _analytic_heights(g_now, g_old, cur, old):
    """(h_now, h_old, both within the wall's extent) of the centres ``cur`` / ``old`` relative to
    an analytic wall's geometry rows now and at the mark."""
    kind = int(g_now[0])
    n = g_now[4:7]
    p_now, p_old = g_now[1:4], g_old[1:4]
    h_now = (cur - p_now) @ n
    h_old = (old - p_old) @ n
    within = np.ones(len(cur), bool)
    if kind == KIND_CYLINDER:  # signed distance from the ring surface, > 0 on the particles' side
        sg = 1.0 if g_now[7] < 0.0 else -1.0
        rc, hh = g_now[13], g_now[14]
        within = (np.abs(h_now) <= hh) & (np.abs(h_old) <= hh)
        h_now, h_old = (sg * (rc - np.linalg.norm(q - p - np.outer(h, n), axis=1))
                        for q, p, h in ((cur, p_now, h_now), (old, p_old, h_old)))
    elif kind == KIND_ANNULUS:
        for q, p, h in ((cur, p_now, h_now), (old, p_old, h_old)):
            rq = np.linalg.norm(q - p - np.outer(h, n), axis=1)
            within &= (rq >= g_now[13]) & (rq <= g_now[14])
    elif kind == KIND_RECT:
        for q, p in ((cur, p_now), (old, p_old)):
            within &= (np.abs((q - p) @ g_now[7:10]) <= g_now[13]) & (np.abs((q - p) @ g_now[10:13]) <= g_now[14])
    return h_now, h_old, within


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

    wg = system._wgeom
    for iw, w in enumerate(system.walls):
        if wg[iw, 0] < 0.0 or mark["wgeom"][iw, 0] < 0.0:  # a gate open now or at the mark
            continue
        sel = None
        if int(wg[iw, 0]) != KIND_CYLINDER:
            # the plane heights first (two products); the extent only for the few behind the plane
            n = wg[iw, 4:7]
            sel = np.flatnonzero(((old - mark["wgeom"][iw, 1:4]) @ n >= 0.0) & ((cur - wg[iw, 1:4]) @ n < -r))
            if not len(sel):
                continue
        c_, o_, r_ = (cur, old, r) if sel is None else (cur[sel], old[sel], r[sel])
        h_now, h_old, within = _analytic_heights(wg[iw], mark["wgeom"][iw], c_, o_)
        crossed = (h_old >= 0.0) & (h_now < -r_) & within
        if crossed.any():
            j = int(np.flatnonzero(crossed)[0])
            i = j if sel is None else int(sel[j])
            return found(i, w.name, -1, -h_now[j])
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
