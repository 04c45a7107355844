"""Particle inlets.

:class:`SluiceInlet` - the rotating-chute feed of physics.md §5: particles enter through a
rectangular "sluice" across the full chute width at the entrance, arranged on a body-centred
cubic (bcc) lattice with as many particles as fit in the sluice cross-section.  The lattice moves
downstream at the speed that carries the prescribed mass rate:

    v0 = mdot / (m_p * n_cell / a)

where a is the bcc cube side, n_cell the particles per lattice period along z (one corner layer
plus one body-centre layer) and m_p the particle mass.  A new layer (corner and body-centre
layers alternate, a/2 apart) enters at the insertion plane whenever the lattice has advanced by
a/2 (the Simulation makes these due times events, so layers enter on time to within one step).
A layer is inserted only if none of its spheres overlaps a particle already there; otherwise it
waits, and the delay is recorded (``backlog_time``), so the inlet never creates overlaps and the
mass fed never exceeds the prescribed rate.

Polydisperse feed: with ``diameter_max > diameter`` each particle's diameter is drawn uniformly
in [diameter, diameter_max]; the lattice is spaced for the largest one and the feed velocity uses
the mean particle mass, rho pi/6 E[d^3] with E[d^3] = (d_max^4 - d_min^4) / (4 (d_max - d_min)).
The diameters of layer k come from a generator seeded with (seed, k), so a layer that waits, a
restarted run and an uninterrupted one all draw the same sizes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass
class SluiceLattice:
    a: float  # bcc cube side (m)
    corner: np.ndarray  # (n1, 2) x, y of the corner layer
    centre: np.ndarray  # (n2, 2) x, y of the body-centre layer

    @property
    def per_period(self) -> int:
        return len(self.corner) + len(self.centre)


def bcc_sluice_lattice(width: float, height: float, diameter: float, gap: float = 0.02) -> SluiceLattice:
    """The bcc lattice with as many spheres of ``diameter`` as fit in ``width`` x ``height``.

    Nearest neighbours in bcc touch along the body diagonal: a = 2 d / sqrt(3), here enlarged by
    ``gap`` (a fraction of d) so that new spheres start apart.  Sites keep a clearance of
    ``gap * d / 2`` from the walls and the floor.
    """
    r = 0.5 * diameter
    a = 2.0 * diameter * (1.0 + gap) / math.sqrt(3.0)
    clear = r * (1.0 + gap)
    span_x = width - 2 * clear
    span_y = height - 2 * clear
    if span_x < 0 or span_y < 0:
        raise ValueError("sluice smaller than one particle")
    nx = int(math.floor(span_x / a + 1e-9)) + 1
    ny = int(math.floor(span_y / a + 1e-9)) + 1
    x0 = 0.5 * (width - (nx - 1) * a)  # centred across the width
    y0 = clear
    xs = x0 + a * np.arange(nx)
    ys = y0 + a * np.arange(ny)
    corner = np.array([(x, y) for y in ys for x in xs])
    xc = xs[:-1] + 0.5 * a
    yc = ys[:-1] + 0.5 * a
    centre = np.array([(x, y) for y in yc for x in xc]).reshape(-1, 2)
    return SluiceLattice(a=a, corner=corner, centre=centre)


class SluiceInlet:
    """Feeds the bcc sluice lattice at a mass rate; see the module docstring."""

    def __init__(self, *, width: float, height: float, z: float, diameter: float, density: float,
                 mass_rate: float, start_time: float = 0.0, end_time: float = math.inf, gap: float = 0.02,
                 diameter_max: float = 0.0, seed: int = 12345):
        dmax = max(diameter, diameter_max)
        self.lattice = bcc_sluice_lattice(width, height, dmax, gap)
        self.d_min, self.d_max = diameter, dmax
        self.seed = int(seed)
        self.radius = 0.5 * dmax
        self.density = density
        self.mass_rate = mass_rate
        self.start_time = start_time
        self.end_time = end_time
        if dmax > diameter:
            mean_d3 = (dmax ** 4 - diameter ** 4) / (4.0 * (dmax - diameter))
        else:
            mean_d3 = diameter ** 3
        self.particle_mass = density * math.pi / 6.0 * mean_d3  # mean particle mass
        lin_density = self.particle_mass * self.lattice.per_period / self.lattice.a  # kg/m along z
        self.velocity = mass_rate / lin_density
        # first layer: its back touches the sluice's upstream edge (the back wall)
        self.z_insert = z + self.radius * (1.0 + gap)
        self.layers_done = 0  # layers inserted so far
        self.backlog_time = 0.0  # accumulated time layers waited for room
        self.mass_inserted = 0.0
        self.count_inserted = 0

    # layer k (k = 0, 1, ...) is due when the lattice has advanced k a/2
    def _due_time(self, k: int) -> float:
        return self.start_time + k * 0.5 * self.lattice.a / self.velocity

    def due(self, time: float) -> bool:
        return (self.start_time <= time < self.end_time + 1e-15
                and time + 1e-15 >= self._due_time(self.layers_done))

    def layer(self, k: int) -> np.ndarray:
        """Positions (n, 3) of layer k at the insertion plane."""
        xy = self.lattice.corner if k % 2 == 0 else self.lattice.centre
        z = self.z_insert
        out = np.empty((len(xy), 3))
        out[:, 0] = xy[:, 0]
        out[:, 1] = xy[:, 1]
        out[:, 2] = z
        return out

    def radii(self, k: int, n: int) -> np.ndarray:
        """Radii of the n particles of layer k (deterministic in (seed, k))."""
        if self.d_max == self.d_min:
            return np.full(n, 0.5 * self.d_min)
        rng = np.random.default_rng([self.seed, k])
        return 0.5 * rng.uniform(self.d_min, self.d_max, n)

    def insert(self, system, time: float, dt: float) -> int:
        """Insert every layer that is due and has room; return the number of particles added."""
        added = 0
        while self.due(time):
            pos = self.layer(self.layers_done)
            rad = self.radii(self.layers_done, len(pos))
            if len(pos) and system.overlaps(pos, rad).any():
                self.backlog_time += dt
                break
            vel = np.zeros_like(pos)
            vel[:, 2] = self.velocity
            system.add_particles(pos, vel, rad, self.density)
            added += len(pos)
            self.count_inserted += len(pos)
            self.mass_inserted += float(np.sum(self.density * 4.0 / 3.0 * math.pi * rad ** 3))
            self.layers_done += 1
            if self.layers_done > 10_000_000:
                break
        return added

    def get_state(self) -> dict:
        return {"layers_done": self.layers_done, "backlog_time": self.backlog_time,
                "mass_inserted": self.mass_inserted, "count_inserted": self.count_inserted}

    def set_state(self, s: dict) -> None:
        self.layers_done = int(s["layers_done"])
        self.backlog_time = float(s["backlog_time"])
        self.mass_inserted = float(s["mass_inserted"])
        self.count_inserted = int(s["count_inserted"])
