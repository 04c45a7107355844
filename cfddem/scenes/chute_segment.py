"""A streamwise-periodic segment of the inclined chute (``geometry.type = "chute_segment"``,
case section ``[segment]``): the chute's floor and side walls over a periodic length
``segment.length``, a bed of ``segment.bed_depth`` placed at the start and moving down the
chute at ``segment.velocity``; with gas, the air between the side walls up to ``gas.height``,
periodic along z, with the chute's lid condition on top (docs/scenes.md, docs/chute-study.md
"The gas effect against diameter and rotation").

Axes and frame as the chute (:mod:`cfddem.scenes.chute`): x across (0..width), y normal to the
floor, z down the chute.  The segment spans z from ``segment.z`` to ``segment.z + length``, a
position along the full chute: the rotating-frame terms (centrifugal force, lid cross-wind)
are those of that stretch of the chute.

The bed: ``n = solid_fraction * width * bed_depth * length / (pi d^3 / 6)`` beads (the mass of
a bed of that depth) on the lowest sites of a jittered cubic lattice of spacing
``d (1 + lattice_gap)`` (the jitter and the choice of the top layer's sites follow
``particles.seed``: replicas), all moving at ``segment.velocity`` along z.  The gas starts
uniform at ``segment.gas_velocity`` (default: the beads' velocity, as the full chute's co-flow
inlet blows at the feed velocity).

The hydrostatic pressure along the periodic axis.  In the full chute the air's weight along z
(and the centrifugal force along z) is carried by a pressure that rises down the chute, and
that pressure gradient pushes the beads back (their buoyancy).  A pressure periodic along z
cannot hold a mean gradient, so the segment imposes it: the gas feels the mean streamwise
pressure gradient ``G = rho_g (g_z + c_z)`` (c_z the centrifugal acceleration along z at the
segment's centre) as a body force ``-G/rho_g`` that cancels its weight there, and the particles
feel ``-V G``: their gravity along z is lowered by ``(rho_g / rho_p) (g_z + c_z)`` whenever the
gas is on.  Without gas nothing changes (as the full chute without gas has no buoyancy).
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from ..errors import CaseError
from ..schema import Key
from ..schema import positive as _pos
from .chute import ChuteScene
from .common import frame_omega, gravity_vector

_CHUTE = ChuteScene.SCHEMA


class ChuteSegmentScene(ChuteScene):
    DOC = "'chute_segment': a streamwise-periodic stretch of the chute with a bed placed at the start, [segment]"
    HAS_GAS = True
    EXAMPLE = "chute_segment"
    SCHEMA = {
        "geometry": {k: _CHUTE["geometry"][k] for k in ("width", "depth")},
        "segment": {
            "length": _pos(0.024, "m", "periodic length along z (the map driver scales it with the diameter: 8 d)"),
            "z": Key("float", 0.35, "m", "z of the segment's upstream end along the full chute (its rotating-frame "
                     "terms: centrifugal force and lid cross-wind); default the middle of the 16 rpm chute"),
            "bed_depth": _pos(0.011, "m", "depth of the bed at solid_fraction (the flagship's developed bed at the "
                              "chute end: about 11 mm)"),
            "solid_fraction": Key("float", 0.55, "-", "solid fraction of the bed of bed_depth (sets the number of "
                                  "beads)", lo=0.05, hi=0.74),
            "velocity": Key("float", 0.26, "m/s", "initial streamwise velocity of the beads (default: the flagship "
                            "sluice's feed velocity)"),
            "gas_velocity": Key("float", None, "m/s", "initial streamwise velocity of the gas (default: the beads' "
                                "velocity, like the full chute's co-flow inlet; 0: air at rest)"),
            "lattice_gap": Key("float", 0.1, "-", "extra lattice spacing as a fraction of d; the jitter is 45 % of "
                               "the gap", lo=0.0, hi=1.0),
        },
        "measurements": {k: _CHUTE["measurements"][k] for k in ("sensors_x", "cell_x", "n_top")},
        "gas": {k: _CHUTE["gas"][k] for k in ("height", "lid")},
    }

    # -------------------------------------------------------------- from the case alone
    @classmethod
    def check(cls, r: dict, case_dir) -> None:
        p, geo, seg = r["particles"], r["geometry"], r["segment"]
        d = p["diameter"]
        if p["diameter_max"] and p["diameter_max"] != d:
            raise CaseError("particles.diameter_max", "the chute segment places beads of one diameter "
                            "(particles.diameter)")
        if d >= geo["width"]:
            raise CaseError("geometry.width", f"{geo['width']:g} m is not wider than a particle ({d:g} m)")
        if seg["length"] < 4 * d:
            raise CaseError("segment.length", f"{seg['length']:g} m is shorter than 4 particle diameters ({4 * d:g} m)")
        if seg["bed_depth"] < d:
            raise CaseError("segment.bed_depth", f"{seg['bed_depth']:g} m is less than one particle diameter")
        top = cls.lattice_top(r)
        if top > geo["depth"] + 1e-12:
            raise CaseError("segment.bed_depth", f"{seg['bed_depth']:g} m: the placed bed reaches "
                            f"{top * 1e3:.3g} mm, above the side walls (geometry.depth = {geo['depth']:g} m)")
        if r["gas"]["enabled"] and top > r["gas"]["height"]:
            raise CaseError("segment.bed_depth", f"{seg['bed_depth']:g} m: the placed bed reaches "
                            f"{top * 1e3:.3g} mm, above the gas domain (gas.height = {r['gas']['height']:g} m)")
        m = r["measurements"]
        if m["enabled"] and m["start_time"] >= r["time"]["end_time"]:
            raise CaseError("measurements.start_time", f"{m['start_time']:g} s is not before time.end_time = "
                                                       f"{r['time']['end_time']:g} s: nothing would be averaged")

    @staticmethod
    def _lattice(r: dict):
        """(number of beads, sites across, sites along, lattice spacing across / along / up)."""
        d, geo, seg = r["particles"]["diameter"], r["geometry"], r["segment"]
        a = d * (1.0 + seg["lattice_gap"])
        nx = max(1, int(math.floor((geo["width"] - d) / a)) + 1)
        nz = max(1, int(math.floor(seg["length"] / a)))
        ax = (geo["width"] - d) / (nx - 1) if nx > 1 else 0.0
        n = int(round(seg["solid_fraction"] * geo["width"] * seg["bed_depth"] * seg["length"] / (math.pi * d ** 3 / 6)))
        return max(n, 1), nx, nz, ax, seg["length"] / nz, a

    @classmethod
    def lattice_top(cls, r: dict) -> float:
        """The top of the placed (loose) bed: layers x spacing."""
        n, nx, nz, _, _, a = cls._lattice(r)
        return math.ceil(n / (nx * nz)) * a + 0.5 * r["particles"]["diameter"] * r["segment"]["lattice_gap"]

    @classmethod
    def bed(cls, case) -> np.ndarray:
        """The initial positions (module docstring): lowest lattice sites, the top layer's sites
        and the jitter drawn with ``particles.seed``."""
        r = case.resolved
        d = case.particles.diameter
        n, nx, nz, ax, az, a = cls._lattice(r)
        rng = np.random.default_rng(case.particles.seed)
        layers = math.ceil(n / (nx * nz))
        k, i, j = np.meshgrid(np.arange(layers), np.arange(nx), np.arange(nz), indexing="ij")
        sites = np.stack([0.5 * d + i.ravel() * ax, 0.5 * d + k.ravel() * a + 0.5 * (a - d),
                          case.segment.z + (j.ravel() + 0.5) * az], axis=1)
        per = nx * nz
        full = (layers - 1) * per
        top = full + rng.choice(per, size=n - full, replace=False)
        pos = np.concatenate([sites[:full], sites[np.sort(top)]])
        jit = 0.45 * (min(a if nx == 1 else ax, az, a) - d)
        return pos + rng.uniform(-jit, jit, size=pos.shape)

    @classmethod
    def _chute_like(cls, case):
        """The chute's geometry for its walls: the segment's stretch, one diameter longer at each
        end (the wrapped particles always lie inside), no back wall."""
        geo, d = case.geometry, case.particles.diameter
        return SimpleNamespace(geometry=SimpleNamespace(width=geo.width, depth=geo.depth, length=case.segment.length + 2 * d,
                                                        z_start=case.segment.z - d, back_wall=False))

    @classmethod
    def wall_specs(cls, case):
        return super().wall_specs(cls._chute_like(case))

    @classmethod
    def periodic(cls, case) -> tuple:
        z0 = case.segment.z
        return (None, None, (z0, z0 + case.segment.length))

    @classmethod
    def bounds(cls, case):
        z0 = case.segment.z
        return np.array([[0, 0, z0], [case.geometry.width, case.geometry.depth, z0 + case.segment.length]], float)

    @classmethod
    def has_particles(cls, case) -> bool:
        return True

    @classmethod
    def inserts_clumps(cls, r: dict) -> bool:
        return False

    @classmethod
    def expected_particles(cls, case) -> int:
        return cls._lattice(case.resolved)[0]

    @classmethod
    def speed_scale(cls, case) -> float:
        """The beads accelerating freely at g sin(theta) from the initial velocity to the end
        time, or the lid cross-wind at the segment's far corner, whichever is larger."""
        th = math.radians(case.gravity.inclination_deg)
        seg = case.segment
        v = abs(seg.velocity) + case.gravity.g * max(math.sin(th), 0.0) * case.time.end_time
        return max(v, abs(cls.gas_velocity(case)), cls._wind(case, (seg.z, seg.z + seg.length)))

    @classmethod
    def _wind(cls, case, z_range) -> float:
        om = frame_omega(case)
        if not np.any(om):
            return 0.0
        ap = np.array(case.frame.axis_point, float)
        corners = np.array([[x, case.gas.height, z] for x in (0.0, case.geometry.width) for z in z_range])
        return float(np.max(np.linalg.norm(np.cross(om, corners - ap), axis=1)))

    @classmethod
    def gas_velocity(cls, case) -> float:
        v = case.segment.gas_velocity
        return float(case.segment.velocity if v is None else v)

    @classmethod
    def mean_pressure_gradient(cls, case) -> float:
        """G = rho_g (g_z + c_z) [Pa/m], the full chute's hydrostatic pressure gradient along z at
        the segment's centre (module docstring)."""
        om = frame_omega(case)
        ap = np.array(case.frame.axis_point, float)
        c = np.array([0.5 * case.geometry.width, 0.5 * case.gas.height, case.segment.z + 0.5 * case.segment.length])
        cz = float(-np.cross(om, np.cross(om, c - ap))[2])
        return float(case.gas.density) * (float(gravity_vector(case)[2]) + cz)

    @classmethod
    def describe(cls, case) -> list[str]:
        n, nx, nz, *_ = cls._lattice(case.resolved)
        seg = case.segment
        lines = [f"segment: z {seg.z:g}..{seg.z + seg.length:g} m periodic, {n} beads ({nx} x {nz} sites per layer, "
                 f"bed of {seg.bed_depth * 1e3:.3g} mm at solid fraction {seg.solid_fraction:g}), initial velocity "
                 f"{seg.velocity:g} m/s, gas {cls.gas_velocity(case):g} m/s"]
        if case.gas.enabled:
            lines.append(f"segment: imposed mean pressure gradient along z {cls.mean_pressure_gradient(case):.4g} Pa/m "
                         "(the full chute's hydrostatic one: the gas's weight there, the particles' buoyancy)")
        return lines

    @classmethod
    def gas_domain(cls, case):
        """x in [0, width], y in [0, gas.height], z periodic over the segment on ``gas.cells``;
        no-slip x-, x+, y-; y+ per ``gas.lid`` (:meth:`ChuteScene.lid_bc`); gravity along z
        replaced by the imposed mean pressure gradient (module docstring); the gas starts at
        :meth:`gas_velocity` along z with the pressure hydrostatic across y."""
        from ..gas import NoSlip, Periodic, StaggeredGrid
        from ..gas.domain import GasDomain

        geo, gcfg, seg = case.geometry, case.gas, case.segment
        nx, ny, nz = (int(v) for v in gcfg.cells)
        grid = StaggeredGrid((nx, ny, nz), (float(geo.width), float(gcfg.height), float(seg.length)),
                             (0.0, 0.0, float(seg.z)), halo=2)
        g = np.asarray(gravity_vector(case), float).copy()
        rho = float(gcfg.density)
        g[2] -= cls.mean_pressure_gradient(case) / rho
        om = np.asarray(frame_omega(case), float)
        ap = tuple(float(v) for v in case.frame.axis_point)
        vg = cls.gas_velocity(case)
        bcs = {"x-": NoSlip(), "x+": NoSlip(), "y-": NoSlip(), "y+": cls.lid_bc(case), "z-": Periodic(),
               "z+": Periodic()}
        wind = cls._wind(case, (seg.z, seg.z + seg.length))
        return GasDomain(
            grid=grid, bcs=bcs, gravity=tuple(g), omega=tuple(om), axis_point=ap,
            velocity=lambda x, y, z: (0.0 * x, 0.0 * x, vg + 0.0 * x),
            pressure=lambda x, y, z: rho * (g[0] * x + g[1] * y) + 0.0 * z,
            speed_scale=max(abs(vg), wind, cls.speed_scale(case), 1e-12),
            notes=[f"gas periodic along z, initial velocity {vg:.4g} m/s; lid: {gcfg.lid} (max cross-wind "
                   f"{wind:.3g} m/s); imposed mean pressure gradient {cls.mean_pressure_gradient(case):.4g} Pa/m"],
            budget_axis=2, side_names={"x-": "side wall x-", "x+": "side wall x+", "y-": "floor",
                                       "y+": f"lid ({gcfg.lid})", "z-": "periodic z-", "z+": "periodic z+"})

    @classmethod
    def plots(cls, results_h5, out_dir) -> list:
        return []

    # -------------------------------------------------------------- during a run
    def make_inlet(self):
        """No inlet.  Called once the particle system is built (a fresh run and a resumed one
        alike): with gas, lowers the particles' gravity along z by the imposed mean pressure
        gradient's force per unit mass, G / rho_p (their buoyancy in the full chute)."""
        case = self.case
        if case.gas.enabled:
            self.sim.system.gravity[2] -= self.mean_pressure_gradient(case) / case.particles.density
        return None

    def start(self) -> None:
        self._count_impulse()
        pos = self.bed(self.case)
        p = self.case.particles
        self.sim.system.add_particles(pos, np.array([0.0, 0.0, self.case.segment.velocity]), 0.5 * p.diameter,
                                      p.density)
        self.sim.log.info("chute segment: %d beads up to y = %.4g m, moving at %.4g m/s", len(pos),
                          float(pos[:, 1].max()) + 0.5 * p.diameter, self.case.segment.velocity)

    def make_measurements(self):
        case = self.case
        if not case.measurements.enabled:
            return None
        from ..measure.chute import ChuteMeasurements

        m, seg = case.measurements, case.segment
        return ChuteMeasurements(
            width=case.geometry.width, z_range=(seg.z, seg.z + seg.length), start_time=m.start_time,
            stations=(seg.z + 0.5 * seg.length,), sensor_x=tuple(m.sensors_x), dx=m.cell_x, dz=seg.length,
            n_top=m.n_top, profile_half_length=0.5 * seg.length)

    def make_budget(self):
        """The particles' momentum budget over the whole segment (one bin; a particle wrapped
        through the periodic faces stays in it, so the flux is zero)."""
        case = self.case
        if not case.measurements.enabled:
            return None
        from ..measure.budget import MomentumBudget

        z0, L = case.segment.z, case.segment.length
        names = [w.name for w in self.wall_specs(case)]
        return MomentumBudget(np.array([z0, z0 + L]), axis=2, start_time=case.measurements.start_time,
                              wall_names=names)

    def exit_plane(self):
        return None

    def _count_impulse(self, value: float = 0.0) -> None:
        """Put :class:`_GasImpulse` in front of the coupling's force sink (with gas)."""
        gas = self.sim.gas
        if gas is not None:
            self.impulse = _GasImpulse(gas.force_sink, value)
            gas.force_sink = self.impulse

    def series(self) -> dict:
        """With gas: ``gas_mean_velocity_z``, the mean streamwise gas velocity over the domain's z
        faces (not weighted by porosity); ``gas_impulse_z`` [N s], the gas's streamwise impulse
        on the beads since the start: drag and pressure force integrated over every gas step,
        plus the imposed mean pressure gradient's force -G V t (the direct effect of the gas)."""
        gas = self.sim.gas
        if gas is None or not hasattr(gas, "gas"):
            return {}
        w = gas.gas.w.interior  # faces 0..nz along the periodic z: face nz is face 0
        sys_ = self.sim.system
        vol = float(np.sum(sys_.mass)) / self.case.particles.density
        return {"gas_mean_velocity_z": float(np.mean(w[:, :, :-1])),
                "gas_impulse_z": self.impulse.value - self.mean_pressure_gradient(self.case) * vol * sys_.time}

    def get_state(self) -> dict:
        return {"gas_impulse": np.float64(self.impulse.value)} if hasattr(self, "impulse") else {}

    def set_state(self, d: dict) -> None:
        self._count_impulse(float(d.get("gas_impulse", 0.0)))


class _GasImpulse:
    """The coupling's force sink (``CoupledGas.force_sink``) of the segment: sums every gas
    step's streamwise drag and pressure impulse on the free particles, then hands the step on
    to the momentum budget it wraps (if that wants it)."""

    def __init__(self, inner, value: float = 0.0):
        self.inner = inner
        self.value = float(value)

    def wants_gas(self, time: float) -> bool:
        return True

    def add_gas(self, time, dt_gas, pos, held, drag, pressure, keff=None, eps=None) -> None:
        free = ~np.asarray(held, bool)
        self.value += dt_gas * float(np.sum(drag[free, 2]) + np.sum(pressure[free, 2]))
        if self.inner is not None and self.inner.wants_gas(time):
            self.inner.add_gas(time, dt_gas, pos, held, drag, pressure, keff, eps)
