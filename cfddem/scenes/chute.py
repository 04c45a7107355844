"""The inclined chute (``geometry.type = "chute"``; physics.md §4-5): a floor and two side walls
(and a back wall at the entrance), fed by a sluice inlet at a mass rate, emptied through the
exit plane, measured by bed height, surface velocity and depth profiles; with gas, the air
between the side walls up to ``gas.height``.

Axes (right-handed): x across the chute (0..width), y normal to the floor (floor at y = 0), z down
the chute (entrance at ``geometry.z_start``, measurement origin at z = 0).  Sides are named as seen
in the direction of flow (:mod:`cfddem.measure.chute`): the x = 0 wall is the right wall.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import CaseError
from ..measure.chute import SIDE_AT_X0, SIDE_AT_XW
from ..schema import INF, Key
from ..schema import nonneg as _nonneg
from ..schema import number as _f
from ..schema import positive as _pos
from . import Scene
from .common import WallSpec, frame_omega, gravity_vector


class ChuteScene(Scene):
    DOC = "'chute': floor + two side walls (+ a back wall at the entrance), fed by [inlet]"
    HAS_GAS = True
    EXAMPLE = "chute_16rpm"
    SCHEMA = {
        "geometry": {
            "width": _pos(0.08, "m", "chute width (x from 0 to width)"),
            "depth": _pos(0.045, "m", "height of the chute side walls (y from 0 to depth)"),
            "length": _pos(0.9, "m", "chute length (z from z_start to z_start + length)"),
            "z_start": _f(-0.1, "m", "z of the chute entrance (the measurement origin is z = 0)"),
            "back_wall": Key("bool", True, "-", "close the chute entrance with a wall at z = z_start"),
        },
        "inlet": {
            "type": Key("str", "none", "-", "'sluice': bcc lattice layers across the chute entrance at a mass rate",
                        choices=("none", "sluice")),
            "mass_rate": _pos(1.6, "kg/s", "mass feed rate"),
            "height": _pos(0.045, "m", "sluice height above the floor"),
            "z": Key("float", None, "m", "upstream edge of the sluice (default: geometry.z_start)"),
            "start_time": _nonneg(0.0, "s", "feeding starts"),
            "end_time": _pos(INF, "s", "feeding stops"),
            "gap": _nonneg(0.1, "-", "extra bcc lattice spacing as a fraction of the diameter: room for the settling "
                           "of the previous layer, so new layers do not wait"),
            "hold_length": Key("float", None, "m", "fed particles move at the feed velocity, unaffected by forces, "
                               "until they are this far past the insertion plane, pushing what is ahead like the "
                               "material behind a sluice gate (default: one lattice period, about 1.3 d; 0: released "
                               "at once)", lo=0.0),
            "label": Key("int", 0, "-", "tracer label of the fed particles (written with every snapshot and "
                         "ParaView frame)"),
        },
        "exit": {
            "z": Key("float", None, "m", "particles with z beyond this plane leave the simulation "
                     "(default: the chute end, z_start + length)"),
        },
        "measurements": {
            "stations": Key("floats", [0.0, 0.2, 0.4, 0.6], "m", "streamwise positions z of the cross-width profiles"),
            "sensors_x": Key("floats", [0.015, 0.035, 0.065], "m", "x of the three bed-height sensors, each named by "
                             "its side seen in the direction of flow: right below 0.4 width (the x = 0 side), centre "
                             "within 0.1 width of the centre line, left above; the default (0.015 m from either wall, "
                             "and 0.035 m) mirrors physics.md's 0.015, 0.045, 0.065 m counted from its left wall, "
                             "our x = width", length=3),
            "cell_x": _pos(0.005, "m", "measurement cell size across the chute"),
            "cell_z": _pos(0.006, "m", "measurement cell size along the chute"),
            "n_top": Key("int", 6, "-", "topmost particles per cell for the surface velocity", lo=1),
            "budget_bin": _pos(0.05, "m", "streamwise bin length of the particles' momentum budget "
                               "(/measurements/momentum_budget; bins from the first multiple of it past the sluice "
                               "to one bin before the exit)"),
        },
        "gas": {
            "height": _pos(0.045, "m", "height of the gas domain above the floor"),
            "lid": Key("str", "crosswind", "-", "open-top boundary: 'crosswind' (lab air at rest seen from the "
                       "rotating frame), 'slip' (free slip) or 'wall' (no slip)", choices=("crosswind", "slip", "wall")),
            "inlet_velocity": Key("float", None, "m/s", "co-flow velocity at the entrance (default: the feed "
                                  "velocity)"),
        },
    }

    # -------------------------------------------------------------- from the case alone
    @classmethod
    def check(cls, r: dict, case_dir) -> None:
        p, inl, geo = r["particles"], r["inlet"], r["geometry"]
        dmax = max(p["diameter"], p["diameter_max"])
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
        m = r["measurements"]
        if m["start_time"] >= r["time"]["end_time"] and m["enabled"]:
            # averaging would never start: starting at half the run instead would silently change
            # the meaning; refuse
            raise CaseError("measurements.start_time", f"{m['start_time']:g} s is not before time.end_time = "
                                                       f"{r['time']['end_time']:g} s: nothing would be averaged")

    @classmethod
    def wall_specs(cls, case) -> list[WallSpec]:
        geo = case.geometry
        W, H, L, z0 = geo.width, geo.depth, geo.length, geo.z_start
        zc = z0 + 0.5 * L
        walls = [
            WallSpec("floor", "rectangle", np.array([0.5 * W, 0.0, zc]), np.array([0.0, 1.0, 0.0]),
                     np.array([1.0, 0.0, 0.0]), (0.5 * W, 0.5 * L)),
            WallSpec(SIDE_AT_X0, "rectangle", np.array([0.0, 0.5 * H, zc]), np.array([1.0, 0.0, 0.0]),
                     np.array([0.0, 1.0, 0.0]), (0.5 * H, 0.5 * L)),
            WallSpec(SIDE_AT_XW, "rectangle", np.array([W, 0.5 * H, zc]), np.array([-1.0, 0.0, 0.0]),
                     np.array([0.0, 1.0, 0.0]), (0.5 * H, 0.5 * L)),
        ]
        if geo.back_wall:
            walls.append(WallSpec("back", "rectangle", np.array([0.5 * W, 0.5 * H, z0]), np.array([0.0, 0.0, 1.0]),
                                  np.array([1.0, 0.0, 0.0]), (0.5 * W, 0.5 * H)))
        return walls

    @classmethod
    def bounds(cls, case):
        geo = case.geometry
        return np.array([[0, 0, geo.z_start], [geo.width, geo.depth, geo.z_start + geo.length]], float)

    @classmethod
    def has_particles(cls, case) -> bool:
        return case.inlet.type != "none"

    @classmethod
    def inserts_clumps(cls, r: dict) -> bool:
        return r["inlet"]["type"] == "sluice"

    @classmethod
    def sluice(cls, case):
        """The case's sluice inlet (physics.md §5)."""
        from ..particles.clumps import particle_shape
        from ..particles.inlets import SluiceInlet

        p, inl = case.particles, case.inlet
        return SluiceInlet(width=case.geometry.width, height=inl.height, z=inl.z, diameter=p.diameter,
                           diameter_max=p.diameter_max, seed=p.seed, density=p.density, mass_rate=inl.mass_rate,
                           start_time=inl.start_time, end_time=inl.end_time, gap=inl.gap,
                           hold_length=inl.hold_length, shape=particle_shape(p), label=inl.label)

    @classmethod
    def expected_particles(cls, case) -> int:
        """The steady hold-up of the fed chute: feed rate x the time to slide the chute length,
        accelerating at g (sin theta - mu_w cos theta) from the feed speed, capped by what is fed
        before the end time."""
        if case.inlet.type != "sluice":
            return 0
        from ..particles.clumps import spheres_per_body

        inl = cls.sluice(case)
        th = math.radians(case.gravity.inclination_deg)
        a = case.gravity.g * (math.sin(th) - case.contact.particle_wall.mu * math.cos(th))
        L = case.exit.z - case.inlet.z
        v0 = inl.velocity
        if a > 1e-9:
            t_res = (-v0 + math.sqrt(v0 * v0 + 2 * a * L)) / a
        else:
            t_res = L / v0
        t_feed = max(0.0, min(case.time.end_time, case.inlet.end_time) - case.inlet.start_time)
        return spheres_per_body(case.particles.clump, case.particles.clump_spheres) * int(case.inlet.mass_rate * min(t_res, t_feed)
                                                             / inl.particle_mass)

    @classmethod
    def speed_scale(cls, case) -> float:
        """A particle sliding the whole chute from the feed velocity, accelerating at
        g (sin theta - mu_w cos theta), or the lid cross-wind at the chute's far corner, whichever
        is larger."""
        th = math.radians(case.gravity.inclination_deg)
        a = max(0.0, case.gravity.g * (math.sin(th) - case.contact.particle_wall.mu * math.cos(th)))
        v0 = cls.sluice(case).velocity if case.inlet.type == "sluice" else 0.0
        v = math.sqrt(v0 * v0 + 2.0 * a * case.geometry.length)
        om = frame_omega(case)
        if np.any(om):
            geo = case.geometry
            ap = np.array(case.frame.axis_point, float)
            corners = np.array([[x, case.gas.height, z] for x in (0.0, geo.width)
                                for z in (geo.z_start, geo.z_start + geo.length)])
            v = max(v, float(np.max(np.linalg.norm(np.cross(om, corners - ap), axis=1))))
        return v

    @classmethod
    def describe(cls, case) -> list[str]:
        if case.inlet.type != "sluice":
            return []
        inl = cls.sluice(case)
        return [f"inlet: {case.inlet.mass_rate:g} kg/s through a bcc sluice of {inl.lattice.per_period} particles "
                f"per {inl.lattice.a * 1e3:.3f} mm, feed velocity {inl.velocity:.4g} m/s"]

    @classmethod
    def gas_inlet_velocity(cls, case) -> float:
        """The co-flow at the entrance: ``gas.inlet_velocity``, by default the sluice's feed
        velocity (of the largest particles), 0 without a sluice."""
        vin = case.gas.inlet_velocity
        if vin is not None:
            return float(vin)
        if case.inlet.type != "sluice":
            return 0.0
        from ..particles.inlets import SluiceInlet

        geo = case.geometry
        dmax = max(case.particles.diameter, case.particles.diameter_max)
        return float(SluiceInlet(width=geo.width, height=case.inlet.height, z=case.inlet.z, diameter=dmax,
                                 density=case.particles.density, mass_rate=case.inlet.mass_rate,
                                 gap=case.inlet.gap).velocity)

    @classmethod
    def lid_bc(cls, case):
        """The open top's boundary condition per ``gas.lid``."""
        from ..gas import FreeSlip, LidCrossWind, NoSlip

        om = tuple(float(v) for v in frame_omega(case))
        return {"crosswind": LidCrossWind(omega=om, axis_point=tuple(float(v) for v in case.frame.axis_point)),
                "slip": FreeSlip(), "wall": NoSlip()}[case.gas.lid]

    @classmethod
    def gas_domain(cls, case):
        """x in [0, width], y in [0, gas.height], z in [z_start, exit.z] on ``gas.cells``; no-slip
        x-, x+, y-; y+ per ``gas.lid``; z- velocity inlet at :meth:`gas_inlet_velocity`; z+
        pressure outlet, hydrostatic across the plane.  The gas starts with the inlet velocity
        everywhere along z (divergence-free, compatible with inlet and outlet) and the
        hydrostatic pressure."""
        from ..gas import Inlet, NoSlip, PressureOutlet, StaggeredGrid
        from ..gas.domain import GasDomain

        geo, gcfg = case.geometry, case.gas
        nx, ny, nz = (int(v) for v in gcfg.cells)
        z0, z1 = float(geo.z_start), float(case.exit.z)
        grid = StaggeredGrid((nx, ny, nz), (float(geo.width), float(gcfg.height), z1 - z0), (0.0, 0.0, z0), halo=2)
        g = np.asarray(gravity_vector(case), float)
        om = np.asarray(frame_omega(case), float)
        ap = tuple(float(v) for v in case.frame.axis_point)
        vin = cls.gas_inlet_velocity(case)
        lid = cls.lid_bc(case)
        rho = float(gcfg.density)
        # outlet pressure hydrostatic across the outlet plane (zero for gas at rest)
        # (particles past the exit plane wait there for the engine's next rebuild: they have left
        # the gas, particle rule "leave")
        pout = PressureOutlet(p=lambda x, y, z, _g=g, _r=rho: _r * (_g[0] * x + _g[1] * y), particle_rule="leave")
        bcs = {"x-": NoSlip(), "x+": NoSlip(), "y-": NoSlip(), "y+": lid, "z-": Inlet(speed=vin), "z+": pout}
        # velocity scale: the inlet, and the lid cross-wind at the far corner of the domain
        corners = np.array([[x, grid.lengths[1], z] for x in (0.0, grid.lengths[0])
                            for z in (grid.origin[2], grid.origin[2] + grid.lengths[2])])
        wind = float(np.max(np.linalg.norm(np.cross(om, corners - np.asarray(ap)), axis=1))) if np.any(om) else 0.0
        return GasDomain(
            grid=grid, bcs=bcs, gravity=tuple(g), omega=tuple(om), axis_point=ap,
            velocity=lambda x, y, z: (0.0 * x, 0.0 * x, vin + 0.0 * x),
            pressure=lambda x, y, z: rho * (g[0] * x + g[1] * y + g[2] * (z - grid.origin[2] - grid.lengths[2])),
            speed_scale=max(vin, wind, 1e-12),
            notes=[f"gas inlet velocity {vin:.4g} m/s; lid: {gcfg.lid} (max cross-wind {wind:.3g} m/s); "
                   f"min porosity: computed at run time (cells below 0.3 are counted in the end-of-run summary)"],
            budget_axis=2, side_names={"x-": f"{SIDE_AT_X0} side wall", "x+": f"{SIDE_AT_XW} side wall", "y-": "floor", "y+": f"lid ({gcfg.lid})",
                                       "z-": "inlet", "z+": "outlet"})

    @classmethod
    def plots(cls, results_h5, out_dir) -> list:
        from ..report.plots import chute_plots

        return chute_plots(results_h5, out_dir)

    # -------------------------------------------------------------- during a run
    def make_inlet(self):
        return self.sluice(self.case) if self.case.inlet.type == "sluice" else None

    def make_measurements(self):
        case = self.case
        if not case.measurements.enabled:
            return None
        from ..measure.chute import ChuteMeasurements

        m = case.measurements
        return ChuteMeasurements(
            width=case.geometry.width, z_range=(case.geometry.z_start, case.exit.z), start_time=m.start_time,
            stations=tuple(m.stations), sensor_x=tuple(m.sensors_x), dx=m.cell_x, dz=m.cell_z, n_top=m.n_top)

    def make_budget(self):
        """The particles' streamwise momentum budget (:mod:`cfddem.measure.budget`) in bins of
        ``measurements.budget_bin`` from the first multiple of it at least one bin past the
        sluice's release plane to one bin before the exit (so that the flux slabs at the end
        faces hold neither held feed particles nor the exit plane)."""
        case = self.case
        if not case.measurements.enabled:
            return None
        from ..measure.budget import MomentumBudget

        h = float(case.measurements.budget_bin)
        inl = self.sluice(case) if case.inlet.type == "sluice" else None
        z_rel = (case.inlet.z + inl.hold_length) if inl is not None else case.geometry.z_start
        z_a = math.ceil((z_rel + h) / h - 1e-9) * h
        z_b = math.floor((case.exit.z - h) / h + 1e-9) * h
        if z_b - z_a < h - 1e-12:
            return None
        nb = int(round((z_b - z_a) / h))
        names = [w.name for w in self.wall_specs(case)]
        return MomentumBudget(z_a + h * np.arange(nb + 1), axis=2, start_time=case.measurements.start_time,
                              wall_names=names)

    def exit_plane(self):
        return (0.0, 0.0, float(self.case.exit.z)), (0.0, 0.0, 1.0)
