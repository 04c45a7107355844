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
Fed particles are *held* (:meth:`ParticleSystem.add_particles` ``held=True``): they move at the
feed velocity, unaffected by forces, until they are ``hold_length`` (default one lattice period a)
past the insertion plane, and push whatever is in front of them, like the material behind a real
sluice gate pushes the bed out (LIGGGHTS' ``fix insert/stream`` likewise moves inserted particles
at the insertion velocity through its extrusion volume before releasing them).  Without the hold
the bottom rows, pressed onto the floor by the rows above, slowed under wall friction and blocked
the sites of the next layers: the 16 rpm chute took 1.0 instead of 1.6 kg/s.

Each site of a due layer is filled if its sphere overlaps no particle already there.  A blocked
site (a bead that bounced back into the sluice) is not lost: it stays pending and is retried at
every later call (the Simulation calls at least every millisecond) at its lattice position, which
moves on with the lattice at v0, for up to ``retry_periods`` lattice periods; only then is it
dropped and its mass counted as a feed deficit (``mass_dropped``, logged).  So the inlet never
creates overlaps, never exceeds the prescribed rate, and meets it to within the deficit.
(A first version inserted a layer only when all of its ~215 sites were free: in the 16 rpm chute
a single bouncing bead blocked whole layers and the feed came out at 1.0 instead of 1.6 kg/s.)

Polydisperse feed: with ``diameter_max > diameter`` each particle's diameter is drawn uniformly
in [diameter, diameter_max]; the lattice is spaced for the largest one and the feed velocity uses
the mean particle mass, rho pi/6 E[d^3] with E[d^3] = (d_max^4 - d_min^4) / (4 (d_max - d_min)).
The diameters of layer k come from a generator seeded with (seed, k), so a layer that waits, a
restarted run and an uninterrupted one all draw the same sizes.

Pellet feed (``shape``: a :class:`~cfddem.particles.clumps.ClumpShape`, ``particles.clump``):
each site holds one rigid pellet, centre of mass on the site, in a random orientation (uniform
on SO(3), :func:`random_quaternions`, generator seeded with (seed, k, site) so a retried site
keeps its orientation).  The lattice is spaced for the pellet's bounding diameter
D_b = 2 max_m (|s_m| + r_m) (:func:`bounding_diameter`; pellet2: 1.5 d, pellet4:
(1 + sqrt(6)/4) d = 1.612 d), a site is free if the bounding sphere overlaps no particle, and the
feed velocity uses the pellet mass M (union of its spheres):

    v0 = mdot / (M n_cell / a).

Held pellets: the clump kernels write the member spheres' velocities from the body, so the
sphere ``held`` flag would not hold a pellet; instead the BODY's centre-of-mass velocity is held
(``vfix`` = (1, 1, 1), ``vset`` = (0, 0, v0) on the clump, :mod:`cfddem.particles.clumps`) until
its centre of mass is ``hold_length`` past the insertion plane, then released (``vfix`` = 0).
A held pellet can still rotate (its spin is not held).  Releasing a held pellet drops only the
constraint: it keeps the feed velocity.
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


def bounding_diameter(shape) -> float:
    """Diameter of the smallest sphere about the centre of mass that holds every member sphere
    of a clump shape: D_b = 2 max_m (|s_m| + r_m)."""
    return 2.0 * float(np.max(np.linalg.norm(shape.offsets, axis=1) + shape.radii))


def random_quaternions(rng, n: int) -> np.ndarray:
    """(n, 4) unit quaternions uniform on SO(3): normalised 4D standard normals (Marsaglia 1972;
    the normal distribution is isotropic, so the direction is uniform on S^3)."""
    q = rng.standard_normal((n, 4))
    return q / np.linalg.norm(q, axis=1)[:, None]


class SluiceInlet:
    """Feeds the bcc sluice lattice at a mass rate; see the module docstring."""

    def __init__(self, *, width: float, height: float, z: float, diameter: float, density: float,
                 mass_rate: float, start_time: float = 0.0, end_time: float = math.inf, gap: float = 0.02,
                 diameter_max: float = 0.0, seed: int = 12345, retry_periods: float = 2.0,
                 min_spacing: float | None = None, hold_length: float | None = None, shape=None,
                 label: int = 0):
        self.shape = shape
        #: tracer label of the particles fed from now on (a scene may change it during the run)
        self.label = int(label)  # ClumpShape: pellets (monodisperse), None: spheres
        if shape is not None and diameter_max > diameter:
            raise ValueError("a pellet feed is monodisperse (diameter_max must be 0)")
        dmax = max(diameter, diameter_max) if shape is None else bounding_diameter(shape)
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
        if shape is not None:
            self.particle_mass = float(shape.mass)  # one pellet per site
        lin_density = self.particle_mass * self.lattice.per_period / self.lattice.a  # kg/m along z
        self.velocity = mass_rate / lin_density
        # first layer: its back touches the sluice's upstream edge (the back wall)
        self.z_insert = z + self.radius * (1.0 + gap)
        self.layers_done = 0  # layers started so far
        self.retry_periods = float(retry_periods)
        # closest layer spacing (fraction of a/2) at which no two lattice sites overlap: same
        # sublattice a s >= d, the other one (a/2)^2 (2 + s^2) >= d^2; 1 % margin
        a_d = self.lattice.a / dmax
        s_free = max(1.0 / a_d, math.sqrt(max(0.0, 4.0 / a_d ** 2 - 2.0)))
        self.min_spacing = min(1.0, 1.01 * s_free) if min_spacing is None else float(min_spacing)
        self.t_last = -math.inf  # when the last layer entered
        self.hold_length = self.lattice.a if hold_length is None else float(hold_length)
        self.pending: list[tuple[int, np.ndarray]] = []  # (layer, blocked site indices)
        self.mass_inserted = 0.0
        self.count_inserted = 0  # particles, or pellets with a shape
        self.mass_dropped = 0.0  # feed deficit: sites still blocked after retry_periods
        self.count_dropped = 0

    # layer k (k = 0, 1, ...) is due when the lattice has advanced k a/2, brought forward by the
    # time the dropped mass would have taken to feed (the deficit is made up), but never sooner
    # than min_spacing a/2 after the previous layer (so no two layers overlap)
    def _due_time(self, k: int) -> float:
        half = 0.5 * self.lattice.a / self.velocity
        t = self.start_time + k * half
        if self.mass_dropped > 0.0 and k == self.layers_done and k > 0:
            t = max(t - self.mass_dropped / self.mass_rate, self.t_last + self.min_spacing * half)
        return t

    def _nominal_time(self, k: int) -> float:
        return self.start_time + k * 0.5 * self.lattice.a / self.velocity

    def next_due_time(self) -> float:
        """When the next layer is due (the Simulation makes it an event)."""
        return self._due_time(self.layers_done)

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
        """Radii of the n particles of layer k (deterministic in (seed, k)); pellets: the
        bounding radius."""
        if self.shape is not None or self.d_max == self.d_min:
            return np.full(n, 0.5 * self.d_min)
        rng = np.random.default_rng([self.seed, k])
        return 0.5 * rng.uniform(self.d_min, self.d_max, n)

    def _lattice_shift(self, t_layer: float, time: float) -> float:
        """How far a layer that entered at ``t_layer`` has moved downstream of the insertion plane."""
        return max(0.0, self.velocity * (time - t_layer))

    def _try_sites(self, system, k: int, t_layer: float, sites: np.ndarray, time: float) -> np.ndarray:
        """Insert the free ones of layer k's ``sites`` at the lattice position; return the blocked."""
        pos = self.layer(k)[sites]
        pos[:, 2] += self._lattice_shift(t_layer, time)
        rad = self.radii(k, self.layer_size(k))[sites]
        blocked = system.overlaps(pos, rad) if len(pos) else np.zeros(0, bool)
        free = ~blocked
        if free.any():
            vel = np.zeros((int(free.sum()), 3))
            vel[:, 2] = self.velocity
            if self.shape is None:
                system.add_particles(pos[free], vel, rad[free], self.density, held=self.hold_length > 0,
                                     label=self.label)
            else:
                q = np.array([random_quaternions(np.random.default_rng([self.seed, k, int(i), 1]), 1)[0]
                              for i in sites[free]])
                bids = system.add_clumps(self.shape, pos[free], quat=q, vel=vel, label=self.label)
                if self.hold_length > 0:
                    c = system.clumps
                    idx = np.arange(c.nb - len(bids), c.nb)  # add_clumps appends
                    c.vfix[idx] = 1.0
                    c.vset[idx] = vel
            self.mass_inserted += self._sites_mass(rad[free])
            self.count_inserted += int(free.sum())
        return sites[blocked]

    def _sites_mass(self, rad: np.ndarray) -> float:
        """Mass of the spheres of radii ``rad`` fed at those sites (a pellet each with a shape)."""
        if self.shape is not None:
            return float(self.shape.mass) * len(rad)
        return float(np.sum(self.density * 4.0 / 3.0 * math.pi * rad ** 3))

    def _release_pellets(self, system) -> None:
        """Release the held pellets whose centre of mass is past the hold zone (vfix = 0)."""
        c = system.clumps
        if c is None or c.nb == 0:
            return
        past = (c.com[:, 2] > self.z_insert + self.hold_length - 1e-12) & (c.vfix[:, 2] != 0.0)
        if past.any():
            c.vfix[past] = 0.0
            c.vset[past] = 0.0

    def layer_size(self, k: int) -> int:
        return len(self.lattice.corner) if k % 2 == 0 else len(self.lattice.centre)

    def insert(self, system, time: float, dt: float) -> int:
        """Insert every layer that is due (its free sites) and retry pending blocked sites;
        return the number of particles added."""
        n0 = self.count_inserted
        if self.hold_length > 0 and system.n:
            # release the fed particles that are past the hold zone
            if self.shape is None:
                system.release(system.pos[:, 2] > self.z_insert + self.hold_length - 1e-12)
            else:
                self._release_pellets(system)
        # retry the sites still pending from earlier layers (oldest first)
        keep = []
        for k, t_layer, sites in self.pending:
            if self._lattice_shift(t_layer, time) > self.retry_periods * self.lattice.a:
                self.count_dropped += len(sites)
                self.mass_dropped += self._sites_mass(self.radii(k, self.layer_size(k))[sites])
                continue
            left = self._try_sites(system, k, t_layer, sites, time)
            if len(left):
                keep.append((k, t_layer, left))
        self.pending = keep
        while self.due(time):
            k = self.layers_done
            t_layer = self._due_time(k)
            left = self._try_sites(system, k, t_layer, np.arange(self.layer_size(k)), time)
            if len(left):
                self.pending.append((k, t_layer, left))
            self.layers_done += 1
            self.t_last = t_layer
            if self.layers_done > 10_000_000:
                break
        return self.count_inserted - n0

    @property
    def n_pending(self) -> int:
        return int(sum(len(s) for _, _, s in self.pending))

    def get_state(self) -> dict:
        pk = np.array([k for k, _, s in self.pending for _ in s], np.int64)
        pt = np.array([t for _, t, s in self.pending for _ in s], float)
        ps = np.array([i for _, _, s in self.pending for i in s], np.int64)
        return {"layers_done": self.layers_done, "t_last": self.t_last, "mass_inserted": self.mass_inserted,
                "count_inserted": self.count_inserted, "mass_dropped": self.mass_dropped,
                "count_dropped": self.count_dropped, "pending_layer": pk, "pending_time": pt,
                "pending_site": ps, "label": np.int64(self.label)}

    def set_state(self, s: dict) -> None:
        self.layers_done = int(s["layers_done"])
        self.t_last = float(s.get("t_last", self._nominal_time(self.layers_done - 1)))
        self.mass_inserted = float(s["mass_inserted"])
        self.count_inserted = int(s["count_inserted"])
        self.mass_dropped = float(s.get("mass_dropped", 0.0))
        self.count_dropped = int(s.get("count_dropped", 0))
        self.label = int(s.get("label", self.label))  # checkpoints written before labels: the case's
        pk = np.asarray(s.get("pending_layer", np.zeros(0, np.int64)), np.int64).reshape(-1)
        pt = np.asarray(s.get("pending_time", np.zeros(0)), float).reshape(-1)
        ps = np.asarray(s.get("pending_site", np.zeros(0, np.int64)), np.int64).reshape(-1)
        self.pending = [(int(k), float(pt[pk == k][0]), ps[pk == k]) for k in np.unique(pk)]
