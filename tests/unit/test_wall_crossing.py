"""The analytic-wall crossing check (cfddem.particles.crossing) against a numpy oracle of its
rule, on random moves across every wall kind: the same first crossing (wall, particle, depth)."""

import numpy as np
import pytest

from cfddem.particles import CylinderWall, LinearContact, ParticleSystem, PlaneWall, RectangleWall
from cfddem.particles.walls import AnnulusWall
from cfddem.particles.crossing import crossing_mark, find_crossing
from cfddem.particles.walls import KIND_ANNULUS, KIND_CYLINDER, KIND_RECT

C = LinearContact(k_n=1000.0, e_n=0.5, e_t=0.5, mu=0.3)


def oracle(wg, wg_old, ids, pos, rad, pid, old_pos):
    """The rule written with whole-array numpy operations: (row, wall index, depth) or None."""
    row_at_mark = {int(p): k for k, p in enumerate(pid)}
    rows = np.array([i for i in range(len(ids)) if int(ids[i]) in row_at_mark], int)
    cur = pos[rows]
    old = old_pos[[row_at_mark[int(ids[i])] for i in rows]]
    r = rad[rows]
    for w in range(len(wg)):
        g, go = wg[w], wg_old[w]
        if g[0] < 0 or go[0] < 0:
            continue
        kind, n = int(g[0]), g[4:7]
        h_now, h_old = (cur - g[1:4]) @ n, (old - go[1:4]) @ n
        within = np.ones(len(cur), bool)
        if kind == KIND_CYLINDER:
            within = (np.abs(h_now) <= g[14]) & (np.abs(h_old) <= g[14])
            sg = 1.0 if g[7] < 0 else -1.0
            h_now, h_old = (sg * (g[13] - np.linalg.norm(q - p - np.outer(h, n), axis=1))
                            for q, p, h in ((cur, g[1:4], h_now), (old, go[1:4], h_old)))
        elif kind == KIND_ANNULUS:
            for q, p, h in ((cur, g[1:4], h_now), (old, go[1:4], h_old)):
                rq = np.linalg.norm(q - p - np.outer(h, n), axis=1)
                within &= (rq >= g[13]) & (rq <= g[14])
        elif kind == KIND_RECT:
            for q, p in ((cur, g[1:4]), (old, go[1:4])):
                within &= (np.abs((q - p) @ g[7:10]) <= g[13]) & (np.abs((q - p) @ g[10:13]) <= g[14])
        hit = np.flatnonzero((h_old >= 0) & (h_now < -r) & within)
        if len(hit):
            return int(rows[hit[0]]), w, float(-h_now[hit[0]])
    return None


WALLS = [
    PlaneWall(contact=C, name="floor", point=(0, 0, 0), normal=(0, 1, 0)),
    RectangleWall(contact=C, name="plate", point=(0.02, 0.01, 0), normal=(-1, 0, 0), axis1=(0, 1, 0),
                  half1=0.01, half2=0.01),
    AnnulusWall(contact=C, name="ledge", point=(0, 0.02, 0), normal=(0, 1, 0), r_in=0.005, r_out=0.015),
    CylinderWall(contact=C, name="barrel", point=(0, 0.01, 0), axis=(0, 1, 0), radius=0.018, half_height=0.012),
    CylinderWall(contact=C, name="post", point=(0, 0.01, 0), axis=(0, 1, 0), radius=0.004, half_height=0.012,
                 inside=False),
]


@pytest.mark.parametrize("seed", range(12))
def test_kernel_finds_the_oracles_crossing(seed):
    rng = np.random.default_rng(seed)
    walls = [WALLS[k] for k in sorted(rng.choice(len(WALLS), size=rng.integers(1, 6), replace=False))]
    s = ParticleSystem(pp=C, walls=walls, dt=1e-5)
    n = 400
    s.add_particles(rng.uniform([-0.025, -0.005, -0.025], [0.025, 0.03, 0.025], (n, 3)), 0.0, 1e-3, 2500.0)
    mark = crossing_mark(s)
    s.remove_particles(rng.random(n) < 0.1)  # some leave, some rows move
    s.add_particles(rng.uniform(-0.02, 0.02, (5, 3)) + [0, 0.01, 0], 0.0, 1e-3, 2500.0)  # new ones: not checked
    s._pos[: s.n] += rng.normal(0.0, 0.006, (s.n, 3))  # jumps across the walls
    if rng.random() < 0.3 and len(walls) > 1:
        s.set_wall_active(walls[0].name, False)  # a gate opened since the mark: not checked
    got = find_crossing(s, mark)
    want = oracle(s._wgeom[: s.nw], mark["wgeom"], s.ids, s.pos, s.radius, mark["ids"], mark["pos"])
    assert want is not None  # these jumps always cross a wall somewhere
    i, w, depth = want
    assert got is not None
    assert (got.index, got.wall, got.triangle) == (i, walls[w].name, -1)
    assert got.pid == s.ids[i] and got.depth == pytest.approx(depth, rel=1e-12)


def test_small_moves_cross_nothing():
    """Moves smaller than a radius from a spot clear of every wall: neither finds a crossing."""
    rng = np.random.default_rng(5)
    s = ParticleSystem(pp=C, walls=WALLS, dt=1e-5)
    s.add_particles(rng.uniform([-0.002, 0.001, -0.002], [0.002, 0.002, 0.002], (50, 3)) + [0.011, 0.0, 0.0],
                    0.0, 1e-3, 2500.0)
    mark = crossing_mark(s)
    s._pos[: s.n] += rng.normal(0.0, 3e-4, (s.n, 3))
    assert oracle(s._wgeom[: s.nw], mark["wgeom"], s.ids, s.pos, s.radius, mark["ids"], mark["pos"]) is None
    assert find_crossing(s, mark) is None
    s._pos[0, 1] = -0.0015  # one through the floor, 1.5 mm behind it
    c = find_crossing(s, mark)
    assert (c.index, c.wall, c.depth) == (0, "floor", pytest.approx(0.0015, rel=1e-12))
