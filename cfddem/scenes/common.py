"""What every scene shares: gravity, frame rotation, the wall description (:class:`WallSpec`),
the extra ``[[geometry.walls]]``, the bounding box and the initial particles.  Pure set-up code
used by the :class:`~cfddem.simulation.Simulation`, ``cfddem check`` and the scene modules.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from ..errors import CaseError
from ..particles.contact import contact_keys


FILL_KEYS = ("fill_friction", "fill_rolling_friction")


def check_fill_friction(section: str, s: dict) -> None:
    """A scene's ``fill_friction`` and ``fill_rolling_friction``
    (:func:`cfddem.schema.fill_friction`, :func:`cfddem.schema.fill_rolling_friction`): -1 or >= 0."""
    for key in FILL_KEYS:
        value = s[key]
        if value != -1.0 and value < 0.0:
            raise CaseError(f"{section}.{key}", f"{value:g} must be >= 0 (or -1: unchanged)")


def fill_friction_set(s: dict) -> bool:
    """Whether a scene's section asks for a fill friction of its own (either key >= 0)."""
    return any(s[key] >= 0.0 for key in FILL_KEYS)


def apply_fill_friction(system, s: dict) -> None:
    """The fill's particle-particle sliding and rolling friction (the keys that are >= 0; the
    rest keep the case's) until the scene calls ``system.set_friction(True)``."""
    if fill_friction_set(s):
        mu, mur = (s[key] for key in FILL_KEYS)
        system.set_friction(False, pp_mu=mu if mu >= 0.0 else None, pp_mur=mur if mur >= 0.0 else None)


def gravity_vector(case) -> np.ndarray:
    """g (0, -cos theta, sin theta): chute axes x across, y normal to the floor, z downstream."""
    th = math.radians(case.gravity.inclination_deg)
    return case.gravity.g * np.array([0.0, -math.cos(th), math.sin(th)])


def frame_omega(case) -> np.ndarray:
    """Frame angular velocity: rpm * 2 pi / 60 about the vertical (against gravity)."""
    rpm = case.frame.rpm
    if rpm == 0.0:
        return np.zeros(3)
    g = gravity_vector(case)
    up = -g / np.linalg.norm(g)
    return rpm * 2.0 * math.pi / 60.0 * up


@dataclass
class WallSpec:
    """A wall as the case describes it (converted to the engine's wall objects by the caller)."""

    name: str
    kind: str  # "plane" | "rectangle" | "cylinder" (normal = axis, half_extents = (radius, half_height)) | "mesh"
    point: np.ndarray
    normal: np.ndarray
    u_axis: np.ndarray | None = None
    half_extents: tuple[float, float] | None = None
    params: dict | None = None  # contact keys of the law (cfddem.particles.contact), e.g. k_n, e_n, e_t, mu, mu_r
    inside: bool = True  # cylinder: particles inside the ring
    #: angular speed (rad/s) of the surface about the wall's axis / normal through its point
    #: (cfddem.particles.walls: a rotating drum's shell and end plates)
    spin: float = 0.0
    #: a mesh wall: its [[geometry.walls]] keys (``file`` resolved against the case folder) and
    #: ``key`` (``geometry.walls[i]``, for error messages); :func:`mesh_wall` reads it
    mesh: dict | None = None

    def quads(self, size: float = 1.0, segments: int = 32) -> list[np.ndarray]:
        """Quadrilaterals for drawing: the corners of a plane/rectangle, or a cylinder's band of
        ``segments`` quads; none for a mesh (ParaView gets meshes as triangles)."""
        if self.kind == "mesh":
            return []
        if self.kind != "cylinder":
            return [self.corners(size)]
        a = self.normal / np.linalg.norm(self.normal)
        t = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e1 = t - np.dot(t, a) * a
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(a, e1)
        rc, hh = self.half_extents
        ph = np.linspace(0.0, 2.0 * np.pi, segments + 1)
        ring = [self.point + rc * (np.cos(f) * e1 + np.sin(f) * e2) for f in ph]
        return [np.array([ring[k] - hh * a, ring[k + 1] - hh * a, ring[k + 1] + hh * a, ring[k] + hh * a])
                for k in range(segments)]

    def box(self) -> np.ndarray:
        """(2, 3) lower and upper corner of a cylinder's axis-aligned bounding box."""
        a = self.normal / np.linalg.norm(self.normal)
        rc, hh = self.half_extents
        ext = hh * np.abs(a) + rc * np.sqrt(np.clip(1.0 - a * a, 0.0, 1.0))
        return np.array([self.point - ext, self.point + ext])

    def corners(self, size: float = 1.0) -> np.ndarray:
        """Four corners (for drawing); planes are drawn as a square of side 2*size."""
        n = self.normal / np.linalg.norm(self.normal)
        if self.u_axis is not None:
            u = self.u_axis - np.dot(self.u_axis, n) * n
        else:
            t = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
            u = t - np.dot(t, n) * n
        u /= np.linalg.norm(u)
        v = np.cross(n, u)
        a, b = self.half_extents if self.half_extents is not None else (size, size)
        c = self.point
        return np.array([c - a * u - b * v, c + a * u - b * v, c + a * u + b * v, c - a * u + b * v])


def wall_specs(case) -> list[WallSpec]:
    """Every wall of a case: its scene's walls, then the extra ``[[geometry.walls]]``; each with
    its complete contact parameters (``contact.particle_wall`` under its own overrides)."""
    from . import scene_of

    geo = case.geometry
    pw = case.resolved["contact"]["particle_wall"]
    walls: list[WallSpec] = list(scene_of(case).wall_specs(case))
    for i, w in enumerate(geo.walls):
        params = {k: float(w[k]) for k in contact_keys() if k in w}
        if w["type"] == "mesh":
            m = {k: w[k] for k in MESH_KEYS if k in w}
            m["file"] = str(case.path / w["file"])
            m["key"] = f"geometry.walls[{i}]"
            walls.append(WallSpec(w.get("name", mesh_default_name(w["file"])), "mesh", np.zeros(3), np.zeros(3),
                                  params=params, mesh=m))
            continue
        if w["type"] == "cylinder":
            walls.append(WallSpec(w.get("name", f"wall{i}"), "cylinder", np.array(w["point"], float),
                                  np.array(w["axis"], float), None,
                                  (float(w["radius"]), float(w["half_height"])), params,
                                  inside=bool(w.get("inside", True))))
            continue
        spec = WallSpec(w.get("name", f"wall{i}"), w["type"], np.array(w["point"], float),
                        np.array(w["normal"], float),
                        np.array(w["u_axis"], float) if "u_axis" in w else None,
                        tuple(w["half_extents"]) if "half_extents" in w else None, params)
        if spec.kind == "rectangle":
            n = spec.normal / np.linalg.norm(spec.normal)
            u = spec.u_axis
            if np.linalg.norm(u - np.dot(u, n) * n) < 1e-9 * np.linalg.norm(u):
                raise CaseError(f"geometry.walls[{i}].u_axis", "must not be parallel to the normal")
        walls.append(spec)
    for w in walls:
        full = dict(pw)
        full.update(w.params or {})
        w.params = full
    return walls


#: the keys of a ``type = "mesh"`` wall besides ``type``, ``name`` and the contact keys
MESH_KEYS = ("file", "scale", "units", "rotate", "translate", "velocity", "angular_velocity", "center",
             "schedule", "active", "flip_normals")


def mesh_default_name(file: str) -> str:
    """A mesh wall's name when the case gives none: the file's stem, characters other than
    letters, digits, '_' and '-' replaced by '_'."""
    from pathlib import PurePath

    return re.sub(r"[^A-Za-z0-9_-]", "_", PurePath(file).stem) or "mesh"


def mesh_wall(w: WallSpec, contact=None):
    """The :class:`~cfddem.particles.mesh.MeshWall` of a ``kind = "mesh"`` WallSpec, read from its
    file (``contact``: its contact law; None to check the geometry only).  Errors are one-line
    :class:`CaseError` naming ``geometry.walls[i].<key>``."""
    from ..particles.mesh import MeshWall

    m = w.mesh
    rot = m.get("rotate")
    kw = {k: m[k] for k in ("velocity", "angular_velocity", "center", "active", "flip_normals") if k in m}
    try:
        return MeshWall.from_file(m["file"], contact, scale=m.get("scale"), units=m.get("units"),
                                  rotate=None if rot is None else (rot[:3], rot[3]),
                                  translate=m.get("translate", (0.0, 0.0, 0.0)), name=w.name,
                                  schedule=[tuple(x) for x in m.get("schedule", ())], **kw)
    except CaseError as e:  # MeshWall names its keys "mesh 'name'.<key>": name the case's key
        sub = e.key.rsplit(".", 1)[1] if e.key and e.key.startswith("mesh ") and "." in e.key else None
        raise CaseError(f"{m['key']}.{sub}" if sub else m["key"], e.reason) from None


def mesh_box(w: WallSpec, mesh=None) -> np.ndarray | None:
    """(2, 3) box a mesh wall stays within: its bounds, or for a rotating mesh the box of the
    sphere about its centre holding all vertices; None for a translating mesh (no fixed box)."""
    m = mesh if mesh is not None else mesh_wall(w)
    if np.any(m.velocity != 0.0):
        return None
    if np.any(m.angular_velocity != 0.0):
        r = float(np.max(np.linalg.norm(m.vertices - m.center, axis=1)))
        return np.array([m.center - r, m.center + r])
    return np.array(m.bounds())


def walls_bounding_box(walls: list[WallSpec], case) -> tuple[np.ndarray, np.ndarray]:
    """Bounding box of the scene (for lost-particle detection): rectangles' corners, cylinders'
    boxes, meshes' boxes (:func:`mesh_box`) and the scene's own bounds; unbounded when a mesh
    translates."""
    from . import scene_of

    pts = [w.corners() for w in walls if w.kind == "rectangle"] + [w.box() for w in walls if w.kind == "cylinder"]
    for w in walls:
        if w.kind == "mesh":
            b = mesh_box(w)
            if b is None:
                return np.full(3, -np.inf), np.full(3, np.inf)
            pts.append(b)
    extra = scene_of(case).bounds(case)
    if extra is not None:
        pts.append(np.asarray(extra, float))
    if not pts:
        return np.full(3, -np.inf), np.full(3, np.inf)
    allp = np.concatenate(pts)
    return allp.min(axis=0), allp.max(axis=0)


def initial_particles(case) -> dict[str, np.ndarray]:
    """Initial particles from [[particles.initial]] and/or particles.initial_file."""
    d = case.particles.diameter
    pos, vel, om, rad, lab = [], [], [], [], []
    for t in case.particles.initial:
        pos.append(t["pos"])
        vel.append(t.get("vel", [0.0, 0.0, 0.0]))
        om.append(t.get("omega", [0.0, 0.0, 0.0]))
        rad.append(float(t.get("radius", d / 2)))
        lab.append(int(t.get("label", 0)))
    if case.particles.initial_file:
        f = case.path / case.particles.initial_file
        data = read_particle_file(f)
        pos.extend(data["pos"].tolist())
        vel.extend(data["vel"].tolist())
        om.extend(data["omega"].tolist())
        rad.extend(data["radius"].tolist())
        lab.extend(data["label"].tolist())
    out = {
        "pos": np.array(pos, float).reshape(-1, 3),
        "vel": np.array(vel, float).reshape(-1, 3),
        "omega": np.array(om, float).reshape(-1, 3),
        "radius": np.array(rad, float),
        "label": np.array(lab, np.int64),
    }
    return out


def read_particle_file(f) -> dict[str, np.ndarray]:
    """CSV (header x,y,z,vx,vy,vz,wx,wy,wz,radius,label; velocities, spins and labels optional)
    or HDF5 (datasets pos, radius; optional vel, omega, label)."""
    key = "particles.initial_file"
    try:
        if f.suffix.lower() == ".csv":
            arr = np.genfromtxt(f, delimiter=",", names=True, dtype=float)
            names = arr.dtype.names or ()
            arr = np.atleast_1d(arr)
            for c in ("x", "y", "z", "radius"):
                if c not in names:
                    raise CaseError(key, f"{f.name}: missing column '{c}' (need x,y,z,radius; optional vx,vy,vz,wx,wy,wz)")

            def col(c):
                return arr[c] if c in names else np.zeros(len(arr))

            pos = np.stack([col("x"), col("y"), col("z")], axis=1)
            vel = np.stack([col("vx"), col("vy"), col("vz")], axis=1)
            om = np.stack([col("wx"), col("wy"), col("wz")], axis=1)
            rad = col("radius")
            lab = col("label")
        else:
            import h5py

            with h5py.File(f, "r") as h:
                if "pos" not in h or "radius" not in h:
                    raise CaseError(key, f"{f.name}: needs datasets 'pos' (n,3) and 'radius' (n,)")
                pos = np.asarray(h["pos"], float).reshape(-1, 3)
                rad = np.asarray(h["radius"], float).ravel()
                vel = np.asarray(h["vel"], float).reshape(-1, 3) if "vel" in h else np.zeros_like(pos)
                om = np.asarray(h["omega"], float).reshape(-1, 3) if "omega" in h else np.zeros_like(pos)
                lab = np.asarray(h["label"]).ravel() if "label" in h else np.zeros(len(pos))
    except CaseError:
        raise
    except (OSError, ValueError) as e:
        raise CaseError(key, f"cannot read {f.name}: {e}") from None
    n = len(pos)
    if not (len(rad) == len(vel) == len(om) == len(lab) == n):
        raise CaseError(key, f"{f.name}: columns have different lengths")
    if not np.all(np.isfinite(lab)) or np.any(lab != np.round(lab)):
        raise CaseError(key, f"{f.name}: label must be an integer (row {int(np.argmax(lab != np.round(lab)))})")
    if not np.all(np.isfinite(pos)) or not np.all(np.isfinite(rad)):
        raise CaseError(key, f"{f.name}: non-finite positions or radii")
    if n and rad.min() <= 0:
        raise CaseError(key, f"{f.name}: radius must be positive (row {int(np.argmin(rad))})")
    return {"pos": pos, "vel": vel, "omega": om, "radius": rad, "label": np.asarray(lab).astype(np.int64)}
