"""Case files: TOML -> validated, resolved configuration objects, in one place.

A case is a directory holding ``case.toml`` (SI units).  :func:`load_case` reads it, applies
command-line overrides (``--set particles.diameter=0.004``), checks every key against
:data:`SCHEMA` (unknown keys with a "did you mean" hint, types, ranges) and then the consistency
of the whole (inlet inside the chute, ...).  Every problem raises :class:`CaseError` naming the
dotted key and the reason; the CLI prints it as one line and exits with code 2.

The schema is also the documentation: ``docs/case-format.md`` is generated from it by
:func:`schema_markdown` (a test checks that the committed file is current).
"""

from __future__ import annotations

import copy
import difflib
import json
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .errors import CaseError

INF = float("inf")


# --------------------------------------------------------------------------------------------
# schema
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Key:
    """One case-file key: its type, default, unit, meaning and allowed range."""

    type: str  # float | int | bool | str | vec3 | floats | ints | bools3 | tables
    default: Any
    unit: str
    doc: str
    lo: float | None = None  # lower bound
    hi: float | None = None  # upper bound
    lo_open: bool = False  # lower bound excluded
    hi_open: bool = False
    choices: tuple[str, ...] | None = None
    required: bool = False

    def describe_range(self) -> str:
        if self.choices:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        if self.lo is None and self.hi is None:
            return ""
        lo = "-inf" if self.lo is None else f"{self.lo:g}"
        hi = "inf" if self.hi is None else f"{self.hi:g}"
        lb = "(" if (self.lo_open or self.lo is None) else "["
        hb = ")" if (self.hi_open or self.hi is None) else "]"
        return f"{lb}{lo}, {hi}{hb}"


def _f(default, unit, doc, **kw):
    return Key("float", default, unit, doc, **kw)


def _pos(default, unit, doc, **kw):
    return Key("float", default, unit, doc, lo=0.0, lo_open=True, **kw)


def _nonneg(default, unit, doc, **kw):
    return Key("float", default, unit, doc, lo=0.0, **kw)


def _contact_section(mu_default: float, e_n_default: float) -> dict:
    return {
        "k_n": _pos(1000.0, "N/m", "normal spring stiffness of the linear spring-dashpot law"),
        "e_n": _f(e_n_default, "-", "normal coefficient of restitution", lo=0.0, lo_open=True, hi=1.0),
        "e_t": _f(0.33, "-", "tangential restitution of a sticking collision", lo=0.0, lo_open=True, hi=1.0),
        "mu": _nonneg(mu_default, "-", "Coulomb friction coefficient"),
        "mu_r": _nonneg(0.0, "-", "rolling friction coefficient (constant directional torque)"),
        "E": _pos(5e7, "Pa", "hertz_mindlin: Young's modulus (DEM practice: a reduced value, glass is 6.3e10)"),
        "nu": _f(0.25, "-", "hertz_mindlin: Poisson ratio", lo=-1.0, lo_open=True, hi=0.5),
        "e": _f(e_n_default, "-", "hertz_mindlin: coefficient of restitution", lo=0.0, lo_open=True, hi=1.0),
    }


def _wall_override(what: str) -> dict:
    """Per-wall contact overrides of the silo (unset: contact.particle_wall)."""
    return {k: Key("float", None, u, f"{what}: {doc} (default: contact.particle_wall.{k})", lo=0.0)
            for k, u, doc in (("mu", "-", "sliding friction"), ("mu_r", "-", "rolling friction"),
                              ("e_n", "-", "normal restitution"), ("e_t", "-", "tangential restitution"),
                              ("k_n", "N/m", "normal stiffness"), ("E", "Pa", "Young's modulus (hertz_mindlin)"),
                              ("nu", "-", "Poisson ratio (hertz_mindlin)"), ("e", "-", "restitution (hertz_mindlin)"))}


_SHEAR_SCHEMA = {
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
    "consolidate_time": _nonneg(0.05, "s", "shortest consolidation after the lid is placed"),
    "lid_settle_speed": _pos(2e-3, "m/s", "consolidation ends when the lid's vertical speed is below this"),
    "lid_sphere_diameter": _nonneg(0.0, "m", "diameter of the lid's glued spheres (0: particles.diameter)"),
    "lid_clearance": _nonneg(0.0005, "m", "gap between the lid's outline and the ring"),
    "lid_density": _pos(7800.0, "kg/m3", "density of the lid's spheres (its weight is cancelled; sets its inertia)"),
    "check_steps": Key("int", 20, "-", "steps between the scene's checks (load update, force sampling)", lo=1),
    "sample_interval": _pos(0.01, "s", "interval of the averaged shear samples (/measurements/shear)"),
    "steady_window": Key("floats", [0.5, 1.0], "-", "bulk friction: mean over shear displacements between these "
                         "fractions of shear_distance"),
    "rings": _wall_override("base ring, bottom and shear ring"),
    "plate": _wall_override("wall-friction plate (variant 'wall')"),
}


_SILO_SCHEMA = {
    "width": _pos(0.15, "m", "inner width of the planar silo (x from 0 to width; y up, the outlet plane at y = 0)"),
    "depth": _pos(0.04, "m", "distance between the front (z = 0) and back (z = depth) walls"),
    "height": _nonneg(0.0, "m", "height of the side walls above the outlet plane (0: the top of the fill lattice + 2 d)"),
    "outlet_width": _pos(0.04, "m", "width b of the slot outlet (full depth), centred at x = width/2"),
    "hopper_angle_deg": _f(0.0, "deg", "hopper wall inclination measured from the HORIZONTAL (0: flat bottom; "
                           "60: walls at 60 deg to the horizontal, 30 deg from the vertical)", lo=0.0, hi=80.0),
    "lip": _nonneg(0.0, "m", "thickness of the bottom plate: vertical lip walls line the slot from y = -lip to 0 and "
                   "the gate closes it at y = -lip (0: one particle diameter)"),
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
    "settle_energy": _pos(2e-9, "J", "kinetic energy per particle below which the fill counts as settled"),
    "settle_check_interval": _pos(0.01, "s", "interval of the settled / clogged / empty checks"),
    "clog_time": _pos(0.5, "s", "no outflow for this long while particles remain just above the slot: clogged "
                      "(the run stops); with none there: discharge ended (empty)"),
    "fit_range": Key("floats", [0.2, 0.8], "-", "mass flow rate: linear fit of discharged mass against time between "
                     "these fractions of the final discharged mass"),
    "field_cell": _nonneg(0.0, "m", "cell size of the time-averaged x-y velocity field (0: 2 d)"),
    "field_interval": _pos(0.01, "s", "sampling interval of the velocity field during discharge"),
    "field_start": _nonneg(0.1, "s", "velocity field: start averaging this long after the gate opened"),
    "channel_fraction": _f(0.1, "-", "flow-channel boundary: where the downward speed falls below this fraction "
                           "of the centreline speed", lo=0.0, lo_open=True, hi=1.0, hi_open=True),
    "front_back": _wall_override("front and back walls"),
    "sides": _wall_override("side walls"),
    "bottom": _wall_override("bottom plates or hopper walls, and the slot lips"),
    "gate_wall": _wall_override("gate"),
}


SCHEMA: dict[str, dict] = {
    "case": {
        "name": Key("str", "", "-", "name of the case (default: the case folder's name)"),
        "description": Key("str", "", "-", "free text"),
    },
    "time": {
        "end_time": _pos(1.0, "s", "simulated time at which the run stops"),
        "dt": _pos(1e-5, "s", "particle time step"),
        "max_steps": Key("int", 0, "-", "stop after this many steps (0: no limit)", lo=0),
        "wall_time_limit": _nonneg(0.0, "s", "stop (cleanly, with all outputs) after this wall time (0: no limit)"),
        "threads": Key("int", 0, "-", "numba threads (0: all cores)", lo=0),
        "force": Key("bool", False, "-", "run even when dt > t_c/5 or above the stable step of one contact "
                     "(otherwise refused, docs/stability.md)"),
    },
    "output": {
        "series_interval": _pos(0.005, "s", "interval of the /series/ time series in results.h5"),
        "snapshot_interval": _pos(0.05, "s", "interval of particle snapshots in results.h5"),
        "vtk": Key("bool", True, "-", "write ParaView files (per-frame VTU + .pvd) under OUT/vtk/"),
        "vtk_interval": _nonneg(0.0, "s", "interval of VTU frames (0: the snapshot interval)"),
        "progress_interval": _pos(1.0, "s (wall)", "interval of the progress line"),
        "plots": Key("bool", True, "-", "write the PNG report under OUT/report/ at the end"),
    },
    "checkpoint": {
        "interval": _nonneg(0.0, "s", "checkpoint every this much simulated time (0: off)"),
        "wall_interval": _nonneg(600.0, "s (wall)", "checkpoint every this much wall time (0: off)"),
        "every_steps": Key("int", 0, "-", "checkpoint every this many particle steps (0: off)", lo=0),
        "keep": Key("int", 2, "-", "number of newest checkpoints kept", lo=1),
        "start_from": Key("str", "", "-", "start this run from another run's state: a checkpoint file, or a run "
                          "folder (its newest checkpoint); the time step, contact parameters, coupling interval... "
                          "may differ (a branch from a developed flow); averages start afresh; relative to the case "
                          "folder"),
    },
    "gravity": {
        "g": _nonneg(9.81, "m/s^2", "magnitude of gravity"),
        "inclination_deg": _f(0.0, "deg", "chute inclination theta: gravity = g (0, -cos theta, sin theta) in chute axes "
                              "(x across, y normal to the floor, z down the chute)", lo=0.0, hi=90.0),
    },
    "frame": {
        "rpm": _f(0.0, "1/min", "rotation rate of the frame about a vertical axis (parallel to gravity); positive: "
                  "counter-clockwise seen from above"),
        "axis_point": Key("vec3", [0.0, 0.0, 0.0], "m", "a point on the rotation axis, in case coordinates"),
    },
    "particles": {
        "diameter": _pos(0.003, "m", "particle diameter (the smallest one if diameter_max is set)"),
        "diameter_max": _nonneg(0.0, "m", "polydisperse: diameters uniform in [diameter, diameter_max] (0: monodisperse)"),
        "density": _pos(2550.0, "kg/m^3", "particle material density"),
        "initial_file": Key("str", "", "-", "CSV or HDF5 file of initial particles (relative to the case folder); "
                            "CSV columns x,y,z,vx,vy,vz,wx,wy,wz,radius (header line), HDF5 datasets pos, vel, omega, radius"),
        "initial": Key("tables", [], "-", "inline initial particles: [[particles.initial]] tables with pos (m), "
                       "radius (m), and optional vel (m/s), omega (rad/s)"),
        "max_overlap_ratio": _f(0.5, "-", "stop the run when an overlap exceeds this fraction of the smaller radius",
                                lo=0.0, lo_open=True, hi=1.0),
        "skin": _nonneg(0.0, "m", "Verlet-list skin (0: 0.3 x the largest diameter)"),
        "seed": Key("int", 12345, "-", "seed for polydisperse sizes", lo=0),
        "clump": Key("str", "none", "-", "particle shape: 'none' (spheres) or a rigid clump of spheres of this "
                     "diameter: 'pellet2' (two spheres d/2 apart), 'pellet4' (tetrahedron of edge d/2); clumps are "
                     "inserted by the shear_cell and silo fills and the sluice inlet, one per lattice "
                     "site in a random orientation; initial particles stay spheres (docs/particles.md)",
                     choices=("none", "pellet2", "pellet4")),
    },
    "contact": {
        "model": Key("str", "linear", "-", "contact law: 'linear' spring-dashpot (keys k_n, e_n, e_t, mu, mu_r) or "
                     "'hertz_mindlin' (keys E, nu, e, mu, mu_r; physics.md §1.2)", choices=("linear", "hertz_mindlin")),
        "particle_particle": _contact_section(0.12, 0.97),
        "particle_wall": _contact_section(0.22, 0.95),
    },
    "geometry": {
        "type": Key("str", "chute", "-", "'chute': floor + two side walls (+ a back wall at the entrance); "
                    "'box': six walls lo..hi; 'silo': the planar silo of [silo]; 'shear_cell': the Jenike shear "
                    "cell of [shear]; 'none': walls only from [[geometry.walls]]",
                    choices=("chute", "box", "silo", "shear_cell", "none")),
        "width": _pos(0.08, "m", "chute width (x from 0 to width)"),
        "depth": _pos(0.045, "m", "height of the chute side walls (y from 0 to depth)"),
        "length": _pos(0.9, "m", "chute length (z from z_start to z_start + length)"),
        "z_start": _f(-0.1, "m", "z of the chute entrance (the measurement origin is z = 0)"),
        "back_wall": Key("bool", True, "-", "close the chute entrance with a wall at z = z_start"),
        "lo": Key("vec3", [0.0, 0.0, 0.0], "m", "box: lower corner"),
        "hi": Key("vec3", [0.1, 0.1, 0.1], "m", "box: upper corner"),
        "periodic": Key("bools3", [False, False, False], "-", "box: periodic axes (no walls on those axes)"),
        "walls": Key("tables", [], "-", "extra walls: [[geometry.walls]] with type = 'plane' (point, normal) or "
                     "'rectangle' (point = centre, normal, u_axis, half_extents = [a, b]) or 'cylinder' (the inside of a ring: "
                     "point = centre, axis, radius, half_height, optional inside = false for the outer surface); "
                     "optional contact keys mu, mu_r, e_n, e_t, k_n (linear) or E, nu, e (hertz_mindlin)"),
    },
    "silo": _SILO_SCHEMA,
    "shear": _SHEAR_SCHEMA,
    "inlet": {
        "type": Key("str", "none", "-", "'sluice': bcc lattice layers across the chute entrance at a mass rate",
                    choices=("none", "sluice")),
        "mass_rate": _pos(1.6, "kg/s", "mass feed rate"),
        "height": _pos(0.045, "m", "sluice height above the floor"),
        "z": Key("float", None, "m", "upstream edge of the sluice (default: geometry.z_start)"),
        "start_time": _nonneg(0.0, "s", "feeding starts"),
        "end_time": _pos(INF, "s", "feeding stops"),
        "gap": _nonneg(0.1, "-", "extra bcc lattice spacing as a fraction of the diameter: room for the settling of the previous layer, so new layers do not wait"),
        "hold_length": Key("float", None, "m", "fed particles move at the feed velocity, unaffected by forces, until they are this far "
                           "past the insertion plane, pushing what is ahead like the material behind a sluice gate "
                           "(default: one lattice period, about 1.3 d; 0: released at once)", lo=0.0),
    },
    "exit": {
        "z": Key("float", None, "m", "particles with z beyond this plane leave the simulation "
                 "(default: the chute end, z_start + length; chute only)"),
        "lost_margin": _pos(0.5, "m", "particles farther than this outside the walls' bounding box are removed as lost"),
    },
    "measurements": {
        "enabled": Key("bool", True, "-", "chute measurements (bed height, surface velocity, mean velocity)"),
        "start_time": _nonneg(0.0, "s", "time averages start here (steady state)"),
        "interval": _pos(0.01, "s", "sampling interval of the time averages"),
        "stations": Key("floats", [0.0, 0.2, 0.4, 0.6], "m", "streamwise positions z of the cross-width profiles"),
        "sensors_x": Key("floats", [0.015, 0.045, 0.065], "m", "x of the left, centre and right bed-height sensors"),
        "cell_x": _pos(0.005, "m", "measurement cell size across the chute"),
        "cell_z": _pos(0.006, "m", "measurement cell size along the chute"),
        "n_top": Key("int", 6, "-", "topmost particles per cell for the surface velocity", lo=1),
    },
    "study": {
        "compare_without_gas": Key("bool", False, "-", "after a run with gas, run the same case without gas into "
                                   "OUT/no_gas and write the gas-against-no-gas report into OUT/compare"),
    },
    "gas": {
        "enabled": Key("bool", False, "-", "solve the interstitial gas (two-way coupled)"),
        "density": _pos(1.2, "kg/m^3", "gas density"),
        "viscosity": _pos(1.8e-5, "Pa s", "gas dynamic viscosity"),
        "cells": Key("ints", [16, 15, 150], "-", "gas grid NX, NY, NZ"),
        "height": _pos(0.045, "m", "height of the gas domain above the floor"),
        "coupling_interval": Key("int", 10, "-", "particle steps per gas step", lo=1),
        "drag_treatment": Key("str", "implicit", "-", "'implicit': drag implicit in the gas step and bounded "
                              "(exact exponential relaxation) for the particles, stable for any particle relaxation "
                              "time; 'explicit': forward Euler, for comparison", choices=("implicit", "explicit")),
        "drag": Key("str", "beetstra", "-", "drag closure",
                    choices=("beetstra", "wen_yu", "ergun_gidaspow", "di_felice", "koch_hill")),
        "lid": Key("str", "crosswind", "-", "open-top boundary: 'crosswind' (lab air at rest seen from the rotating "
                   "frame), 'slip' (free slip) or 'wall' (no slip)", choices=("crosswind", "slip", "wall")),
        "inlet_velocity": Key("float", None, "m/s", "co-flow velocity at the entrance (default: the feed velocity)"),
        "pressure_solver": Key("str", "mg", "-", "pressure solver: 'mg' (compiled geometric multigrid as CG "
                               "preconditioner) or 'amg' (pyamg smoothed aggregation, for comparison)",
                               choices=("mg", "amg")),
        "pressure_tol": Key("float", 1e-8, "-", "relative residual at which the pressure solve stops; on the "
                            "recorded chute gas steps 1e-6 is 12 % cheaper per gas step and moves p and grad p "
                            "by < 1e-6 of their scale (docs/gas.md, 'Tolerance')", lo=0.0, hi=0.1, lo_open=True),
    },
}


# --------------------------------------------------------------------------------------------
# resolved configuration objects
# --------------------------------------------------------------------------------------------
class Section:
    """Attribute access to a resolved section (``cfg.particles.diameter``)."""

    def __init__(self, name: str, values: dict):
        self._name = name
        for k, v in values.items():
            setattr(self, k, Section(f"{name}.{k}", v) if isinstance(v, dict) else v)

    def to_dict(self) -> dict:
        out = {}
        for k, v in vars(self).items():
            if k.startswith("_"):
                continue
            out[k] = v.to_dict() if isinstance(v, Section) else copy.deepcopy(v)
        return out

    def __repr__(self) -> str:
        return f"Section({self._name}: {self.to_dict()!r})"


@dataclass
class Case:
    """A validated case: resolved values (defaults filled in) and where it came from."""

    path: Path  # the case folder
    raw_text: str  # case.toml as written
    overrides: dict[str, Any]
    resolved: dict
    cfg: Section = field(init=False)

    def __post_init__(self):
        self.cfg = Section("", self.resolved)

    def __getattr__(self, item):  # case.particles.diameter
        if item in SCHEMA:
            return getattr(self.cfg, item)
        raise AttributeError(item)

    @property
    def name(self) -> str:
        return self.resolved["case"]["name"]

    def to_toml(self) -> str:
        """The resolved configuration as TOML (written beside the results)."""
        return dumps_toml(self.resolved)

    def to_json(self) -> str:
        return json.dumps(self.resolved, indent=1, default=_json_default)


def _json_default(o):
    if isinstance(o, float) and math.isinf(o):
        return "inf"
    raise TypeError(str(type(o)))


# --------------------------------------------------------------------------------------------
# loading
# --------------------------------------------------------------------------------------------
def parse_override(text: str) -> tuple[str, Any]:
    """``"particles.diameter=0.004"`` -> ``("particles.diameter", 0.004)``; value parsed as TOML,
    falling back to a bare string (``--set inlet.type=sluice``)."""
    if "=" not in text:
        raise CaseError(None, f"--set {text!r}: expected KEY=VALUE, e.g. --set particles.diameter=0.004")
    key, value = text.split("=", 1)
    key = key.strip()
    if not key or any(not part for part in key.split(".")):
        raise CaseError(None, f"--set {text!r}: expected a dotted key such as particles.diameter")
    value = value.strip()
    try:
        parsed = tomllib.loads(f"v = {value}")["v"]
    except tomllib.TOMLDecodeError:
        parsed = value
    return key, parsed


def _set_dotted(d: dict, key: str, value: Any) -> None:
    parts = key.split(".")
    cur = d
    for p in parts[:-1]:
        nxt = cur.get(p)
        if nxt is None:
            nxt = cur[p] = {}
        if not isinstance(nxt, dict):
            raise CaseError(key, f"cannot set a sub-key: '{p}' is a value, not a section")
        cur = nxt
    cur[parts[-1]] = value


def case_file(path: str | Path) -> Path:
    p = Path(path)
    if p.is_dir():
        p = p / "case.toml"
    if not p.exists():
        raise CaseError(None, f"no case file at {p}")
    return p


def load_case(path: str | Path, overrides: dict[str, Any] | list[str] | None = None) -> Case:
    """Read, override, validate and resolve a case (folder or ``case.toml`` path)."""
    f = case_file(path)
    text = f.read_text()
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise CaseError(None, f"{f}: malformed TOML: {e}") from None
    return build_case(raw, case_dir=f.parent, overrides=overrides, raw_text=text)


def build_case(raw: dict, case_dir: str | Path = ".", overrides=None, raw_text: str = "") -> Case:
    """Validate a raw dict (as parsed from TOML) plus overrides into a :class:`Case`."""
    raw = copy.deepcopy(raw)
    ov: dict[str, Any] = {}
    if isinstance(overrides, (list, tuple)):
        for item in overrides:
            k, v = parse_override(item)
            ov[k] = v
    elif overrides:
        ov = dict(overrides)
    for k, v in ov.items():
        _set_dotted(raw, k, v)
    resolved = _validate_section(raw, SCHEMA, "")
    case_dir = Path(case_dir)
    if not resolved["case"]["name"]:
        resolved["case"]["name"] = case_dir.resolve().name
    _check_consistency(resolved, case_dir)
    return Case(path=case_dir, raw_text=raw_text, overrides=ov, resolved=resolved)


def _suggest(name: str, options) -> str:
    m = difflib.get_close_matches(name, list(options), n=1, cutoff=0.6)
    return f"; did you mean '{m[0]}'?" if m else f"; known keys: {', '.join(sorted(options))}"


def _validate_section(raw: Any, schema: dict, prefix: str) -> dict:
    if not isinstance(raw, dict):
        raise CaseError(prefix.rstrip(".") or None, "expected a table (section)")
    for k in raw:
        if k not in schema:
            raise CaseError(f"{prefix}{k}", "unknown key" + _suggest(k, schema.keys()))
    out = {}
    for k, spec in schema.items():
        dotted = f"{prefix}{k}"
        if isinstance(spec, dict):
            out[k] = _validate_section(raw.get(k, {}), spec, dotted + ".")
        else:
            if k in raw:
                out[k] = _check_value(dotted, spec, raw[k])
            elif spec.required:
                raise CaseError(dotted, "required key is missing")
            else:
                out[k] = copy.deepcopy(spec.default)
    return out


def _typename(v) -> str:
    return {bool: "a boolean", int: "an integer", float: "a number", str: "a string",
            list: "an array", dict: "a table"}.get(type(v), type(v).__name__)


def _as_float(key: str, v) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise CaseError(key, f"expected a number, got {_typename(v)} {v!r}")
    x = float(v)
    if math.isnan(x):
        raise CaseError(key, "expected a number, got nan")
    return x


def _check_range(key: str, spec: Key, x: float) -> None:
    bad = False
    if spec.lo is not None and (x < spec.lo or (spec.lo_open and x == spec.lo)):
        bad = True
    if spec.hi is not None and (x > spec.hi or (spec.hi_open and x == spec.hi)):
        bad = True
    if bad:
        raise CaseError(key, f"{x:g} is out of range: must be in {spec.describe_range()}")


def _check_value(key: str, spec: Key, v: Any) -> Any:
    t = spec.type
    if v is None:  # only reachable through defaults
        return None
    if t == "float":
        x = _as_float(key, v)
        _check_range(key, spec, x)
        return x
    if t == "int":
        if isinstance(v, bool) or not isinstance(v, int):
            raise CaseError(key, f"expected an integer, got {_typename(v)} {v!r}")
        _check_range(key, spec, v)
        return int(v)
    if t == "bool":
        if not isinstance(v, bool):
            raise CaseError(key, f"expected true or false, got {_typename(v)} {v!r}")
        return v
    if t == "str":
        if not isinstance(v, str):
            raise CaseError(key, f"expected a string, got {_typename(v)} {v!r}")
        if spec.choices and v not in spec.choices:
            raise CaseError(key, f"{v!r} is not allowed: {spec.describe_range()}" + _suggest_choice(v, spec.choices))
        return v
    if t == "vec3":
        if not isinstance(v, list) or len(v) != 3:
            raise CaseError(key, f"expected an array of 3 numbers, got {v!r}")
        return [_as_float(f"{key}[{i}]", x) for i, x in enumerate(v)]
    if t == "bools3":
        if not isinstance(v, list) or len(v) != 3 or not all(isinstance(x, bool) for x in v):
            raise CaseError(key, f"expected an array of 3 booleans, got {v!r}")
        return list(v)
    if t == "floats":
        if not isinstance(v, list):
            raise CaseError(key, f"expected an array of numbers, got {_typename(v)} {v!r}")
        return [_as_float(f"{key}[{i}]", x) for i, x in enumerate(v)]
    if t == "ints":
        if not isinstance(v, list) or not all(isinstance(x, int) and not isinstance(x, bool) for x in v):
            raise CaseError(key, f"expected an array of integers, got {v!r}")
        if any(x < 1 for x in v):
            raise CaseError(key, f"every entry must be >= 1, got {v!r}")
        return list(v)
    if t == "tables":
        if not isinstance(v, list) or not all(isinstance(x, dict) for x in v):
            raise CaseError(key, "expected an array of tables ([[...]] entries)")
        return copy.deepcopy(v)
    raise AssertionError(t)


def _suggest_choice(v: str, choices) -> str:
    m = difflib.get_close_matches(v, list(choices), n=1, cutoff=0.5)
    return f"; did you mean '{m[0]}'?" if m else ""


# --------------------------------------------------------------------------------------------
# consistency of the whole case
# --------------------------------------------------------------------------------------------
_WALL_KEYS = {"type", "point", "normal", "u_axis", "half_extents", "mu", "mu_r", "e_n", "e_t", "k_n", "name",
              "E", "nu", "e", "axis", "radius", "half_height", "inside"}
_INITIAL_KEYS = {"pos", "vel", "omega", "radius"}


def _vec(key: str, v, n=3) -> list[float]:
    if not isinstance(v, list) or len(v) != n:
        raise CaseError(key, f"expected an array of {n} numbers, got {v!r}")
    return [_as_float(f"{key}[{i}]", x) for i, x in enumerate(v)]


def _check_consistency(r: dict, case_dir: Path) -> None:
    p, inl, geo = r["particles"], r["inlet"], r["geometry"]
    d = p["diameter"]
    if p["diameter_max"] and p["diameter_max"] < d:
        raise CaseError("particles.diameter_max", f"{p['diameter_max']:g} is smaller than particles.diameter = {d:g}")
    dmax = max(d, p["diameter_max"])
    if geo["type"] == "chute":
        if dmax >= geo["width"]:
            raise CaseError("geometry.width", f"{geo['width']:g} m is not wider than a particle ({dmax:g} m)")
        if inl["z"] is None:
            inl["z"] = geo["z_start"]
        if r["exit"]["z"] is None:
            r["exit"]["z"] = geo["z_start"] + geo["length"]
        z0, z1 = geo["z_start"], geo["z_start"] + geo["length"]
        if inl["type"] == "sluice":
            if not (z0 <= inl["z"] < z1):
                raise CaseError("inlet.z", f"{inl['z']:g} m is outside the chute (z from {z0:g} to {z1:g} m)")
            if inl["height"] > geo["depth"] + 1e-12:
                raise CaseError("inlet.height", f"{inl['height']:g} m is higher than the side walls "
                                                f"(geometry.depth = {geo['depth']:g} m)")
            if inl["height"] < dmax * (1 + inl["gap"]):
                raise CaseError("inlet.height", f"{inl['height']:g} m does not fit one particle layer")
        if not (z0 < r["exit"]["z"] <= z1 + 1e-12):
            raise CaseError("exit.z", f"{r['exit']['z']:g} m is outside the chute (z from {z0:g} to {z1:g} m)")
    else:
        if inl["type"] != "none":
            raise CaseError("inlet.type", f"'{inl['type']}' needs geometry.type = 'chute'")
        if inl["z"] is None:
            inl["z"] = 0.0
    if geo["type"] == "box":
        lo, hi = geo["lo"], geo["hi"]
        for i in range(3):
            if hi[i] <= lo[i]:
                raise CaseError("geometry.hi", f"hi[{i}] = {hi[i]:g} must be above lo[{i}] = {lo[i]:g}")
    elif any(geo["periodic"]):
        raise CaseError("geometry.periodic", "periodic axes need geometry.type = 'box'")
    for i, w in enumerate(geo["walls"]):
        key = f"geometry.walls[{i}]"
        for k in w:
            if k not in _WALL_KEYS:
                raise CaseError(f"{key}.{k}", "unknown key" + _suggest(k, _WALL_KEYS))
        wt = w.get("type")
        if wt not in ("plane", "rectangle", "cylinder"):
            raise CaseError(f"{key}.type", f"{wt!r} is not allowed: one of 'plane', 'rectangle', 'cylinder'")
        _vec(f"{key}.point", w.get("point"))
        nkey = "axis" if wt == "cylinder" else "normal"
        nrm = _vec(f"{key}.{nkey}", w.get(nkey))
        if math.hypot(*nrm) == 0:
            raise CaseError(f"{key}.{nkey}", "must not be the zero vector")
        if wt == "cylinder":
            for k in ("radius", "half_height"):
                if k not in w:
                    raise CaseError(f"{key}.{k}", "required for a cylinder wall (m)")
                if not _as_float(f"{key}.{k}", w[k]) > 0:
                    raise CaseError(f"{key}.{k}", f"must be positive, got {w[k]!r}")
            if "inside" in w and not isinstance(w["inside"], bool):
                raise CaseError(f"{key}.inside", f"expected true or false, got {w['inside']!r}")
        if wt == "rectangle":
            _vec(f"{key}.u_axis", w.get("u_axis"))
            he = _vec(f"{key}.half_extents", w.get("half_extents"), 2)
            if min(he) <= 0:
                raise CaseError(f"{key}.half_extents", "must be positive")
        for k in ("mu", "mu_r"):
            if k in w and _as_float(f"{key}.{k}", w[k]) < 0:
                raise CaseError(f"{key}.{k}", "must be >= 0")
        for k in ("e_n", "e_t"):
            if k in w and not (0 < _as_float(f"{key}.{k}", w[k]) <= 1):
                raise CaseError(f"{key}.{k}", "must be in (0, 1]")
        if "k_n" in w and _as_float(f"{key}.k_n", w["k_n"]) <= 0:
            raise CaseError(f"{key}.k_n", "must be positive")
        if "E" in w and not (0 < _as_float(f"{key}.E", w["E"]) < INF):
            raise CaseError(f"{key}.E", "Young's modulus must be positive (Pa)")
        if "nu" in w and not (-1 < _as_float(f"{key}.nu", w["nu"]) <= 0.5):
            raise CaseError(f"{key}.nu", "Poisson ratio must be in (-1, 0.5]")
        if "e" in w and not (0 < _as_float(f"{key}.e", w["e"]) <= 1):
            raise CaseError(f"{key}.e", "must be in (0, 1]")
    for i, t in enumerate(p["initial"]):
        key = f"particles.initial[{i}]"
        for k in t:
            if k not in _INITIAL_KEYS:
                raise CaseError(f"{key}.{k}", "unknown key" + _suggest(k, _INITIAL_KEYS))
        _vec(f"{key}.pos", t.get("pos"))
        rad = _as_float(f"{key}.radius", t.get("radius", d / 2))
        if rad <= 0:
            raise CaseError(f"{key}.radius", f"{rad:g} must be positive")
        for k in ("vel", "omega"):
            if k in t:
                _vec(f"{key}.{k}", t[k])
    sf = r["checkpoint"]["start_from"]
    if sf:
        f = case_dir / sf
        if not f.exists():
            raise CaseError("checkpoint.start_from", f"not found: {f}")
        if f.is_dir() and not (f / "checkpoints").is_dir() and not any(f.glob("ckpt_*.h5")):
            raise CaseError("checkpoint.start_from", f"{f} holds no checkpoints")
    if p["initial_file"]:
        f = case_dir / p["initial_file"]
        if not f.exists():
            raise CaseError("particles.initial_file", f"file not found: {f}")
        if f.suffix.lower() not in (".csv", ".h5", ".hdf5"):
            raise CaseError("particles.initial_file", f"unsupported file type '{f.suffix}': use .csv or .h5")
    m = r["measurements"]
    if m["start_time"] >= r["time"]["end_time"] and m["enabled"] and geo["type"] == "chute":
        # averaging would never start: start at half the run instead would silently change the
        # meaning; refuse
        raise CaseError("measurements.start_time", f"{m['start_time']:g} s is not before time.end_time = "
                                                   f"{r['time']['end_time']:g} s: nothing would be averaged")
    if geo["type"] == "silo":
        from .scenes.silo import check_silo_case

        check_silo_case(r)
    if geo["type"] == "shear_cell":
        from .scenes.shear import check_shear_case

        check_shear_case(r)
    if p["clump"] != "none" and geo["type"] not in ("shear_cell", "silo") and r["inlet"]["type"] != "sluice":
        raise CaseError("particles.clump", "pellets are inserted by the shear_cell and silo fills and the sluice "
                                           "inlet only (initial particles are spheres): this case has none of them")
    if p["clump"] != "none" and p["diameter_max"] > 0:
        raise CaseError("particles.diameter_max", "pellets (particles.clump) are monodisperse: leave it 0")
    if geo["type"] != "chute" and r["gas"]["enabled"]:
        raise CaseError("gas.enabled", "the gas phase is available for geometry.type = 'chute' only")
    if r["frame"]["rpm"] != 0 and r["gravity"]["g"] == 0:
        raise CaseError("frame.rpm", "a rotating frame needs gravity to define the vertical axis (gravity.g > 0)")


# --------------------------------------------------------------------------------------------
# TOML writer (resolved configuration beside the results) and the generated docs
# --------------------------------------------------------------------------------------------
def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        if v and all(isinstance(x, dict) for x in v):
            raise TypeError("array of tables")
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if v is None:
        raise TypeError("None")
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(type(v))


def dumps_toml(d: dict, prefix: str = "") -> str:
    lines: list[str] = []
    scalars = {k: v for k, v in d.items() if not isinstance(v, dict)}
    tables = {k: v for k, v in d.items() if isinstance(v, dict)}
    aot = {k: v for k, v in scalars.items() if isinstance(v, list) and v and all(isinstance(x, dict) for x in v)}
    for k, v in scalars.items():
        if k in aot or v is None:
            continue
        lines.append(f"{k} = {_toml_value(v)}")
    for k, v in aot.items():
        for item in v:
            lines.append(f"\n[[{prefix}{k}]]")
            for kk, vv in item.items():
                lines.append(f"{kk} = {_toml_value(vv)}")
    for k, v in tables.items():
        lines.append(f"\n[{prefix}{k}]")
        lines.append(dumps_toml(v, prefix=f"{prefix}{k}."))
    return "\n".join(x for x in lines if x is not None).strip() + "\n"


def _fmt_default(v) -> str:
    if v is None:
        return "(derived)"
    if isinstance(v, str):
        return f'"{v}"' if v else '""'
    if isinstance(v, float) and math.isinf(v):
        return "inf"
    return _toml_value(v) if not isinstance(v, list) or not v or not isinstance(v[0], dict) else "[]"


def schema_markdown() -> str:
    """The reference of every key (``docs/case-format.md`` body)."""
    out = []

    def walk(sec: dict, prefix: str):
        rows = []
        subs = []
        for k, spec in sec.items():
            if isinstance(spec, dict):
                subs.append((k, spec))
            else:
                rng = spec.describe_range()
                rows.append(f"| `{k}` | {spec.type} | {spec.unit} | `{_fmt_default(spec.default)}` | {rng} | {spec.doc} |")
        if rows:
            out.append(f"\n### `[{prefix}]`\n")
            out.append("| key | type | unit | default | allowed | meaning |")
            out.append("|---|---|---|---|---|---|")
            out.extend(rows)
        for k, spec in subs:
            walk(spec, f"{prefix}.{k}")

    for name, sec in SCHEMA.items():
        walk(sec, name)
    return "\n".join(out) + "\n"



CASE_FORMAT_HEADER = """# Case format

A case is a folder holding `case.toml` (TOML, SI units). Every key is optional unless marked;
the defaults are below. Unknown keys, wrong types and out-of-range values are refused with a
one-line error naming the key (exit code 2), with a "did you mean" hint for typos.

Any key can be overridden on the command line with a dotted path, the value parsed as TOML:

    cfddem run cases/chute_16rpm --set particles.diameter=0.004 --set frame.rpm=8 --set inlet.type=sluice

Axes (chute): x across the chute (0..width), y normal to the floor (floor at y = 0), z down the
chute (entrance at `geometry.z_start`, measurement origin at z = 0). Gravity is
g (0, -cos theta, sin theta) with theta = `gravity.inclination_deg`; the frame rotates about the
vertical (the direction of -gravity) through `frame.axis_point`.

Derived numbers (`cfddem check CASE`): particle mass; per contact pair the normal damping
eta_n = -2 ln(e_n) sqrt(m* k_n) / sqrt(pi^2 + ln^2 e_n), k_t = (2/7) k_n (pi^2 + ln^2 e_t)/(pi^2 + ln^2 e_n),
eta_t (with m_t = 2/7 m*), the collision time t_c = sqrt(m* (pi^2 + ln^2 e_n)/k_n) (m* = m/2
particle-particle, m particle-wall); dt/t_c (warning above t_c/20, refused above t_c/5 unless
`time.force = true` or `--force`); the stable step: velocity Verlet on the most limiting contact,
normal and tangential modes with their damping (refused above it unless forced: the run would fail;
docs/stability.md); the expected particle count and memory.
With `contact.model = "hertz_mindlin"`: E* = E/(2(1 - nu^2)), G* = E/(4(2 - nu)(1 + nu)), beta, and
at the expected impact speed v (the case's speed scale, at least 1 m/s) the Hertz collision time
t_c = 2.87 (m*^2/(R* E*^2 v))^(1/5) and the Rayleigh time T_R = pi R sqrt(rho/G)/(0.1631 nu + 0.8766);
warning above dt = t_c/20 or 0.2 T_R, refused above t_c/5 or the stable step unless forced.

This file is generated from `cfddem/config.py` (`python -m cfddem.config > docs/case-format.md`);
a test keeps it current.
"""


def case_format_markdown() -> str:
    return CASE_FORMAT_HEADER + schema_markdown()


if __name__ == "__main__":  # pragma: no cover
    print(case_format_markdown(), end="")
