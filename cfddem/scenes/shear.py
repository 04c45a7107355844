"""The Jenike shear cell (``geometry.type = "shear_cell"``, case section ``[shear]``; physics.md §6).

Axes: y UP (gravity (0, -g, 0): ``gravity.inclination_deg`` must be 0), shear along +x; the
cell axis is the y axis through x = z = 0.

Walls (named; contact parameters ``contact.particle_wall`` with the overrides of
``[shear.rings]`` and ``[shear.plate]``):

- ``bottom``: the plane y = 0 (normal +y), the floor of the base ring;
- ``base_ring``: the inside of a ring of inner diameter D (``cell_diameter``, 95 mm), y from 0
  to H_b (``base_height``, 13 mm), fixed;
- ``shear_ring``: the inside of a ring of the same diameter, y from H_b to H_b + H_s
  (``ring_height``, 16 mm).  The shear plane is y = H_b.
- ``base_ledge`` / ``ring_ledge``: the faces of the rings' walls (``wall_thickness``, 3 mm) at
  the shear plane: annuli R..R + t at y = H_b about each ring's axis, facing up (the base ring's
  top) and down (the shear ring's bottom, moving with it).  Where the offset exposes them,
  particles rest on the base ring's top or are held under the shear ring's wall.
- wall-friction variant (``variant = "wall"``): no base ring and no bottom; the sample sits in
  the shear ring on ``plate``, a flat plane at y = H_b (``[shear.plate]`` friction): the shear
  force then measures wall friction.
- ``mould``: the filling mould, the inside of the shear ring continued from its top to one
  particle spacing above the fill lattice (:func:`mould_half_height`); it holds an overfill
  that settles above the ring and is switched off when the bed is scraped.  Without it the
  overfill spilled over the ring's rim and a particle that fell onto the back of
  ``ring_ledge`` was thrown out (issue #22; the engine now ignores such back-of-wall contacts
  and reports them).

Ring offset (``ring_offset``, 3 mm): as in a Jenike tester the shear ring starts displaced by
the offset AGAINST the shear direction (its axis at x = -offset) and travels ``shear_distance``
(6 mm) in +x, so it crosses the base ring's axis half way and ends at x = +offset.  The wall
thickness (3 mm) does not enter: only the inner surfaces touch particles.

Lid: a rigid clump (:mod:`cfddem.particles.clumps`) of touching spheres of diameter
``lid_sphere_diameter`` (0: the particle diameter) on a hexagonal lattice filling a disc whose
outline keeps ``lid_clearance`` from the ring, density ``lid_density``.  It is free to move
vertically and to tilt (and to spin about y); its horizontal centre-of-mass velocity is held at
the shear ring's (0 during consolidation) by a velocity constraint; the force that constraint
takes is recorded.  External force on the lid: -sigma A f(t) e_y - M g (its weight cancelled),
with A = pi D^2 / 4 and f ramping linearly from 0 to 1 over ``load_ramp_time``.  Lid-particle
contacts use the particle-particle law.

Phases:

1. fill: ``n_particles`` spheres (or ``particles.clump`` pellets, random orientations) on a
   jittered cubic lattice inside the disc common to both rings (seeded by ``particles.seed``),
   dropped under gravity inside the rings and the mould; from ``fill_time`` on, the first check
   where the kinetic energy per particle is below ``settle_energy`` ends the fill: the mould is
   lifted, particles (clumps) reaching above the scrape level y_s = H_b + H_s - lid sphere diameter - lid_clearance are removed (the
   "scraping off" of a Jenike test) and the lid is placed on the bed.
2. consolidation: the load ramps up; after at least ``consolidate_time`` and once the lid's
   vertical speed is below ``lid_settle_speed`` the shear starts.
3. shear: ring and lid move at ``shear_speed`` in +x until the ring has travelled
   ``shear_distance``; the run then stops.

Samples every ``sample_interval`` (averages over the scene's check points in that interval,
every ``check_steps`` steps): shear displacement (ring travel), shear force
S = -(F_ring,x + F_lid,x) (the particles' horizontal force against the moving ring and lid),
normal force N = the particles' vertical force on the lid (target sigma A), the weight W of the
particles above the shear plane, lid height and tilt (angle between the lid's normal and y).
Bulk friction = <S> / <N + W> over the steady window ``steady_window`` (fractions of the travel;
default the second half) (:func:`cfddem.measure.shear.bulk_friction`).

Stored in results.h5: ``/series/shear_force``, ``/series/shear_displacement``,
``/series/normal_force``, ``/series/lid_height``, ``/series/lid_tilt_deg`` (instantaneous at
the series rows), ``/measurements/bulk_friction`` and the details (the sampled averages, the
load error, the inertial number) under ``/measurements/shear``.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import CaseError, RunError
from ..measure.shear import bulk_friction, inertial_number, lid_disc, slab_solid_fraction
from ..particles.contact import check_contact_values
from . import Scene
from .common import apply_fill_friction, check_fill_friction, fill_friction_set
from ..schema import Key, fill_friction, fill_rolling_friction, wall_override
from ..schema import nonneg as _nonneg
from ..schema import number as _f
from ..schema import positive as _pos

PHASES = ("fill", "consolidate", "shear", "done")


SHEAR_KEYS = {
    "variant": Key("str", "bulk", "-", "'bulk': base ring + shear ring (bulk friction); 'wall': the base ring "
                   "replaced by a flat plate at the shear plane (wall friction)", choices=("bulk", "wall")),
    "cell_diameter": _pos(0.095, "m", "inner diameter D of both rings (axis = y through x = z = 0)"),
    "base_height": _pos(0.013, "m", "height of the base ring (y from 0; the shear plane is its top)"),
    "ring_height": _pos(0.016, "m", "height of the shear ring above the base ring"),
    "ring_offset": _nonneg(0.003, "m", "initial offset of the shear ring against the shear direction (-x)"),
    "wall_thickness": _pos(0.003, "m", "ring wall thickness: the width of the ledges (ring faces) at the shear plane"),
    "normal_stress": _pos(4000.0, "Pa", "consolidation stress sigma on the lid: load sigma pi D^2 / 4"),
    "load_ramp_time": _nonneg(0.05, "s", "the lid load ramps linearly from 0 over this time"),
    "shear_speed": _pos(0.003, "m/s", "speed of the shear ring and lid"),
    "shear_distance": _pos(0.006, "m", "travel of the shear ring (the run stops there)"),
    "n_particles": Key("int", 3000, "-", "particles (or clumps) of the fill lattice (overfilled, then scraped)", lo=1),
    "lattice_gap": _f(0.1, "-", "fill lattice spacing d (1 + gap)", lo=0.0, lo_open=True, hi=2.0),
    "lattice_jitter": _f(0.05, "-", "random displacement of the sites, up to +-jitter d / 2 per axis", lo=0.0, hi=2.0),
    "fill_time": _nonneg(0.2, "s", "earliest end of the fill (settled check)"),
    "settle_energy": _pos(1e-8, "J", "kinetic energy per particle below which the fill counts as settled"),
    "fill_friction": fill_friction("the scraping (before the lid is placed)"),
    "fill_rolling_friction": fill_rolling_friction("the scraping (before the lid is placed)"),
    "consolidate_time": _nonneg(0.05, "s", "shortest consolidation after the lid is placed"),
    "lid_settle_speed": _pos(2e-3, "m/s", "consolidation ends when the lid's vertical speed is below this"),
    "lid_sphere_diameter": _nonneg(0.0, "m", "diameter of the lid's glued spheres (0: particles.diameter)"),
    "lid_clearance": _nonneg(0.0005, "m", "gap between the lid's outline and the ring"),
    "lid_density": _pos(7800.0, "kg/m3", "density of the lid's spheres (its weight is cancelled; sets its inertia)"),
    "check_steps": Key("int", 20, "-", "steps between the scene's checks (load update, force sampling)", lo=1),
    "sample_interval": _pos(0.01, "s", "interval of the averaged shear samples (/measurements/shear)"),
    "steady_window": Key("floats", [0.5, 1.0], "-", "bulk friction: mean over shear displacements between these "
                         "fractions of shear_distance", length=2),
    "rings": wall_override("base ring, bottom and shear ring"),
    "plate": wall_override("wall-friction plate (variant 'wall')"),
}


def check_shear_case(r: dict) -> None:
    """Consistency of a shear-cell case (raises CaseError naming the key)."""
    s = r["shear"]
    d = r["particles"]["diameter"]
    if r["gravity"]["inclination_deg"] != 0.0:
        raise CaseError("gravity.inclination_deg", "the shear cell needs gravity along -y (inclination 0)")
    if r["gravity"]["g"] <= 0.0:
        raise CaseError("gravity.g", "the shear cell needs gravity (the fill settles under it)")
    if r["frame"]["rpm"] != 0.0:
        raise CaseError("frame.rpm", "the shear cell runs in a fixed frame (rpm = 0)")
    for grp in ("rings", "plate"):
        check_contact_values(f"shear.{grp}", s[grp])
    check_fill_friction("shear", s)
    D = s["cell_diameter"]
    if D < 10 * d:
        raise CaseError("shear.cell_diameter", f"{D:g} m is less than 10 particle diameters ({10 * d:g} m)")
    if 2 * s["ring_offset"] >= D - 4 * d:
        raise CaseError("shear.ring_offset", f"{s['ring_offset']:g} m leaves no common disc for the fill")
    lo, hi = s["steady_window"]
    if not (0.0 <= lo < hi <= 1.0):
        raise CaseError("shear.steady_window", f"need 0 <= lo < hi <= 1, got [{lo:g}, {hi:g}]")
    dl = s["lid_sphere_diameter"] or d
    if s["ring_height"] < 2 * dl + s["lid_clearance"] + d:
        raise CaseError("shear.ring_height", f"{s['ring_height']:g} m has no room for a bed and the lid "
                                             f"(lid spheres {dl:g} m)")
    if s["variant"] == "bulk" and s["base_height"] < d:
        raise CaseError("shear.base_height", f"{s['base_height']:g} m is lower than one particle")
    if r["particles"]["diameter_max"]:
        raise CaseError("particles.diameter_max", "the shear cell fill is monodisperse (set 0)")


def _wall_params(case, group: str) -> dict:
    full = dict(case.resolved["contact"]["particle_wall"])
    full.update({k: float(v) for k, v in case.resolved["shear"][group].items() if v is not None})
    return full


class ShearGeometry:
    """Derived dimensions (m): R, H_b, H_s, offset, shear plane y, scrape level, lid spheres."""

    def __init__(self, s: dict, d: float):
        self.d = d
        self.R = 0.5 * s["cell_diameter"]
        self.Hb = s["base_height"]
        self.Hs = s["ring_height"]
        self.off = s["ring_offset"]
        self.wall = s["variant"] == "wall"
        self.y_shear = self.Hb
        self.y_floor = self.Hb if self.wall else 0.0
        self.r_lid = 0.5 * (s["lid_sphere_diameter"] or d)
        self.clear = s["lid_clearance"]
        self.y_scrape = self.Hb + self.Hs - 2 * self.r_lid - self.clear
        self.area = math.pi * self.R**2


def shear_walls(case):
    """The shear cell's :class:`~cfddem.scene.WallSpec` list (complete contact parameters)."""
    from .common import WallSpec

    s = case.resolved["shear"]
    g = ShearGeometry(s, case.particles.diameter)
    ey = np.array([0.0, 1.0, 0.0])
    rings = _wall_params(case, "rings")
    walls = []
    if not g.wall:
        walls.append(WallSpec("bottom", "plane", np.zeros(3), ey, params=dict(rings)))
        walls.append(WallSpec("base_ring", "cylinder", np.array([0.0, 0.5 * g.Hb, 0.0]), ey, None,
                              (g.R, 0.5 * g.Hb), dict(rings), inside=True))
    else:
        walls.append(WallSpec("plate", "plane", np.array([0.0, g.Hb, 0.0]), ey, params=_wall_params(case, "plate")))
    walls.append(WallSpec("shear_ring", "cylinder", np.array([-g.off, g.Hb + 0.5 * g.Hs, 0.0]), ey, None,
                          (g.R, 0.5 * g.Hs), dict(rings), inside=True))
    if not g.wall:  # the rings' wall faces at the shear plane (ledges exposed by the offset)
        t = s["wall_thickness"]
        walls.append(WallSpec("base_ledge", "annulus", np.array([0.0, g.Hb, 0.0]), ey, None, (g.R, g.R + t),
                              dict(rings)))
        walls.append(WallSpec("ring_ledge", "annulus", np.array([-g.off, g.Hb, 0.0]), -ey, None, (g.R, g.R + t),
                              dict(rings)))
    # the filling mould: the shear ring continued up to a spacing above the fill lattice, removed
    # when the settled bed is scraped (module docstring)
    hh = mould_half_height(case, g)
    walls.append(WallSpec("mould", "cylinder", np.array([-g.off, g.Hb + g.Hs + hh, 0.0]), ey, None, (g.R, hh),
                          dict(rings), inside=True))
    return walls


# solid fraction of the settled fill assumed by cfddem check's estimate: the poured lattice
# settles loose and uneven; 0.5 gives the scraped share of cases/shear_jenike (24 % predicted,
# 781 of 3400 = 23 % scraped) and of issue #22's thesis fill (35 %; 1690 of 4700 = 36 %)
FILL_FRACTION = 0.5


def fill_estimate(case) -> dict:
    """Heights (m) of the fill for ``cfddem check``: the lattice top, the mould top, the bed
    height the fill's solid volume gives at a solid fraction :data:`FILL_FRACTION` over the
    cell's cross-section above the floor, the shear ring's top and the scrape level."""
    s = case.resolved["shear"]
    p = case.particles
    g = ShearGeometry(s, p.diameter)
    sites, spacing, shape = fill_lattice(case)
    v1 = math.pi / 6.0 * p.diameter**3 if shape is None else shape.mass / p.density
    n = len(sites)
    return {"n": n, "what": "spheres" if shape is None else f"{p.clump} clumps",
            "lattice_top": float(sites[:, 1].max()) + 0.5 * spacing,
            "mould_top": g.Hb + g.Hs + 2 * mould_half_height(case, g),
            "floor": g.y_floor, "bed": g.y_floor + n * v1 / (FILL_FRACTION * g.area), "ring_top": g.Hb + g.Hs,
            "scrape": g.y_scrape}


def mould_half_height(case, g: ShearGeometry) -> float:
    """Half height of the mould: from the shear ring's top to one spacing above the fill lattice
    (at least one particle diameter)."""
    sites, spacing, _ = fill_lattice(case)
    return 0.5 * max(float(sites[:, 1].max()) + spacing - (g.Hb + g.Hs), g.d)


def fill_lattice(case) -> tuple[np.ndarray, float, object]:
    """The fill's lattice sites (:func:`fill_sites` with the case's keys), its particle spacing
    (the diameter, or a clump's bounding diameter) and the clump shape (None for spheres)."""
    from ..particles.clumps import particle_shape

    s = case.resolved["shear"]
    p = case.particles
    g = ShearGeometry(s, p.diameter)
    shape = particle_shape(p)
    spacing = p.diameter if shape is None else 2 * float(np.max(np.linalg.norm(shape.offsets, axis=1) + shape.radii))
    return fill_sites(g, s["n_particles"], spacing, s["lattice_gap"], s["lattice_jitter"], p.seed), spacing, shape


def fill_sites(g: ShearGeometry, n: int, spacing: float, gap: float, jitter: float, seed: int) -> np.ndarray:
    """First ``n`` sites (bottom up) of a cubic lattice of ``spacing`` (1 + gap) inside the disc
    common to both rings (centre x = -offset/2, radius R - offset/2 - spacing (1 + gap)/2), the
    lowest layer half a spacing above the floor; each site moved by up to +-jitter spacing / 2
    per axis (seeded)."""
    a = spacing * (1.0 + gap)
    rc = g.R - 0.5 * g.off - 0.5 * a
    k = int(rc / a) + 1
    xs = a * np.arange(-k, k + 1)
    X, Z = np.meshgrid(xs, xs, indexing="ij")
    inside = X**2 + Z**2 <= rc * rc
    X, Z = X[inside] - 0.5 * g.off, Z[inside]
    per = len(X)
    if per == 0:
        raise CaseError("shear.cell_diameter", "the cell is too small for one lattice site")
    layers = -(-n // per)
    pos = np.concatenate([np.stack([X, np.full(per, g.y_floor + 0.5 * a + a * j), Z], axis=1)
                          for j in range(layers)])[:n]
    rng = np.random.default_rng(seed)
    return pos + rng.uniform(-0.5 * jitter * spacing, 0.5 * jitter * spacing, size=pos.shape)


class ShearCellScene(Scene):
    """Fill, lid, consolidation, shear, measurements of a Jenike shear test (module doc)."""

    DOC = "'shear_cell': the Jenike shear cell of [shear]"
    EXAMPLE = "shear_jenike"
    SCHEMA = {"shear": SHEAR_KEYS}
    locks_rotation_after_fill = True  # at the scraping, before the lid is placed

    @classmethod
    def check(cls, r: dict, case_dir) -> None:
        check_shear_case(r)

    @classmethod
    def wall_specs(cls, case) -> list:
        return shear_walls(case)

    @classmethod
    def has_particles(cls, case) -> bool:
        return True

    @classmethod
    def describe(cls, case) -> list[str]:
        """The fill: lattice top, the bed height a settled solid fraction of 0.5 gives, against
        the shear ring's top and the scrape level (:func:`fill_estimate`)."""
        f = fill_estimate(case)
        mm = 1e3
        line = (f"shear cell fill: {f['n']} {f['what']} on a lattice up to y = {f['lattice_top'] * mm:.3g} mm, held by "
                f"the mould (the shear ring continued to {f['mould_top'] * mm:.3g} mm, lifted at the scraping); settled "
                f"(solid fraction {FILL_FRACTION:g}) the bed reaches about {f['bed'] * mm:.3g} mm against the shear ring's "
                f"top {f['ring_top'] * mm:.3g} mm and the scrape level {f['scrape'] * mm:.3g} mm")
        if f["bed"] < f["scrape"]:
            line += " (WARNING: below the scrape level: raise shear.n_particles)"
        elif f["bed"] > f["ring_top"]:
            line += " (above the ring: the mould holds the overfill, about " \
                    f"{100 * (f['bed'] - f['scrape']) / (f['bed'] - f['floor']):.0f} % of the fill is scraped)"
        else:
            line += " (OK)"
        return [line]

    @classmethod
    def expected_particles(cls, case) -> int:
        return 4 * case.shear.n_particles + 1000  # the fill (up to 4 spheres per clump) and the lid

    @classmethod
    def inserts_clumps(cls, r: dict) -> bool:
        return True

    @classmethod
    def speed_scale(cls, case) -> float:
        return float(case.shear.shear_speed)  # the ring and lid; the fill falls slower than 1 m/s

    def __init__(self, sim):
        super().__init__(sim)
        s = self.case.resolved["shear"]
        self.s = s
        self.g = ShearGeometry(s, self.case.particles.diameter)
        self.phase = "fill"
        self.t_phase = 0.0
        self.k_check = 1
        self.lid_bid = -1
        self.y_lid0 = math.nan
        self.rec = {k: [] for k in ("time", "displacement", "shear_force", "normal_force", "weight_above",
                                    "lid_height", "lid_tilt_deg", "load_target")}
        self._acc = np.zeros(8)  # running sums of the current sample: S, N, W, y, tilt, target, count, x
        self.k_sample = 0
        self.note = ""
        self.load_log = []  # (time, lid vertical force, target) at every check during consolidation+shear
        self.fill_info: dict = {}  # the settled fill, at the scraping (_place_lid)

    # ------------------------------------------------------------------ helpers
    @property
    def sys(self):
        return self.sim.system

    def _lid(self) -> int:
        return self.sys.body_index(self.lid_bid)

    def _ring_x(self) -> float:
        return float(self.sys.wall_position("shear_ring")[0])

    def displacement(self) -> float:
        return self._ring_x() + self.g.off

    def load_target(self, t: float) -> float:
        """sigma A f(t) (N)."""
        ramp = self.s["load_ramp_time"]
        f = 1.0 if ramp <= 0 else min(1.0, max(0.0, (t - self.t_load) / ramp))
        return self.s["normal_stress"] * self.g.area * f

    def _apply_load(self, t: float) -> None:
        c = self.sys.clumps
        b = self._lid()
        gv = self.sys.gravity
        c.ext_force[b] = -c.mass[b] * gv + np.array([0.0, -self.load_target(t), 0.0])

    def lid_forces(self) -> np.ndarray:
        """Force of the particles on the lid (N): the body force minus its gravity."""
        c = self.sys.clumps
        b = self._lid()
        return c.force[b] - c.mass[b] * self.sys.gravity

    def ring_force(self) -> np.ndarray:
        """Force of the particles on the moving ring (its inner surface and its bottom face)."""
        sys_ = self.sys
        f = sys_.wall_forces()
        out = f[sys_._wall_index("shear_ring")]
        if not self.g.wall:
            out = out + f[sys_._wall_index("ring_ledge")]
        return out

    def lid_tilt_deg(self) -> float:
        from ..particles.clumps import matrix_from_quat

        c = self.sys.clumps
        b = self._lid()
        R = matrix_from_quat(c.quat[b])
        n = R @ self._lid_normal_body
        return math.degrees(math.acos(min(1.0, abs(float(n[1])))))

    def weight_above(self) -> float:
        sys_ = self.sys
        if not sys_.n:
            return 0.0
        free = sys_.body < 0
        if self.lid_bid >= 0:
            free = free | (sys_.body != self._lid())
        sel = free & (sys_.pos[:, 1] > self.g.y_shear) if not self.g.wall else free
        return float(np.sum(sys_.mass[sel])) * float(np.linalg.norm(sys_.gravity))

    # ------------------------------------------------------------------ hooks
    def _fill_friction(self) -> None:
        """The fill's particle-particle sliding and rolling friction (``fill_friction``,
        ``fill_rolling_friction``), until the scraping."""
        apply_fill_friction(self.sys, self.s)

    def _fill_mu(self) -> float:
        """The fill's particle-particle sliding friction (``fill_friction`` or the case's)."""
        v = self.s["fill_friction"]
        return float(v if v >= 0.0 else self.case.contact.particle_particle.mu)

    def _fill_mur(self) -> float:
        """The fill's particle-particle rolling friction (``fill_rolling_friction`` or the case's)."""
        v = self.s["fill_rolling_friction"]
        return float(v if v >= 0.0 else self.case.contact.particle_particle.mu_r)

    def sample_solid_fraction(self, bed_top: float) -> float:
        """Solid fraction of the scraped sample between one diameter above the floor and one
        below the bed top (:func:`~cfddem.measure.shear.slab_solid_fraction`; spheres and
        clumps by their centres, the lid excluded)."""
        sys_ = self.sys
        d = self.g.d
        free = sys_.body < 0
        y = [sys_.pos[free, 1]]
        v = [sys_.mass[free] / self.case.particles.density]
        c = sys_.clumps
        if c is not None and c.nb:
            keep = np.ones(c.nb, bool)
            if self.lid_bid >= 0:
                keep[self._lid()] = False
            y.append(c.com[keep, 1])
            v.append(c.mass[keep] / self.case.particles.density)
        return slab_solid_fraction(np.concatenate(y), np.concatenate(v), self.g.y_floor + d, bed_top - d, self.g.area)

    def start(self) -> None:
        self._fill_friction()
        p = self.case.particles
        pos, _, shape = fill_lattice(self.case)
        if shape is None:
            self.sys.add_particles(pos, np.zeros(3), 0.5 * p.diameter, p.density)
        else:
            rng = np.random.default_rng(p.seed + 1)
            q = rng.standard_normal((len(pos), 4))
            self.sys.add_clumps(shape, pos, quat=q)
        self.sim.log.info("shear cell: %d %s on a lattice up to y = %.4g m; rings D = %.4g m, base %.4g m, "
                          "shear ring %.4g m offset %.3g mm%s", len(pos), p.clump if shape is not None else "spheres",
                          float(pos[:, 1].max()), 2 * self.g.R, self.g.Hb, self.g.Hs, 1e3 * self.g.off,
                          f"; filled with particle friction {self._fill_mu():g}, rolling friction "
                          f"{self._fill_mur():g} (the case's {self.case.contact.particle_particle.mu:g}, "
                          f"{self.case.contact.particle_particle.mu_r:g} from the scraping on)"
                          if fill_friction_set(self.s) else "")

    def max_steps(self) -> int:
        return self.s["check_steps"]

    def next_time(self, t: float) -> float:
        return math.inf

    def after_steps(self) -> None:
        sys_ = self.sys
        t = sys_.time
        if self.phase == "fill":
            if t < self.s["fill_time"]:
                return
            ke = sys_.kinetic_energy() / max(sys_.n, 1)
            if ke < self.s["settle_energy"]:
                self._place_lid(t, ke)
            return
        if self.phase == "done":
            return
        self._apply_load(t)
        fl = self.lid_forces()
        self.load_log.append((t, float(fl[1]), self.load_target(t), 1.0 if self.phase == "shear" else 0.0))
        if self.phase == "consolidate":
            c = sys_.clumps
            vy = abs(float(c.vel[self._lid(), 1]))
            if t - self.t_phase >= self.s["consolidate_time"] and vy < self.s["lid_settle_speed"] \
                    and t - self.t_load >= self.s["load_ramp_time"]:
                self._start_shear(t)
            return
        # shear: accumulate the sample
        fr = self.ring_force()
        S = -(fr[0] + fl[0])
        x = self.displacement()
        self._acc += (S, fl[1], self.weight_above(), float(sys_.clumps.com[self._lid(), 1]), self.lid_tilt_deg(),
                      self.load_target(t), 1.0, x)
        if t >= self.t_phase + (self.k_sample + 1) * self.s["sample_interval"] - 0.5 * sys_.dt:
            self._flush_sample(t)
        if x >= self.s["shear_distance"] - 1e-12:
            if self._acc[6] > 0:
                self._flush_sample(t)
            sys_.set_wall_velocity("shear_ring", (0.0, 0.0, 0.0))
            if not self.g.wall:
                sys_.set_wall_velocity("ring_ledge", (0.0, 0.0, 0.0))
            c = sys_.clumps
            c.vset[self._lid(), 0] = 0.0
            self.phase = "done"
            self.note = f"shear complete: {1e3 * x:.3g} mm at t = {t:.4g} s"

    def _flush_sample(self, t: float) -> None:
        a = self._acc / self._acc[6]
        self.rec["time"].append(t)
        self.rec["displacement"].append(a[7])
        self.rec["shear_force"].append(a[0])
        self.rec["normal_force"].append(a[1])
        self.rec["weight_above"].append(a[2])
        self.rec["lid_height"].append(a[3])
        self.rec["lid_tilt_deg"].append(a[4])
        self.rec["load_target"].append(a[5])
        self._acc[:] = 0.0
        self.k_sample += 1

    def _place_lid(self, t: float, ke: float) -> None:
        from ..particles.clumps import ClumpShape

        sys_ = self.sys
        g = self.g
        sys_.set_wall_active("mould", False)  # lifted off: what it held is above the scrape level
        if fill_friction_set(self.s):
            sys_.set_friction(True)  # the case's friction for the consolidation and the shear
        if self.case.particles.rotation == "locked":
            sys_.lock_rotation()  # the sample was poured with free rotation (particles.rotation)
        settled_top = float(np.max(sys_.pos[:, 1] + sys_.radius))
        top = sys_.pos[:, 1] + sys_.radius > g.y_scrape
        k, m = sys_.remove_particles(top) if top.any() else (0, 0.0)
        self.sim.counters["count_out"] += k
        self.sim.counters["mass_out"] += m
        if sys_.n == 0:
            raise RunError("shear cell: no particles left below the scrape level")
        bed_top = float(np.max(sys_.pos[:, 1] + sys_.radius))
        if bed_top < g.y_scrape - 3 * g.d:
            self.sim.log.warning("shear cell: the settled bed (top %.4g m) is more than 3 d below the scrape level "
                                 "%.4g m: raise shear.n_particles", bed_top, g.y_scrape)
        solid = self.sample_solid_fraction(bed_top)
        c = lid_disc(g.R - g.clear, g.r_lid)
        y = bed_top + g.r_lid + 0.05 * g.d
        # the lid (centred on the shear ring) reaching into the base ring: with the ring offset
        # larger than the lid's clearance its spheres would sit in the base ring's wall
        out = float(np.max(np.hypot(c[:, 0] + self._ring_x(), c[:, 2]))) + g.r_lid - g.R
        if not g.wall and y - g.r_lid < g.y_shear and out > 0.0:
            raise RunError(f"shear cell: the settled bed (top {bed_top:.4g} m) puts the lid's bottom below the shear "
                           f"plane ({g.y_shear:.4g} m): the lid, centred on the shear ring, would reach {out * 1e3:.3g} mm "
                           f"into the base ring's wall; raise shear.n_particles (cfddem check estimates the bed height)")
        dens = self.s["lid_density"]
        shape = ClumpShape.from_spheres(c, g.r_lid, dens, name="lid")
        # the lid's normal in its body frame
        self._lid_normal_body = shape.frame.T @ np.array([0.0, 1.0, 0.0])
        bid = sys_.add_clumps(shape, [[self._ring_x(), y, 0.0]], rotation_locked=False)  # the lid tilts
        self.lid_bid = int(bid[0])
        cl = sys_.clumps
        b = self._lid()
        cl.vfix[b] = (1.0, 0.0, 1.0)
        cl.vset[b] = 0.0
        self.t_load = t
        self.t_phase = t
        self.y_lid0 = y
        self._apply_load(t)
        self.phase = "consolidate"
        self.fill_info = {"kinetic_energy_per_particle": ke, "removed": k, "removed_mass": m, "bed_top": bed_top,
                          "settled_top": settled_top, "solid_fraction": solid,
                          "lid_spheres": len(c), "lid_mass": shape.mass, "time": t}
        self.sim.log.info("shear cell: settled at t = %.4g s (kinetic energy per particle %.3g J, bed top %.4g m, "
                          "mould lifted); scraped %d "
                          "particles above y = %.4g m (the sample's solid fraction %.4f); lid of %d spheres (%.4g kg) "
                          "placed at y = %.4g m; load %.4g N ramps over %.3g s", t, ke, settled_top, k, g.y_scrape,
                          solid, len(c), shape.mass, y, self.s["normal_stress"] * g.area, self.s["load_ramp_time"])

    def _start_shear(self, t: float) -> None:
        v = self.s["shear_speed"]
        sys_ = self.sys
        sys_.set_wall_velocity("shear_ring", (v, 0.0, 0.0))
        if not self.g.wall:
            sys_.set_wall_velocity("ring_ledge", (v, 0.0, 0.0))
        cl = sys_.clumps
        cl.vset[self._lid(), 0] = v
        self.phase = "shear"
        self.t_phase = t
        self.k_sample = 0
        self.sim.log.info("shear cell: consolidated at t = %.4g s (lid at y = %.4g m); shearing %.3g mm at %.3g mm/s",
                          t, float(cl.com[self._lid(), 1]), 1e3 * self.s["shear_distance"], 1e3 * v)

    def series(self) -> dict:
        if self.lid_bid < 0 or self.phase == "fill":
            return {"shear_force": 0.0, "shear_displacement": 0.0, "normal_force": 0.0, "lid_height": 0.0,
                    "lid_tilt_deg": 0.0, "shear_phase": float(PHASES.index(self.phase))}
        fr = self.ring_force()
        fl = self.lid_forces()
        return {"shear_force": float(-(fr[0] + fl[0])), "shear_displacement": self.displacement(),
                "normal_force": float(fl[1]), "lid_height": float(self.sys.clumps.com[self._lid(), 1]),
                "lid_tilt_deg": self.lid_tilt_deg(), "shear_phase": float(PHASES.index(self.phase))}

    def stop_reason(self) -> str | None:
        if self.phase != "done":
            return None
        r = self.result()
        return f"{self.note}; bulk friction {r['mu']:.4g}" if not self.g.wall else \
            f"{self.note}; wall friction {r['mu']:.4g}"

    def result(self) -> dict:
        rec = self.rec
        n = np.array(rec["normal_force"]) + np.array(rec["weight_above"])
        return bulk_friction(rec["displacement"], rec["shear_force"], n, self.s["shear_distance"],
                             tuple(self.s["steady_window"]))

    def load_error(self) -> float:
        """Relative error of the time-averaged vertical force of the particles on the lid (mean
        over the checks, every ``check_steps`` steps) against the target, during the shear."""
        if not self.load_log:
            return math.nan
        a = np.array(self.load_log)
        sel = (a[:, 3] > 0.5) & (a[:, 0] >= self.t_load + self.s["load_ramp_time"])
        if not sel.any():
            return math.nan
        return float(a[sel, 1].mean() / a[sel, 2].mean() - 1.0)

    def measurements(self):
        r = self.result()
        p = self.case.particles
        sigma = self.s["normal_stress"]
        shear = {k: np.array(v, float) for k, v in self.rec.items()}
        shear.update({
            "phase": PHASES.index(self.phase),
            "mu": r["mu"], "mean_shear_force": r["shear_force"], "mean_normal_force": r["normal_force"],
            "ratio_std": r["ratio_std"], "window": np.array(r["window"], float), "n_samples": r["n_samples"],
            "load_error": self.load_error(),
            "fill_solid_fraction": float(self.fill_info.get("solid_fraction", math.nan)),
            "fill_bed_top": float(self.fill_info.get("bed_top", math.nan)),
            "fill_removed": int(self.fill_info.get("removed", 0)),
            "fill_friction": self._fill_mu(),
            "fill_rolling_friction": self._fill_mur(),
            "inertial_number": inertial_number(self.s["shear_speed"], p.diameter, sigma, p.density),
            "@attrs": {"variant": self.s["variant"],
                       "shear_force": "-(F_ring,x + F_lid,x): the particles' horizontal force against the moving "
                                      "ring and lid, N",
                       "normal_force": "vertical force of the particles on the lid, N",
                       "bulk_friction": "mean(shear_force) / mean(normal_force + weight_above) over displacement "
                                        "in window (m)",
                       "inertial_number": "speed / (10 d) * d / sqrt(normal_stress / density)",
                       "fill_solid_fraction": "solid fraction of the scraped sample from d above the floor to d "
                                              "below its top (units counted by their centres)",
                       "fill_friction": "particle-particle sliding friction of the fill (shear.fill_friction, or "
                                        "the case's)",
                       "fill_rolling_friction": "particle-particle rolling friction of the fill "
                                                "(shear.fill_rolling_friction, or the case's)",
                       "stop": self.note},
        })
        name = "bulk_friction" if not self.g.wall else "wall_friction"
        arrays = {name: r["mu"], "shear": shear, f"@attrs:{name}": {"unit": "-"}}
        if self.g.wall:
            arrays["bulk_friction"] = math.nan
        return None, arrays, {}

    def get_state(self) -> dict:
        st = {"phase": self.phase, "t_phase": self.t_phase, "k_check": np.int64(self.k_check),
              "lid_bid": np.int64(self.lid_bid), "y_lid0": self.y_lid0, "acc": self._acc.copy(),
              "k_sample": np.int64(self.k_sample), "note": self.note, "t_load": getattr(self, "t_load", math.nan),
              "load_log": np.array(self.load_log, float).reshape(-1, 4),
              "lid_normal_body": getattr(self, "_lid_normal_body", np.zeros(3)),
              "fill_info": {k: float(v) for k, v in self.fill_info.items()}}
        for k, v in self.rec.items():
            st["rec_" + k] = np.array(v, float)
        return st

    def set_state(self, d: dict) -> None:
        def s(v):
            return v.decode() if isinstance(v, bytes) else str(v)

        self.phase = s(d["phase"])
        self.t_phase = float(d["t_phase"])
        self.k_check = int(d["k_check"])
        self.lid_bid = int(d["lid_bid"])
        self.y_lid0 = float(d["y_lid0"])
        self._acc = np.asarray(d["acc"], float).copy()
        self.k_sample = int(d["k_sample"])
        self.note = s(d["note"])
        self.t_load = float(d["t_load"])
        self.load_log = [tuple(r) for r in np.asarray(d["load_log"], float).reshape(-1, 4)]
        self._lid_normal_body = np.asarray(d["lid_normal_body"], float)
        self.fill_info = {k: float(v) for k, v in d.get("fill_info", {}).items()}  # absent: written before it
        if self.phase == "fill":
            self._fill_friction()
        for k in self.rec:
            self.rec[k] = [float(x) for x in np.asarray(d["rec_" + k]).ravel()]
