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
import logging
import math
import shutil
import signal
import threading
import time as _time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from . import __version__
from ._jit import get_threads, set_threads
from .config import Case
from .errors import CaseError, RunError
from .particles.contact import ContactLaw, contact_law
from .scenes import scene_of
from .scenes.common import frame_omega, gravity_vector, initial_particles, mesh_wall, wall_specs, walls_bounding_box

from numba.core import event as _nb_event  # noqa: E402  (after cfddem._jit: it sets numba's threading first)

RUN_MARKER = "run.json"  # written by every run: how we recognise our own run folders
RESULTS_FLUSH_INTERVAL = 2.0  # s of wall time between rewrites of results.h5 during a run


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


def check_out_dir(out: Path, overwrite: bool) -> None:
    """Refuse a run folder that exists and is not one (writes nothing): a non-empty folder
    unless ``overwrite``, and a non-empty folder that holds no cfddem run at all."""
    if out.exists() and not out.is_dir():
        raise CaseError("--out", f"{out} exists and is not a folder")
    if out.exists() and any(out.iterdir()):
        if not overwrite:
            raise CaseError("--out", f"{out} already holds a run: use --overwrite or another --out")
        if not (out / RUN_MARKER).exists():
            raise CaseError("--out", f"{out} is not empty and holds no cfddem run ({RUN_MARKER} missing): "
                                     "refusing to delete files the run did not write")


def prepare_out_dir(out: Path, overwrite: bool) -> None:
    """Create the run folder; refuse an existing non-empty one unless ``overwrite``
    (:func:`check_out_dir`).  With ``overwrite`` only what a cfddem run writes is removed (never
    foreign files)."""
    check_out_dir(out, overwrite)
    if out.exists() and any(out.iterdir()):
        for name in ("results.h5", "results_snapshots", "run.log", "case.resolved.toml", RUN_MARKER, "vtk", "report",
                     "checkpoints", "no_gas", "compare"):
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
    snapshot).  ``resume=True`` continues the run in ``out_dir`` from its newest valid
    checkpoint; the result is bit-identical to an uninterrupted run (same machine and threads).
    SIGINT and SIGTERM write a checkpoint and end the run cleanly (status "interrupted")."""

    def __init__(self, case: Case, out_dir: str | Path | None = None, *, overwrite: bool = False,
                 resume: bool = False, threads: int | None = None, echo: bool = True, progress: bool = True):
        self.case = case
        self.out = Path(out_dir) if out_dir is not None else case.path / "output"
        self.overwrite = overwrite
        self.resume = resume
        self.end_time = case.time.end_time
        self.threads = threads if threads is not None else case.time.threads
        self.echo = echo
        self.show_progress = progress
        self.dt = case.time.dt
        self._results = None  # the open results.h5 writer during run()
        self._exit_every = max(1, int(round(1e-3 / self.dt)))  # steps between exit/lost checks (~1 ms)
        # wall time per part of the loop; "compile": numba's compilation of kernels met for the
        # first time (on a fresh machine or after a code change), already inside the other parts
        self.timings = {"particles": 0.0, "inlet_exit": 0.0, "measurements": 0.0, "output": 0.0,
                        "checkpoints": 0.0, "gas": 0.0, "coupling": 0.0, "compile": 0.0}
        self._jit_timer = None
        self.counters = {"mass_out": 0.0, "count_out": 0, "mass_lost": 0.0, "count_lost": 0}
        self._built = False
        self._signal: int | None = None
        self._wall_prev = 0.0  # wall time of the run before the checkpoint it resumed from
        self._t_wall0: float | None = None
        self.log = logging.getLogger("cfddem")

    # ------------------------------------------------------------------------------- set-up
    def build(self) -> None:
        """Build the particle system, inlet, measurements and schedules (no files written)."""
        from .particles.system import ParticleSystem

        case = self.case
        cls = scene_of(case)
        self.scene = cls(self)
        self.walls = wall_specs(case)
        self.box_lo, self.box_hi = walls_bounding_box(self.walls, case)
        set_threads(self.threads)
        periodic = cls.periodic(case)
        self.system = ParticleSystem(
            pp=contact_law(case.resolved["contact"]["particle_particle"], case.contact.model),
            walls=[engine_wall(w, case.contact.model) for w in self.walls],
            dt=self.dt,
            gravity=gravity_vector(case),
            omega=frame_omega(case),
            axis_point=np.array(case.frame.axis_point, float),
            periodic=periodic,
            skin=case.particles.skin or None,
            max_overlap_ratio=case.particles.max_overlap_ratio,
            capacity=max(1024, int(1.2 * expected_particles(case))),
        )
        self.system.rotation_locked = case.particles.rotation == "locked" and not cls.locks_rotation_after_fill
        init = initial_particles(case)
        if len(init["pos"]):
            if self.system.overlaps(init["pos"], init["radius"]).any():
                raise CaseError("particles.initial", "initial particles overlap each other")
            self.system.add_particles(init["pos"], init["vel"], init["radius"], case.particles.density,
                                      omega=init["omega"], label=init["label"])
        self.inlet = self.scene.make_inlet()
        plane = self.scene.exit_plane()
        if plane is not None:  # particles past the exit leave at the engine's next rebuild
            self.system.set_sink(*plane)
        self.measure = self.scene.make_measurements()
        self.budget = self.scene.make_budget()  # the particles' momentum budget, sampled with measure
        if self.budget is not None:  # it counts every step from its first sample on
            self.budget.attach(self.system)
        self.gas = None
        self.gas_budget = None
        if case.gas.enabled:
            from .coupling.exchange import build_coupled_gas

            domain = cls.gas_domain(case)
            self.gas = build_coupled_gas(case, self.system, domain, self.log)
            self.gas.force_sink = self.budget
            if case.measurements.enabled and domain.budget_axis is not None:
                from .measure.gas_budget import GasBudget

                # the gas's momentum budget over its domain, every gas step from measurements.start_time
                self.gas_budget = GasBudget(self.gas.gas, axis=domain.budget_axis,
                                            start_time=case.measurements.start_time,
                                            side_names=domain.side_names).attach()
        o = case.output
        self.schedules = {
            "series": Schedule(o.series_interval),
            "snapshot": Schedule(o.snapshot_interval),
            "vtk": Schedule(o.vtk_interval or o.snapshot_interval),
            "measure": Schedule(case.measurements.interval, start=case.measurements.start_time),
        }
        if case.checkpoint.interval > 0:
            self.schedules["checkpoint"] = Schedule(case.checkpoint.interval, start=case.checkpoint.interval)
        self._built = True

    # ------------------------------------------------------------------------------- state
    def get_state(self) -> dict:
        """The complete evolving state (what a checkpoint holds)."""
        st = {
            "system": self.system.get_state(),
            "schedules": {k: np.int64(v.k) for k, v in self.schedules.items()},
            "counters": dict(self.counters),
            "timings": {**self.timings, "total": self._wall_prev + (
                _time.perf_counter() - self._t_wall0 if self._t_wall0 is not None else 0.0)},
            "clock": {"time": float(self.system.time), "step": int(self.system.step_count)},
        }
        if self.inlet is not None:
            st["inlet"] = self.inlet.get_state()
        if self.measure is not None:
            st["measure"] = self.measure.get_state()
        if self.budget is not None:
            st["budget"] = self.budget.get_state()
        if self.gas is not None:
            st["gas"] = self.gas.get_state()
        if self.gas_budget is not None:
            st["gas_budget"] = self.gas_budget.get_state()
        scene_state = self.scene.get_state()
        if scene_state:
            st["scene"] = scene_state
        return st

    def set_state(self, st: dict) -> None:
        if self.measure is not None and hasattr(self.measure, "upgrade_checkpoint"):
            st = self.measure.upgrade_checkpoint(st)  # a checkpoint with older measurement names
        self.system.set_state(st["system"])
        for k, v in st["schedules"].items():
            if k in self.schedules:
                self.schedules[k].k = int(v)
        self.counters.update({k: type(self.counters[k])(v) for k, v in st["counters"].items()})
        self.timings.update({k: float(v) for k, v in st.get("timings", {}).items() if k in self.timings})
        self._wall_prev = float(st.get("timings", {}).get("total", 0.0))  # a resumed run's wall time adds on
        if self.inlet is not None:
            self.inlet.set_state(st["inlet"])
        if self.measure is not None and "measure" in st:
            self.measure.set_state(st["measure"])
        if self.budget is not None and "budget" in st:
            self.budget.set_state(st["budget"])
        if self.gas is not None:
            self.gas.set_state(st["gas"])
        if self.gas_budget is not None and "gas_budget" in st:
            self.gas_budget.set_state(st["gas_budget"])
        if "scene" in st:
            self.scene.set_state(st["scene"])

    def write_checkpoint(self) -> Path:
        from .io.checkpoint import write_checkpoint

        t0 = _time.perf_counter()
        if self._results is not None:  # the rows up to the checkpoint are on disk before it is
            self._results.flush()
        path = write_checkpoint(self.out / "checkpoints", self.system.step_count, self.get_state(),
                                keep=self.case.checkpoint.keep)
        self.timings["checkpoints"] += _time.perf_counter() - t0
        self.log.info("checkpoint at t = %.6g s, step %d: %s", self.system.time, self.system.step_count, path.name)
        return path

    # ------------------------------------------------------------------------------- the run
    def _open_outputs(self):
        from .io.checkpoint import latest_checkpoint
        from .io.log import setup_run_logger
        from .io.results import ResultsFile
        from .io.vtk import ParaViewOutput

        case = self.case
        if self.resume:
            if not (self.out / RUN_MARKER).exists():
                raise CaseError("--resume", f"{self.out} holds no cfddem run to resume")
            found = latest_checkpoint(self.out / "checkpoints")
            if found is None:
                raise CaseError("--resume", f"no valid checkpoint in {self.out / 'checkpoints'}")
            ckpt_path, state = found
        else:
            check_out_dir(self.out, self.overwrite)
        # everything that can refuse the case comes before the first file is written
        if not self._built:
            self.build()
        branch_note = None
        if not self.resume:
            if case.checkpoint.start_from:
                branch_note = self._branch_from(case.path / case.checkpoint.start_from)
            check_disk_space(case, self.out)
            prepare_out_dir(self.out, self.overwrite)
        self.log = setup_run_logger(self.out, stderr=self.echo)
        if branch_note:
            self.log.info(branch_note)
        if self.resume:
            self.set_state(state)
            t = self.system.time
            self.log.info("resuming from %s at t = %.6g s, step %d", ckpt_path.name, t, self.system.step_count)
            res = ResultsFile(self.out / "results.h5", mode="a")
            res.truncate_after(t)
        else:
            (self.out / "case.resolved.toml").write_text(case.to_toml())
            res = ResultsFile(self.out / "results.h5", mode="w")
            res.write_config(case.raw_text, case.resolved)
        (self.out / RUN_MARKER).write_text(json.dumps({"program": "cfddem", "version": __version__,
                                                       "case": case.name, "status": "running"}))
        res.write_metadata(version=__version__, case=case.name, threads=get_threads(), dt=self.dt,
                           end_time=self.end_time, started=_time.strftime("%Y-%m-%dT%H:%M:%S"))
        pv = None
        if case.output.vtk:
            pv = ParaViewOutput(self.out, append=self.resume, restart_time=self.system.time if self.resume else None)
            quads = [q for w in self.walls for q in w.quads(size=0.1)]
            if quads:
                pv.set_walls(quads)
        self._results = res
        return res, pv

    def _branch_from(self, src: Path) -> str:
        """Start from another run's checkpoint (``checkpoint.start_from``): particles with their
        contact history and neighbour list, the inlet, the exit counters and the clock; the gas
        fields when the grid matches.  Averages, timings and the rest start afresh; the schedules
        continue from the checkpoint's time.  Returns the line for the run log."""
        from .io.checkpoint import latest_checkpoint, read_checkpoint

        key = "checkpoint.start_from"
        if src.is_dir():
            found = latest_checkpoint(src / "checkpoints" if (src / "checkpoints").is_dir() else src)
            if found is None:
                raise CaseError(key, f"no valid checkpoint in {src}")
            path, st = found
        else:
            path = src
            try:
                st = read_checkpoint(src)
            except (OSError, KeyError, ValueError) as e:
                raise CaseError(key, f"{src}: not a readable checkpoint ({e})") from None
        try:
            self.system.set_state(st["system"])
        except (KeyError, ValueError) as e:
            raise CaseError(key, f"{path.name}: particle state does not fit this case ({e}); "
                                 "the walls must be the same") from None
        if self.inlet is not None and "inlet" in st:
            self.inlet.set_state(st["inlet"])
        self.counters.update({k: type(self.counters[k])(v) for k, v in st.get("counters", {}).items()
                              if k in self.counters})
        t = self.system.time
        for s in self.schedules.values():
            s.k = max(0, int(math.ceil((t - s.start) / s.interval - 1e-9))) if s.interval > 0 else 0
        gas_note = ""
        if self.gas is not None:
            if "gas" in st:
                try:
                    self.gas.set_state(st["gas"])
                    gas_note = "; gas fields from the checkpoint"
                except (KeyError, ValueError, CaseError) as e:  # another grid: CaseError on a shape
                    gas_note = f"; gas starts afresh (state does not fit: {e})"
            else:
                gas_note = "; gas starts afresh (the source run had none)"
        self.branched_from = str(path)
        ck = self.case.checkpoint
        if ck.perturb_velocity > 0:
            k = self.system.perturb_velocities(ck.perturb_velocity, ck.perturb_seed)
            gas_note += (f"; velocities of {k} free particles perturbed by {ck.perturb_velocity:g} m/s RMS "
                         f"(checkpoint.perturb_seed = {ck.perturb_seed})")
        return f"branched from {path} at t = {t:.6g} s (step {self.system.step_count}, {self.system.n} particles)" \
               f"{gas_note}"

    def _install_signals(self):
        if threading.current_thread() is not threading.main_thread():
            return {}

        def handler(signum, frame):
            self._signal = signum

        old = {}
        for sig in (signal.SIGINT, signal.SIGTERM):
            old[sig] = signal.signal(sig, handler)
        return old

    def run(self) -> RunSummary:
        from .io.log import Progress

        case = self.case
        check_time_step(case)
        res, pv = self._open_outputs()
        log = self.log
        log.info("cfddem %s: case %s -> %s (threads: %d)", __version__, case.name, self.out, get_threads())
        for line in describe_case(case):
            log.info(line)
        if self.gas is not None:
            for line in self.gas.diagnostics()[:-1]:
                log.info("gas: %s", line)
        check_time_step(case, log=log)
        t_wall0 = self._t_wall0 = _time.perf_counter()
        self._jit_timer = _nb_event.TimingListener()  # numba's compilations from here to _finish
        _nb_event.register("numba:compile", self._jit_timer)
        dt = self.dt
        sys_ = self.system
        sch = self.schedules
        exit_every = self._exit_every  # exit/lost check every ~1 ms of simulated time
        max_steps = case.time.max_steps or None
        wall_limit = case.time.wall_time_limit or None
        wall_ckpt = case.checkpoint.wall_interval or None
        every_steps = case.checkpoint.every_steps
        last_ckpt_wall = _time.perf_counter()
        progress = Progress(end_time=self.end_time, interval=case.output.progress_interval) \
            if self.show_progress else None
        status, message = "done", ""
        old_handlers = self._install_signals()

        last = {"series": None, "vtk": None}  # step of the last row / frame

        def outputs(final=False):
            # final: make sure the end state is in the series and the VTU frames
            t0 = _time.perf_counter()
            t = sys_.time
            final_row = final and last["series"] != sys_.step_count and res.last_series_time() != t
            if sch["series"].due(t, dt) or final_row:
                res.append_series(**self._series_row())
                sch["series"].advance(t, dt)
                last["series"] = sys_.step_count
            if sch["snapshot"].due(t, dt):
                gas_fields = {}
                if self.gas is not None:
                    cd = self.gas.vtk_fields()["cell_data"]
                    gas_fields = {f"gas_{k}": v for k, v in cd.items()}
                res.write_snapshot(t, sys_.step_count, pos=sys_.pos, vel=sys_.vel, omega=sys_.omega,
                                   radius=sys_.radius, ids=sys_.ids, label=sys_.label, **gas_fields)
                sch["snapshot"].advance(t, dt)
                if self.measure is not None and self.measure.n_samples:
                    # the averages so far, so that a killed run keeps them
                    res.write_measurements(self.measure.group, self.measure.results(), self.measure.attrs())
                self._write_budget(res)
                self._write_scene_measurements(res)
            if pv is not None and (sch["vtk"].due(t, dt) or (final and last["vtk"] != sys_.step_count)):
                pv.write(t, sys_.pos, sys_.radius, vel=sys_.vel, omega=sys_.omega, ids=sys_.ids,
                         label=sys_.label, gas=self.gas.vtk_fields() if self.gas is not None else None,
                         meshes=sys_.mesh_surfaces() if sys_.nm else None)
                sch["vtk"].advance(t, dt)
                last["vtk"] = sys_.step_count
            res.flush(min_interval=0.0 if final else RESULTS_FLUSH_INTERVAL)
            self.timings["output"] += _time.perf_counter() - t0

        try:
            scene = self.scene
            if not self.resume:
                scene.start()
                self._feed_and_drain()
                outputs()
            while sys_.time < self.end_time - 0.5 * dt:
                t = sys_.time
                targets = [self.end_time] + [s.next_time for s in sch.values()]
                targets.append(scene.next_time(t))
                if self.inlet is not None and self.inlet.start_time <= t < self.inlet.end_time:
                    targets.append(self.inlet.next_due_time())
                later = [x for x in targets if x > t + 0.5 * dt]
                n = max(1, int(round((min(later) - t) / dt))) if later else 1
                n = min(n, exit_every - (sys_.step_count % exit_every))
                n = max(1, min(n, scene.max_steps()))
                if every_steps:
                    n = min(n, every_steps - (sys_.step_count % every_steps))
                if max_steps is not None:
                    n = max(1, min(n, max_steps - sys_.step_count))
                t0 = _time.perf_counter()
                other0 = self.timings["gas"] + self.timings["coupling"]
                st = self.gas.advance(n, self.timings) if self.gas is not None else sys_.step(n)
                other = self.timings["gas"] + self.timings["coupling"] - other0
                self.timings["particles"] += _time.perf_counter() - t0 - other
                self._report_wall_back()
                if not st.ok:
                    raise RunError(st.message)
                self._feed_and_drain()
                t0 = _time.perf_counter()
                scene.after_steps()
                self.timings["measurements"] += _time.perf_counter() - t0
                if self.measure is not None and sch["measure"].due(sys_.time, dt):
                    t0 = _time.perf_counter()
                    self.measure.measure(sys_.time, sys_.pos, sys_.vel, sys_.radius)
                    if self.budget is not None:
                        self.budget.sample(sys_.time, sys_, self.gas)
                    if self.gas_budget is not None:
                        self.gas_budget.close_interval()  # a block of the gas budget's error bars
                    sch["measure"].advance(sys_.time, dt)
                    self.timings["measurements"] += _time.perf_counter() - t0
                outputs()
                if progress is not None:
                    progress.update(sys_.time, sys_.n, sys_.step_count)
                ck = sch.get("checkpoint")
                if ck is not None and ck.due(sys_.time, dt):
                    ck.advance(sys_.time, dt)
                    self.write_checkpoint()
                    last_ckpt_wall = _time.perf_counter()
                elif every_steps and sys_.step_count % every_steps == 0:
                    self.write_checkpoint()
                    last_ckpt_wall = _time.perf_counter()
                elif wall_ckpt is not None and _time.perf_counter() - last_ckpt_wall >= wall_ckpt:
                    self.write_checkpoint()
                    last_ckpt_wall = _time.perf_counter()
                if self._signal is not None:
                    name = signal.Signals(self._signal).name
                    self.write_checkpoint()
                    status, message = "interrupted", f"{name} received: checkpoint written at t = {sys_.time:.6g} s " \
                                                     f"(continue with --resume)"
                    break
                reason = scene.stop_reason()
                if reason:
                    status, message = "done", reason
                    break
                if max_steps is not None and sys_.step_count >= max_steps:
                    self.write_checkpoint()
                    status, message = "stopped", f"step limit reached ({max_steps} steps); checkpoint written"
                    break
                if wall_limit is not None and _time.perf_counter() - t_wall0 >= wall_limit:
                    self.write_checkpoint()
                    status, message = "stopped", f"wall-time limit reached ({wall_limit:g} s); checkpoint written"
                    break
        except RunError as e:
            if progress is not None:
                progress.close()
            status, message = "failed", str(e)
            log.error("run failed at t = %.6g s, step %d: %s", sys_.time, sys_.step_count, message)
            try:
                res.append_series(**self._series_row())
                res.write_measurements("diagnostic", {"pos": sys_.pos.copy(), "vel": sys_.vel.copy(),
                                                      "omega": sys_.omega.copy(), "radius": sys_.radius.copy(),
                                                      "ids": sys_.ids.copy()},
                                       {"time": sys_.time, "step": sys_.step_count, "message": message})
            except Exception as e2:  # the diagnostic must never hide the real error
                log.error("could not write the diagnostic snapshot: %s", e2)
            self._restore_signals(old_handlers)
            self._finish(res, status, message, t_wall0)
            raise RunError(message) from None
        if progress is not None:
            progress.close()
        self._restore_signals(old_handlers)
        if status == "done":
            outputs(final=True)
        return self._finish(res, status, message, t_wall0)

    @staticmethod
    def _restore_signals(old):
        for sig, h in old.items():
            signal.signal(sig, h)

    # ------------------------------------------------------------------------------- helpers
    def _report_wall_back(self) -> None:
        """Log the particles that came to a one-sided wall from its back since the last call
        (the engine gives them no contact there: :func:`cfddem.particles.integrate.wall_forces`)."""
        ev = self.system.wall_back_events
        if not ev:
            return
        for step, pid, wall, k in ev:
            self.log.warning("step %d: particle id %d came to wall '%s' from its back (%d particle(s) in that step): "
                             "it is outside the region the walls enclose (over a rim or through a gap); one-sided "
                             "walls give no contact there", step, pid, wall, k)
        ev.clear()

    def _feed_and_drain(self) -> None:
        t0 = _time.perf_counter()
        sys_ = self.system
        c = self.counters
        if self.inlet is not None:
            self.inlet.insert(sys_, sys_.time, self.dt)
        if sys_.n and sys_.steps_since_rebuild >= self._exit_every and sys_.beyond_sink().any():
            # the exit's particles leave at the engine's neighbour rebuilds, at the latest here,
            # when the lists have stood for a whole check interval (~1 ms): within ~2 ms
            sys_.drain_sink()
        k, m = sys_.take_sunk()
        c["count_out"] += k
        c["mass_out"] += m
        if sys_.n:
            pos = sys_.pos
            self._check_walls_crossed()
            margin = self.case.exit.lost_margin
            lost = np.any((pos < self.box_lo - margin) | (pos > self.box_hi + margin), axis=1)
            if lost.any():
                k, m = sys_.remove_particles(lost)
                c["count_lost"] += k
                c["mass_lost"] += m
                self.log.warning("t = %.4f s: %d particle(s) left the domain and were removed as lost", sys_.time, k)
        self.timings["inlet_exit"] += _time.perf_counter() - t0

    def _check_walls_crossed(self) -> None:
        """Stop with a diagnosis when a particle went through a wall (analytic or mesh) since the
        last check (:mod:`cfddem.particles.crossing`): on the wall's side then, more than its
        radius behind it now, through the wall itself.  Particles that fly over a wall's edge
        are not affected."""
        from .particles.crossing import crossing_mark, find_crossing

        sys_ = self.system
        prev = getattr(self, "_prev_check", None)
        self._prev_check = crossing_mark(sys_)
        if prev is None:
            return
        c = find_crossing(sys_, prev)
        if c is None:
            return
        j = c.index
        speed = float(np.linalg.norm(sys_.vel[j]))
        r = float(sys_.radius[j])
        ratio = self.dt / collision_time(self.case)
        where = f"wall '{c.wall}'"
        if c.triangle >= 0:
            x = sys_.pos[j]
            where += (f" (mesh, triangle {c.triangle}) since step {c.since_step} (now at "
                      f"[{x[0]:.4g}, {x[1]:.4g}, {x[2]:.4g}] m, ")
        else:
            where += f" since step {c.since_step} (now "
        raise RunError(
            f"step {sys_.step_count}, t = {sys_.time:.6g} s: particle {c.pid} went through {where}"
            f"{c.depth * 1e3:.3g} mm behind it, speed {speed:.3g} m/s); "
            f"likely cause: time step too large for this stiffness and speed "
            f"(dt = {20 * ratio:.2g} t_c/20, the particle moves {speed * self.dt / r:.2g} radii per step)")

    def _series_row(self) -> dict:
        s = self.system
        c = self.counters
        mass_in = self.inlet.mass_inserted if self.inlet is not None else 0.0
        row = dict(time=s.time, step=float(s.step_count), n_particles=float(s.n), mass_in=mass_in,
                   feed_deficit=self.inlet.mass_dropped if self.inlet is not None else 0.0,
                   mass_out=c["mass_out"], mass_lost=c["mass_lost"],
                   mass_present=float(np.sum(s.mass)) if s.n else 0.0,
                   kinetic_energy=s.kinetic_energy(), max_overlap_ratio=s.max_overlap_ratio(),
                   mean_velocity_z=float(np.mean(s.vel[:, 2])) if s.n else 0.0)
        if self.gas is not None:
            row.update(self.gas.series_row())
        if s.nm:  # force and torque (about each mesh's centre) the particles exert on each mesh wall
            for m, f, tq in zip(s.meshes, s.mesh_forces(), s.mesh_torques()):
                row.update({f"mesh_{m.name}_{c}": float(v) for c, v in zip(("fx", "fy", "fz"), f)})
                row.update({f"mesh_{m.name}_{c}": float(v) for c, v in zip(("tx", "ty", "tz"), tq)})
        row.update({k: float(v) for k, v in self.scene.series().items()})
        return row

    def _write_budget(self, res) -> None:
        """The particles' and the gas's momentum budgets (those that have data)."""
        if self.budget is not None and self.budget.n_samples:
            res.write_measurements(self.budget.group, self.budget.results(), self.budget.attrs())
        if self.gas_budget is not None and self.gas_budget.n_steps:
            res.write_measurements(self.gas_budget.group, self.gas_budget.results(), self.gas_budget.attrs())

    def _write_scene_measurements(self, res) -> None:
        m = self.scene.measurements()
        if m is not None:
            group, arrays, attrs = m
            res.write_measurements(group, arrays, attrs)

    def _finish(self, res, status: str, message: str, t_wall0: float) -> RunSummary:
        wall = self._wall_prev + _time.perf_counter() - t_wall0  # with the wall time before a resume
        s = self.system
        if self.measure is not None:
            try:
                res.write_measurements(self.measure.group, self.measure.results(), self.measure.attrs())
            except Exception as e:  # keep what is written; say why
                self.log.error("could not store the measurements: %s", e)
        try:
            self._write_budget(res)
        except Exception as e:
            self.log.error("could not store the momentum budget: %s", e)
        try:
            self._write_scene_measurements(res)
        except Exception as e:
            self.log.error("could not store the scene measurements: %s", e)
        if self.gas is not None:
            try:
                self.gas.write_measurements(res)
            except Exception as e:
                self.log.error("could not store the gas measurements: %s", e)
        if self._jit_timer is not None:
            _nb_event.unregister("numba:compile", self._jit_timer)
            if self._jit_timer.done:
                self.timings["compile"] += self._jit_timer.duration
            self._jit_timer = None
        timings = dict(self.timings)
        timings["total"] = wall
        summary = RunSummary(status=status, out_dir=str(self.out), time=s.time, steps=s.step_count,
                             wall_time=wall, n_particles=s.n,
                             mass_in=self.inlet.mass_inserted if self.inlet is not None else 0.0,
                             mass_out=self.counters["mass_out"], message=message, timings=timings)
        res.write_metadata(status=status, message=message, wall_time=wall, steps=s.step_count,
                           wall_back_events=s.wall_back_count,
                           **{f"time_{k}": v for k, v in timings.items()})
        if self.gas is not None:
            res.write_metadata(**self.gas.run_stats())
        res.close()
        self._results = None
        (self.out / RUN_MARKER).write_text(json.dumps({"program": "cfddem", "version": __version__,
                                                       "case": self.case.name, **summary.to_dict()}, indent=1))
        self.log.info("%s at t = %.6g s after %d steps, %.1f s wall (%s)%s", status, s.time, s.step_count, wall,
                      ", ".join(f"{k} {v:.1f} s" for k, v in timings.items() if k != "compile"),
                      f"; numba compiled kernels for {timings['compile']:.1f} s of it" if timings["compile"] >= 0.1
                      else "")
        if message:
            self.log.info(message)
        if s.wall_back_count:
            self.log.warning("%d time(s) a particle came to a wall from its back in this run (no contact there): "
                             "particles left the region the walls enclose", s.wall_back_count)
        if self.gas is not None:
            line = self.gas.run_summary()
            if line:
                self.log.info(line)
        inl = self.inlet
        if inl is not None and inl.mass_inserted > 0:
            frac = inl.mass_dropped / (inl.mass_inserted + inl.mass_dropped)
            (self.log.warning if frac > 0.01 else self.log.info)(
                "inlet: %.4g kg fed, %d particles; feed deficit %.3g %% (%d sites blocked for %g lattice "
                "periods and dropped)", inl.mass_inserted, inl.count_inserted, 100 * frac, inl.count_dropped,
                inl.retry_periods)
        if self.case.output.plots and status != "failed":
            try:
                from .report.plots import write_run_report

                t0 = _time.perf_counter()
                files = write_run_report(self.out / "results.h5", self.out / "report")
                self.log.info("report: %d plot(s) in %s (%.1f s)", len(files), self.out / "report",
                              _time.perf_counter() - t0)
            except Exception as e:
                self.log.error("could not write the plots: %s", e)
        from .io.log import log_repeat_totals

        log_repeat_totals(self.log)  # the totals of the rate-limited repeated warnings
        return summary


def run_case(case: Case, out_dir: str | Path | None = None, **kw) -> tuple[RunSummary, dict | None]:
    """Run a case as ``cfddem run`` does: the run itself and, when the case asks for it
    (``study.compare_without_gas`` with gas enabled), the same case without gas into
    ``OUT/no_gas`` and the comparison report into ``OUT/compare``.  Returns the main run's
    summary and the comparison summary (or None)."""
    from .config import build_case

    sim = Simulation(case, out_dir, **kw)
    summary = sim.run()
    if not (case.study.compare_without_gas and case.gas.enabled) or summary.status != "done":
        return summary, None
    from .report.compare import compare_runs

    twin = build_case(case.resolved, case_dir=case.path, overrides={"gas.enabled": False},
                      raw_text=case.raw_text)
    kw2 = dict(kw)
    kw2["resume"] = kw.get("resume", False) and (sim.out / "no_gas" / RUN_MARKER).exists() and \
        json.loads((sim.out / "no_gas" / RUN_MARKER).read_text()).get("status") != "done"
    kw2["overwrite"] = True
    sim.log.info("study: the same case without gas -> %s", sim.out / "no_gas")
    Simulation(twin, sim.out / "no_gas", **kw2).run()
    comparison = compare_runs(sim.out / "no_gas", sim.out, sim.out / "compare", labels=("no gas", "with gas"))
    return summary, comparison


def check_disk_space(case: Case, out: Path) -> None:
    """Fail early when the disk cannot hold the run's estimated output."""
    n = max(expected_particles(case), 1)
    T = case.time.end_time
    o = case.output
    per_snap = n * 13 * 8
    n_snap = T / o.snapshot_interval
    n_vtk = T / (o.vtk_interval or o.snapshot_interval) if o.vtk else 0
    need = per_snap * n_snap * 0.7 + n * 120 * n_vtk + 3 * memory_estimate(n)
    probe = out
    while not probe.exists() and probe != probe.parent:  # the run folder may not exist yet
        probe = probe.parent
    free = shutil.disk_usage(probe).free
    if free < need:
        raise CaseError("--out", f"only {free / 2**20:.0f} MiB free on the disk of {out}, the run needs about "
                                 f"{need / 2**20:.0f} MiB (snapshots, VTU frames, checkpoints)")


# ----------------------------------------------------------------------------------------------
# engine adapters and derived numbers (shared with `cfddem check`)
# ----------------------------------------------------------------------------------------------
def engine_wall(w, model: str | None = None):
    """The engine's wall object for a :class:`~cfddem.scenes.common.WallSpec` (``model``: see
    :func:`contact_law`)."""
    from .particles.walls import AnnulusWall, CylinderWall, PlaneWall, RectangleWall

    law = contact_law(w.params, model)
    if w.kind == "mesh":
        return mesh_wall(w, law)
    if w.kind == "plane":
        return PlaneWall(contact=law, name=w.name, point=tuple(w.point), normal=tuple(w.normal), spin=w.spin)
    if w.kind == "annulus":  # half_extents = (inner radius, outer radius)
        return AnnulusWall(contact=law, name=w.name, point=tuple(w.point), normal=tuple(w.normal),
                           r_in=w.half_extents[0], r_out=w.half_extents[1])
    if w.kind == "cylinder":
        return CylinderWall(contact=law, name=w.name, point=tuple(w.point), axis=tuple(w.normal),
                            radius=w.half_extents[0], half_height=w.half_extents[1], inside=w.inside, spin=w.spin)
    return RectangleWall(contact=law, name=w.name, point=tuple(w.point), normal=tuple(w.normal),
                         axis1=tuple(w.u_axis), half1=w.half_extents[0], half2=w.half_extents[1])


def particle_mass(case: Case, diameter: float | None = None) -> float:
    d = case.particles.diameter if diameter is None else diameter
    return case.particles.density * math.pi / 6.0 * d ** 3


def impact_speed(case: Case) -> float:
    """Impact speed for the Hertz collision time: the case's speed scale
    (:func:`expected_max_speed`), at least 1 m/s."""
    return max(expected_max_speed(case), 1.0)


def contact_pairs(case: Case) -> list[tuple[str, ContactLaw, float, float]]:
    """(label, law, m*, R*) of every contact pair of the case, for the smallest particle:
    particle-particle (m* = m/2, R* = R/2), then each wall (m* = m, R* = R)."""
    m = particle_mass(case)
    r = 0.5 * case.particles.diameter
    model = case.contact.model
    pp = contact_law(case.resolved["contact"]["particle_particle"], model)
    return [("particle-particle", pp, 0.5 * m, 0.5 * r)] + [
        (f"particle-wall ({w.name})", contact_law(w.params, model), m, r) for w in wall_specs(case)]


def collision_time(case: Case) -> float:
    """The shortest normal collision time of the case's contact pairs (:func:`contact_pairs`),
    at :func:`impact_speed` for laws whose time depends on it (Hertz-Mindlin)."""
    v = impact_speed(case)
    return min(law.collision_time(meff, reff, v) for _, law, meff, reff in contact_pairs(case))


def rayleigh_time(case: Case) -> float:
    """The Rayleigh time of the smallest particle (particle-particle material); inf for laws
    without one (linear)."""
    law = contact_law(case.resolved["contact"]["particle_particle"], case.contact.model)
    return law.rayleigh_time(0.5 * case.particles.diameter, case.particles.density)


def has_particles(case: Case) -> bool:
    """Whether the case can hold particles at all (its scene creates them, or initial particles)."""
    return bool(case.particles.initial) or bool(case.particles.initial_file) or scene_of(case).has_particles(case)


def check_time_step(case: Case, log=None) -> float:
    """dt / t_c; refuses (unless time.force) above the stable step the stability maps predict
    (velocity Verlet on the case's most limiting contact, docs/stability.md) and above 1/5;
    warns above 1/20 (no particles: 0)."""
    if not has_particles(case):
        return 0.0
    from .stability import predicted_step_limit

    tc = collision_time(case)
    ratio = case.time.dt / tc
    pred = predicted_step_limit(case)
    if case.time.dt > pred["dt"] and not case.time.force:
        raise CaseError("time.dt", f"{case.time.dt:g} s = {ratio:.3g} t_c: the run would fail ({pred['cause']}): above "
                                   f"the stable step {pred['dt']:.3g} s = {pred['ratio']:.3g} t_c of velocity Verlet on "
                                   f"one {pred['where']} contact (docs/stability.md); reduce it or set time.force = true")
    if case.time.dt > pred["sure"] and log is not None:
        log.warning("time.dt = %g s is %.2f of the stable step %.3g s (velocity Verlet on one %s contact): the "
                    "stability maps had failures within a grid step of it (docs/stability.md)", case.time.dt,
                    case.time.dt / pred["dt"], pred["dt"], pred["where"])
    if ratio > 0.2 and not case.time.force:
        raise CaseError("time.dt", f"{case.time.dt:g} s is {ratio * 20:.1f} t_c/20 (t_c = {tc:.3g} s): above t_c/5 "
                                   "the contacts are not resolved; reduce it or set time.force = true")
    if ratio > 0.05 and log is not None:
        log.warning("time.dt = %g s is %.1f t_c/20: collisions resolved by fewer than 20 steps", case.time.dt,
                    ratio * 20)
    tr = rayleigh_time(case)
    if case.time.dt > 0.2 * tr and log is not None:
        log.warning("time.dt = %g s is %.2g T_R (Rayleigh time %.3g s): above the usual 0.2 T_R of "
                    "Hertz-Mindlin DEM", case.time.dt, case.time.dt / tr, tr)
    return ratio


def expected_particles(case: Case) -> int:
    """Estimate of the particle count: initial particles plus what the scene creates."""
    n = len(case.particles.initial) + scene_of(case).expected_particles(case)
    if case.particles.initial_file:
        try:
            n += len(initial_particles(case)["pos"]) - len(case.particles.initial)
        except CaseError:
            pass
    return n


def memory_estimate(n: int, n_walls: int = 0, mesh_slots: int = 0) -> float:
    """Bytes for n particles: ~30 float64 per particle, ~12 neighbour pairs of ~72 bytes, and the
    per-particle contact slots of each analytic wall (history, force, torque: 10 float64 and a
    flag, 81 bytes) and of each mesh slot (18 float64; one is allocated without mesh walls).
    Measured on the full multi-flow blender (1.2 M spheres, 25 walls): 4.05 kB per sphere
    resident, this gives 3.3 kB (the rest: neighbour-list scratch and Python)."""
    return n * (30 * 8 + 12 * 72 + 81 * n_walls + 144 * mesh_slots)


def describe_case(case: Case) -> list[str]:
    """The derived numbers `cfddem check` prints (and the run log records)."""
    lines = []
    particles = has_particles(case)
    if not particles:
        lines.append("particles: none (no inlet, no initial particles): no particle or contact numbers")
        lines.append(f"time step: dt = {case.time.dt:g} s (no particles: no contact time-step limit)")
    else:
        d = case.particles.diameter
        m = particle_mass(case)
        lines.append(f"particle: d = {d * 1e3:.3g} mm" + (f"..{case.particles.diameter_max * 1e3:.3g} mm"
                                                         if case.particles.diameter_max else "")
                     + f", rho = {case.particles.density:g} kg/m3, m = {m:.4g} kg, I = {0.1 * m * d * d:.4g} kg m2")
        v = impact_speed(case)
        for label, law, meff, reff in contact_pairs(case):
            lines.append(f"{label}: {law.describe(meff, reff, v, 0.5 * d)}")
        tr = rayleigh_time(case)
        if math.isfinite(tr):
            lines.append(f"Rayleigh time T_R = {tr:.4g} s: dt = {case.time.dt / tr:.3g} T_R "
                         f"({'OK' if case.time.dt <= 0.2 * tr else 'WARNING: above 0.2 T_R'})")
        ratio = case.time.dt / collision_time(case)
        from .stability import predicted_step_limit

        pred = predicted_step_limit(case)
        lines.append(f"time step: dt = {case.time.dt:g} s = t_c/{1 / ratio:.1f} "
                     f"({'OK' if ratio <= 0.05 else 'WARNING: above t_c/20' if ratio <= 0.2 else 'REFUSED: above t_c/5'})")
        if not math.isfinite(pred["dt"]):
            lines.append("stable step: not predicted (the contact law gives no linearised springs)")
        else:
            lines.append(f"stable step: {pred['dt']:.3g} s = {pred['ratio']:.3g} t_c, dt is "
                         f"{case.time.dt / pred['dt']:.3g} of it "
                         + ("(OK)" if case.time.dt <= pred["sure"] else "(WARNING: within a grid step of the maps' "
                            "failures)" if case.time.dt <= pred["dt"] else f"(REFUSED: the run would fail, {pred['cause']})")
                         + f"; source: {pred['source']}")
    g = gravity_vector(case)
    om = frame_omega(case)
    lines.append(f"gravity: ({g[0]:.4g}, {g[1]:.4g}, {g[2]:.4g}) m/s2; frame rotation: "
                 + (f"{case.frame.rpm:g} rpm, Omega = ({om[0]:.4g}, {om[1]:.4g}, {om[2]:.4g}) rad/s about "
                    f"{tuple(case.frame.axis_point)}" if case.frame.rpm else "none (inertial frame, no rotation terms)"))
    lines += scene_of(case).describe(case)
    walls = wall_specs(case)
    for w in walls:
        if w.kind == "mesh":
            lines += mesh_wall(w).check_lines(case.particles.diameter if particles else None)
    if particles:
        n = expected_particles(case)
        nw = sum(1 for w in walls if w.kind != "mesh")
        mem = memory_estimate(n, nw, 6 if any(w.kind == "mesh" for w in walls) else 1)
        lines.append(f"expected particles: about {n:,}; memory about {mem / 2 ** 20:.0f} MiB ({nw} analytic wall{'s' if nw != 1 else ''})")
        v = expected_max_speed(case)
        if v > 0:
            lines.append(f"expected speed scale: {v:.3g} m/s (the scene's fastest expected particle or gas speed)")
    steps = int(math.ceil(case.time.end_time / case.time.dt))
    lines.append(f"steps to end time {case.time.end_time:g} s: {steps:,}")
    if case.gas.enabled:
        from .coupling.exchange import coupling_diagnostics

        d = max(case.particles.diameter, case.particles.diameter_max) if particles else None
        domain = scene_of(case).gas_domain(case)
        lines += ["gas: " + x for x in coupling_diagnostics(case, domain, d)]
        n_rec = recommended_coupling_interval(case, domain=domain)
        lines.append(f"gas: recommended coupling interval {n_rec} particle steps (gas step {n_rec * case.time.dt:.3g} s: "
                     f"gas CFL <= 0.3 at the fastest expected flow); the case uses {case.gas.coupling_interval}")
        from .stability import courant_limit

        h = min(domain.grid.spacing)
        re_h = case.gas.density * max(expected_max_speed(case), 1e-9) * h / case.gas.viscosity
        c_ok, c_bad = courant_limit(re_h)
        lines.append(f"gas: at the cell Reynolds number {re_h:.3g} (fastest expected flow, smallest cell) the Courant "
                     f"map (gas alone) found the TVD advection stable up to C = {c_ok:.2g} and growing from C = {c_bad:.2g}; "
                     f"explicit drag needs dt_g < 2 tau (docs/stability.md)")
    else:
        lines.append("gas: off (no gas solver is built)")
    return lines


def expected_max_speed(case: Case) -> float:
    """Speed scale of the flow (the scene's; e.g. the chute: a particle sliding its whole length,
    or the lid cross-wind at its far corner)."""
    return scene_of(case).speed_scale(case)


def recommended_coupling_interval(case: Case, cfl: float = 0.3, domain=None) -> int:
    """Largest number of particle steps per gas step keeping the gas CFL number (sum over the
    axes of u dt_g / h) at or below ``cfl`` for the expected flow speed, and the gas step below
    the rotating frame's explicit Coriolis limit 0.05/|Omega|.  ``domain``: the scene's gas
    domain if already built."""
    h = (domain or scene_of(case).gas_domain(case)).grid.spacing
    u = max(expected_max_speed(case), 1e-9)
    dtg = cfl / sum(u / hh for hh in h)
    om = float(np.linalg.norm(frame_omega(case)))
    if om > 0:
        dtg = min(dtg, 0.05 / om)
    return max(1, int(dtg / case.time.dt))
