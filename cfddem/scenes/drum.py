"""The rotating drum (``geometry.type = "drum"``, case section ``[drum]``): a horizontal cylinder
with two end plates, partly filled with beads, turning at ``drum.rpm``; the dynamic angle of
repose of the free surface, the flow regime and the torque against the rotation rate
(docs/drum.md).

Axes: the drum axis along z through the origin (end plates at z = -length/2 and +length/2),
gravity along -y (``gravity.inclination_deg`` must be 0), x horizontal.  A positive rpm turns the
drum counter-clockwise seen from +z (angular velocity +z): the bottom of the drum moves towards
+x and the bed rises on the +x side.

Walls (``drum.walls``):

- ``"analytic"``: the inside of a cylinder ``drum`` of ``drum.radius`` (reaching one particle
  diameter past each end plate) and the planes ``plate_back`` (z = -length/2, normal +z) and
  ``plate_front`` (z = +length/2, normal -z); all turn at w = 2 pi rpm / 60 about +z through their
  surface velocity (the walls' ``spin``; the geometry of a surface of revolution does not change
  as it turns).  Contact overrides: ``[drum.wall]`` for the shell, ``[drum.end_plates]`` for the
  plates (unset keys: ``contact.particle_wall``).
- ``"mesh"``: the triangle mesh ``drum.stl`` (a closed cylinder with end plates, normals
  inwards; path relative to the case folder, lengths in ``drum.stl_units``), turned about the z
  axis through the origin at w (the scene sets the mesh's angular velocity: rpm is given once).
  One mesh has one material: ``[drum.wall]``; ``[drum.end_plates]`` is refused with a mesh
  drum.  ``cfddem check`` (and the run) refuse an STL whose radius or length differs from
  ``drum.radius`` / ``drum.length`` by more than 2 % (the facets' mid-lines lie on the radius;
  vertices at up to 2 % beyond it are accepted).

Fill: ``n = fill_fraction * pi R^2 L * solid_fraction / (pi d^3 / 6)`` beads on the lowest sites
of a cubic lattice of spacing d (1 + lattice_gap) inside the drum (seeded jitter), at rest;
they settle with the drum at rest until ``settle_time``, then the drum turns at w.

Sampling: every ``sample_interval`` from the start of the rotation the free-surface profile of
the cross-section (:func:`cfddem.measure.drum.surface_profile`, columns of one diameter, gaps of
one diameter, two diameters clear of the wall) and its line fit over the middle ``fit_fraction``
(:func:`cfddem.measure.drum.fit_surface`): the angle, the S-shape, the fraction of beads
detached above the surface, the torque about the axis that the beads exert on the drum (shell
and plates, or the mesh) and the bed's mean x.  Averages (the dynamic angle of repose with
its standard error from ``n_blocks`` block means, the torque, ...) are over the samples at or
after ``average_start`` (0: settle_time + the time of an eighth of a turn + 0.5 s).  In steady
rotation the torque balances the moment of the bed's weight about the axis:
torque_z = -M g x_com (stored beside the torque as a check).

Regime: expected from the Froude number Fr = w^2 R / g with Mellmann's ranges
(:func:`cfddem.measure.drum.mellmann_regimes`) and found from the run
(:func:`cfddem.measure.drum.classify_run`).

Stored in results.h5: series ``drum_angle_deg`` (the latest sample), ``drum_torque_z`` and
``drum_omega``; ``/measurements/dynamic_angle_deg`` and the details under
``/measurements/drum``; the plot ``drum.png`` (angle against time, the cross-section of the
last sample with its surface and fitted line).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import CaseError
from ..measure.drum import (block_average, classify_run, fit_surface, froude, mellmann_regimes,
                            surface_profile)
from ..particles.contact import check_contact_values
from ..schema import Key, wall_override
from ..schema import nonneg as _nonneg
from ..schema import number as _f
from ..schema import positive as _pos
from . import Scene

DRUM_KEYS = {
    "radius": _pos(0.04, "m", "inner radius R of the drum (axis along z through the origin)"),
    "length": _pos(0.024, "m", "inner length between the end plates (z from -length/2 to +length/2)"),
    "rpm": _f(10.0, "1/min", "rotation rate (positive: counter-clockwise seen from +z, the bed rises on the +x side)"),
    "fill_fraction": _f(0.5, "-", "fraction of the drum's volume taken by the bed (at solid_fraction)", lo=0.0,
                        lo_open=True, hi=0.8),
    "solid_fraction": _f(0.6, "-", "solid fraction of the settled bed, for the number of beads of the fill",
                         lo=0.3, hi=0.74),
    "walls": Key("str", "analytic", "-", "'analytic': a rotating cylinder and two end-plate planes; 'mesh': the "
                 "triangle mesh drum.stl turned about the z axis at rpm", choices=("analytic", "mesh")),
    "stl": Key("str", "drum.stl", "-", "walls = 'mesh': STL or OBJ file of the closed drum (cylinder and end plates, "
               "normals inwards, axis along z through the origin), relative to the case folder"),
    "stl_units": Key("str", "mm", "-", "length unit of the STL file", choices=("m", "cm", "mm", "um", "in", "ft")),
    "settle_time": _nonneg(0.3, "s", "the fill settles with the drum at rest until this time; then it turns"),
    "average_start": _nonneg(0.0, "s", "time averages from here (0: settle_time + the time of 1/8 turn + 0.5 s)"),
    "sample_interval": _pos(0.02, "s", "interval of the free-surface samples"),
    "fit_fraction": _f(0.6, "-", "the line is fitted to the middle fraction of the surface profile's x range",
                       lo=0.2, hi=1.0),
    "n_blocks": Key("int", 5, "-", "block averages for the standard errors of the time averages", lo=2),
    "lattice_gap": _f(0.12, "-", "fill lattice spacing d (1 + lattice_gap)", lo=0.0, lo_open=True, hi=2.0),
    "lattice_jitter": _f(0.08, "-", "random displacement of each lattice site, up to +-jitter d / 2 per axis "
                         "(seeded by particles.seed; below lattice_gap)", lo=0.0, hi=2.0),
    "wall": wall_override("drum shell (and the whole mesh drum)"),
    "end_plates": wall_override("end plates (analytic drum)"),
}


def omega(case) -> float:
    """Angular speed of the drum (rad/s, about +z)."""
    return 2.0 * math.pi * case.resolved["drum"]["rpm"] / 60.0


def n_beads(dr: dict, d: float) -> int:
    """Beads of the fill (module docstring)."""
    vol = dr["fill_fraction"] * math.pi * dr["radius"] ** 2 * dr["length"] * dr["solid_fraction"]
    return max(1, int(round(vol / (math.pi / 6.0 * d ** 3))))


def fill_sites(dr: dict, d: float, n: int, seed: int) -> np.ndarray:
    """The lowest ``n`` sites (by height, then x, then z) of a cubic lattice of spacing
    d (1 + gap) whose spheres, displaced by the seeded jitter, stay clear of the shell and the
    plates; CaseError (drum.fill_fraction) when the drum holds fewer sites."""
    R, L = dr["radius"], dr["length"]
    a = d * (1.0 + dr["lattice_gap"])
    clear = 0.5 * d * (1.0 + dr["lattice_gap"])
    g = np.arange(-R + clear, R - clear + 1e-12, a)
    nz = int(math.floor((L - 2 * clear) / a + 1e-9)) + 1
    if L - 2 * clear < 0:
        raise CaseError("drum.length", f"{L:g} m does not fit one bead of d = {d:g} m")
    z = (np.arange(nz) - 0.5 * (nz - 1)) * a
    X, Y, Z = np.meshgrid(g, g, z, indexing="ij")
    pos = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    pos = pos[np.hypot(pos[:, 0], pos[:, 1]) <= R - clear]
    if len(pos) < n:
        raise CaseError("drum.fill_fraction", f"{dr['fill_fraction']:g} needs {n} beads but the fill lattice holds "
                                              f"{len(pos)}: lower it or drum.lattice_gap")
    pos = pos[np.lexsort((pos[:, 2], pos[:, 0], pos[:, 1]))][:n]
    rng = np.random.default_rng(seed)
    return pos + rng.uniform(-0.5 * dr["lattice_jitter"] * d, 0.5 * dr["lattice_jitter"] * d, size=pos.shape)


def _mesh_spec(case_path, dr: dict, w: float, params: dict | None = None):
    from .common import WallSpec

    m = {"file": str(case_path / dr["stl"]), "units": dr["stl_units"], "angular_velocity": [0.0, 0.0, w],
         "center": [0.0, 0.0, 0.0], "key": "drum.stl"}
    return WallSpec("drum", "mesh", np.zeros(3), np.zeros(3), params=params or {}, mesh=m)


def check_stl(case_path, dr: dict) -> None:
    """Read the drum's mesh and check it against drum.radius / drum.length (module docstring)."""
    from .common import mesh_wall

    try:
        mesh = mesh_wall(_mesh_spec(case_path, dr, 0.0))
    except CaseError as e:  # mesh_wall names "drum.stl.<its key>": drum.stl is the case's key
        raise CaseError("drum.stl", f"{dr['stl']}: {e.reason}") from None
    V = mesh.vertices
    R, L = dr["radius"], dr["length"]
    rho = np.hypot(V[:, 0], V[:, 1])
    r_out = float(rho.max())
    zl = float(np.ptp(V[:, 2]))
    if not R * (1 - 1e-6) <= r_out <= 1.02 * R:
        raise CaseError("drum.stl", f"{dr['stl']}: its largest radius about the z axis is {r_out:.5g} m, not "
                                    f"drum.radius = {R:g} m (up to +2 %): check drum.stl_units and the axis")
    if abs(zl - L) > 0.02 * L:
        raise CaseError("drum.stl", f"{dr['stl']}: its length along z is {zl:.5g} m, not drum.length = {L:g} m")
    zc = 0.5 * float(V[:, 2].min() + V[:, 2].max())
    if abs(zc) > 0.02 * L:
        raise CaseError("drum.stl", f"{dr['stl']}: its z range is not centred on z = 0 (centre {zc:.4g} m)")


class DrumScene(Scene):
    """Fill, rotation, sampling and measurements of a rotating drum (module docstring)."""

    DOC = "'drum': the rotating drum of [drum]"
    EXAMPLE = "drum"
    SCHEMA = {"drum": DRUM_KEYS}

    # ------------------------------------------------------------------ from the case alone
    @classmethod
    def check(cls, r: dict, case_dir) -> None:
        dr = r["drum"]
        p = r["particles"]
        d = p["diameter"]
        if p["diameter_max"]:
            raise CaseError("particles.diameter_max", "the drum fill lattice is monodisperse: leave it 0")
        if p["clump"] != "none":
            raise CaseError("particles.clump", "the drum is filled with spheres: leave it 'none'")
        if r["gravity"]["inclination_deg"] != 0.0:
            raise CaseError("gravity.inclination_deg", "the drum needs gravity along -y (inclination 0)")
        if r["frame"]["rpm"] != 0.0:
            raise CaseError("frame.rpm", "the drum turns, not the frame: set drum.rpm and leave frame.rpm 0")
        if dr["radius"] < 4 * d:
            raise CaseError("drum.radius", f"{dr['radius']:g} m is less than 4 bead diameters ({4 * d:g} m)")
        if not dr["lattice_jitter"] < dr["lattice_gap"]:
            raise CaseError("drum.lattice_jitter", f"{dr['lattice_jitter']:g} must be below drum.lattice_gap = "
                                                   f"{dr['lattice_gap']:g} (otherwise lattice spheres could overlap)")
        if dr["average_start"] and dr["average_start"] < dr["settle_time"]:
            raise CaseError("drum.average_start", f"{dr['average_start']:g} s is before the drum starts turning "
                                                  f"(drum.settle_time = {dr['settle_time']:g} s)")
        check_contact_values("drum.wall", dr["wall"])
        check_contact_values("drum.end_plates", dr["end_plates"])
        if dr["walls"] == "mesh":
            if any(v is not None for v in dr["end_plates"].values()):
                raise CaseError("drum.end_plates", "a mesh drum is one mesh with one material: set its contact "
                                                   "keys in [drum.wall] (or use drum.walls = 'analytic')")
            if case_dir is not None:
                from pathlib import Path

                check_stl(Path(case_dir), dr)
        fill_sites(dr, d, n_beads(dr, d), 0)

    @classmethod
    def wall_specs(cls, case) -> list:
        from .common import WallSpec

        dr = case.resolved["drum"]
        w = omega(case)
        shell = {k: float(v) for k, v in dr["wall"].items() if v is not None}
        if dr["walls"] == "mesh":
            return [_mesh_spec(case.path, dr, w, shell)]
        plates = {k: float(v) for k, v in dr["end_plates"].items() if v is not None}
        R, L, d = dr["radius"], dr["length"], case.particles.diameter
        ez = np.array([0.0, 0.0, 1.0])
        return [WallSpec("drum", "cylinder", np.zeros(3), ez, None, (R, 0.5 * L + d), shell, spin=w),
                WallSpec("plate_back", "plane", -0.5 * L * ez, ez, params=plates, spin=w),
                WallSpec("plate_front", "plane", 0.5 * L * ez, -ez, params=plates, spin=-w)]

    @classmethod
    def bounds(cls, case):
        dr = case.resolved["drum"]
        R, L = dr["radius"], dr["length"]
        return np.array([[-R, -R, -0.5 * L], [R, R, 0.5 * L]])

    @classmethod
    def has_particles(cls, case) -> bool:
        return True

    @classmethod
    def expected_particles(cls, case) -> int:
        return n_beads(case.resolved["drum"], case.particles.diameter)

    @classmethod
    def speed_scale(cls, case) -> float:
        """The wall speed w R, at least the speed of a bead falling across the drum."""
        R = case.resolved["drum"]["radius"]
        return max(abs(omega(case)) * R, math.sqrt(2.0 * case.gravity.g * 2.0 * R))

    @classmethod
    def describe(cls, case) -> list[str]:
        dr = case.resolved["drum"]
        R, L, d = dr["radius"], dr["length"], case.particles.diameter
        fr = froude(dr["rpm"], R, case.gravity.g)
        exp = mellmann_regimes(fr)
        lines = [f"drum: R = {R * 1e3:.4g} mm ({R / d:.3g} d), L = {L * 1e3:.4g} mm ({L / d:.3g} d), "
                 f"{dr['walls']} walls, {dr['rpm']:g} rpm (w = {omega(case):.4g} rad/s, a turn in "
                 f"{60.0 / abs(dr['rpm']) if dr['rpm'] else math.inf:.3g} s)",
                 f"drum: Froude number w^2 R / g = {fr:.3g}; Mellmann (2001) regime expected: "
                 f"{' or '.join(exp) if exp else 'slipping or at rest (Fr < 1e-5)'}",
                 f"drum: {n_beads(dr, d)} beads (fill fraction {dr['fill_fraction']:g} at solid fraction "
                 f"{dr['solid_fraction']:g}); at rest until {dr['settle_time']:g} s, averages from "
                 f"{average_start(case):.4g} s"]
        return lines

    @classmethod
    def plots(cls, results_h5, out_dir) -> list:
        """``drum.png``: the angle against time and the cross-section of the last sample."""
        from ..io.results import read_measurements

        m = read_measurements(results_h5)
        if "drum" not in m or not len(m["drum"]["time"]):
            return [("drum.png", None, "no drum sample in this run (it ended before the drum turned)")]
        return [("drum.png", write_drum_plot(m["drum"], out_dir), "")]

    # ------------------------------------------------------------------ during a run
    def __init__(self, sim):
        super().__init__(sim)
        self.dr = self.case.resolved["drum"]
        self.w = omega(self.case)
        self.d = self.case.particles.diameter
        self.turning = False
        self.k_sample = 0
        self.t_avg = average_start(self.case)
        self.rec: dict[str, list] = {k: [] for k in REC_KEYS}
        self.last = {"profile_x": np.zeros(0), "profile_y": np.zeros(0), "section_x": np.zeros(0),
                     "section_y": np.zeros(0), "slope": math.nan, "intercept": math.nan, "time": math.nan}

    def start(self) -> None:
        dr, sys_ = self.dr, self.sim.system
        pos = fill_sites(dr, self.d, n_beads(dr, self.d), self.case.particles.seed)
        sys_.add_particles(pos, np.zeros(3), 0.5 * self.d, self.case.particles.density)
        self._set_rotation(0.0)
        self.sim.log.info("drum: %d beads on a lattice up to y = %.4g m; at rest until %.4g s, then %.4g rpm "
                          "(Fr = %.3g)", len(pos), float(pos[:, 1].max()), dr["settle_time"], dr["rpm"],
                          froude(dr["rpm"], dr["radius"], self.case.gravity.g))

    def _set_rotation(self, w: float) -> None:
        sys_ = self.sim.system
        if self.dr["walls"] == "mesh":
            sys_.set_mesh_motion("drum", angular_velocity=(0.0, 0.0, w))
        else:
            sys_.set_wall_spin("drum", w)
            sys_.set_wall_spin("plate_back", w)
            sys_.set_wall_spin("plate_front", -w)

    def _sample_time(self) -> float:
        return self.dr["settle_time"] + self.k_sample * self.dr["sample_interval"]

    def next_time(self, t: float) -> float:
        return self.dr["settle_time"] if not self.turning else self._sample_time()

    def after_steps(self) -> None:
        t = self.sim.system.time
        half = 0.5 * self.sim.dt
        if not self.turning and t >= self.dr["settle_time"] - half:
            self._set_rotation(self.w)
            self.turning = True
            self.sim.log.info("drum: turning at %.4g rpm from t = %.4g s", self.dr["rpm"], t)
        if self.turning and t >= self._sample_time() - half:
            self._sample(t)
            while self._sample_time() <= t + half:
                self.k_sample += 1

    def torque_z(self) -> float:
        """Torque about the axis that the beads exert on the drum (shell and plates, or the mesh)."""
        sys_ = self.sim.system
        if self.dr["walls"] == "mesh":
            return float(sys_.mesh_torques()[[m.name for m in sys_.meshes].index("drum"), 2])
        names = [w.name for w in sys_.walls]
        return float(sum(sys_.wall_torques()[names.index(k), 2] for k in ("drum", "plate_back", "plate_front")))

    def _sample(self, t: float) -> None:
        sys_ = self.sim.system
        pos = sys_.pos
        R, d = self.dr["radius"], self.d
        x, y, detached = surface_profile(pos, R, d, d, wall_clearance=2 * d)
        fit = fit_surface(x, y, R, self.dr["fit_fraction"], sign=1.0 if self.w >= 0 else -1.0)
        row = {"time": t, "angle_deg": fit["angle_deg"], "s_shape": fit["cubic"], "rms_dev": fit["rms_dev"],
               "max_dev": fit["max_dev"], "airborne": detached / max(sys_.n, 1), "torque_z": self.torque_z(),
               "x_com": float(np.mean(pos[:, 0])) if sys_.n else math.nan,
               "mass": float(np.sum(sys_.mass)) if sys_.n else 0.0}
        for k in REC_KEYS:
            self.rec[k].append(row[k])
        self.last.update(profile_x=x, profile_y=y, section_x=pos[:, 0].copy(), section_y=pos[:, 1].copy(),
                         slope=fit["slope"], intercept=fit["intercept"], time=t)

    def series(self) -> dict:
        a = self.rec["angle_deg"]
        return {"drum_angle_deg": a[-1] if a else math.nan, "drum_torque_z": self.torque_z() if self.sim.system.n
                else 0.0, "drum_omega": self.w if self.turning else 0.0}

    def summary(self) -> dict:
        """Time averages over the samples at or after average_start (module docstring)."""
        nb = self.dr["n_blocks"]
        t = np.array(self.rec["time"], float)
        sel = t >= self.t_avg - 0.5 * self.sim.dt
        r = {k: np.array(v, float)[sel] for k, v in self.rec.items()}
        g = self.case.gravity.g
        out = {"n_samples": int(sel.sum())}
        for k in ("angle_deg", "s_shape", "torque_z", "x_com", "airborne", "rms_dev"):
            out[k + "_mean"], out[k + "_err"] = block_average(r[k], nb)
        a = r["angle_deg"][np.isfinite(r["angle_deg"])]
        out["angle_std_deg"] = float(np.std(a, ddof=1)) if len(a) > 1 else math.nan
        out["torque_weight"] = -float(np.mean(r["mass"])) * g * out["x_com_mean"] if len(t[sel]) else math.nan
        fr = froude(self.dr["rpm"], self.dr["radius"], g)
        out["froude"] = fr
        out["regime_expected"] = " or ".join(mellmann_regimes(fr)) or "slipping or at rest"
        out["regime_run"] = classify_run(out["angle_std_deg"], out["s_shape_mean"], out["airborne_mean"])
        return out

    def measurements(self):
        s = self.summary()
        drum = {k: np.array(v, float) for k, v in self.rec.items()}
        drum.update(s)
        drum.update({k: self.last[k] for k in ("profile_x", "profile_y", "section_x", "section_y")})
        drum.update(fit_slope=self.last["slope"], fit_intercept=self.last["intercept"],
                    profile_time=self.last["time"], rpm=self.dr["rpm"], radius=self.dr["radius"],
                    length=self.dr["length"], average_start=self.t_avg, walls=self.dr["walls"])
        drum["@attrs"] = {
            "axes": "drum axis z through the origin, gravity -y; positive rpm turns counter-clockwise seen from +z",
            "angle": "dynamic angle of repose (deg): line fitted to the free-surface profile of the cross-section, "
                     "time average over the samples from average_start, error = standard error of n_blocks "
                     "block means",
            "torque_z": "torque (N m) about the axis exerted by the beads on the drum; torque_weight = -M g x_com, "
                        "the moment of the bed's weight it balances in steady rotation",
            "regime": "regime_expected from the Froude number (Mellmann 2001 ranges), regime_run from the run "
                      "(cfddem.measure.drum.classify_run)"}
        arrays = {"dynamic_angle_deg": s["angle_deg_mean"], "dynamic_angle_err_deg": s["angle_deg_err"], "drum": drum,
                  "@attrs:dynamic_angle_deg": {"unit": "deg"}, "@attrs:dynamic_angle_err_deg": {"unit": "deg"}}
        return None, arrays, {}

    def get_state(self) -> dict:
        st = {"turning": np.int64(self.turning), "k_sample": np.int64(self.k_sample)}
        st.update({f"rec_{k}": np.array(v, float) for k, v in self.rec.items()})
        st.update({f"last_{k}": np.asarray(v, float) for k, v in self.last.items()})
        return st

    def set_state(self, d: dict) -> None:
        self.turning = bool(int(d["turning"]))
        self.k_sample = int(d["k_sample"])
        self.rec = {k: [float(x) for x in np.asarray(d[f"rec_{k}"]).ravel()] for k in REC_KEYS}
        for k in self.last:
            v = np.asarray(d[f"last_{k}"], float)
            self.last[k] = float(v) if v.ndim == 0 else v


#: the per-sample records of the drum scene
REC_KEYS = ("time", "angle_deg", "s_shape", "rms_dev", "max_dev", "airborne", "torque_z", "x_com", "mass")


def average_start(case) -> float:
    """drum.average_start, or settle_time + the time of 1/8 turn + 0.5 s when it is 0."""
    dr = case.resolved["drum"]
    if dr["average_start"]:
        return dr["average_start"]
    turn = 60.0 / abs(dr["rpm"]) if dr["rpm"] else 0.0
    return dr["settle_time"] + turn / 8.0 + 0.5


def write_drum_plot(m: dict, out_dir):
    """``drum.png``: the angle of every sample against time with the time average and its
    window, and the cross-section (beads projected on x-y) of the last sample with the surface
    profile and the fitted line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from pathlib import Path

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    R = float(m["radius"])
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.5))
    t, ang = m["time"], m["angle_deg"]
    a1.plot(t, ang, ".-", lw=0.8, label="fitted surface angle")
    mean, err, t0 = float(m["angle_deg_mean"]), float(m["angle_deg_err"]), float(m["average_start"])
    if math.isfinite(mean):
        a1.axhline(mean, color="C3", lw=1.5, label=f"mean from {t0:.3g} s: {mean:.1f} +- {err:.1f} deg")
        a1.axvspan(t0, float(t[-1]), color="C3", alpha=0.08)
    a1.set_xlabel("time (s)")
    a1.set_ylabel("dynamic angle of repose (deg)")
    a1.set_title(f"{float(m['rpm']):g} rpm, Fr = {float(m['froude']):.2g}: {m['regime_run']} "
                 f"(Mellmann: {m['regime_expected']})", fontsize=9)
    a1.grid(alpha=0.3)
    a1.legend(fontsize=8)
    th = np.linspace(0, 2 * np.pi, 200)
    a2.plot(R * 1e3 * np.cos(th), R * 1e3 * np.sin(th), "k-", lw=1)
    a2.plot(m["section_x"] * 1e3, m["section_y"] * 1e3, "o", ms=2, color="0.6", alpha=0.4, label="beads (all z)")
    a2.plot(m["profile_x"] * 1e3, m["profile_y"] * 1e3, "C0s", ms=3, label="surface profile")
    b, c = float(m["fit_slope"]), float(m["fit_intercept"])
    if math.isfinite(b):
        xx = np.linspace(-R, R, 2)
        a2.plot(xx * 1e3, (c + b * xx) * 1e3, "C3-", lw=1.5, label=f"fit: {math.degrees(math.atan(abs(b))):.1f} deg")
    a2.set_aspect("equal")
    a2.set_xlim(-1.05 * R * 1e3, 1.05 * R * 1e3)
    a2.set_ylim(-1.05 * R * 1e3, 1.05 * R * 1e3)
    a2.set_xlabel("x (mm)")
    a2.set_ylabel("y (mm)")
    a2.set_title(f"cross-section at t = {float(m['profile_time']):.3g} s", fontsize=9)
    a2.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    path = out / "drum.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_rate_study(results, path):
    """The dynamic angle of repose (with its standard error) and the surface's cubic coefficient
    against the Froude number, one line per wall kind, over Mellmann's regime ranges, from the
    ``results.h5`` files of drum runs (e.g. the folders of a ``cfddem sweep`` over drum.rpm)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from pathlib import Path

    from ..io.results import read_measurements
    from ..measure.drum import MELLMANN_RANGES

    runs: dict[str, list] = {}
    for f in results:
        m = read_measurements(f).get("drum")
        if m is not None and int(m["n_samples"]):
            runs.setdefault(str(m["walls"]), []).append(m)
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.2))
    for k, (walls, ms) in enumerate(sorted(runs.items())):
        ms.sort(key=lambda m: float(m["froude"]))
        fr = [float(m["froude"]) for m in ms]
        a1.errorbar(fr, [float(m["angle_deg_mean"]) for m in ms], [float(m["angle_deg_err"]) for m in ms],
                    marker="os"[k % 2], capsize=3, label=f"{walls} drum")
        a2.errorbar(fr, [float(m["s_shape_mean"]) for m in ms], [float(m["s_shape_err"]) for m in ms],
                    marker="os"[k % 2], capsize=3, label=f"{walls} drum")
    for ax in (a1, a2):
        ax.set_xscale("log")
        lo, hi = ax.get_xlim()
        for j, (name, (a, b)) in enumerate(MELLMANN_RANGES.items()):
            if b > lo and a < hi:
                ax.axvspan(max(a, lo), min(b, hi), ymin=0.02 + 0.06 * j, ymax=0.07 + 0.06 * j, color=f"C{j + 2}",
                           alpha=0.5, label=f"Mellmann: {name}")
        ax.set_xlim(lo, hi)
        ax.set_xlabel("Froude number w^2 R / g")
        ax.grid(alpha=0.3, which="both")
    a1.set_ylabel("dynamic angle of repose (deg)")
    a2.set_ylabel("cubic coefficient of the surface (S-shape)")
    a1.legend(fontsize=7)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)
