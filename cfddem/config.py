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
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .coupling.drag import CLOSURES, DEFAULT_CLOSURE
from .errors import CaseError
from .particles.contact import CONTACT_LAWS, DEFAULT_LAW, check_contact_values, check_docs, contact_keys
from .scenes import DEFAULT_SCENE, SCENE_TYPES, scene_class, scene_docs, scene_schemas
from .scenes.common import MESH_KEYS, mesh_default_name
from .schema import Key
from .schema import nonneg as _nonneg
from .schema import number as _f
from .schema import positive as _pos

INF = float("inf")


# --------------------------------------------------------------------------------------------
# schema
# --------------------------------------------------------------------------------------------
def _contact_section() -> dict:
    """The [contact] schema from the registered contact laws (cfddem/particles/contact/):
    ``model`` and the keys of every law in ``particle_particle`` and ``particle_wall``."""

    def table(wall: bool) -> dict:
        return {k.name: Key("float", k.default_for(wall), k.unit, k.doc, lo=k.lo, hi=k.hi, lo_open=k.lo_open,
                            hi_open=k.hi_open)
                for k in contact_keys().values()}

    laws = " or ".join(law.model_doc() for law in CONTACT_LAWS.values())
    return {
        "model": Key("str", DEFAULT_LAW, "-", f"contact law: {laws}", choices=tuple(CONTACT_LAWS)),
        "particle_particle": table(False),
        "particle_wall": table(True),
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
        "perturb_velocity": Key("float", 0.0, "m/s", "replicas of a branch: add to every free particle (not held "
                                "feeds) a random velocity of this root-mean-square magnitude when the run starts from "
                                "checkpoint.start_from, drawn with checkpoint.perturb_seed, zero net momentum; the "
                                "chaotic flow amplifies a tiny one (1e-6) into an independent replica (0: off)",
                                lo=0.0, hi=INF, hi_open=True),
        "perturb_seed": Key("int", 0, "-", "seed of checkpoint.perturb_velocity: branches with the same seed are "
                            "identical, with different seeds independent replicas", lo=0),
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
                            "CSV columns x,y,z,vx,vy,vz,wx,wy,wz,radius,label (header line), HDF5 datasets pos, vel, "
                            "omega, radius, label (velocities, spins and the integer tracer label optional)"),
        "initial": Key("tables", [], "-", "inline initial particles: [[particles.initial]] tables with pos (m), "
                       "radius (m), and optional vel (m/s), omega (rad/s), label (integer tracer label, 0)"),
        "max_overlap_ratio": _f(0.5, "-", "stop the run when an overlap exceeds this fraction of the smaller radius",
                                lo=0.0, lo_open=True, hi=1.0),
        "skin": _nonneg(0.0, "m", "Verlet-list skin (0: 0.3 x the largest diameter)"),
        "seed": Key("int", 12345, "-", "seed for polydisperse sizes", lo=0),
        "clump": Key("str", "none", "-", "particle shape: 'none' (spheres) or a rigid clump of spheres of this "
                     "diameter: 'pellet2' (two spheres d/2 apart), 'pellet4' (tetrahedron of edge d/2); clumps are "
                     "inserted by the shear_cell and silo fills and the sluice inlet, one per lattice "
                     "site in a random orientation; 'template': the spheres of particles.clump_spheres; initial "
                     "particles stay spheres (docs/particles.md)",
                     choices=("none", "pellet2", "pellet4", "template")),
        "clump_spheres": Key("rows", [], "d", "clump template (particles.clump = 'template'): one row [x, y, z, r] per "
                             "sphere, centre and radius in units of particles.diameter, e.g. the thesis's 2-sphere "
                             "clump of 3 mm spheres 0.75 mm apart: [[-0.125, 0, 0, 0.5], [0.125, 0, 0, 0.5]] with "
                             "diameter = 0.003; the spheres must overlap or touch (one rigid body); mass and inertia "
                             "of their union", length=4),
        "rotation": Key("str", "free", "-", "'free', or 'locked': the case's particles (spheres and clumps) do not "
                        "rotate (their spin stays zero; contact torques are ignored), the usual calibration device "
                        "that stands in for the interlocking of non-spherical grains; bodies a scene adds (the shear "
                        "cell's lid) stay free.  Scenes that pour a lattice and let it settle (shear_cell, silo) "
                        "pour with free rotation and lock at the end of the fill (locked spheres dropped on a "
                        "lattice stay stacked in columns: docs/particles.md)", choices=("free", "locked")),
    },
    "contact": _contact_section(),
    "geometry": {
        "type": Key("str", DEFAULT_SCENE, "-", "the scene (cfddem/scenes/): " + scene_docs(), choices=SCENE_TYPES),
        "walls": Key("tables", [], "-", "extra walls: [[geometry.walls]] with type = 'plane' (point, normal) or "
                     "'rectangle' (point = centre, normal, u_axis, half_extents = [a, b]) or 'cylinder' (the inside of a ring: "
                     "point = centre, axis, radius, half_height, optional inside = false for the outer surface) or "
                     "'mesh' (a triangle mesh from file = an STL or OBJ file, relative to the case folder; optional "
                     "scale or units = 'm', 'cm', 'mm', 'um', 'in', 'ft'; rotate = [axis x, y, z, degrees] about the "
                     "origin, then translate = [x, y, z] m; motion: velocity = [vx, vy, vz] m/s, angular_velocity = "
                     "[wx, wy, wz] rad/s about center = [x, y, z] m (default: the centre of the mesh's bounds), "
                     "schedule = [[time, true/false], ...] switches it on/off at those times, active = false starts it "
                     "off; flip_normals = true when the triangles' normals point away from the particles; name: "
                     "letters, digits, '_', '-' (default: the file's stem), used in the results.h5 series "
                     "mesh_<name>_fx..tz); optional contact keys: any key of [contact.particle_wall] (the contact "
                     "law's), for this wall"),
    },
    "exit": {
        "lost_margin": _pos(0.5, "m", "particles farther than this outside the walls' bounding box are removed as lost"),
    },
    "measurements": {
        "enabled": Key("bool", True, "-", "the scene's sampled measurements (the chute: bed height, surface velocity, "
                       "mean velocity)"),
        "start_time": _nonneg(0.0, "s", "time averages (the scene's and the gas's) start here (steady state)"),
        "interval": _pos(0.01, "s", "sampling interval of the time averages"),
    },
    "study": {
        "compare_without_gas": Key("bool", False, "-", "after a run with gas, run the same case without gas into "
                                   "OUT/no_gas and write the gas-against-no-gas report into OUT/compare"),
    },
    "gas": {
        "enabled": Key("bool", False, "-", "solve the interstitial gas (two-way coupled)"),
        "density": _pos(1.2, "kg/m^3", "gas density"),
        "viscosity": _pos(1.8e-5, "Pa s", "gas dynamic viscosity"),
        "cells": Key("ints", [16, 15, 150], "-", "gas grid NX, NY, NZ", length=3),
        "coupling_interval": Key("int", 10, "-", "particle steps per gas step", lo=1),
        "coupling": Key("str", "two_way", "-", "'two_way': the gas and the particles act on each other; "
                        "'one_way_rest': a bracketing run, the air held at rest in the simulation's frame with "
                        "its initial (hydrostatic) pressure, not solved: the particles feel its drag and buoyancy, "
                        "the air feels nothing (the most slip drag could act on)",
                        choices=("two_way", "one_way_rest")),
        "drag_factor": Key("float", 1.0, "-", "every drag coefficient times this (a bracketing run: how the result "
                           "follows the drag; 1: the closure as published)", lo=0.0),
        "drag_treatment": Key("str", "implicit", "-", "'implicit': drag implicit in the gas step and bounded "
                              "(exact exponential relaxation) for the particles, stable for any particle relaxation "
                              "time; 'explicit': forward Euler, for comparison", choices=("implicit", "explicit")),
        "drag": Key("str", DEFAULT_CLOSURE, "-", "drag closure (cfddem/coupling/drag.py, docs/coupling.md)",
                    choices=tuple(CLOSURES)),
        "pressure_solver": Key("str", "mg", "-", "pressure solver: 'mg' (compiled geometric multigrid as CG "
                               "preconditioner) or 'amg' (pyamg smoothed aggregation, for comparison)",
                               choices=("mg", "amg")),
        "pressure_tol": Key("float", 1e-8, "-", "relative residual at which the pressure solve stops; on the "
                            "recorded chute gas steps 1e-6 is 7-9 % cheaper per gas step and moves p and grad p "
                            "by < 1e-6 of their scale (docs/gas.md, 'Tolerance')", lo=0.0, hi=0.1, lo_open=True),
    },
}



def _assemble(base: dict, scenes: dict[str, dict]) -> tuple[dict, dict]:
    """The full schema: the base sections with every scene's keys merged in (a scene's new
    sections right after ``[geometry]``), and the owner of each scene key."""
    owner: dict[tuple[str, str], set[str]] = {}
    added: dict[str, dict] = {}
    for name, parts in scenes.items():
        for sec, keys in parts.items():
            target = base.get(sec)
            if target is None:
                target = added.setdefault(sec, {})
            for k, spec in keys.items():
                prev = owner.get((sec, k))
                if k in target and prev is None:
                    raise AssertionError(f"scene {name!r} redefines the shared key {sec}.{k}")
                if prev is not None and target[k] != spec:
                    raise AssertionError(f"scenes {sorted(prev)} and {name!r} define {sec}.{k} differently")
                target[k] = spec
                owner.setdefault((sec, k), set()).add(name)
    out: dict[str, dict] = {}
    for sec, keys in base.items():
        out[sec] = keys
        if sec == "geometry":
            out.update(added)
    return out, owner


SCHEMA, _SCENE_KEY_OWNER = _assemble(SCHEMA, scene_schemas())

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
        _check_length(key, spec, v, "numbers")
        out = [_as_float(f"{key}[{i}]", x) for i, x in enumerate(v)]
        for i, x in enumerate(out):
            _check_range(f"{key}[{i}]", spec, x)
        return out
    if t == "ints":
        if not isinstance(v, list) or not all(isinstance(x, int) and not isinstance(x, bool) for x in v):
            raise CaseError(key, f"expected an array of integers, got {v!r}")
        _check_length(key, spec, v, "integers")
        if any(x < 1 for x in v):
            raise CaseError(key, f"every entry must be >= 1, got {v!r}")
        return list(v)
    if t == "rows":
        if not isinstance(v, list) or not all(isinstance(x, list) for x in v):
            raise CaseError(key, f"expected an array of rows (arrays of {spec.length} numbers), got {v!r}")
        for i, row in enumerate(v):
            if spec.length is not None and len(row) != spec.length:
                raise CaseError(f"{key}[{i}]", f"expected {spec.length} numbers, got {len(row)}: {row!r}")
        return [[_as_float(f"{key}[{i}][{j}]", x) for j, x in enumerate(row)] for i, row in enumerate(v)]
    if t == "tables":
        if not isinstance(v, list) or not all(isinstance(x, dict) for x in v):
            raise CaseError(key, "expected an array of tables ([[...]] entries)")
        return copy.deepcopy(v)
    raise AssertionError(t)


def _check_length(key: str, spec: Key, v: list, what: str) -> None:
    if spec.length is not None and len(v) != spec.length:
        raise CaseError(key, f"expected an array of {spec.length} {what}, got {len(v)}: {v!r}")
    if not v:
        raise CaseError(key, f"expected an array of {what}, got an empty array")


def _suggest_choice(v: str, choices) -> str:
    m = difflib.get_close_matches(v, list(choices), n=1, cutoff=0.5)
    return f"; did you mean '{m[0]}'?" if m else ""


# --------------------------------------------------------------------------------------------
# consistency of the whole case
# --------------------------------------------------------------------------------------------
_ANALYTIC_WALL_KEYS = {"point", "normal", "u_axis", "half_extents", "axis", "radius", "half_height", "inside"}
_WALL_KEYS = {"type", "name"} | _ANALYTIC_WALL_KEYS | set(MESH_KEYS) | set(contact_keys())  # geometry.walls
# entries: geometry (analytic or mesh) and the contact-law keys
_INITIAL_KEYS = {"pos", "vel", "omega", "radius", "label"}


def _vec(key: str, v, n=3) -> list[float]:
    if not isinstance(v, list) or len(v) != n:
        raise CaseError(key, f"expected an array of {n} numbers, got {v!r}")
    return [_as_float(f"{key}[{i}]", x) for i, x in enumerate(v)]


def _check_mesh_wall(key: str, w: dict, case_dir: Path) -> None:
    """A ``type = "mesh"`` wall of geometry.walls: its keys, then its file read as a mesh."""
    from .particles.mesh import UNITS
    from .scenes.common import WallSpec, mesh_wall

    for k in w:
        if k in _ANALYTIC_WALL_KEYS:
            raise CaseError(f"{key}.{k}", "not a key of a mesh wall (its geometry comes from file)")
    if "file" not in w:
        raise CaseError(f"{key}.file", "required for a mesh wall: an STL or OBJ file, relative to the case folder")
    if not isinstance(w["file"], str) or not w["file"]:
        raise CaseError(f"{key}.file", f"expected a file name, got {w['file']!r}")
    f = case_dir / w["file"]
    if not f.is_file():
        raise CaseError(f"{key}.file", f"no such file: {f}")
    name = w.get("name", mesh_default_name(w["file"]))
    if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z0-9_-]+", name):
        raise CaseError(f"{key}.name", f"{name!r}: use letters, digits, '_' and '-' (it names the results.h5 series)")
    if "scale" in w and not _as_float(f"{key}.scale", w["scale"]) > 0:
        raise CaseError(f"{key}.scale", f"must be positive, got {w['scale']!r}")
    if "units" in w and w["units"] not in UNITS:
        raise CaseError(f"{key}.units", f"{w['units']!r} is not allowed: one of {', '.join(map(repr, UNITS))}")
    if "scale" in w and "units" in w:
        raise CaseError(f"{key}.scale", "give scale or units, not both")
    if "rotate" in w:
        rot = w["rotate"]
        if not isinstance(rot, list) or len(rot) != 4:
            raise CaseError(f"{key}.rotate", f"expected [axis x, y, z, angle in degrees], got {rot!r}")
        rot = _vec(f"{key}.rotate", rot, 4)
        if math.hypot(*rot[:3]) == 0:
            raise CaseError(f"{key}.rotate", "the axis (first three numbers) must not be the zero vector")
    for k in ("translate", "velocity", "angular_velocity", "center"):
        if k in w:
            _vec(f"{key}.{k}", w[k])
    for k in ("active", "flip_normals"):
        if k in w and not isinstance(w[k], bool):
            raise CaseError(f"{key}.{k}", f"expected true or false, got {w[k]!r}")
    if "schedule" in w:
        sch = w["schedule"]
        if not isinstance(sch, list) or not all(isinstance(x, list) and len(x) == 2 and isinstance(x[1], bool)
                                                and not isinstance(x[0], bool) for x in sch):
            raise CaseError(f"{key}.schedule", f"expected [[time, true or false], ...], got {sch!r}")
        for j, (t, _) in enumerate(sch):
            if not _as_float(f"{key}.schedule[{j}]", t) >= 0:
                raise CaseError(f"{key}.schedule[{j}]", f"switch time must be >= 0, got {t!r}")
    m = {k: w[k] for k in MESH_KEYS if k in w}
    m.update(file=str(f), key=key)
    mesh_wall(WallSpec(name, "mesh", None, None, mesh=m))  # reads it: not a mesh, no triangles, ...


def _default_of(spec):
    """The default of a key, or the defaults of a (sub)section."""
    return {k: _default_of(v) for k, v in spec.items()} if isinstance(spec, dict) else spec.default


def _check_consistency(r: dict, case_dir: Path) -> None:
    p, geo = r["particles"], r["geometry"]
    d = p["diameter"]
    if p["diameter_max"] and p["diameter_max"] < d:
        raise CaseError("particles.diameter_max", f"{p['diameter_max']:g} is smaller than particles.diameter = {d:g}")
    scene = scene_class(geo["type"])
    for (sec, k), owners in _SCENE_KEY_OWNER.items():
        if geo["type"] not in owners and r[sec][k] != _default_of(SCHEMA[sec][k]):
            names = " or ".join(f"'{o}'" for o in sorted(owners))
            raise CaseError(f"{sec}.{k}", f"needs geometry.type = {names} (this case has '{geo['type']}')")
    scene.check(r, case_dir)
    seen = {}
    for i, w in enumerate(geo["walls"]):
        key = f"geometry.walls[{i}]"
        name = w.get("name", mesh_default_name(w["file"]) if w.get("type") == "mesh" and isinstance(w.get("file"), str)
                      else f"wall{i}")
        if isinstance(name, str) and name in seen:
            raise CaseError(f"{key}.name", f"{name!r} is already the name of geometry.walls[{seen[name]}]: "
                                           "give each wall its own name")
        seen[name] = i
        for k in w:
            if k not in _WALL_KEYS:
                raise CaseError(f"{key}.{k}", "unknown key" + _suggest(k, _WALL_KEYS))
        wt = w.get("type")
        if wt not in ("plane", "rectangle", "cylinder", "mesh"):
            raise CaseError(f"{key}.type", f"{wt!r} is not allowed: one of 'plane', 'rectangle', 'cylinder', 'mesh'")
        if wt == "mesh":
            _check_mesh_wall(key, w, case_dir)
            check_contact_values(key, {k: _as_float(f"{key}.{k}", w[k]) for k in contact_keys() if k in w})
            continue
        for k in w:
            if k in MESH_KEYS:
                raise CaseError(f"{key}.{k}", "only for a mesh wall (type = 'mesh')")
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
        check_contact_values(key, {k: _as_float(f"{key}.{k}", w[k]) for k in contact_keys() if k in w})
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
        if "label" in t and (isinstance(t["label"], bool) or not isinstance(t["label"], int)):
            raise CaseError(f"{key}.label", f"{t['label']!r} must be an integer (a tracer label)")
    sf = r["checkpoint"]["start_from"]
    if r["checkpoint"]["perturb_velocity"] > 0 and not sf:
        raise CaseError("checkpoint.perturb_velocity", "perturbs a branch: set checkpoint.start_from too")
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
        from .scenes.common import read_particle_file

        read_particle_file(f)  # its columns and values are checked before any run folder exists
    if p["clump"] != "none" and not scene.inserts_clumps(r):
        raise CaseError("particles.clump", "clumps are inserted by a scene's fill or inlet only (initial particles "
                                           f"are spheres): geometry.type = '{geo['type']}' with these settings has none")
    if p["clump"] == "template":
        from .particles.clumps import check_template

        check_template(p["clump_spheres"])
    elif p["clump_spheres"]:
        raise CaseError("particles.clump_spheres", f"a clump template needs particles.clump = 'template' "
                                                   f"(this case has {p['clump']!r})")
    if p["clump"] != "none" and p["diameter_max"] > 0:
        raise CaseError("particles.diameter_max", "pellets (particles.clump) are monodisperse: leave it 0")
    if r["gas"]["enabled"] and not scene.HAS_GAS:
        with_gas = ", ".join(f"'{n}'" for n in SCENE_TYPES if scene_class(n).HAS_GAS)
        raise CaseError("gas.enabled", f"geometry.type = '{geo['type']}' declares no gas domain (scenes with gas: "
                                       f"{with_gas})")
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

    def scenes_of(prefix: str, k: str | None = None) -> str:
        """'' or ' (geometry.type = ...)' for a key or section a scene contributes."""
        top, *rest = prefix.split(".")
        owners = _SCENE_KEY_OWNER.get((top, rest[0] if rest else k))
        if not owners or (k is not None and rest):  # keys inside a scene's section: said at the header
            return ""
        return " (geometry.type = " + " or ".join(f"'{o}'" for o in sorted(owners)) + ")"

    def walk(sec: dict, prefix: str):
        rows = []
        subs = []
        whole = bool(scenes_of(prefix)) and "." in prefix or all(scenes_of(prefix, k) for k in sec)
        for k, spec in sec.items():
            if isinstance(spec, dict):
                subs.append((k, spec))
            else:
                rng = spec.describe_range()
                doc = spec.doc if whole else (f"*{scenes_of(prefix, k)[2:-1]}:* " if scenes_of(prefix, k) else "") + spec.doc
                rows.append(f"| `{k}` | {spec.type} | {spec.unit} | `{_fmt_default(spec.default)}` | {rng} | {doc} |")
        if rows:
            head = (scenes_of(prefix) if "." in prefix else scenes_of(prefix, next(iter(sec)))) if whole else ""
            out.append(f"\n### `[{prefix}]`{head}\n")
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
one-line error naming the key (exit code 2), with a "did you mean" hint for typos; arrays must
have the stated number of entries. A case that does not validate writes nothing.

`geometry.type` names the scene (one module in `cfddem/scenes/`). Keys and sections marked with a
geometry type belong to that scene: setting one to a non-default value in a case of another
scene is refused.

Any key can be overridden on the command line with a dotted path, the value parsed as TOML:

    cfddem run cases/chute_16rpm --set particles.diameter=0.004 --set frame.rpm=8 --set inlet.type=sluice

Axes (chute): x across the chute (0..width), y normal to the floor (floor at y = 0), z down the
chute (entrance at `geometry.z_start`, measurement origin at z = 0). Gravity is
g (0, -cos theta, sin theta) with theta = `gravity.inclination_deg`; the frame rotates about the
vertical (the direction of -gravity) through `frame.axis_point`.

Derived numbers (`cfddem check CASE`): particle mass; per contact pair {default_law_numbers}; dt/t_c (warning above t_c/20, refused above t_c/5 unless
`time.force = true` or `--force`); the stable step: velocity Verlet on the most limiting contact,
normal and tangential modes with their damping (refused above it unless forced: the run would fail;
docs/stability.md); the expected particle count and memory.
{other_law_numbers}
This file is generated from `cfddem/config.py` (`python -m cfddem.config > docs/case-format.md`);
a test keeps it current.
"""


def case_format_markdown() -> str:
    # the derived numbers of each contact law come from its module (check_doc)
    default_law, other_laws = check_docs()
    header = CASE_FORMAT_HEADER.replace("{default_law_numbers}", default_law).replace("{other_law_numbers}", other_laws)
    return header + schema_markdown()


if __name__ == "__main__":  # pragma: no cover
    print(case_format_markdown(), end="")
