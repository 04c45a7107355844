"""The planar (quasi-2D) silo discharge scene (``geometry.type = "silo"``, case section ``[silo]``).

Axes: x across the silo (side walls at x = 0 and x = width), y UP (gravity (0, -g, 0):
``gravity.inclination_deg`` must be 0), z through the depth (front wall z = 0, back wall
z = depth).  The slot outlet (full depth) spans x = width/2 +- b/2 at the outlet plane y = 0.

Walls (all bounded rectangles, one-sided, named; each group has its own contact parameters in
``[silo.front_back]``, ``[silo.sides]``, ``[silo.bottom]``, ``[silo.gate_wall]``, unset keys from
``contact.particle_wall``):

- ``front`` (z = 0, normal +z) and ``back`` (z = depth, normal -z), covering everything;
- ``left`` / ``right`` side walls (normals +x / -x) from the hopper top (flat: the bottom) up to
  the silo height;
- flat bottom: ``bottom_left`` / ``bottom_right`` at y = 0 (normal +y) from the side walls to the
  slot edges; hopper: ``hopper_left`` / ``hopper_right`` planes from the slot edges up to the side
  walls, inclined at ``hopper_angle_deg`` to the HORIZONTAL (normals (sin a, cos a, 0) and
  (-sin a, cos a, 0)), so the hopper top is at y_h = (width - b)/2 tan a;
- ``lip_left`` / ``lip_right``: vertical walls lining the slot from y = -lip to 0 (the thickness
  of the bottom plate).  They keep a particle that has passed the outlet plane from sliding
  sideways under a bottom plate (a one-sided rectangle pushes a centre that is less than a radius
  behind its face back through it);
- ``gate``: a rectangle at y = -lip (normal +y) closing the slot; ``system.set_wall_active("gate",
  False)`` opens it.
- the multi-flow blender's internals (``silo.tube``, ``silo.insert``): closed thin bodies of
  rectangles, contact group ``[silo.internals]`` (:mod:`cfddem.scenes.silo_internals`); the fill
  lattice then starts above them.

Seams: walls that meet are extended past the seam by one particle diameter (on the side away
from the particles), so no particle can leak through a corner; the slot edge is where the
bottom (or hopper) plate meets the lip: a particle rolling over that edge touches both walls'
edges at the same point (two equal edge contacts: twice the stiffness, the same friction ratio).

``silo.walls = "mesh"``: the container (every wall above but the gate) is the case's
``[[geometry.walls]]`` mesh walls, each with its own contact keys, and the scene supplies only
the gate; :func:`container_meshes` / :func:`write_container_stl` (``python -m
cfddem.scenes.silo CASE --write-stl DIR``) triangulate the analytic container, one STL file per
contact group.  ``cfddem check`` says whether the meshes' bounds cover the silo's box.

Filling (``silo.fill = "lattice"``): ``n_particles`` on a cubic lattice of spacing
d (1 + lattice_gap), each site displaced by up to +-lattice_jitter d/2 per axis (seeded), starting
just above the flat bottom or the hopper top, at rest, dropped under gravity.  ``fill = "pour"``:
one layer of that lattice (its own seeded jitter) is inserted at rest at ``pour_height`` every
m_layer / pour_rate seconds (m_layer the mass of a full layer; the last one is partial) until
``n_particles`` are in; a layer that would overlap a particle already there waits for the next
check (so the real rate can fall below pour_rate, never above it).  The gate opens at
``gate_time`` (``gate = "time"``) or, with ``gate = "settled"``, at the first check at or after
``gate_time`` where all particles are in and the kinetic energy per particle is below
``settle_energy``.  With ``frictionless_fill`` the fill runs with zero sliding and rolling
friction on every contact (:meth:`~cfddem.particles.system.ParticleSystem.set_friction`) and the
case's friction is switched on at the gate opening.

At the opening: the fill height (:func:`~cfddem.measure.silo.surface_height`, median over 2 d
wide bins of the highest centre) and the bulk density
(:func:`~cfddem.measure.silo.bulk_density`) in the box x in [3 d, width - 3 d], full depth,
y from 3 d above the bottom (flat) or the hopper top, to 3 d below the free surface.

Discharge: particles whose centres fall below y = -removal_depth are removed (at the engine's
next neighbour rebuild, within ~2 ms: the scene's exit plane is the engine's sink) and counted
(``/series/discharged_mass``, the run counters ``mass_out``/``count_out``).  Every
``settle_check_interval`` the discharged mass is recorded; if nothing left for ``clog_time``
the discharge has stopped: CLOGGED if some particle centre lies in the slot's x range below
y = 2 d (flat) or 2 d (1 + tan a) (hopper: where it is 4 d wider than the slot) (an arch over
the outlet) and, with ``clog_speed`` > 0, every particle over the outlet (the slot's x range
widened by d, below that height) is slower than ``clog_speed`` (else the arch is
still collapsing: the checks go on); otherwise ended (flat bottom: stagnant heaps remain;
hopper: empty).  Either way the run stops with that message.  The discharge duration (gate
opening to the removal of the last discharged particle) is stored once the discharge ended.  The steady flow rate is the slope of a
line through the discharged mass between the ``fit_range`` fractions of the final discharged
mass (:func:`~cfddem.measure.silo.fit_mass_flow`).  A time-averaged x-y velocity field is sampled
during discharge and the flow-channel boundary taken from it
(:func:`~cfddem.measure.silo.channel_boundary`).

Stored in results.h5: ``/measurements/mass_flow_rate`` (kg/s), ``/measurements/bulk_density``
(kg/m3), ``/measurements/clogged`` (0/1) and the details under ``/measurements/silo``
(``discharge_duration`` among them).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import CaseError
from ..measure.silo import (VelocityField, bulk_density, centreline_velocity, channel_boundary, fit_mass_flow,
                            profile_measurements, surface_height)
from ..particles.contact import check_contact_values
from . import Scene
from .common import FILL_KEYS, apply_fill_friction, check_fill_friction, fill_friction_set
from .silo_internals import GROUP as INTERNALS_GROUP, KEYS as INTERNALS_KEYS, WALL_NAMES as INTERNALS_WALLS
from .silo_internals import ChannelProbe, Internals, check_internals
from ..schema import Key, fill_friction, fill_rolling_friction, wall_override
from ..schema import nonneg as _nonneg
from ..schema import number as _f
from ..schema import positive as _pos

WALL_GROUPS = {"front": "front_back", "back": "front_back", "left": "sides", "right": "sides",
               "bottom_left": "bottom", "bottom_right": "bottom", "hopper_left": "bottom",
               "hopper_right": "bottom", "lip_left": "bottom", "lip_right": "bottom", "gate": "gate_wall"}
WALL_GROUPS.update(dict.fromkeys(INTERNALS_WALLS, INTERNALS_GROUP))  # blender internals: silo_internals.py
#: the walls that silo.floor_drop lowers (those of them the silo has)
FLOOR_WALLS = ("bottom_left", "bottom_right", "hopper_left", "hopper_right", "lip_left", "lip_right", "gate")
#: the vertical walls by pair, as the fill's wall loads group them (their shares, the friction they
#: carry, their stresses against height)
WALL_PAIRS = {"front_back": ("front", "back"), "sides": ("left", "right")}
#: the contact groups of the container (every wall but the gate): one mesh wall each with silo.walls = "mesh"
CONTAINER_GROUPS = ("front_back", "sides", "bottom")


class SiloGeometry:
    """Derived dimensions of the silo (m): width W, depth L, slot b, hopper angle a (rad), lip,
    centre xc, hopper top y_h (0 for a flat bottom), fill lattice, side-wall height H, removal
    depth."""

    def __init__(self, silo: dict, d: float, seed: int = 12345, clump: str = "none", density: float = 2550.0,
                 spheres=()):
        self.seed = seed
        # pellets (particles.clump): one pellet per lattice site, the lattice spaced for the
        # pellet's bounding diameter d_site = 2 max_m (|s_m| + r_m); spheres: d_site = d
        from ..particles.clumps import shape_from_case
        from ..particles.inlets import bounding_diameter

        self.shape = shape_from_case(clump, d, density, spheres)
        self.d_site = d if self.shape is None else bounding_diameter(self.shape)
        self.W = silo["width"]
        self.L = silo["depth"]
        self.b = silo["outlet_width"]
        self.angle = math.radians(silo["hopper_angle_deg"])
        self.d = d
        self.lip = silo["lip"] or d
        self.xc = 0.5 * self.W
        self.y_h = 0.5 * (self.W - self.b) * math.tan(self.angle) if self.angle > 0 else 0.0
        # top of the region where an arch over the outlet is looked for: 2 d (flat); in a hopper up
        # to where it is 4 d wider than the slot, 2 d (1 + tan a) (an arch spans the converging walls)
        self.y_arch = 2.0 * d * (1.0 + (math.tan(self.angle) if self.angle > 0 else 0.0))
        self.internals = Internals.from_silo(silo, d, self.d_site)  # blender tube and insert, or None
        self.y_fill = max(self.y_h, self.internals.top if self.internals else self.y_h)  # the fill starts above them
        self.removal_depth = silo["removal_depth"] or (self.lip + 1.5 * d)
        self.lattice = fill_lattice(self.W, self.L, self.y_fill, self.d_site, silo["n_particles"], silo["lattice_gap"],
                                    silo["lattice_jitter"], seed)
        top = float(self.lattice[:, 1].max()) + 0.5 * self.d_site
        self.H = silo["height"] or (top + 2 * d)
        self.lattice_top = top
        self.pour = silo["fill"] == "pour"
        self.pour_y = silo["pour_height"] or (top - 0.5 * d)
        if self.pour:
            self.H = silo["height"] or max(top + 2 * d, self.pour_y + 2.5 * d)
        self.gap, self.jitter = silo["lattice_gap"], silo["lattice_jitter"]

    def pour_layer(self, k: int, n: int) -> np.ndarray:
        """Layer ``k`` of the pour: the first ``n`` sites of one lattice layer at y = pour_y
        (jitter seeded with (seed, k))."""
        clear = 0.5 * self.d_site * (1.0 + self.gap)
        per = self.layer_size()
        lay = fill_lattice(self.W, self.L, self.pour_y - clear, self.d_site, per, self.gap, self.jitter,
                           np.random.SeedSequence([self.seed, k]).generate_state(1)[0])
        return lay[:n]

    def orientations(self, k: int, n: int) -> np.ndarray:
        """Random uniform unit quaternions (n, 4) of the pellets of pour layer ``k`` (k = -1:
        the lattice fill), deterministic in (seed, k)."""
        from ..particles.inlets import random_quaternions

        return random_quaternions(np.random.default_rng([self.seed, 7919, k + 1]), n)

    def layer_size(self) -> int:
        r = 0.5 * self.d_site
        a = self.d_site * (1.0 + self.gap)
        clear = r * (1.0 + self.gap)
        nx = int(math.floor((self.W - 2 * clear) / a + 1e-9)) + 1
        nz = int(math.floor((self.L - 2 * clear) / a + 1e-9)) + 1
        return nx * nz

    @property
    def hopper(self) -> bool:
        return self.angle > 0


def fill_lattice(W: float, L: float, y0: float, d: float, n: int, gap: float, jitter: float,
                 seed: int) -> np.ndarray:
    """The first ``n`` sites (layer by layer, bottom up) of a cubic lattice of spacing
    a = d (1 + gap) filling x in [0, W], z in [0, L] with a clearance r (1 + gap) from the walls,
    the lowest layer at y0 + r (1 + gap); each site moved by a uniform random offset in
    [-jitter d/2, jitter d/2]^3 (seed ``seed``).  With jitter < gap no two spheres and no sphere
    and wall overlap."""
    r = 0.5 * d
    a = d * (1.0 + gap)
    clear = r * (1.0 + gap)
    nx = int(math.floor((W - 2 * clear) / a + 1e-9)) + 1
    nz = int(math.floor((L - 2 * clear) / a + 1e-9)) + 1
    if W - 2 * clear < 0 or L - 2 * clear < 0:
        raise CaseError("silo.depth", f"the silo ({W:g} x {L:g} m) is too small for one lattice site of d = {d:g} m")
    x = 0.5 * (W - (nx - 1) * a) + a * np.arange(nx)
    z = 0.5 * (L - (nz - 1) * a) + a * np.arange(nz)
    per = nx * nz
    layers = -(-n // per)
    y = y0 + clear + a * np.arange(layers)
    Y, Z, X = np.meshgrid(y, z, x, indexing="ij")
    pos = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)[:n]
    rng = np.random.default_rng(seed)
    pos = pos + rng.uniform(-0.5 * jitter * d, 0.5 * jitter * d, size=pos.shape)
    return pos


SILO_KEYS = {
    "width": _pos(0.15, "m", "inner width of the planar silo (x from 0 to width; y up, the outlet plane at y = 0)"),
    "depth": _pos(0.04, "m", "distance between the front (z = 0) and back (z = depth) walls"),
    "height": _nonneg(0.0, "m", "height of the side walls above the outlet plane (0: the top of the fill lattice + 2 d)"),
    "outlet_width": _pos(0.04, "m", "width b of the slot outlet (full depth), centred at x = width/2"),
    "hopper_angle_deg": _f(0.0, "deg", "hopper wall inclination measured from the HORIZONTAL (0: flat bottom; "
                           "60: walls at 60 deg to the horizontal, 30 deg from the vertical)", lo=0.0, hi=80.0),
    "lip": _nonneg(0.0, "m", "thickness of the bottom plate: vertical lip walls line the slot from y = -lip to 0 and "
                   "the gate closes it at y = -lip (0: one particle diameter)"),
    "walls": Key("str", "analytic", "-", "'analytic': the scene builds its container (front/back, side walls, bottom "
                 "plates or hopper planes, slot lips) from these keys; 'mesh': the container comes from the case's "
                 "[[geometry.walls]] type = 'mesh' walls (each with its own contact keys; [silo.front_back], "
                 "[silo.sides], [silo.bottom] are then refused) and the scene adds only the gate it opens.  Fill, "
                 "gate, removal, measurements and stop are the same.  The STL files of the analytic container: "
                 "python -m cfddem.scenes.silo CASE --write-stl DIR (docs/silo.md)", choices=("analytic", "mesh")),
    "removal_depth": _nonneg(0.0, "m", "particles whose centre falls below y = -removal_depth are removed as "
                             "discharged (0: lip + 1.5 d)"),
    "n_particles": Key("int", 2000, "-", "particles of the fill lattice", lo=1),
    "fill": Key("str", "lattice", "-", "'lattice': n_particles on a loose jittered lattice above the bottom, dropped "
                "and settled; 'pour': jittered lattice layers inserted at pour_height at the mass rate pour_rate "
                "until n_particles are in", choices=("lattice", "pour")),
    "pour_rate": _pos(0.5, "kg/s", "pour: mass rate of the pour (one lattice layer every layer mass / rate; a layer "
                      "that would overlap waits)"),
    "pour_height": _nonneg(0.0, "m", "pour: height of the inserted layers (0: the top of the lattice fill of the same "
                           "n_particles)"),
    "lattice_gap": _f(0.12, "-", "fill lattice spacing d (1 + lattice_gap)", lo=0.0, lo_open=True, hi=2.0),
    "lattice_jitter": _f(0.08, "-", "random displacement of each lattice site, up to +-jitter d / 2 per axis "
                         "(seeded by particles.seed; must be below lattice_gap)", lo=0.0, hi=2.0),
    "gate": Key("str", "settled", "-", "'time': the gate opens at gate_time; 'settled': at the first check at or "
                "after gate_time where the kinetic energy per particle is below settle_energy",
                choices=("time", "settled")),
    "gate_time": _nonneg(0.3, "s", "gate opening time ('time') or earliest opening time ('settled')"),
    "floor_drop": _nonneg(0.0, "m", "once the fill has settled (gate = 'settled'), lower the floor (the bottom "
                          "plates or hopper walls, the slot lips and the gate) by this much at floor_drop_speed, "
                          "with the case's friction on from then, and open the gate once the bed has settled again: "
                          "the bed slides down along the walls and mobilises their friction, as Janssen's analysis "
                          "assumes (at most d/2; 0: no drop)"),
    "floor_drop_speed": _pos(0.005, "m/s", "floor_drop: speed of the floor's descent"),
    "floor_drop_wait": _nonneg(0.1, "s", "floor_drop: the gate opens at the first settled check at least this long "
                               "after the floor has stopped"),
    "frictionless_fill": Key("bool", False, "-", "fill with zero sliding and rolling friction on every contact "
                             "(particles and walls), the case's friction from the gate opening on (a DEM stand-in "
                             "for a silo filled by hand in layers)"),
    "fill_friction": fill_friction("the gate opening"),
    "fill_rolling_friction": fill_rolling_friction("the gate opening"),
    "settle_energy": _pos(2e-9, "J", "kinetic energy per particle below which the fill counts as settled"),
    "settle_check_interval": _pos(0.01, "s", "interval of the settled / clogged / empty checks"),
    "clog_time": _pos(0.5, "s", "no outflow for this long while particles remain just above the slot: clogged "
                      "(the run stops); with none there: discharge ended (empty)"),
    "clog_speed": _nonneg(0.0, "m/s", "a clog also needs the particles over the outlet (centres within the slot's x "
                          "range widened by d on each side, below the arch height: 2 d, in a hopper 2 d (1 + tan a)) to be at rest: all slower than this (0: "
                          "not checked); while one moves faster the run keeps checking, so an arch that is still "
                          "collapsing is not reported as a clog"),
    "fit_range": Key("floats", [0.2, 0.8], "-", "mass flow rate: linear fit of discharged mass against time between "
                     "these fractions of the final discharged mass", length=2),
    "field_cell": _nonneg(0.0, "m", "cell size of the time-averaged x-y velocity field (0: 2 d)"),
    "field_interval": _pos(0.01, "s", "sampling interval of the velocity field during discharge"),
    "field_start": _nonneg(0.1, "s", "velocity field: start averaging this long after the gate opened"),
    "outlet_radii": Key("floats", [0.5, 1.0, 2.0], "-", "with gas: radii, in slot widths, of the half-discs around "
                        "the slot's centre (full depth, above the outlet plane) whose particles' air forces and weight "
                        "/measurements/silo/outlet records (docs/outputs.md)", lo=0.0),
    "channel_fraction": _f(0.1, "-", "flow-channel boundary: where the downward speed falls below this fraction "
                           "of the centreline speed", lo=0.0, lo_open=True, hi=1.0, hi_open=True),
    "depth_boundary": Key("str", "walls", "-", "'walls': front and back walls at z = 0 and z = depth "
                          "([silo.front_back]); 'periodic': no front and back walls, the depth is periodic over "
                          "z in [0, depth) (a slice of an infinitely deep silo; [silo.front_back] is then unused)",
                          choices=("walls", "periodic")),
    "profile_heights": Key("floats", [0.02, 0.04, 0.08, 0.12, 0.16], "m", "heights above the outlet of the "
                           "vertical-velocity profiles across the width, the kinematic-model fits (B) and the "
                           "centreline-velocity series (/measurements/silo/profiles; [] for none)", lo=0.0, lo_open=True),
    "profile_window": Key("floats", [0.5, 0.7], "s", "time window after the gate opening over which the "
                          "profiles' velocity field is averaged (sampled every settle_check_interval)", length=2,
                          lo=0.0),
    "profile_cell": _nonneg(0.0, "m", "cell size (x and y) of the profiles' time-averaged velocity fields, "
                            "depth-averaged and in the layer at the front wall (0: d)"),
    "stress_profile": Key("bool", False, "-", "at the gate opening (the end of the fill), coarse-grain the "
                          "vertical stress (cfddem.measure.coarse) and store its cross-section average against "
                          "height with Janssen's curve (/measurements/silo/stress)"),
    "stress_grid": Key("floats", [0.006, 0.004, 0.006], "m", "stress_profile: coarse-graining cell sizes along "
                       "x, y (vertical), z (the thesis's 6 x 4 x 6 mm grid, 4 mm taken vertical)", length=3,
                       lo=0.0, lo_open=True),
    "stress_width": _nonneg(0.0, "m", "stress_profile: standard deviation of the Gaussian kernel (0: 3 particle "
                            "radii, the thesis's)"),
    "bulk_friction": _f(0.37, "-", "stress_profile: bulk friction tan(phi) for Janssen's K = (1 - sin phi) / "
                        "(1 + sin phi); 0.37 is the 40 mm test cell's with the thesis's parameters (mu 0.35, mu_r 0.1); "
                        "the 95 mm Jenike cell gives 0.438 (cases/shear_thesis, two fills; docs/shear-cell.md)",
                        lo=0.0, lo_open=True),
    "front_back": wall_override("front and back walls"),
    "sides": wall_override("side walls"),
    "bottom": wall_override("bottom plates or hopper walls, and the slot lips"),
    "gate_wall": wall_override("gate"),
    **INTERNALS_KEYS,
}


def check_silo_case(r: dict) -> None:
    """Consistency of a silo case (:meth:`SiloScene.check`)."""
    s = r["silo"]
    d = max(r["particles"]["diameter"], r["particles"]["diameter_max"])
    if r["particles"]["diameter_max"]:
        raise CaseError("particles.diameter_max", "the silo fill lattice is monodisperse: leave it 0")
    if r["gravity"]["inclination_deg"] != 0.0:
        raise CaseError("gravity.inclination_deg", "the silo needs gravity along -y (inclination 0)")
    if r["frame"]["rpm"] != 0.0:
        raise CaseError("frame.rpm", "the silo runs in an inertial frame (0)")
    for key in FILL_KEYS:
        if s[key] >= 0.0 and s["frictionless_fill"]:
            raise CaseError(f"silo.{key}", "give either a fill friction or frictionless_fill = true, not both")
    check_fill_friction("silo", s)
    if s["floor_drop"] > 0.0:
        if s["gate"] != "settled":
            raise CaseError("silo.floor_drop", "needs silo.gate = 'settled' (the floor drops once the fill has "
                                               "settled, and the gate opens once it has settled again)")
        if s["walls"] == "mesh":
            raise CaseError("silo.floor_drop", "lowers the scene's analytic floor: not with silo.walls = 'mesh' "
                                               "(the floor is part of the meshes)")
        if s["floor_drop"] > 0.5 * d:
            raise CaseError("silo.floor_drop", f"{s['floor_drop']:g} m is more than half a particle diameter "
                                               f"({0.5 * d:g} m): the side walls reach only d below the floor")
    if not s["outlet_width"] < s["width"] - 2 * d:
        raise CaseError("silo.outlet_width", f"{s['outlet_width']:g} m leaves no bottom: must be below "
                                             f"silo.width - 2 d = {s['width'] - 2 * d:g} m")
    from ..particles.clumps import shape_from_case
    from ..particles.inlets import bounding_diameter

    shape = shape_from_case(r["particles"]["clump"], d, r["particles"]["density"], r["particles"]["clump_spheres"])
    d_site = d if shape is None else bounding_diameter(shape)
    if s["outlet_width"] <= d_site:
        key = {"none": "silo.outlet_width", "template": "particles.clump_spheres"}.get(r["particles"]["clump"],
                                                                                     "particles.clump")
        raise CaseError(key, f"one particle (bounding diameter {d_site:.4g} m) does not fit through the outlet "
                             f"(silo.outlet_width = {s['outlet_width']:g} m)")
    if s["depth"] < d_site * (1 + s["lattice_gap"]):
        raise CaseError("silo.depth", f"{s['depth']:g} m does not fit one particle (lattice site {d_site:g} m)")
    if not s["lattice_jitter"] < s["lattice_gap"]:
        raise CaseError("silo.lattice_jitter", f"{s['lattice_jitter']:g} must be below silo.lattice_gap = "
                                               f"{s['lattice_gap']:g} (otherwise lattice spheres could overlap)")
    fr = s["fit_range"]
    if len(fr) != 2 or not (0.0 <= fr[0] < fr[1] <= 1.0):
        raise CaseError("silo.fit_range", f"{fr!r}: needs two fractions 0 <= lo < hi <= 1")
    lip = s["lip"] or d
    if s["removal_depth"] and s["removal_depth"] < lip + 0.5 * d:
        raise CaseError("silo.removal_depth", f"{s['removal_depth']:g} m is above the gate and lips: must be at "
                                              f"least lip + d/2 = {lip + 0.5 * d:g} m")
    for grp in ("front_back", "sides", "bottom", "gate_wall"):
        check_contact_values(f"silo.{grp}", s[grp])
    if s["walls"] == "mesh":
        if not any(isinstance(w, dict) and w.get("type") == "mesh" for w in r["geometry"]["walls"]):
            raise CaseError("silo.walls", "'mesh' takes the silo's container from [[geometry.walls]] type = 'mesh' "
                                          "walls and this case has none (write the analytic one with python -m "
                                          "cfddem.scenes.silo CASE --write-stl DIR)")
        for grp in CONTAINER_GROUPS:
            given = [k for k, v in s[grp].items() if v is not None]
            if given:
                raise CaseError(f"silo.{grp}.{given[0]}", "with silo.walls = 'mesh' the container's contact keys "
                                                          "belong to its [[geometry.walls]] mesh walls")
    if s["depth_boundary"] == "periodic":
        if s["walls"] == "mesh":
            raise CaseError("silo.depth_boundary", "'periodic' replaces the front and back walls of the analytic "
                                                   "silo: not with silo.walls = 'mesh' (the meshes are the container)")
        if r["gas"]["enabled"]:
            raise CaseError("silo.depth_boundary", "'periodic' is not for a run with gas (the gas domain has "
                                                   "no-slip front and back walls)")
        need = 2.0 * (d + (r["particles"]["skin"] or 0.3 * d))
        if s["depth"] < need:
            raise CaseError("silo.depth", f"{s['depth']:g} m is too shallow for a periodic depth: the neighbour "
                                          f"search needs at least 2 (2 R + skin) = {need:.4g} m")
    hs = s["profile_heights"]
    if any(b <= a for a, b in zip(hs, hs[1:])):
        raise CaseError("silo.profile_heights", f"{hs!r}: give increasing heights")
    pw = s["profile_window"]
    if not pw[0] < pw[1]:
        raise CaseError("silo.profile_window", f"{pw!r}: needs start < end (s after the gate opening)")
    check_internals(r, d, d_site, s["height"] or None)
    if s["height"]:
        g = SiloGeometry(s, d, r["particles"]["seed"], r["particles"]["clump"], r["particles"]["density"],
                         r["particles"]["clump_spheres"])
        if s["fill"] == "pour" and s["height"] < g.pour_y + 0.5 * d:
            raise CaseError("silo.height", f"{s['height']:g} m is below the pour height ({g.pour_y:.4g} m)")
        if s["fill"] == "lattice" and s["height"] < g.lattice_top:
            raise CaseError("silo.height", f"{s['height']:g} m is below the top of the fill lattice "
                                           f"({g.lattice_top:.4g} m): raise it or set 0 (automatic)")


def silo_walls(case, container: bool | None = None, silo: dict | None = None):
    """The silo's :class:`~cfddem.scenes.common.WallSpec` list (params: the per-group overrides
    only; :func:`cfddem.scenes.common.wall_specs` fills in ``contact.particle_wall``).
    ``container``: include the container (every wall but the gate); default: unless
    ``silo.walls = "mesh"`` (then the case's mesh walls are the container and only the gate is
    the scene's).  ``silo``: the ``[silo]`` values to build from (default the case's; a scene
    built on the silo passes its derived ones)."""
    from .common import WallSpec

    s = case.resolved["silo"] if silo is None else silo
    if container is None:
        container = s["walls"] != "mesh"
    p = case.particles
    g = SiloGeometry(s, p.diameter, p.seed, p.clump, p.density, p.clump_spheres)
    d, W, L, b, H, xc = g.d, g.W, g.L, g.b, g.H, g.xc
    e = d  # extension past a seam
    ex = np.array([1.0, 0, 0])
    ey = np.array([0, 1.0, 0])
    ez = np.array([0, 0, 1.0])
    ybot = -g.removal_depth - e
    walls = []

    def add(name, point, normal, u, h1, h2):
        grp = s[WALL_GROUPS[name]]
        params = {k: float(v) for k, v in grp.items() if v is not None}
        walls.append(WallSpec(name, "rectangle", np.asarray(point, float), np.asarray(normal, float),
                              np.asarray(u, float), (float(h1), float(h2)), params))

    yc = 0.5 * (ybot + H + e)
    hy = 0.5 * (H + e - ybot)
    if s["depth_boundary"] != "periodic":  # periodic depth: no front and back walls
        add("front", (xc, yc, 0.0), ez, ex, 0.5 * W + e, hy)
        add("back", (xc, yc, L), -ez, ex, 0.5 * W + e, hy)
    ys = g.y_h - e
    add("left", (0.0, 0.5 * (ys + H), 0.5 * L), ex, ey, 0.5 * (H - ys), 0.5 * L + e)
    add("right", (W, 0.5 * (ys + H), 0.5 * L), -ex, ey, 0.5 * (H - ys), 0.5 * L + e)
    x_edge = xc - 0.5 * b  # left slot edge
    if not g.hopper:
        x0 = -e
        add("bottom_left", (0.5 * (x0 + x_edge), 0.0, 0.5 * L), ey, ex, 0.5 * (x_edge - x0), 0.5 * L + e)
        add("bottom_right", (W - 0.5 * (x0 + x_edge), 0.0, 0.5 * L), ey, ex, 0.5 * (x_edge - x0), 0.5 * L + e)
    else:
        a = g.angle
        run = x_edge + e * math.cos(a)  # to the side wall plus e along the plane
        length = run / math.cos(a)
        t_left = np.array([-math.cos(a), math.sin(a), 0.0])  # from the slot edge up to the left wall
        c_left = np.array([x_edge, 0.0, 0.5 * L]) + 0.5 * length * t_left
        add("hopper_left", c_left, (math.sin(a), math.cos(a), 0.0), t_left, 0.5 * length, 0.5 * L + e)
        t_right = np.array([math.cos(a), math.sin(a), 0.0])
        c_right = np.array([W - x_edge, 0.0, 0.5 * L]) + 0.5 * length * t_right
        add("hopper_right", c_right, (-math.sin(a), math.cos(a), 0.0), t_right, 0.5 * length, 0.5 * L + e)
    add("lip_left", (x_edge, -0.5 * g.lip, 0.5 * L), ex, ey, 0.5 * g.lip, 0.5 * L + e)
    add("lip_right", (W - x_edge, -0.5 * g.lip, 0.5 * L), -ex, ey, 0.5 * g.lip, 0.5 * L + e)
    add("gate", (xc, -g.lip, 0.5 * L), ey, ex, 0.5 * b + e, 0.5 * L + e)
    for face in (g.internals.rectangles(L, e) if g.internals else ()):
        add(*face)
    return walls if container else [w for w in walls if WALL_GROUPS[w.name] not in CONTAINER_GROUPS]


def container_meshes(case, max_edge: float = 0.0) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The analytic container of the silo (:func:`silo_walls` with ``container=True``, all but
    the gate) as triangle meshes, one per contact group (:data:`CONTAINER_GROUPS`):
    ``{group: (vertices (nv, 3) in m, triangles (nt, 3))}``.  Each rectangle, with its extension
    past the seams, becomes two triangles (or, with ``max_edge`` > 0 m, a grid of cells no longer
    than ``max_edge`` on a side, two triangles each: :func:`~cfddem.particles.mesh.grid_surface`)
    whose normal is the rectangle's; rectangles of one group meet only where the analytic ones
    do (the slot edge, where a hopper or bottom plate meets its lip: one shared edge in the mesh)."""
    from ..particles.mesh import grid_surface

    parts: dict[str, list] = {g: [] for g in CONTAINER_GROUPS}
    for w in silo_walls(case, container=True):
        grp = WALL_GROUPS[w.name]
        if grp not in parts:
            continue
        c = w.corners()  # c - a u - b v, c + a u - b v, c + a u + b v, c - a u + b v: (u x v) = normal
        a, b = w.half_extents
        nu, nv = ((max(1, math.ceil(2 * a / max_edge - 1e-9)), max(1, math.ceil(2 * b / max_edge - 1e-9)))
                  if max_edge > 0 else (1, 1))
        parts[grp].append(grid_surface(c[0], c[1] - c[0], c[3] - c[0], nu, nv))
    out = {}
    for grp, lst in parts.items():
        if not lst:  # (front_back with a periodic depth)
            continue
        offs = np.cumsum([0] + [len(V) for V, _ in lst])
        out[grp] = (np.concatenate([V for V, _ in lst]), np.concatenate([F + o for (_, F), o in zip(lst, offs)]))
    return out


def write_container_stl(case, out_dir, units: str = "mm", max_edge: float = 0.0) -> dict:
    """Write :func:`container_meshes` as ASCII STL files ``<group>.stl`` in ``out_dir`` (lengths
    in ``units``, one of :data:`cfddem.particles.mesh.UNITS`; ASCII so that the coordinates keep
    all their digits: binary STL holds 32-bit floats) with meshio.  Returns ``{group: path}``."""
    from pathlib import Path

    import meshio

    from ..particles.mesh import UNITS

    if units not in UNITS:
        raise CaseError("--units", f"unknown unit {units!r} (one of {', '.join(UNITS)})")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {}
    for grp, (V, F) in container_meshes(case, max_edge).items():
        p = out / f"{grp}.stl"
        meshio.write(p, meshio.Mesh(V / UNITS[units], [("triangle", F)]), file_format="stl", binary=False)
        paths[grp] = p
    return paths


def container_walls_toml(case, paths: dict, units: str) -> str:
    """The ``[[geometry.walls]]`` tables of the files :func:`write_container_stl` wrote, each
    with its group's contact keys from ``[silo.<group>]`` (the keys set in the case)."""
    s = case.resolved["silo"]
    out = []
    for grp, p in paths.items():
        out += ["[[geometry.walls]]", f'name = "{grp}"', 'type = "mesh"', f'file = "{p.name}"', f'units = "{units}"']
        out += [f"{k} = {v!r}" for k, v in s[grp].items() if v is not None]
        out.append("")
    return "\n".join(out)


def load_silo_case(path, overrides=()):
    """A silo case with command-line overrides (``KEY=VALUE``), or a one-line CaseError."""
    from ..config import load_case

    case = load_case(path, overrides=list(overrides))
    if case.geometry.type != "silo":
        raise CaseError("geometry.type", f"{case.geometry.type!r}: needs a silo case")
    return case


def main(argv=None) -> int:
    """``python -m cfddem.scenes.silo CASE --write-stl DIR [--units mm] [--max-edge M] [--set K=V]...``:
    write the analytic container of a silo case as STL files (one per contact group) and print
    the ``[[geometry.walls]]`` tables of a ``silo.walls = "mesh"`` case that uses them."""
    import argparse
    import sys

    from ..particles.mesh import UNITS

    ap = argparse.ArgumentParser(prog="python -m cfddem.scenes.silo",
                                 description="write the silo's analytic container walls as STL files")
    ap.add_argument("case", help="a silo case (its folder or case.toml)")
    ap.add_argument("--write-stl", metavar="DIR", required=True, help="folder for <group>.stl")
    ap.add_argument("--units", default="mm", choices=tuple(UNITS), help="length unit in the files (default mm)")
    ap.add_argument("--max-edge", type=float, default=0.0, metavar="M",
                    help="split each rectangle into cells no longer than M metres (default 0: two triangles)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args(argv)
    try:
        case = load_silo_case(args.case, args.overrides)
        paths = write_container_stl(case, args.write_stl, args.units, args.max_edge)
    except CaseError as e:
        print(f"cfddem: error: {e}", file=sys.stderr)
        return 2
    for grp, (V, F) in container_meshes(case, args.max_edge).items():
        print(f"# wrote {paths[grp]} ({len(F)} triangles, {args.units})")
    print(container_walls_toml(case, paths, args.units))
    return 0


def mesh_cover_line(case) -> str:
    """The ``cfddem check`` line of a ``silo.walls = "mesh"`` case: whether the union of its fixed
    mesh walls' bounds covers the silo's box x 0..width, y -lip..H (the side-wall height), z
    0..depth (within 1e-9 of its diagonal).  Bounds only: that says nothing about holes."""
    from .common import mesh_box, wall_specs

    s = case.resolved["silo"]
    p = case.particles
    g = SiloGeometry(s, p.diameter, p.seed, p.clump, p.density, p.clump_spheres)
    box = np.array([[0.0, -g.lip, 0.0], [g.W, g.H, g.L]])
    names, boxes = [], []
    for w in wall_specs(case):
        if w.kind == "mesh":
            names.append(w.name)
            b = mesh_box(w)
            boxes.append(np.array([np.full(3, -np.inf), np.full(3, np.inf)]) if b is None else b)
    lo = np.min([b[0] for b in boxes], axis=0)
    hi = np.max([b[1] for b in boxes], axis=0)

    def fmt(v):
        return "[" + ", ".join(f"{x:.4g}" for x in v) + "]"

    tol = 1e-9 * float(np.linalg.norm(box[1] - box[0]))
    short = [f"{'xyz'[a]} {'from' if k == 0 else 'to'} {(lo if k == 0 else hi)[a]:.4g} m, not "
             f"{box[k, a]:.4g} m" for k in (0, 1) for a in range(3)
             if (lo[a] > box[0, a] + tol if k == 0 else hi[a] < box[1, a] - tol)]
    head = (f"silo walls: the meshes {', '.join(names)} and the scene's gate; mesh bounds {fmt(lo)} .. {fmt(hi)} m ")
    if not short:
        return head + f"cover the silo's box {fmt(box[0])} .. {fmt(box[1])} m"
    return head + (f"WARNING: do not cover the silo's box {fmt(box[0])} .. {fmt(box[1])} m ({'; '.join(short)}): "
                   "particles can leave the container")


class SiloScene(Scene):
    """Fill, gate, discharge, measurements and the stop condition of a silo run (module doc)."""

    DOC = "'silo': the planar silo of [silo]"
    EXAMPLE = "silo_flat"
    SCHEMA = {"silo": SILO_KEYS}
    HAS_GAS = True
    locks_rotation_after_fill = True  # at the gate opening

    @classmethod
    def check(cls, r: dict, case_dir) -> None:
        check_silo_case(r)
        if r["gas"]["enabled"] and r["silo"]["hopper_angle_deg"] > 0:
            raise CaseError("gas.enabled", "the silo's gas domain is a box whose bottom is the outlet plane: it "
                                           "needs a flat-bottom silo (silo.hopper_angle_deg = 0)")

    @classmethod
    def speed_scale(cls, case) -> float:
        """A particle falling freely from the top of the side walls to the removal plane."""
        s = case.resolved["silo"]
        p = case.particles
        g = SiloGeometry(s, p.diameter, p.seed, p.clump, p.density, p.clump_spheres)
        return math.sqrt(2.0 * case.gravity.g * (g.H + g.removal_depth))

    @classmethod
    def gas_domain(cls, case):
        """The air in the silo: x in [0, width], y in [0, H] (H the side-wall height), z in
        [0, depth] on ``gas.cells``; no-slip side, front and back walls; the open top a pressure
        outlet at p = 0 (gauge); the bottom (the outlet plane y = 0) patched: no-slip plates
        with a pressure outlet over the slot (the face cells whose centres lie within the slot)
        at the hydrostatic p = rho g H of air at rest, the particle rule "leave" (a particle
        below the outlet plane has left the gas: no volume, drag or pressure force).  The gas
        starts at rest with the hydrostatic pressure ``rho g (H - y)``."""
        from ..gas import NoSlip, Patched, PressureOutlet, StaggeredGrid
        from ..gas.domain import GasDomain
        from .common import gravity_vector

        s = case.resolved["silo"]
        p = case.particles
        geo = SiloGeometry(s, p.diameter, p.seed, p.clump, p.density, p.clump_spheres)
        nx, ny, nz = (int(v) for v in case.gas.cells)
        grid = StaggeredGrid((nx, ny, nz), (geo.W, geo.H, geo.L), (0.0, 0.0, 0.0), halo=2)
        g = np.asarray(gravity_vector(case), float)
        rho = float(case.gas.density)
        H = geo.H
        x0, x1 = geo.xc - 0.5 * geo.b, geo.xc + 0.5 * geo.b
        slot = ((x0, -math.inf, -math.inf), (x1, math.inf, math.inf))
        bottom = Patched(default=NoSlip(), patches=[(slot, PressureOutlet(p=rho * g[1] * (0.0 - H)))],
                         particle_rule="leave")
        top = PressureOutlet(p=0.0)
        bcs = {"x-": NoSlip(), "x+": NoSlip(), "y-": bottom, "y+": top, "z-": NoSlip(), "z+": NoSlip()}
        xc = grid.centres(0)
        inside = (xc >= x0) & (xc <= x1)
        n_in = int(inside.sum())
        if n_in == 0:
            raise CaseError("gas.cells", f"no gas cell centre lies in the slot (x {x0:.4g}..{x1:.4g} m) with "
                                         f"{nx} cells across {geo.W:g} m: use more cells across (gas.cells[0])")
        dx = grid.spacing[0]
        return GasDomain(
            grid=grid, bcs=bcs, gravity=tuple(g),
            velocity=lambda x, y, z: (0.0 * x, 0.0 * x, 0.0 * x),
            pressure=lambda x, y, z: rho * g[1] * (y - H) + 0.0 * x,
            speed_scale=cls.speed_scale(case),
            notes=[f"silo air: box {geo.W:g} x {H:.4g} x {geo.L:g} m; open top p = 0, slot outlet p = "
                   f"{rho * -g[1] * H:.3g} Pa over {n_in} cells across (x {xc[inside][0] - 0.5 * dx:.4g}..."
                   f"{xc[inside][-1] + 0.5 * dx:.4g} m; the slot is {x0:.4g}...{x1:.4g} m), no-slip plates and walls; "
                   "particles below the outlet plane take no part in the exchange"])

    @classmethod
    def wall_specs(cls, case) -> list:
        return silo_walls(case)

    @classmethod
    def periodic(cls, case) -> tuple:
        """``silo.depth_boundary = "periodic"``: z periodic over [0, depth)."""
        s = case.resolved["silo"]
        return (None, None, (0.0, float(s["depth"]))) if s["depth_boundary"] == "periodic" else (None, None, None)

    @classmethod
    def describe(cls, case) -> list[str]:
        """With ``silo.walls = "mesh"``: whether the mesh walls' bounds cover the silo's box; the
        blender's internals and fill (:func:`~cfddem.scenes.silo_internals.describe_fill`)."""
        from .silo_internals import describe_fill

        s = case.resolved["silo"]
        per = ([f"silo depth: periodic along z over 0..{s['depth']:g} m, no front and back walls"
                + (" ([silo.front_back] is set but unused)" if any(v is not None for v in s["front_back"].values())
                   else "")] if s["depth_boundary"] == "periodic" else [])
        return ([mesh_cover_line(case)] if s["walls"] == "mesh" else []) + per + describe_fill(case)

    @classmethod
    def has_particles(cls, case) -> bool:
        return True

    @classmethod
    def expected_particles(cls, case) -> int:
        from ..particles.clumps import spheres_per_body

        return spheres_per_body(case.particles.clump, case.particles.clump_spheres) * case.silo.n_particles

    @classmethod
    def inserts_clumps(cls, r: dict) -> bool:
        return True

    @classmethod
    def plots(cls, results_h5, out_dir) -> list:
        """The discharge curve with its fitted flow rate and the time-averaged velocity field
        with the flow-channel boundary (:func:`cfddem.silo_study.write_silo_plots`)."""
        from ..io.results import read_measurements
        from ..silo_study import write_silo_plots

        names = ("silo_discharge.png", "silo_field.png")
        if "silo" not in read_measurements(results_h5):
            return [(n, None, "no silo measurements in this run") for n in names]
        paths = {p.name: p for p in write_silo_plots(results_h5, out_dir)}
        return [(n, paths.get(n), "" if n in paths else "no velocity sample (the gate never opened)")
                for n in names]

    def __init__(self, sim):
        super().__init__(sim)
        s = self.case.resolved["silo"]
        self.s = s
        p = self.case.particles
        self.g = SiloGeometry(s, p.diameter, p.seed, p.clump, p.density, p.clump_spheres)
        self.check_dt = s["settle_check_interval"]
        self.k_check = 1
        self.gate_open_time = math.nan
        self.last_out_time = math.nan
        # the system's sink counters (particles, clumps) at the last look (after_steps)
        self._sunk_seen = (0, 0)  # (the system is made after the scene, with both at 0)
        self.rec_t: list[float] = []
        self.rec_m: list[float] = []
        self.fill = {"bulk_density": math.nan, "fill_height": math.nan, "n_particles": 0,
                     "n_in_box": 0, "box_lo": np.full(3, np.nan), "box_hi": np.full(3, np.nan),
                     "kinetic_energy_per_particle": math.nan}
        self.clogged = False
        self.ended = ""
        cell = s["field_cell"] or 2 * self.g.d
        self.field = VelocityField(0.0, self.g.W, -self.g.lip, self.g.H, cell)
        # the chapter-5 profiles: fields over profile_window (depth average, front-wall layer) and
        # the centreline series at profile_heights
        self.heights = np.asarray(s["profile_heights"], float)
        pcell = s["profile_cell"] or self.g.d
        self.win_all = VelocityField(0.0, self.g.W, -self.g.lip, self.g.H, pcell)
        self.win_front = VelocityField(0.0, self.g.W, -self.g.lip, self.g.H, pcell)
        self.cl_t: list[float] = []
        self.cl_v: list[np.ndarray] = []
        self.stress: dict = {}
        self.wall_load: dict = {}  # the walls' share of the weight at the end of the fill (_wall_load)
        # silo.floor_drop: phase 0 (not yet), 1 (the floor moving down), 2 (stopped at drop_done);
        # drop_y0: the gate's height when it started
        self.drop_phase = 0
        self.drop_start = self.drop_end = self.drop_done = self.drop_y0 = math.nan
        self.outlet = None
        if self.case.gas.enabled:
            from ..measure.outlet_budget import OutletBudget

            self.outlet = OutletBudget(self.g.xc, np.asarray(s["outlet_radii"], float) * self.g.b,
                                       self.case.gravity.g, air=self._air_flows)
        self.probe = (ChannelProbe(self.g.internals, self.g.xc, 0.0, self.g.W, -self.g.lip, self.g.H, cell,
                                   s["fit_range"], s["centreline_heights"])
                      if self.g.internals else None)
        self.k_field = 0
        self.n_inserted = 0  # lattice sites filled (spheres, or pellets with particles.clump)
        self.spheres_inserted = 0  # spheres inserted (pellets: their member spheres)
        self.bodies_out = 0  # pellets discharged (removed whole)
        self.layers_done = 0
        d = self.g.d
        # mass of one site's particle: a sphere, or a pellet (its union-of-spheres mass)
        self.m_p = (self.case.particles.density * math.pi / 6.0 * d ** 3 if self.g.shape is None
                    else self.g.shape.mass)
        self.pour_interval = self.g.layer_size() * self.m_p / s["pour_rate"] if self.g.pour else math.inf

    # ------------------------------------------------------------------ hooks
    def exit_plane(self):
        """Below y = -removal_depth: the particles leave at the engine's next neighbour rebuild
        (within ~2 ms of flow; ParticleSystem.set_sink), instead of forcing a rebuild of their own."""
        return (float(self.g.xc), -float(self.g.removal_depth), 0.0), (0.0, -1.0, 0.0)

    def start(self) -> None:
        d = self.g.d
        self._fill_friction()
        self._wire_outlet()
        if self.g.pour:
            self._pour(0.0)
            what = (f"pour of {self.s['n_particles']} particles at {self.s['pour_rate']:g} kg/s (a layer of "
                    f"{self.g.layer_size()} every {self.pour_interval:.4g} s) at y = {self.g.pour_y:.4g} m")
        else:
            pos = self.g.lattice
            self._insert(pos, -1)
            what = (f"{len(pos)} {'particles' if self.g.shape is None else self.g.shape.name + ' pellets'} on a "
                    f"lattice up to y = {self.g.lattice_top:.4g} m")
        drop = (f"; once settled the floor drops {1e3 * self.s['floor_drop']:.4g} mm at "
                f"{1e3 * self.s['floor_drop_speed']:.4g} mm/s and the gate opens when the bed has settled again"
                if self.s["floor_drop"] > 0.0 else "")
        self.sim.log.info("silo: %s (side walls to %.4g m), gate %s%s", what, self.g.H,
                          f"opens at {self.s['gate_time']:g} s" if self.s["gate"] == "time" else
                          f"opens when settled (kinetic energy per particle < {self.s['settle_energy']:g} J) "
                          f"from {self.s['gate_time']:g} s", drop)

    def _wire_outlet(self) -> None:
        """With gas: the coupling hands every gas step's per-particle forces to the outlet budget."""
        if self.outlet is not None and self.sim.gas is not None:
            self.sim.gas.force_sink = self.outlet

    def _air_flows(self) -> tuple[float, float, float]:
        """The air's volume flows (m^3/s, up positive) through the outlet plane and the open top,
        eps_f v A summed over the faces with the face porosity of the porous continuity equation
        (:func:`cfddem.gas.operators.porous_divergence_at`), and the air volume sum(eps V)."""
        gs = self.sim.gas.gas
        grid, h = gs.grid, gs.grid.halo
        nx, ny, nz = grid.shape
        v, e = gs.v.data, gs.eps.data
        dx, _, dz = grid.spacing
        xs, zs = slice(h, h + nx), slice(h, h + nz)

        def q(j):  # the y-face between cells j - 1 and j (array indices)
            return float(np.sum(0.5 * (e[xs, j - 1, zs] + e[xs, j, zs]) * v[xs, j, zs])) * dx * dz

        return q(h), q(h + ny), float(np.sum(e[xs, h:h + ny, zs])) * grid.cell_volume

    def _fill_friction(self) -> None:
        """The fill's friction: none (``frictionless_fill``) or ``fill_friction`` /
        ``fill_rolling_friction`` between particles."""
        if self.s["frictionless_fill"]:
            self.sim.system.set_friction(False)
        else:
            apply_fill_friction(self.sim.system, self.s)

    def _pour(self, t: float) -> None:
        """Insert the pour layers that are due (each only if it overlaps nothing)."""
        n = self.s["n_particles"]
        sys_ = self.sim.system
        half = 0.5 * self.sim.dt
        while self.n_inserted < n and t >= self.layers_done * self.pour_interval - half:
            lay = self.g.pour_layer(self.layers_done, min(self.g.layer_size(), n - self.n_inserted))
            if sys_.n and sys_.overlaps(lay, 0.5 * self.g.d_site).any():
                return  # wait: retried at the next check
            self._insert(lay, self.layers_done)
            self.layers_done += 1

    def _insert(self, pos, k: int) -> None:
        """One sphere, or one pellet (random orientation seeded with (seed, k)), at rest per site."""
        sys_ = self.sim.system
        n0 = sys_.n
        if self.g.shape is None:
            sys_.add_particles(pos, np.zeros(3), 0.5 * self.g.d, self.case.particles.density)
        else:
            sys_.add_clumps(self.g.shape, pos, quat=self.g.orientations(k, len(pos)))
        self.n_inserted += len(pos)
        self.spheres_inserted += sys_.n - n0

    def _bodies(self) -> int:
        c = self.sim.system.clumps
        return 0 if c is None else int(c.nb)

    @property
    def pouring(self) -> bool:
        return self.g.pour and self.n_inserted < self.s["n_particles"]

    @property
    def gate_open(self) -> bool:
        return math.isfinite(self.gate_open_time)

    def next_time(self, t: float) -> float:
        nt = self.k_check * self.check_dt
        if self.pouring:
            due = self.layers_done * self.pour_interval
            if due > t + 0.5 * self.sim.dt:  # (a layer that waits is retried at the next check)
                nt = min(nt, due)
        if self.gate_open:
            nt = min(nt, self._next_field_time())
        if self.drop_phase == 1:
            nt = min(nt, self.drop_end)  # the floor stops at its depth, to the step
        return nt

    def _next_field_time(self) -> float:
        return self.gate_open_time + self.s["field_start"] + self.k_field * self.s["field_interval"]

    def after_steps(self) -> None:
        sim = self.sim
        sys_ = sim.system
        t = sys_.time
        half = 0.5 * sim.dt
        if self.pouring:
            self._pour(t)
        # the particles below the removal depth left through the exit plane (exit_plane: the
        # engine's sink, at its next rebuild; the simulation counts them in count_out/mass_out)
        if sys_.sunk_total != self._sunk_seen[0]:
            self.bodies_out += sys_.sunk_bodies - self._sunk_seen[1]
            self._sunk_seen = (sys_.sunk_total, sys_.sunk_bodies)
            self.last_out_time = t
        if self.gate_open and not self.ended and t >= self._next_field_time() - half:
            if sys_.n:
                self.field.sample(sys_.pos, sys_.vel)
                if self.probe:
                    self.probe.sample(t, sys_.pos, sys_.vel, sim.counters["mass_out"])
            if self.outlet is not None:
                self.outlet.sample(sys_.pos, sys_.mass)
                self.outlet.close_block(t)
            while self._next_field_time() <= t + half:
                self.k_field += 1
        if self.drop_phase == 1 and t >= self.drop_end - half:
            self._stop_drop(t)
        if t < self.k_check * self.check_dt - half:
            return
        while self.k_check * self.check_dt <= t + half:
            self.k_check += 1
        if not self.gate_open:
            n = max(sys_.n, 1)
            ke = sys_.kinetic_energy() / n
            due = t >= self.s["gate_time"] - half
            settled = ke < self.s["settle_energy"] and not self.pouring
            if self.s["floor_drop"] > 0.0:
                if self.drop_phase == 0 and due and settled:
                    self._start_drop(t, ke)
                if self.drop_phase != 2:
                    return
                due = due and t >= self.drop_done + self.s["floor_drop_wait"] - half
            if due and (self.s["gate"] == "time" or settled):
                self._open_gate(t, ke)
            return
        self.rec_t.append(t)
        self.rec_m.append(sim.counters["mass_out"])
        self._sample_profiles(t)
        if self.ended:
            return
        if sys_.n == 0:
            self.ended = f"silo empty at t = {t:.4g} s"
            return
        since = self.last_out_time if math.isfinite(self.last_out_time) else self.gate_open_time
        if t - since >= self.s["clog_time"] - half:
            pos = sys_.pos
            above = (np.abs(pos[:, 0] - self.g.xc) < 0.5 * self.g.b) & (pos[:, 1] < self.g.y_arch)
            if above.any():
                arch = (np.abs(pos[:, 0] - self.g.xc) < 0.5 * self.g.b + self.g.d) & (pos[:, 1] < self.g.y_arch)
                v_arch = float(np.sqrt((sys_.vel[arch] ** 2).sum(axis=1)).max())
                if v_arch >= self.s["clog_speed"] > 0.0:
                    return  # the particles over the outlet still move: not (yet) a clog
                self.clogged = True
                self.ended = (f"CLOGGED: no outflow for {t - since:.3g} s (since t = {since:.4g} s) with "
                              f"{int(above.sum())} particle(s) arched over the outlet (fastest of those over it "
                              f"{v_arch:.2g} m/s); {sys_.n} remain in the silo")
                sim.log.warning("silo %s", self.ended)
            else:
                self.ended = (f"discharge ended: no outflow for {t - since:.3g} s (since t = {since:.4g} s) and "
                              f"no particle over the outlet; {sys_.n} remain in stagnant zones")
                sim.log.info("silo %s", self.ended)

    def _sample_profiles(self, t: float) -> None:
        """At a check after the gate opening: the centreline series at the profile heights and,
        inside profile_window, the two window fields (all particles; centres within d of the
        front wall, z < d)."""
        if not len(self.heights):
            return
        sys_ = self.sim.system
        d = self.g.d
        since = t - self.gate_open_time
        self.cl_t.append(since)
        self.cl_v.append(centreline_velocity(sys_.pos, sys_.vel, self.g.xc, self.heights, d, d) if sys_.n
                         else np.full(len(self.heights), np.nan))
        lo, hi = self.s["profile_window"]
        half = 0.5 * self.sim.dt
        if sys_.n and lo - half <= since <= hi + half:
            self.win_all.sample(sys_.pos, sys_.vel)
            front = sys_.pos[:, 2] < d
            self.win_front.sample(sys_.pos[front], sys_.vel[front])

    def _stress_profile(self) -> dict:
        """The vertical stress at the end of the fill: coarse-grained (:func:`cfddem.measure.coarse.
        coarse_grain`, Gaussian of ``stress_width``, cells ``stress_grid``, the grid the bodies'
        extent widened by the kernel's cutoff), averaged over the cross-section against the
        height above the floor y = 0 (:func:`~cfddem.measure.coarse.vertical_profile`), with
        Janssen's curve for the side walls' and front/back walls' friction (0 with a periodic
        depth) and K from ``bulk_friction``."""
        from ..measure.coarse import (coarse_grain, default_grid, janssen, janssen_length, lateral_pressure_ratio,
                                      vertical_profile)

        sys_ = self.sim.system
        s = self.s
        width = s["stress_width"] or 1.5 * self.g.d
        lo, hi = default_grid(sys_, width, 3.0)
        f = coarse_grain(sys_, lo, hi, np.asarray(s["stress_grid"], float), width, cutoff=3.0,
                         solid_density=self.case.particles.density)
        prof = vertical_profile(f, sys_, 1, 1.0, base=0.0)
        pw = self.case.resolved["contact"]["particle_wall"]
        mu_side = s["sides"]["mu"] if s["sides"]["mu"] is not None else pw["mu"]
        mu_front = 0.0 if s["depth_boundary"] == "periodic" else (
            s["front_back"]["mu"] if s["front_back"]["mu"] is not None else pw["mu"])
        K = lateral_pressure_ratio(s["bulk_friction"])
        g = self.case.gravity.g
        W, T, H = prof["W"], prof["T"], prof["H"]
        zc = janssen_length(W, T, K, mu_side, mu_front)
        y = prof["height"]
        gamma = prof["rho_b"] * g
        hydro = np.where(y < 0.0, np.nan, janssen(y, H, gamma, W, T, K, 0.0, 0.0))  # frictionless walls
        jz = np.where(y < 0.0, np.nan, janssen(y, H, gamma, W, T, K, mu_side, mu_front))
        px, pz = prof["lateral"]
        with np.errstate(invalid="ignore", divide="ignore"):
            kx = np.where(prof["pressure"] > 0, px / prof["pressure"], np.nan)
            kz = np.where(prof["pressure"] > 0, pz / prof["pressure"], np.nan)
        return {"y": y, "pressure": prof["pressure"], "density": prof["density"], "janssen": jz, "hydrostatic": hydro,
                "pressure_x": px, "pressure_z": pz, "K_x": kx, "K_z": kz,
                "rho_b": prof["rho_b"], "H": H, "W": W, "T": T, "K": K, "z_c": zc, "mu_side": float(mu_side),
                "mu_front": float(mu_front), "bulk_friction": s["bulk_friction"], "width": width,
                "spacing": f.spacing, "time": f.time}

    STRESS_ATTRS = {
        "pressure": "vertical pressure -sigma_yy (Pa, compression positive), integral over the horizontal cells "
                    "/ (W T), at the gate opening",
        "y": "cell-centre height above the floor y = 0 (m); janssen and hydrostatic NaN below it",
        "pressure_x": "-sigma_xx (Pa), the same average (against the side walls); pressure_z: -sigma_zz (against the "
                      "front and back walls); K_x, K_z: their ratios to the vertical pressure (the lateral pressure "
                      "ratios Janssen's K stands for)",
        "janssen": "gamma z_c (1 - exp(-(H - y) / z_c)), gamma = rho_b g, z_c = W T / (2 K (mu_side T + mu_front W)), "
                   "K = (1 - sin phi) / (1 + sin phi), tan phi = bulk_friction; H = M / (rho_b W T)"}

    def _end_fill_friction(self) -> None:
        """The case's friction from now on, where the fill had its own (``frictionless_fill``,
        ``fill_friction``, ``fill_rolling_friction``)."""
        if self.s["frictionless_fill"] or fill_friction_set(self.s):
            self.sim.system.set_friction(True)

    def _floor_walls(self) -> list[str]:
        have = set(self.sim.system.wall_labels())
        return [w for w in FLOOR_WALLS if w in have]

    def _start_drop(self, t: float, ke: float) -> None:
        """silo.floor_drop: the settled fill's floor starts to move down; the case's friction
        from now on (a fill friction or a frictionless fill ends here, so that the drop
        mobilises the friction the stress is compared with)."""
        sys_ = self.sim.system
        v, depth = self.s["floor_drop_speed"], self.s["floor_drop"]
        self._end_fill_friction()
        self.drop_y0 = float(sys_.wall_position("gate")[1])
        for w in self._floor_walls():
            sys_.set_wall_velocity(w, (0.0, -v, 0.0))
        self.drop_phase = 1
        self.drop_start = t
        self.drop_end = t + depth / v
        self.sim.log.info("silo: the fill has settled at t = %.4g s (kinetic energy per particle %.3g J): the floor "
                          "drops %.4g mm at %.4g mm/s, until t = %.4g s", t, ke, 1e3 * depth, 1e3 * v, self.drop_end)

    def _stop_drop(self, t: float) -> None:
        """The floor stops at the drop's depth (its last step's rounding put back)."""
        sys_ = self.sim.system
        walls = self._floor_walls()
        for w in walls:
            sys_.set_wall_velocity(w, (0.0, 0.0, 0.0))
        rest = self.s["floor_drop"] - (self.drop_y0 - float(sys_.wall_position("gate")[1]))
        if rest != 0.0:
            for w in walls:
                sys_.move_wall(w, (0.0, -rest, 0.0))
        self.drop_phase = 2
        self.drop_done = t
        self.sim.log.info("silo: the floor stopped at t = %.4g s, %.4g mm lower; the gate opens at the first "
                          "settled check from t = %.4g s", t, 1e3 * self.s["floor_drop"],
                          max(self.s["gate_time"], t + self.s["floor_drop_wait"]))

    def _open_gate(self, t: float, ke: float) -> None:
        sys_ = self.sim.system
        d = self.g.d
        self.fill_measure(sys_.pos, sys_.mass)
        if self.s["stress_profile"]:
            self.stress = self._stress_profile()
            st = self.stress
            y15 = 0.15 * st["H"]
            self.sim.log.info("silo: vertical stress at the end of the fill, 0.15 H = %.4g m above the floor: %.4g Pa "
                              "(Janssen %.4g Pa, z_c = %.4g m, K = %.3g)", y15, float(np.interp(y15, st["y"],
                                                                                                st["pressure"])),
                              float(np.interp(y15, st["y"], st["janssen"])), st["z_c"], st["K"])
        self.fill["kinetic_energy_per_particle"] = ke
        self.wall_load = self._wall_load()
        wl_ = self.wall_load
        self.sim.log.info("silo: at the end of the fill the walls carry %s of the weight %.4g N",
                          ", ".join(f"{k} {100 * v:.3g} %" for k, v in zip(wl_["labels"], wl_["share"])),
                          wl_["weight"])
        sys_.set_wall_active("gate", False)
        if self.drop_phase == 0:  # (with a floor drop the fill's friction ended at the drop)
            self._end_fill_friction()
        if self.case.particles.rotation == "locked":
            sys_.lock_rotation()
        if self.probe:
            self.probe.open(float(sys_.mass.sum()))
        if self.outlet is not None:
            self.outlet.open(t)
        self.gate_open_time = t
        self.k_field = 0
        self.rec_t.append(t)
        self.rec_m.append(self.sim.counters["mass_out"])
        self._sample_profiles(t)
        self.sim.log.info("silo: gate opened at t = %.4g s (kinetic energy per particle %.3g J); fill height "
                          "%.4g m, bulk density %.1f kg/m3 (%d particles in the box x %.3g..%.3g m, y %.3g..%.3g m, "
                          "full depth)", t, ke, self.fill["fill_height"], self.fill["bulk_density"],
                          self.fill["n_in_box"], self.fill["box_lo"][0], self.fill["box_hi"][0],
                          self.fill["box_lo"][1], self.fill["box_hi"][1])
        if not math.isfinite(self.fill["bulk_density"]):
            self.sim.log.warning("silo: the fill is too low for a bulk-density box 3 d (%.3g m) from the walls "
                                 "and the free surface", 3 * d)

    def _wall_load(self) -> dict:
        """How the bed's weight is carried at the end of the fill (before the gate opens): the
        force of the particles on each wall (analytic and mesh, from the last force evaluation)
        along gravity, over the weight of the particles.  A wall with friction that holds the bed
        up carries a positive share; one whose friction pulls the bed down (the bed has moved up
        along it last) a negative one.  The shares add up to 1 when the bed is at rest."""
        sys_ = self.sim.system
        gv = np.asarray(sys_.gravity, float)
        gn = float(np.linalg.norm(gv))
        down = gv / gn if gn > 0 else np.array([0.0, -1.0, 0.0])
        labels = list(sys_.wall_labels())
        forces = [np.asarray(sys_.wall_forces(), float).reshape(-1, 3)]
        if sys_.nm:
            labels += list(sys_.mesh_labels())
            forces.append(np.asarray(sys_.mesh_forces(), float).reshape(-1, 3))
        F = np.concatenate(forces) if labels else np.zeros((0, 3))
        weight = float(np.sum(sys_.mass)) * gn
        load = F @ down
        share = load / weight if weight > 0 else np.full(len(labels), np.nan)
        return {"labels": labels, "force": F, "load": load, "share": share, "weight": weight,
                "profile": self._wall_profile(down)}

    def _wall_profile(self, down) -> dict:
        """The wall stresses against height at the end of the fill: the forces of the analytic
        front and back walls, and of the side walls, on the particles, binned by the particles'
        height in 2 d bins aligned with the floor y = 0 (down into the slot where particles
        are): shear tau (the force against gravity, holding the bed up) and normal sigma (the
        horizontal force) per wall area (Pa), each group's two walls together.  Their ratio is
        the friction the walls carry at that height."""
        sys_ = self.sim.system
        d = self.g.d
        walls = sys_.force_breakdown()["walls"] if sys_.n else {}
        y = sys_.pos[:, 1] if sys_.n else np.zeros(0)
        top = max(float(y.max()) if len(y) else 0.0, 2 * d)
        k0 = min(0, math.floor(float(y.min()) / (2 * d))) if len(y) else 0  # the slot's particles too
        edges = 2 * d * np.arange(k0, math.floor(top / (2 * d)) + 2)
        out = {"y": 0.5 * (edges[1:] + edges[:-1])}
        dy = np.diff(edges)
        for key, width in (("front_back", self.g.W), ("sides", self.g.L)):
            names = WALL_PAIRS[key]
            tau = np.zeros(len(dy))
            sig = np.zeros(len(dy))
            have = [w for w in names if w in walls]
            for w in have:
                f = walls[w]
                up = -(f @ down)  # the wall's force on the particle against gravity
                horiz = np.sqrt(np.maximum(np.sum(f * f, axis=1) - up * up, 0.0))
                tau += np.histogram(y, edges, weights=up)[0]
                sig += np.histogram(y, edges, weights=horiz)[0]
            area = len(have) * width * dy  # (no such walls: NaN)
            out[f"tau_{key}"] = tau / area if have else np.full(len(dy), np.nan)
            out[f"sigma_{key}"] = sig / area if have else np.full(len(dy), np.nan)
        return out

    def fill_measure(self, pos, mass) -> None:
        """Fill height and bulk density of the current packing (module doc for the box)."""
        self.fill.update(self.packing(pos, mass))

    def packing(self, pos, mass) -> dict:
        """Fill height and bulk density of a packing (the box of the module doc), as a dict."""
        d, g = self.g.d, self.g
        h = surface_height(pos, 0.0, g.W, 2 * d)
        lo = np.array([3 * d, g.y_fill + 3 * d, 0.0])
        hi = np.array([g.W - 3 * d, h - 3 * d, g.L])
        rho, k = bulk_density(pos, mass, lo, hi) if hi[1] > lo[1] else (math.nan, 0)
        return dict(bulk_density=rho, fill_height=h, n_particles=len(pos), n_in_box=k, box_lo=lo, box_hi=hi)

    def series(self) -> dict:
        c = self.sim.counters
        return {"discharged_mass": c["mass_out"], "discharged_count": float(c["count_out"]),
                "inserted_count": float(self.spheres_inserted), "gate_open": 1.0 if self.gate_open else 0.0,
                "inserted_bodies": float(self.n_inserted if self.g.shape is not None else 0),
                "discharged_bodies": float(self.bodies_out)}

    def stop_reason(self) -> str | None:
        if not self.ended:
            return None
        fit = self.flow_fit()
        rate = f"; steady mass flow rate {fit['rate']:.4g} kg/s" if math.isfinite(fit["rate"]) else ""
        return self.ended + rate

    def flow_fit(self) -> dict:
        lo, hi = self.s["fit_range"]
        if not self.gate_open or len(self.rec_t) < 3:
            return fit_mass_flow([], [], lo, hi)
        t = np.array(self.rec_t)
        m = np.array(self.rec_m)
        if self.clogged or self.ended:  # the record after the last outflow is not part of the discharge
            keep = t <= (self.last_out_time if math.isfinite(self.last_out_time) else t[0]) + 1e-12
            keep[: 1] = True
            t, m = t[keep], m[keep]
        return fit_mass_flow(t, m, lo, hi)

    def measurements(self):
        fit = self.flow_fit()
        vx, vy = self.field.mean()
        ch = channel_boundary(vy, self.field.x, self.g.xc, self.s["channel_fraction"])
        g = self.g
        silo = {
            "discharge_time": np.array(self.rec_t, float),
            "discharge_mass": np.array(self.rec_m, float),
            "fit_window": np.array([fit["t_lo"], fit["t_hi"], fit["m_lo"], fit["m_hi"]]),
            "fit_residual_rms": fit["residual_rms"],
            "fit_residual_rel": fit["residual_rel"],
            "fit_points": fit["n_points"],
            "gate_open_time": self.gate_open_time,
            "discharge_duration": self.last_out_time - self.gate_open_time if self.ended else math.nan,
            "fill_height": self.fill["fill_height"],
            "fill_particles": self.fill["n_particles"],
            "fill_kinetic_energy_per_particle": self.fill["kinetic_energy_per_particle"],
            "bulk_density_box": np.concatenate([self.fill["box_lo"], self.fill["box_hi"]]),
            "bulk_density_particles": self.fill["n_in_box"],
            "field": {"x": self.field.x, "y": self.field.y, "vx": vx, "vy": vy, "count": self.field.count,
                      "n_samples": self.field.n_samples},
            "channel": {"y": self.field.y, "x_left": ch["x_left"], "x_right": ch["x_right"],
                        "centre_speed": ch["centre_speed"], "fraction": self.s["channel_fraction"]},
            "@attrs": {"axes": "x across, y up (outlet plane y = 0), z depth", "outlet_width": g.b, "width": g.W,
                       "depth": g.L, "hopper_angle_deg_from_horizontal": self.s["hopper_angle_deg"],
                       "fit": f"discharged mass against time between {self.s['fit_range'][0]:g} and "
                              f"{self.s['fit_range'][1]:g} of the final discharged mass (least squares)",
                       "bulk_density": "mass of the particles with centres in bulk_density_box (x0,y0,z0,x1,y1,z1) "
                                       "over its volume, at the gate opening",
                       "stop": self.ended,
                       "discharge_duration": "s from the gate opening to the removal of the last discharged "
                                             "particle (NaN: none left, or the run ended before the discharge did)"},
        }
        if self.probe:
            silo.update(self.probe.measurements())
        if self.outlet is not None:
            silo["outlet"] = self.outlet_measurements(fit)
        if len(self.heights):
            pm = profile_measurements(self.win_all, self.win_front, g.xc, self.heights, self.s["channel_fraction"])
            pm["window"] = np.asarray(self.s["profile_window"], float)
            pm["@attrs"]["window"] = "s after the gate opening"
            silo["profiles"] = pm
            silo["flow_pattern"] = pm["flow_pattern"]
            silo["centreline_series"] = {
                "time": np.array(self.cl_t, float), "heights": self.heights,
                "vy": np.array(self.cl_v, float).reshape(len(self.cl_t), len(self.heights)),
                "@attrs": {"time": "s after the gate opening", "vy": "mean v_y (m/s, up positive) of the centres "
                           "within d of the centreline and of each height, full depth, at each check"}}
        if self.stress:
            silo["stress"] = {**self.stress, "@attrs": self.STRESS_ATTRS}
        if self.drop_phase:
            silo["floor_drop"] = {
                "depth": self.s["floor_drop"], "speed": self.s["floor_drop_speed"], "start_time": self.drop_start,
                "end_time": self.drop_done,
                "@attrs": {"depth": "m the floor (bottom or hopper plates, lips, gate) was lowered once the fill "
                                    "had settled", "speed": "m/s", "start_time": "s, the drop's start",
                           "end_time": "s, the floor stopped (NaN: still moving when the run ended)"}}
        if self.wall_load:
            wl_ = self.wall_load
            silo["fill_wall_load"] = {
                "labels": np.array(wl_["labels"], dtype="S"), "force": wl_["force"], "load": wl_["load"],
                "share": wl_["share"], "weight": wl_["weight"],
                **({"profile": {**wl_["profile"], "@attrs": {
                    "y": "m, bin centres (2 d bins aligned with the floor y = 0, the slot's particles in the lowest) of "
                         "the particle centres",
                    "tau_front_back": "Pa, the front and back walls' force on the particles of the bin against "
                                      "gravity (holding the bed up) over their area 2 W dy; tau_sides likewise for "
                                      "the side walls (area 2 depth dy)",
                    "sigma_front_back": "Pa, their horizontal (normal) force over the same area; tau / sigma is the "
                                        "friction the wall carries at that height (at most its mu)"}}}
                   if "profile" in wl_ else {}),
                "@attrs": {"force": "N, force of the particles on each wall (labels) just before the gate opened",
                           "load": "N, that force along gravity (the part of the bed's weight the wall carries; "
                                   "negative: the wall pulls the bed down)",
                           "share": "load / weight; the shares add up to 1 for a bed at rest",
                           "weight": "N, the particles' weight at the gate opening"}}
        arrays = {"mass_flow_rate": fit["rate"], "bulk_density": self.fill["bulk_density"],
                  "clogged": np.int64(1 if self.clogged else 0), "silo": silo,
                  "@attrs:mass_flow_rate": {"unit": "kg/s"}, "@attrs:bulk_density": {"unit": "kg/m3"},
                  "@attrs:clogged": {"unit": "0/1"}}
        return None, arrays, {}

    def outlet_measurements(self, fit: dict) -> dict:
        """/measurements/silo/outlet: the outlet budget's blocks and their means over the flow-rate
        fit's window (:mod:`cfddem.measure.outlet_budget`), with the particles' volume flow
        W / rho_p and the ratio of the air drawn in through the slot to it."""
        o = self.outlet
        win = o.window(fit["t_lo"], fit["t_hi"]) if math.isfinite(fit["rate"]) else o.window(math.inf, -math.inf)
        q_p = fit["rate"] / self.case.particles.density
        blocks = o.arrays()
        out = {"radii": o.radii, "radii_in_slot_widths": np.asarray(self.s["outlet_radii"], float),
               "blocks": blocks, "q_particles": q_p,
               "slot_air_ratio": win["q_slot"] / q_p if q_p > 0 else math.nan,
               **{f"mean_{k}": v for k, v in win.items()},
               "@attrs": {"regions": "half-discs (x - xc)^2 + y^2 < R^2, y >= 0, full depth, R = radii (m)",
                          "window": "the blocks inside the flow-rate fit's window (fit_window t_lo..t_hi)",
                          "signs": "forces on the particles along y, up positive (N); weight m g positive (N); "
                                   "q_slot up into the silo through the outlet plane, q_top up out of the open "
                                   "top (m^3/s); q_particles = mass_flow_rate / particles.density (m^3/s)"}}
        return out

    def get_state(self) -> dict:
        return {"k_check": np.int64(self.k_check), "gate_open_time": self.gate_open_time,
                "last_out_time": self.last_out_time, "rec_t": np.array(self.rec_t, float),
                "rec_m": np.array(self.rec_m, float), "clogged": np.int64(self.clogged), "ended": self.ended,
                "k_field": np.int64(self.k_field), "field": self.field.get_state(),
                "n_inserted": np.int64(self.n_inserted), "layers_done": np.int64(self.layers_done),
                "spheres_inserted": np.int64(self.spheres_inserted), "bodies_out": np.int64(self.bodies_out),
                "fill": {k: (np.asarray(v) if not isinstance(v, (int, float)) else v) for k, v in self.fill.items()},
                "win_all": self.win_all.get_state(), "win_front": self.win_front.get_state(),
                "cl_t": np.array(self.cl_t, float),
                "drop": np.array([self.drop_phase, self.drop_start, self.drop_end, self.drop_done, self.drop_y0]),
                "cl_v": np.array(self.cl_v, float).reshape(len(self.cl_t), len(self.heights)),
                **({"stress": self.stress} if self.stress else {}),
                **({"wall_load": {**self.wall_load, "labels": np.array(self.wall_load["labels"], dtype="S")}}
                   if self.wall_load else {}),
                **({"probe": self.probe.get_state()} if self.probe else {}),
                **({"outlet": self.outlet.get_state()} if self.outlet is not None else {})}

    def set_state(self, d: dict) -> None:
        self.k_check = int(d["k_check"])
        self.gate_open_time = float(d["gate_open_time"])
        self.last_out_time = float(d["last_out_time"])
        self.rec_t = [float(x) for x in np.asarray(d["rec_t"]).ravel()]
        self.rec_m = [float(x) for x in np.asarray(d["rec_m"]).ravel()]
        self.clogged = bool(int(d["clogged"]))
        e = d["ended"]
        self.ended = e.decode() if isinstance(e, bytes) else str(e)
        self.k_field = int(d["k_field"])
        self.n_inserted = int(d["n_inserted"])
        self.spheres_inserted = int(d.get("spheres_inserted", self.n_inserted))
        self.bodies_out = int(d.get("bodies_out", 0))
        self._sunk_seen = (self.sim.system.sunk_total, self.sim.system.sunk_bodies)
        self.layers_done = int(d["layers_done"])
        self.field.set_state(d["field"])
        if "win_all" in d:
            self.win_all.set_state(d["win_all"])
            self.win_front.set_state(d["win_front"])
            self.cl_t = [float(x) for x in np.asarray(d["cl_t"]).ravel()]
            cl_v = np.asarray(d["cl_v"], float).reshape(len(self.cl_t), len(self.heights))
            self.cl_v = [np.asarray(v, float) for v in cl_v]
        if "stress" in d:
            self.stress = {k: v for k, v in d["stress"].items()}
        if "wall_load" in d:  # (the walls' shares at the gate opening, for the measurements)
            wl_ = dict(d["wall_load"])
            wl_["labels"] = [x.decode() if isinstance(x, bytes) else str(x) for x in np.atleast_1d(wl_["labels"])]
            wl_["weight"] = float(wl_["weight"])
            if "profile" in wl_:
                wl_["profile"] = dict(wl_["profile"])
            self.wall_load = wl_
        if "drop" in d:
            dr = np.asarray(d["drop"], float)
            self.drop_phase = int(dr[0])
            self.drop_start, self.drop_end, self.drop_done, self.drop_y0 = (float(x) for x in dr[1:5])
        if not self.gate_open and self.drop_phase == 0:  # (from the drop on, the case's friction)
            self._fill_friction()
        if self.probe:
            self.probe.set_state(d["probe"])
        if self.outlet is not None and "outlet" in d:
            self.outlet.set_state(d["outlet"])
        self._wire_outlet()
        for k, v in d["fill"].items():
            self.fill[k] = np.asarray(v, float) if k.startswith("box") else float(v)


if __name__ == "__main__":
    raise SystemExit(main())
