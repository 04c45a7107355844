"""The :class:`Simulation`: owns the clock, the stop criteria, and the schedules of outputs and
measurements; drives the particle engine (and, when a case has gas, the gas solver).

Python API (the CLI is a thin layer over it)::

    from cfddem.config import load_case
    from cfddem.simulation import Simulation
    case = load_case("cases/chute_16rpm", overrides=["time.end_time=0.2"])
    summary = Simulation(case, out_dir="out/chute", overwrite=True).run()
"""

from __future__ import annotations

import json
import math
import shutil
import time as _time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from . import __version__
from ._jit import get_threads, set_threads
from .config import Case
from .errors import CaseError, RunError
from .scene import frame_omega, gravity_vector, initial_particles, wall_specs, walls_bounding_box

RUN_MARKER = "run.json"  # written by every run: how we recognise our own run folders


@dataclass
class RunSummary:
    status: str  # "done" | "stopped" (wall-time/step limit, signal) | "failed"
    out_dir: str
    time: float
    steps: int
    wall_time: float
    n_particles: int
    mass_in: float
    mass_out: float
    message: str = ""
    timings: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return asdict(self)


class Schedule:
    """Events every ``interval`` of simulated time from ``start`` (inclusive)."""

    def __init__(self, interval: float, start: float = 0.0):
        self.interval = interval
        self.k = 0
        self.start = start

    @property
    def next_time(self) -> float:
        return self.start + self.k * self.interval

    def due(self, t: float, dt: float) -> bool:
        return t >= self.next_time - 0.5 * dt

    def advance(self, t: float, dt: float) -> None:
        while self.due(t, dt):
            self.k += 1


def prepare_out_dir(out: Path, overwrite: bool) -> None:
    """Create the run folder; refuse an existing non-empty one unless ``overwrite``.

    With ``overwrite`` only what a cfddem run writes is removed (never foreign files)."""
    if out.exists() and not out.is_dir():
        raise CaseError("--out", f"{out} exists and is not a folder")
    if out.exists() and any(out.iterdir()):
        if not overwrite:
            raise CaseError("--out", f"{out} already holds a run: use --overwrite or another --out")
        if not (out / RUN_MARKER).exists():
            raise CaseError("--out", f"{out} is not empty and holds no cfddem run ({RUN_MARKER} missing): "
                                     "refusing to delete files the run did not write")
        for name in ("results.h5", "run.log", "case.resolved.toml", RUN_MARKER, "vtk", "report", "checkpoints"):
            p = out / name
            if p.is_dir():
                shutil.rmtree(p)
            elif p.exists():
                p.unlink()
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".write_test"
        probe.write_text("")
        probe.unlink()
    except OSError as e:
        raise CaseError("--out", f"cannot write to {out}: {e.strerror or e}") from None


class Simulation:
    """One run of a case.  ``run()`` returns a :class:`RunSummary` (and raises
    :class:`RunError` on blow-up, after writing everything written so far plus a diagnostic
    snapshot)."""

    def __init__(self, case: Case, out_dir: str | Path | None = None, *, overwrite: bool = False,
                 end_time: float | None = None, threads: int | None = None, echo: bool = True,
                 progress: bool = True):
        self.case = case
        self.out = Path(out_dir) if out_dir is not None else case.path / "output"
        self.overwrite = overwrite
        self.end_time = float(end_time) if end_time is not None else case.time.end_time
        if self.end_time <= 0:
            raise CaseError("--end-time", f"{self.end_time:g} must be positive")
        self.threads = threads if threads is not None else case.time.threads
        self.echo = echo
        self.show_progress = progress
        self.dt = case.time.dt
        self.timings = {"particles": 0.0, "inlet_exit": 0.0, "measurements": 0.0, "output": 0.0, "gas": 0.0,
                        "coupling": 0.0}
        self.mass_out = 0.0
        self.count_out = 0
        self.mass_lost = 0.0
        self.count_lost = 0
        self._built = False

    # ------------------------------------------------------------------------------- set-up
    def build(self) -> None:
        """Build the particle system, inlet and measurements (no files written)."""
        from .particles.inlets import SluiceInlet
        from .particles.system import ParticleSystem

        case = self.case
        self.walls = wall_specs(case)
        self.box_lo, self.box_hi = walls_bounding_box(self.walls, case)
        set_threads(self.threads)
        periodic = (None, None, None)
        if case.geometry.type == "box":
            periodic = tuple((case.geometry.lo[i], case.geometry.hi[i]) if case.geometry.periodic[i] else None
                             for i in range(3))
        self.system = ParticleSystem(
            pp=contact_law(case.resolved["contact"]["particle_particle"]),
            walls=[engine_wall(w) for w in self.walls],
            dt=self.dt,
            gravity=gravity_vector(case),
            omega=frame_omega(case),
            axis_point=np.array(case.frame.axis_point, float),
            periodic=periodic,
            skin=case.particles.skin or None,
            max_overlap_ratio=case.particles.max_overlap_ratio,
            capacity=max(1024, expected_particles(case)),
        )
        init = initial_particles(case)
        if len(init["pos"]):
            n = len(init["pos"])
            if self.system.overlaps(init["pos"], init["radius"]).any():
                raise CaseError("particles.initial", "initial particles overlap each other")
            self.system.add_particles(init["pos"], init["vel"], init["radius"], case.particles.density,
                                      omega=init["omega"])
            self.mass_initial = float(np.sum(self.system.mass[:n]))
        else:
            self.mass_initial = 0.0
        self.inlet = None
        if case.inlet.type == "sluice":
            dmax = max(case.particles.diameter, case.particles.diameter_max)
            self.inlet = SluiceInlet(width=case.geometry.width, height=case.inlet.height, z=case.inlet.z,
                                     diameter=dmax, density=case.particles.density, mass_rate=case.inlet.mass_rate,
                                     start_time=case.inlet.start_time, end_time=case.inlet.end_time,
                                     gap=case.inlet.gap)
        self.measure = None
        if case.geometry.type == "chute" and case.measurements.enabled:
            from .measure.chute import ChuteMeasurements

            m = case.measurements
            self.measure = ChuteMeasurements(
                width=case.geometry.width, z_range=(case.geometry.z_start, case.exit.z), start_time=m.start_time,
                stations=tuple(m.stations), sensors_x=tuple(m.sensors_x), cell_x=m.cell_x, cell_z=m.cell_z,
                n_top=m.n_top, bin_z=m.bin_z)
        self.gas = None
        if case.gas.enabled:
            from .coupling.exchange import build_coupled_gas

            self.gas = build_coupled_gas(case, self.system)
        self._built = True

    # ------------------------------------------------------------------------------- the run
    def run(self) -> RunSummary:
        from .io.log import Progress, setup_run_logger
        from .io.results import ResultsFile
        from .io.vtk import PvdIndex, write_particles_vtu, write_walls_vtu

        case = self.case
        check_time_step(case, log=None)
        prepare_out_dir(self.out, self.overwrite)
        log = setup_run_logger(self.out, echo=self.echo)
        self.log = log
        t_wall0 = _time.perf_counter()
        (self.out / "case.resolved.toml").write_text(case.to_toml())
        (self.out / RUN_MARKER).write_text(
            '{"program": "cfddem", "version": "%s", "case": "%s", "status": "running"}\n' % (__version__, case.name))
        log.info("cfddem %s: case %s -> %s", __version__, case.name, self.out)
        if not self._built:
            self.build()
        log.info("threads: %d", get_threads())
        for line in describe_case(case):
            log.info(line)

        res = ResultsFile(self.out / "results.h5", mode="w")
        res.write_config(case.raw_text, case.resolved)
        res.write_metadata(version=__version__, case=case.name, threads=get_threads(), dt=self.dt,
                           end_time=self.end_time, started=_time.strftime("%Y-%m-%dT%H:%M:%S"))
        vtk_dir = self.out / "vtk"
        if case.output.vtk:
            vtk_dir.mkdir(exist_ok=True)
            pvd = PvdIndex(vtk_dir / "particles.pvd")
            wall_quads = [w.corners(size=0.1) for w in self.walls]
            if wall_quads:
                write_walls_vtu(vtk_dir / "walls.vtu", wall_quads)
        dt = self.dt
        sys_ = self.system
        series = Schedule(case.output.series_interval)
        snaps = Schedule(case.output.snapshot_interval)
        vtks = Schedule(case.output.vtk_interval or case.output.snapshot_interval)
        meas = Schedule(case.measurements.interval, start=case.measurements.start_time)
        exit_every = max(1, int(round(1e-3 / dt)))  # exit/lost check every ~1 ms of simulated time
        max_steps = case.time.max_steps or None
        wall_limit = case.time.wall_time_limit or None
        progress = Progress(end_time=self.end_time, interval=case.output.progress_interval,
                            enabled=self.show_progress)
        snap_k = 0
        vtk_k = 0
        status, message = "done", ""
        steps_at_start = sys_.step_count

        def outputs(force_all=False):
            nonlocal snap_k, vtk_k
            t0 = _time.perf_counter()
            t = sys_.time
            if series.due(t, dt) or force_all:
                res.append_series(**self._series_row())
                series.advance(t, dt)
            if snaps.due(t, dt) or force_all:
                res.write_snapshot(t, sys_.step_count, pos=sys_.pos, vel=sys_.vel, omega=sys_.omega,
                                   radius=sys_.radius, ids=sys_.ids)
                snap_k += 1
                snaps.advance(t, dt)
            if case.output.vtk and (vtks.due(t, dt) or force_all):
                name = f"particles_{vtk_k:06d}.vtu"
                write_particles_vtu(vtk_dir / name, sys_.pos, sys_.radius, vel=sys_.vel, omega=sys_.omega,
                                    ids=sys_.ids)
                pvd.add(t, name)
                vtk_k += 1
                vtks.advance(t, dt)
            res.flush()
            self.timings["output"] += _time.perf_counter() - t0

        try:
            self._feed_and_drain()
            outputs()
            while sys_.time < self.end_time - 0.5 * dt:
                # steps to the next event
                t = sys_.time
                targets = [self.end_time, series.next_time, snaps.next_time, meas.next_time]
                if case.output.vtk:
                    targets.append(vtks.next_time)
                if self.inlet is not None and self.inlet.start_time <= t < self.inlet.end_time:
                    targets.append(self.inlet._due_time(self.inlet.layers_done))
                t_next = min(x for x in targets if x > t + 0.5 * dt) if any(x > t + 0.5 * dt for x in targets) \
                    else t + dt
                n = max(1, int(round((t_next - t) / dt)))
                n = min(n, exit_every - (sys_.step_count % exit_every))
                if max_steps is not None:
                    n = min(n, max_steps - (sys_.step_count - steps_at_start))
                t0 = _time.perf_counter()
                if self.gas is not None:
                    st = self.gas.advance(n)
                else:
                    st = sys_.step(n)
                self.timings["particles"] += _time.perf_counter() - t0
                if not st.ok:
                    raise RunError(st.message)
                self._feed_and_drain()
                if self.measure is not None and meas.due(sys_.time, dt):
                    t0 = _time.perf_counter()
                    self.measure.sample(sys_.time, sys_.pos, sys_.vel, sys_.radius)
                    meas.advance(sys_.time, dt)
                    self.timings["measurements"] += _time.perf_counter() - t0
                outputs()
                progress.update(sys_.time, sys_.n, sys_.step_count)
                if max_steps is not None and sys_.step_count - steps_at_start >= max_steps:
                    status, message = "stopped", f"step limit reached ({max_steps} steps)"
                    break
                if wall_limit is not None and _time.perf_counter() - t_wall0 >= wall_limit:
                    status, message = "stopped", f"wall-time limit reached ({wall_limit:g} s)"
                    break
        except RunError as e:
            progress.close()
            status, message = "failed", str(e)
            log.error("run failed at t = %.6g s, step %d: %s", sys_.time, sys_.step_count, message)
            try:
                res.write_snapshot(sys_.time, sys_.step_count, group="diagnostic", pos=sys_.pos, vel=sys_.vel,
                                   omega=sys_.omega, radius=sys_.radius, ids=sys_.ids)
                res.append_series(**self._series_row())
            except Exception as e2:  # the diagnostic must never hide the real error
                log.error("could not write the diagnostic snapshot: %s", e2)
            self._finish(res, status, message, t_wall0)
            raise RunError(message) from None
        progress.close()
        outputs(force_all=False)
        return self._finish(res, status, message, t_wall0)

    # ------------------------------------------------------------------------------- helpers
    def _feed_and_drain(self) -> None:
        t0 = _time.perf_counter()
        sys_ = self.system
        if self.inlet is not None:
            self.inlet.insert(sys_, sys_.time, self.dt)
        if sys_.n:
            pos = sys_.pos
            if self.case.geometry.type == "chute":
                out = pos[:, 2] > self.case.exit.z
                if out.any():
                    c, m = sys_.remove_particles(out)
                    self.count_out += c
                    self.mass_out += m
                    pos = sys_.pos
            margin = self.case.exit.lost_margin
            lost = np.any((pos < self.box_lo - margin) | (pos > self.box_hi + margin), axis=1)
            if lost.any():
                c, m = sys_.remove_particles(lost)
                self.count_lost += c
                self.mass_lost += m
                self.log.warning("t = %.4f s: %d particle(s) left the domain and were removed as lost",
                                 sys_.time, c)
        self.timings["inlet_exit"] += _time.perf_counter() - t0

    def _series_row(self) -> dict:
        s = self.system
        mass_in = self.inlet.mass_inserted if self.inlet is not None else 0.0
        row = dict(time=s.time, step=float(s.step_count), n_particles=float(s.n), mass_in=mass_in,
                   mass_out=self.mass_out, mass_lost=self.mass_lost,
                   mass_present=float(np.sum(s.mass)) if s.n else 0.0,
                   kinetic_energy=s.kinetic_energy(), max_overlap_ratio=s.max_overlap_ratio(),
                   mean_velocity_z=float(np.mean(s.vel[:, 2])) if s.n else 0.0)
        if self.gas is not None:
            row.update(self.gas.series_row())
        return row

    def _finish(self, res, status: str, message: str, t_wall0: float) -> RunSummary:
        wall = _time.perf_counter() - t_wall0
        s = self.system
        if self.measure is not None:
            try:
                for name, arr in self.measure.results().items():
                    res.write_measurements(name, arr)
            except Exception as e:  # keep what is written; say why
                self.log.error("could not store the measurements: %s", e)
        timings = dict(self.timings)
        timings["total"] = wall
        summary = RunSummary(status=status, out_dir=str(self.out), time=s.time, steps=s.step_count,
                             wall_time=wall, n_particles=s.n,
                             mass_in=self.inlet.mass_inserted if self.inlet is not None else 0.0,
                             mass_out=self.mass_out, message=message, timings=timings)
        res.write_metadata(status=status, message=message, wall_time=wall, steps=s.step_count,
                           **{f"time_{k}": v for k, v in timings.items()})
        res.close()
        (self.out / RUN_MARKER).write_text(json.dumps({"program": "cfddem", "version": __version__,
                                                       "case": self.case.name, **summary.to_dict()}, indent=1))
        self.log.info("%s at t = %.6g s after %d steps, %.1f s wall (%s)", status, s.time, s.step_count, wall,
                      ", ".join(f"{k} {v:.1f} s" for k, v in timings.items()))
        if message:
            self.log.info(message)
        if self.case.output.plots and status != "failed":
            try:
                from .report.plots import write_run_report

                t0 = _time.perf_counter()
                files = write_run_report(self.out / "results.h5", self.out / "report")
                self.log.info("report: %d plot(s) in %s (%.1f s)", len(files), self.out / "report",
                              _time.perf_counter() - t0)
            except Exception as e:
                self.log.error("could not write the plots: %s", e)
        return summary


# ----------------------------------------------------------------------------------------------
# engine adapters and derived numbers (shared with `cfddem check`)
# ----------------------------------------------------------------------------------------------
def contact_law(params: dict):
    from .particles.contact import LinearContact

    return LinearContact(k_n=params["k_n"], e_n=params["e_n"], e_t=params["e_t"], mu=params["mu"],
                         mu_r=params["mu_r"])


def engine_wall(w):
    """The engine's wall object for a :class:`~cfddem.scene.WallSpec`."""
    from .particles.walls import PlaneWall, RectangleWall

    law = contact_law(w.params)
    if w.kind == "plane":
        return PlaneWall(contact=law, name=w.name, point=tuple(w.point), normal=tuple(w.normal))
    return RectangleWall(contact=law, name=w.name, point=tuple(w.point), normal=tuple(w.normal),
                         axis1=tuple(w.u_axis), half1=w.half_extents[0], half2=w.half_extents[1])


def particle_mass(case: Case, diameter: float | None = None) -> float:
    d = case.particles.diameter if diameter is None else diameter
    return case.particles.density * math.pi / 6.0 * d ** 3


def collision_time(case: Case) -> float:
    """The shortest normal collision time of the case (pp with m* = m/2 of the smallest
    particle; pw with m* = m)."""
    m = particle_mass(case)
    tcs = [contact_law(case.resolved["contact"]["particle_particle"]).collision_time(0.5 * m)]
    for w in wall_specs(case):
        tcs.append(contact_law(w.params).collision_time(m))
    return min(tcs)


def check_time_step(case: Case, log=None) -> float:
    """dt / t_c; warns above 1/20, refuses above 1/5 unless time.force."""
    tc = collision_time(case)
    ratio = case.time.dt / tc
    if ratio > 0.2 and not case.time.force:
        raise CaseError("time.dt", f"{case.time.dt:g} s is {ratio * 20:.1f} t_c/20 (t_c = {tc:.3g} s): above t_c/5 "
                                   "the contacts are not resolved; reduce it or set time.force = true")
    if ratio > 0.05 and log is not None:
        log.warning("time.dt = %g s is %.1f t_c/20: collisions resolved by fewer than 20 steps", case.time.dt,
                    ratio * 20)
    return ratio


def expected_particles(case: Case) -> int:
    """Estimate of the particle count: initial particles plus the steady hold-up of a fed chute
    (feed rate x the time to slide the chute length, accelerating at g (sin theta - mu_w cos
    theta) from the feed speed), capped by what is fed before the end time."""
    n = len(case.particles.initial)
    if case.particles.initial_file:
        try:
            n += len(initial_particles(case)["pos"]) - len(case.particles.initial)
        except CaseError:
            pass
    if case.inlet.type == "sluice":
        from .particles.inlets import SluiceInlet

        dmax = max(case.particles.diameter, case.particles.diameter_max)
        inl = SluiceInlet(width=case.geometry.width, height=case.inlet.height, z=case.inlet.z, diameter=dmax,
                          density=case.particles.density, mass_rate=case.inlet.mass_rate, gap=case.inlet.gap)
        th = math.radians(case.gravity.inclination_deg)
        a = case.gravity.g * (math.sin(th) - case.contact.particle_wall.mu * math.cos(th))
        L = case.exit.z - case.inlet.z
        v0 = inl.velocity
        if a > 1e-9:
            t_res = (-v0 + math.sqrt(v0 * v0 + 2 * a * L)) / a
        else:
            t_res = L / v0
        t_feed = max(0.0, min(case.time.end_time, case.inlet.end_time) - case.inlet.start_time)
        n += int(case.inlet.mass_rate * min(t_res, t_feed) / inl.particle_mass)
    return n


def memory_estimate(n: int) -> float:
    """Bytes for n particles: ~30 float64 per particle plus ~12 neighbour pairs of ~72 bytes."""
    return n * (30 * 8 + 12 * 72)


def describe_case(case: Case) -> list[str]:
    """The derived numbers `cfddem check` prints (and the run log records)."""
    lines = []
    d = case.particles.diameter
    m = particle_mass(case)
    lines.append(f"particle: d = {d * 1e3:.3g} mm" + (f"..{case.particles.diameter_max * 1e3:.3g} mm"
                                                     if case.particles.diameter_max else "")
                 + f", rho = {case.particles.density:g} kg/m3, m = {m:.4g} kg, I = {0.1 * m * d * d:.4g} kg m2")
    pp = contact_law(case.resolved["contact"]["particle_particle"])
    for label, law, meff in [("particle-particle", pp, 0.5 * m)] + [
            (f"particle-wall ({w.name})", contact_law(w.params), m) for w in wall_specs(case)]:
        dv = law.derived(meff)
        lines.append(f"{label}: k_n = {law.k_n:g} N/m, eta_n = {dv['eta_n']:.4g} kg/s, k_t = {dv['k_t']:.4g} N/m, "
                     f"eta_t = {dv['eta_t']:.4g} kg/s, t_c = {dv['t_c']:.4g} s (m* = {meff:.4g} kg)")
    tc = collision_time(case)
    ratio = case.time.dt / tc
    lines.append(f"time step: dt = {case.time.dt:g} s = t_c/{1 / ratio:.1f} "
                 f"({'OK' if ratio <= 0.05 else 'WARNING: above t_c/20' if ratio <= 0.2 else 'REFUSED: above t_c/5'})")
    g = gravity_vector(case)
    om = frame_omega(case)
    lines.append(f"gravity: ({g[0]:.4g}, {g[1]:.4g}, {g[2]:.4g}) m/s2; frame rotation: "
                 + (f"{case.frame.rpm:g} rpm, Omega = ({om[0]:.4g}, {om[1]:.4g}, {om[2]:.4g}) rad/s about "
                    f"{tuple(case.frame.axis_point)}" if case.frame.rpm else "none (inertial frame, no rotation terms)"))
    if case.inlet.type == "sluice":
        from .particles.inlets import SluiceInlet

        dmax = max(d, case.particles.diameter_max)
        inl = SluiceInlet(width=case.geometry.width, height=case.inlet.height, z=case.inlet.z, diameter=dmax,
                          density=case.particles.density, mass_rate=case.inlet.mass_rate, gap=case.inlet.gap)
        lines.append(f"inlet: {case.inlet.mass_rate:g} kg/s through a bcc sluice of {inl.lattice.per_period} particles "
                     f"per {inl.lattice.a * 1e3:.3f} mm, feed velocity {inl.velocity:.4g} m/s")
    n = expected_particles(case)
    lines.append(f"expected particles: about {n:,}; memory about {memory_estimate(n) / 2 ** 20:.0f} MiB")
    steps = int(math.ceil(case.time.end_time / case.time.dt))
    lines.append(f"steps to end time {case.time.end_time:g} s: {steps:,}")
    lines.append("gas: " + ("enabled" if case.gas.enabled else "off (no gas solver is built)"))
    return lines
