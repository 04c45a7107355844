"""Time one gas step (cfddem.gas.GasSolver) with the multigrid ("mg") and the pyamg ("amg")
pressure solvers, on the chute grid and on 64^3 cells, in one command.

Chute grid: 16 x 15 x 150 cells over 0.08 x 0.045 x 0.9 m, inclined 30 deg, rotating at
16 rpm about the vertical axis, no-slip floor and side walls, lid cross-wind on the open
top, co-flow inlet, pressure outlet.  Two porosity fields:

* ``eps=1``: particle-free (no drag);
* ``bed``: a bed 1 cm deep of eps 0.45 along the floor under free air, with a +-0.03 noise
  that changes every step (particles moving), and the implicit drag of that bed
  (Ergun: K = 150 mu (1-eps)^2 / (eps^2 d^2), d = 2 mm; dt K/rho ~ 0.8 in the bed).

64^3: a unit box, walls and lid cross-wind, periodic along z, a moving bed-like porosity
with noise and drag K = 30 everywhere.

Compile time and the first AMG set-up are excluded (warm-up steps).  Each configuration
(grid, solver, numba threads: mg with every count of ``--threads``, amg with the first) is
timed ``--repeats`` times, alternating them so that all see the same machine load; the
output gives the range over the repeats of the mean time per step, wall clock and process
CPU time (all threads; it does not count the time the process waited for the shared
cores), split into predictor (momentum right-hand side and predictor kernels), pressure
(coefficient set-up and solve) and rest, plus pressure iterations, the mass-balance defect,
and the ratios amg/mg and 1 thread / t threads measured in the same round.

Usage: python benchmarks/gas_step.py [--steps 20] [--repeats 3] [--threads 1,2] [--tol 1e-8]
                                     [--no-cube] [--no-amg] [--json]
       python benchmarks/gas_step.py --tol-sweep      (mg iterations and defect against tol)
       python benchmarks/gas_step.py --defect-sweep   (mg iterations and defect against defect_tol)
       python benchmarks/gas_step.py --compare DIR [--repeats 3] [--steps 20] [--grid G1,G2] [--threads 1,2]
           before/after in one command: DIR holds an older ``cfddem`` package (for example
           ``git archive <commit> cfddem | tar -x -C DIR``); each repeat runs this script once
           with that package and once with the current one (separate processes, alternated,
           mg, chute grids 16x15x150 and 16x8x150, 1 thread unless --threads is given: each
           count in its own processes), and prints ranges and the old/new ratio;
           ``--particles CHECKPOINT`` adds the particle step of the chute (no gas, 1 thread)
       python benchmarks/gas_step.py --record CHECKPOINT FILE [--grid 16x15x150] [--interval 10]
                                     [--steps 40] [--warm 100]
           runs the coupled 16 rpm chute (cases/chute_16rpm) from a developed checkpoint with
           the gas grid and coupling interval given, skips ``--warm`` gas steps (the gas starts
           from rest when the checkpoint's gas grid differs) and writes the gas solver's state
           and the inputs of the next ``--steps`` gas steps (porosity, drag K and U_p, source,
           dt) to FILE (.npz, about 3 MB per step on 16 x 15 x 150)
       python benchmarks/gas_step.py --replay FILE [--repeats 3] [--threads 1] [--tol-sweep] [--flush MB]
           times GasSolver.step on those recorded inputs (the real workload: the porosity of
           the moving particles and the sluice feed, instead of the synthetic bed's white
           noise) for each initial guess of the pressure solve; with --compare DIR the
           replay alternates between the package in DIR and the current one (one process each);
           with --tol-sweep: CPU, wall, iterations, defect and the distance of the final gas
           fields from a tol 1e-12 replay, for each pressure tolerance from 0.5 (next to no
           solve: the step's floor) to 1e-10; --flush 512 writes
           512 MB between the steps (untimed): the particle steps of the coupled run evict the
           gas arrays from the caches, and only then do the replay's per-kernel times match the
           run's (64 MB is not enough)
"""

from __future__ import annotations

import os

# One BLAS thread: pyamg's coarsest-level solve goes through OpenBLAS, whose threads spin on
# the shared 2-core machines and made the AMG solve 7x slower (measured: 310 against 38 ms per
# chute step).  Set before numpy is imported; an explicit setting in the environment wins.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

# cfddem._jit first: it selects numba's OpenMP threading layer (passive waiting) before numba
# is imported anywhere; with the TBB layer, which numba picks otherwise, two threads made the
# multigrid solve 3-30x slower on the shared machine (measured).
import cfddem._jit  # noqa: E402, F401

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

import cfddem.gas.solver as solver_mod  # noqa: E402
from cfddem._jit import set_threads  # noqa: E402
from cfddem.gas import GasSolver, Inlet, LidCrossWind, NoSlip, Periodic, PressureOutlet, StaggeredGrid  # noqa: E402

RHO, MU = 1.2, 1.8e-5


def chute_solver(shape=(16, 15, 150), lengths=(0.08, 0.045, 0.9), tol=1e-8, solver="mg"):
    th = np.radians(30.0)
    up = np.array([0.0, np.cos(th), -np.sin(th)])
    omega = tuple(16 * 2 * np.pi / 60 * up)
    axis = (0.04, 0.0, 0.035)
    gvec = tuple(-9.81 * up)
    g = StaggeredGrid(shape, lengths)
    bcs = {"x-": NoSlip(), "x+": NoSlip(), "y-": NoSlip(), "y+": LidCrossWind(omega=omega, axis_point=axis),
           "z-": Inlet(speed=1.0), "z+": PressureOutlet(p=lambda x, y, z: RHO * (gvec[1] * y + gvec[2] * z))}
    return g, GasSolver(g, rho=RHO, mu=MU, bcs=bcs, gravity=gvec, omega=omega, axis_point=axis, tol=tol,
                        pressure_solver=solver)


def cube_solver(n=64, tol=1e-8, solver="mg"):
    g = StaggeredGrid((n, n, n), (1.0, 1.0, 1.0))
    bcs = {"x-": NoSlip(), "x+": NoSlip(), "y-": NoSlip(), "y+": LidCrossWind(omega=(0, 1.7, 0), axis_point=(0.5, 0, 0.5)),
           "z-": Periodic(), "z+": Periodic()}
    return g, GasSolver(g, rho=RHO, mu=MU, bcs=bcs, gravity=(0, -9.81, 0), omega=(0, 1.7, 0),
                        axis_point=(0.5, 0, 0.5), tol=tol, pressure_solver=solver)


def face_mean(g, cell):
    """Cell field -> the three interior face arrays (arithmetic mean, boundary faces copied)."""
    out = []
    for d in range(3):
        e = np.concatenate([np.take(cell, [0], axis=d), cell, np.take(cell, [-1], axis=d)], axis=d)
        n = e.shape[d]
        out.append(0.5 * (np.take(e, range(n - 1), axis=d) + np.take(e, range(1, n), axis=d)))
    return out


def chute_fields(g, kind, nsteps, seed=1):
    """Porosity per step and drag (K, U_p) for the chute grid; kind "eps1" or "bed"."""
    if kind == "eps1":
        return [np.ones(g.shape)] * nsteps, None, None
    rng = np.random.default_rng(seed)
    X, Y, Z = g.mesh("ccc")
    bed = Y < 0.01
    eps = [np.where(bed, 0.45 + 0.03 * rng.uniform(-1, 1, g.shape), 1.0) for _ in range(nsteps)]
    ef = face_mean(g, np.where(bed, 0.45, 1.0))
    d = 2e-3
    K = tuple(150 * MU * (1 - e) ** 2 / (e**2 * d**2) for e in ef)
    Up = (np.zeros_like(K[0]), np.zeros_like(K[1]), np.full(K[2].shape, 0.5))
    return eps, K, Up


def cube_fields(g, nsteps, dt, seed=1):
    rng = np.random.default_rng(seed)
    noise = rng.uniform(-1.0, 1.0, g.shape)
    X, Y, Z = g.mesh("ccc")
    H = g.lengths[1]
    eps = []
    for i in range(nsteps):
        depth = 0.4 * H * (1.0 + 0.3 * np.sin(2 * np.pi * (Z / g.lengths[2] - 2.0 * i * dt)))
        solid = 0.6 / (1.0 + np.exp((Y - depth) / (0.05 * H)))
        eps.append(np.clip(1.0 - solid + 0.08 * noise, 0.4, 1.0))
    shapes = [g.interior_shape(loc) for loc in ("fcc", "cfc", "ccf")]
    K = tuple(np.full(sh, 30.0) for sh in shapes)
    Up = (np.zeros(shapes[0]), np.zeros(shapes[1]), np.full(shapes[2], 1.0))
    return eps, K, Up


class Timers:
    """Wall and thread-CPU time spent in the wrapped callables."""

    def __init__(self):
        self.t = {"predictor": [0.0, 0.0], "pressure": [0.0, 0.0]}

    def wrap(self, key, fn):
        acc = self.t[key]

        def timed(*a, **k):
            w0, c0 = time.perf_counter(), time.process_time()
            out = fn(*a, **k)
            acc[0] += time.perf_counter() - w0
            acc[1] += time.process_time() - c0
            return out

        return timed


def run(make, fields, steps, dt, warm=3):
    """Steps of one solver; returns a dict of per-step means (ms) and diagnostics."""
    g, s = make()
    eps, K, Up = fields
    s.set_porosity(eps[0])
    for i in range(warm):  # compilation, AMG set-up
        s.set_porosity(eps[1 + i])
        s.step(dt, drag_K=K, drag_Up=Up)
    tm = Timers()
    ps = s.psolver
    orig = (solver_mod.momentum_rhs, solver_mod.predictor_kernel, ps.set_coefficients, ps.solve)
    solver_mod.momentum_rhs = tm.wrap("predictor", orig[0])
    solver_mod.predictor_kernel = tm.wrap("predictor", orig[1])
    ps.set_coefficients = tm.wrap("pressure", orig[2])
    ps.solve = tm.wrap("pressure", orig[3])
    its, defects = [], []
    try:
        w0, c0 = time.perf_counter(), time.process_time()
        for i in range(steps):
            s.set_porosity(eps[1 + warm + i])
            info = s.step(dt, drag_K=K, drag_Up=Up)
            if not info.ok:
                raise SystemExit(info.message)
            its.append(info.pressure_iterations)
            defects.append(info.max_divergence)
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    finally:
        solver_mod.momentum_rhs, solver_mod.predictor_kernel = orig[0], orig[1]
        ps.set_coefficients, ps.solve = orig[2], orig[3]
    f = 1e3 / steps
    tp, tq = tm.t["predictor"], tm.t["pressure"]
    return dict(wall=wall * f, cpu=cpu * f, pred=tp[1] * f, pres=tq[1] * f, rest=(cpu - tp[1] - tq[1]) * f,
                wpred=tp[0] * f, wpres=tq[0] * f,
                its=float(np.mean(its)), maxits=int(np.max(its)), defect=float(np.max(defects)), cells=g.ncells)


def fmt_range(vals, w=6, p=1):
    lo, hi = min(vals), max(vals)
    return f"{lo:{w}.{p}f}" if hi - lo < 0.05 * max(abs(hi), 1e-12) else f"{lo:.{p}f}-{hi:.{p}f}".rjust(w)


def bench_pair(name, make, fields, steps, dt, repeats, threads=(1,), solvers=("mg", "amg")):
    """Time every (solver, thread count) configuration ``repeats`` times, alternating them so
    that all see the same machine load; print ranges and the ratios measured in the same
    round (amg/mg at the first thread count, t threads against 1 for mg)."""
    confs = [(sv, nt) for sv in solvers for nt in (threads if sv == "mg" else threads[:1])]
    res = {c: [] for c in confs}
    for _ in range(repeats):
        for sv, nt in confs:
            set_threads(nt)
            res[(sv, nt)].append(run(lambda: make(sv), fields, steps, dt))
    set_threads(threads[0])
    for sv, nt in confs:
        r = res[(sv, nt)]
        print(f"{name:>14s} {sv:>4s} {nt}T: wall {fmt_range([x['wall'] for x in r], 12)} ms/step, "
              f"CPU {fmt_range([x['cpu'] for x in r], 12)} ms (predictor {fmt_range([x['pred'] for x in r])}, "
              f"pressure {fmt_range([x['pres'] for x in r])}, rest {fmt_range([x['rest'] for x in r])}, "
              f"wall: predictor {fmt_range([x['wpred'] for x in r])}, pressure {fmt_range([x['wpres'] for x in r])}); "
              f"pressure iterations {r[0]['its']:.1f} (max {r[0]['maxits']}), mass defect {r[0]['defect']:.1e}")
    t0 = threads[0]
    if "amg" in solvers and "mg" in solvers:
        ratio_cpu = [a["cpu"] / m["cpu"] for a, m in zip(res[("amg", t0)], res[("mg", t0)])]
        ratio_p = [a["pres"] / m["pres"] for a, m in zip(res[("amg", t0)], res[("mg", t0)])]
        print(f"{name:>14s} amg/mg ({t0}T): step (CPU) x{fmt_range(ratio_cpu, 4)}, pressure x{fmt_range(ratio_p, 4)}")
    if "mg" in solvers:
        for nt in threads[1:]:
            rw = [a["wall"] / b["wall"] for a, b in zip(res[("mg", t0)], res[("mg", nt)])]
            rc = [a["cpu"] / b["cpu"] for a, b in zip(res[("mg", t0)], res[("mg", nt)])]
            print(f"{name:>14s} mg {t0}T/{nt}T: wall x{fmt_range(rw, 4, 2)}, CPU (all threads) x{fmt_range(rc, 4, 2)}")
    return {f"{sv}{nt}": v for (sv, nt), v in res.items()}


def tol_sweep(steps):
    """mg on the chute bed: iterations and mass-balance defect against the pressure tolerance."""
    dt = 1e-3
    for tol in (1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-10):
        g, _ = chute_solver()
        fields = chute_fields(g, "bed", steps + 4)
        r = run(lambda: chute_solver(tol=tol), fields, steps, dt)
        print(f"tol {tol:7.0e}: pressure iterations {r['its']:5.1f} (max {r['maxits']:2d}), "
              f"max mass-balance defect per step {r['defect']:.1e}, CPU {r['cpu']:.1f} ms/step")


def particle_step_cost(checkpoint, t_start=1.743, end_time=1.76, short=0.0005):
    """CPU and wall time per particle step of the 16 rpm chute without gas, 1 numba thread,
    branched from a developed checkpoint (copied: the runs must not touch the original).
    Two runs, to the checkpoint time ``t_start`` + ``short`` and to ``end_time``; the difference of their
    child-process CPU times over the difference of their step counts removes the start-up
    (imports, numba cache loading, reading the checkpoint)."""
    import re
    import resource
    import shutil
    import subprocess
    import sys
    import tempfile
    tmp = tempfile.mkdtemp(prefix="gas_step_particles_")
    ck = os.path.join(tmp, "start.h5")
    shutil.copy(checkpoint, ck)
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = dict(os.environ, NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1", PYTHONPATH=repo)
    res = []
    t_end = [t_start + short, end_time]
    for n in range(2):
        c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        out = subprocess.run([sys.executable, "-m", "cfddem.cli", "run", os.path.join(repo, "cases", "chute_16rpm"),
                              "--set", "gas.enabled=false", "--set", f"checkpoint.start_from={ck}",
                              "--set", f"time.end_time={t_end[n]}", "--set", "output.vtk=false",
                              "--set", "measurements.start_time=0", "--out", os.path.join(tmp, f"out{n}"),
                              "--overwrite"], env=env, capture_output=True, text=True, cwd=repo)
        c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        log = out.stdout + out.stderr
        m0 = re.search(r"at t = [0-9.]+ s \(step (\d+), (\d+) particles\)", log)
        m1 = re.search(r"after (\d+) steps, ([0-9.]+) s wall \(particles ([0-9.]+) s", log)
        if out.returncode != 0 or not (m0 and m1):
            print("particle run failed:", log[-2000:])
            shutil.rmtree(tmp, ignore_errors=True)
            return
        res.append((int(m1.group(1)) - int(m0.group(1)), (c1.ru_utime + c1.ru_stime) - (c0.ru_utime + c0.ru_stime),
                    float(m1.group(2)), float(m1.group(3)), m0.group(2)))
    shutil.rmtree(tmp, ignore_errors=True)
    (s0, cpu0, w0, p0, _), (s1, cpu1, w1, p1, npart) = res
    ds = s1 - s0
    print(f"chute particle step ({npart} particles, 1 thread, no gas, {s1} steps against {s0}): "
          f"CPU {(cpu1 - cpu0) / ds * 1e3:.2f} ms per step (difference of the two runs), "
          f"wall {(w1 - w0) / ds * 1e3:.2f} ms (particle part {(p1 - p0) / ds * 1e3:.2f} ms)")


def compare(old_dir, repeats, steps, grids=("16x15x150", "16x8x150"), threads="1"):
    """Alternate subprocess runs of this benchmark with the package in ``old_dir`` and with the
    current one (chute grid of each of ``grids``, mg, numba threads ``threads``: each count
    in its own process); print ranges and ratios old/new per repeat."""
    for grid in grids:
        for nt in threads.split(","):
            print(f"--- chute grid {grid}, {nt} numba thread(s)")
            _compare_one(old_dir, repeats, steps, grid, nt)


def _compare_one(old_dir, repeats, steps, grid, nt):
    import json
    import subprocess
    import sys
    here = os.path.dirname(os.path.abspath(__file__))
    repo = os.path.dirname(here)
    res = {"old": [], "new": []}
    for _ in range(repeats):
        for tag, path in (("old", old_dir), ("new", repo)):
            env = dict(os.environ, PYTHONPATH=path)
            if tag == "old":  # its own numba cache: the old kernels have the same names
                env["NUMBA_CACHE_DIR"] = os.environ.get("NUMBA_CACHE_DIR", "/tmp/numba_cache") + "_compare_old"
            out = subprocess.run([sys.executable, os.path.abspath(__file__), "--no-amg", "--no-cube", "--threads", nt,
                                  "--grid", grid, "--repeats", "1", "--steps", str(steps), "--json"], env=env, cwd="/tmp",
                                 capture_output=True, text=True, check=True).stdout
            res[tag].append(json.loads(out.strip().splitlines()[-1]))
    for kind in ("eps1", "bed"):
        for tag in ("old", "new"):
            r = [x[kind]["mg" + nt][0] for x in res[tag]]
            print(f"chute {kind:4s} {tag}: CPU {fmt_range([x['cpu'] for x in r], 10)} ms/step, "
                  f"wall {fmt_range([x['wall'] for x in r], 10)} ms (predictor {fmt_range([x['pred'] for x in r])}, "
                  f"pressure {fmt_range([x['pres'] for x in r])}, rest {fmt_range([x['rest'] for x in r])}); "
                  f"pressure iterations {r[0]['its']:.1f} (max {r[0]['maxits']}), mass defect {r[0]['defect']:.1e}")
        rc = [o[kind]["mg" + nt][0]["cpu"] / n[kind]["mg" + nt][0]["cpu"] for o, n in zip(res["old"], res["new"])]
        rw = [o[kind]["mg" + nt][0]["wall"] / n[kind]["mg" + nt][0]["wall"] for o, n in zip(res["old"], res["new"])]
        print(f"chute {kind:4s} old/new: CPU x{fmt_range(rc, 4, 2)}, wall x{fmt_range(rw, 4, 2)}")


def defect_sweep(steps):
    """mg on the chute (eps = 1 and bed), tol 1e-8: iterations and mass-balance defect
    against GasSolver's defect_tol (0: the relative criterion alone)."""
    dt = 1e-3
    for kind in ("eps1", "bed"):
        for dtol in (0.0, 1e-11, 1e-10, 1e-9, 1e-8):
            g, s = chute_solver()
            s.defect_tol = dtol
            eps, K, Up = chute_fields(g, kind, steps + 6)
            s.set_porosity(eps[0])
            its, d = [], []
            for i in range(steps + 5):
                s.set_porosity(eps[1 + i])
                info = s.step(dt, drag_K=K, drag_Up=Up)
                if i >= 5:
                    its.append(info.pressure_iterations)
                    d.append(info.max_divergence)
            print(f"chute {kind:4s} defect_tol {dtol:7.0e}: pressure iterations {np.mean(its):5.2f} "
                  f"(max {max(its)}), max mass-balance defect per step {max(d):.1e}")


def record(checkpoint, out, grid="16x15x150", interval=10, steps=40, warm=100):
    """Run the coupled chute from ``checkpoint`` and store the gas solver's state before the
    gas step ``warm`` and the inputs of ``steps`` gas steps from there (see the module doc)."""
    import cfddem.gas.solver as gsm
    from cfddem.config import load_case
    from cfddem.io.checkpoint import read_checkpoint
    from cfddem.simulation import Simulation
    import tempfile
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    case_dir = os.path.join(repo, "cases", "chute_16rpm")
    t0 = float(read_checkpoint(checkpoint)["clock"]["time"])
    cells = "[" + ",".join(grid.split("x")) + "]"
    ov = ["measurements.enabled=false", "output.vtk=false", "output.snapshot_interval=100.0",
          "output.series_interval=100.0", "checkpoint.wall_interval=0", "study.compare_without_gas=false",
          f"checkpoint.start_from={os.path.abspath(checkpoint)}", f"gas.cells={cells}",
          f"gas.coupling_interval={interval}"]
    dt = float(load_case(case_dir, overrides=ov).time.dt)
    ov.append(f"time.end_time={t0 + (warm + steps + 0.5) * interval * dt!r}")
    case = load_case(case_dir, overrides=ov)
    data, count = {}, [0]
    orig = gsm.GasSolver.step

    def step(self, dt, *, source=None, drag_K=None, drag_Up=None):
        i = count[0] - warm
        count[0] += 1
        if i == 0:
            data.update({"state_" + k: np.asarray(v) for k, v in self.get_state().items()
                         if k not in ("amg_reference_coefficients", "amg_reuse")})
        if 0 <= i < steps:
            data[f"dt_{i}"] = np.float64(dt)
            data[f"eps_{i}"] = self.eps.interior.copy()
            for name, arrs in (("S", source), ("K", drag_K), ("Up", drag_Up)):
                if arrs is not None:
                    for c in range(3):
                        data[f"{name}{c}_{i}"] = np.array(arrs[c], copy=True)
        return orig(self, dt, source=source, drag_K=drag_K, drag_Up=drag_Up)

    gsm.GasSolver.step = step
    try:
        with tempfile.TemporaryDirectory(prefix="gas_record_") as tmp:
            Simulation(case, tmp, overwrite=True).run()
    finally:
        gsm.GasSolver.step = orig
    n = sum(1 for k in data if k.startswith("dt_"))
    data.update(grid=np.array(grid), interval=np.int64(interval), steps=np.int64(n), checkpoint=np.array(checkpoint))
    np.savez(out, **data)
    print(f"recorded {n} gas steps of the coupled chute ({grid}, gas every {interval} particle steps, "
          f"after {warm} warm-up gas steps from t = {t0:.4f} s) to {out}")


def replay_solver(rec, guess="scaled"):
    """A GasSolver of the chute case on the recorded grid, in the recorded state."""
    from cfddem.config import load_case
    from cfddem.scenes import scene_of
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    cells = "[" + ",".join(str(rec["grid"]).split("x")) + "]"
    case = load_case(os.path.join(repo, "cases", "chute_16rpm"), overrides=[f"gas.cells={cells}"])
    dom = scene_of(case).gas_domain(case)
    kw = {} if guess is None else {"initial_guess": guess}
    s = GasSolver(dom.grid, rho=case.gas.density, mu=case.gas.viscosity, bcs=dom.bcs, gravity=dom.gravity,
                  omega=dom.omega, axis_point=dom.axis_point, pressure_solver=case.gas.pressure_solver, **kw)
    st = {k[6:]: rec[k] for k in rec.files if k.startswith("state_")}
    st["amg_reference_coefficients"] = None
    s.set_state(st)
    return s


def recorded_inputs(arrs, i):
    """(dt, porosity, source, drag K, drag U_p) of recorded gas step i (``arrs``: the record's
    arrays, loaded); a missing source or drag is None."""
    def get(name):
        return tuple(arrs[f"{name}{c}_{i}"] for c in range(3)) if f"{name}0_{i}" in arrs else None
    return float(arrs[f"dt_{i}"]), arrs[f"eps_{i}"], get("S"), get("K"), get("Up")


def flush_buffer(flush_mb):
    """The buffer that :func:`replayed_steps` writes before each step (None for 0 MB)."""
    return np.zeros(int(flush_mb * 2**20) // 8) if flush_mb > 0 else None


def replayed_steps(s, arrs, n, flush=None):
    """Run GasSolver ``s`` through the ``n`` recorded steps of ``arrs``; yield (i, info, wall
    s, CPU s) per step, the times of ``set_porosity`` and ``step`` together.  ``flush``
    (:func:`flush_buffer`): written before each step, outside the timing, which evicts the gas
    solver's arrays from the caches as the particle steps between two gas steps of the
    coupled run do (512 MB reproduces the coupled run's per-kernel times on the 2-core
    machines; 64 MB does not evict them)."""
    for i in range(n):
        dt, eps, S, K, Up = recorded_inputs(arrs, i)
        if flush is not None:
            flush += 1.0
        w0, c0 = time.perf_counter(), time.process_time()
        s.set_porosity(eps)
        info = s.step(dt, source=S, drag_K=K, drag_Up=Up)
        yield i, info, time.perf_counter() - w0, time.process_time() - c0


def replay_once(rec, guess="scaled", warm=3, flush_mb=0):
    """Time the recorded gas steps once (the first ``warm`` untimed); returns per-step means.
    ``flush_mb`` > 0: before each step (outside the timing) write a buffer of that many MB
    (:func:`replayed_steps`)."""
    n = int(rec["steps"])
    arrs = {k: rec[k] for k in rec.files}  # loaded once, outside the timing
    s = replay_solver(rec, guess)
    its, wall, cpu, defect = [], 0.0, 0.0, 0.0
    for i, info, w, c in replayed_steps(s, arrs, n, flush_buffer(flush_mb)):
        if i >= warm:
            wall += w
            cpu += c
            its.append(info.pressure_iterations)
            defect = max(defect, info.max_divergence)
        if not info.ok:
            raise SystemExit(f"replayed gas step {i} failed: {info.message}")
    m = max(n - warm, 1)
    return dict(wall=wall / m * 1e3, cpu=cpu / m * 1e3, its=float(np.mean(its)), maxits=int(max(its)), defect=defect,
                steps=m)


def replay_tol_sweep(path, tols=(0.5, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-10), ref_tol=1e-12, flush_mb=0):
    """Replay the recorded steps at each pressure tolerance: CPU and wall time, iterations,
    the largest mass-balance defect, and how far the gas is after the recorded steps from the
    replay at ``ref_tol`` (max |p - p_ref| and max |u - u_ref| over the interior, relative to
    the reference's range, and max relative error of the pressure gradient on the faces: the
    pressure force on the particles).  The loosest tolerances show the floor: the cost of a
    step with next to no pressure solve (0.5: under one CG iteration), and the defect that
    the coupled run's stop criterion (1e-4) would not accept.  ``flush_mb``: MB written before
    each step, outside the timing (:func:`replayed_steps`; 512: the coupled run's cold caches)."""
    rec = np.load(path)
    n = int(rec["steps"])
    arrs = {k: rec[k] for k in rec.files}
    flush = flush_buffer(flush_mb)

    def run_tol(tol):
        s = replay_solver(rec)
        s.psolver.tol = tol
        its, defect, cpu, wall = [], 0.0, 0.0, 0.0
        for _, info, w, c in replayed_steps(s, arrs, n, flush):
            cpu += c
            wall += w
            its.append(info.pressure_iterations)
            defect = max(defect, info.max_divergence)
        grads = [np.diff(s.p.interior, axis=d) / s.grid.spacing[d] for d in range(3)]
        return s, dict(cpu=cpu / n * 1e3, wall=wall / n * 1e3, its=float(np.mean(its)), defect=defect, grads=grads)

    ref, r0 = run_tol(ref_tol)
    pr, ur = ref.p.interior, ref.cell_centred_velocity()
    print(f"replay {str(rec['grid'])}: pressure tolerance against the replay at tol {ref_tol:g} "
          f"({r0['its']:.2f} iterations), {n} recorded steps"
          + (f", caches flushed before each step ({flush_mb:g} MB written)" if flush is not None else ""))
    for tol in tols:
        s, r = run_tol(tol)
        dp = np.max(np.abs(s.p.interior - pr)) / np.ptp(pr)
        du = np.max(np.abs(s.cell_centred_velocity() - ur)) / np.max(np.abs(ur))
        dg = max(np.max(np.abs(a - b)) / np.max(np.abs(b)) for a, b in zip(r["grads"], r0["grads"]))
        print(f"tol {tol:7.0e}: CPU {r['cpu']:5.2f}, wall {r['wall']:5.2f} ms/step, iterations {r['its']:5.2f}, max defect {r['defect']:.1e}, "
              f"final p {dp:.1e}, u {du:.1e}, grad p {dg:.1e} (max difference / reference scale)")


def replay(path, repeats, guesses=("scaled", "previous", "zero"), json_out=False, flush_mb=0):
    rec = np.load(path)
    res = {g: [] for g in guesses}
    if flush_mb:
        print(f"caches flushed before each step ({flush_mb:g} MB written)")
    for _ in range(repeats):
        for g in guesses:
            res[g].append(replay_once(rec, g, flush_mb=flush_mb))
    for g in guesses:
        r = res[g]
        print(f"replay {str(rec['grid']):>10s} guess {str(g):>8s}: CPU {fmt_range([x['cpu'] for x in r], 10)} ms/step, "
              f"wall {fmt_range([x['wall'] for x in r], 10)} ms; pressure iterations {r[0]['its']:.2f} "
              f"(max {r[0]['maxits']}), mass defect {r[0]['defect']:.1e} ({r[0]['steps']} steps)")
    if json_out:
        import json
        print(json.dumps({str(g): v for g, v in res.items()}))
    return res


def compare_replay(old_dir, path, repeats, threads="1", flush_mb=0):
    """Alternate replays of ``path`` with the package in ``old_dir`` (its default initial
    guess) and the current one (default), one process each; print ranges and old/new."""
    import json
    import subprocess
    import sys
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    res = {"old": [], "new": []}
    for _ in range(repeats):
        for tag, pkg in (("old", old_dir), ("new", repo)):
            env = dict(os.environ, PYTHONPATH=pkg)
            if tag == "old":
                env["NUMBA_CACHE_DIR"] = os.environ.get("NUMBA_CACHE_DIR", "/tmp/numba_cache") + "_compare_old"
            out = subprocess.run([sys.executable, os.path.abspath(__file__), "--replay", os.path.abspath(path),
                                  "--repeats", "1", "--threads", threads, "--default-guess", "--json",
                                  "--flush", str(flush_mb)], env=env,
                                 cwd="/tmp", capture_output=True, text=True, check=True).stdout
            res[tag].append(json.loads(out.strip().splitlines()[-1])["None"][0])
    for tag in ("old", "new"):
        r = res[tag]
        print(f"replay {tag}: CPU {fmt_range([x['cpu'] for x in r], 10)} ms/step, wall {fmt_range([x['wall'] for x in r], 10)} "
              f"ms; pressure iterations {r[0]['its']:.2f} (max {r[0]['maxits']}), mass defect {r[0]['defect']:.1e}")
    rc = [o["cpu"] / n["cpu"] for o, n in zip(res["old"], res["new"])]
    rw = [o["wall"] / n["wall"] for o, n in zip(res["old"], res["new"])]
    print(f"replay old/new: CPU x{fmt_range(rc, 4, 2)}, wall x{fmt_range(rw, 4, 2)}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=None, help="timed steps (default 20; --record: 40 recorded)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", default=None,
                    help="numba thread counts for mg, comma-separated (amg: the first); default 1,2 (--compare: 1)")
    ap.add_argument("--no-amg", action="store_true", help="time the multigrid solver only")
    ap.add_argument("--tol", type=float, default=1e-8)
    ap.add_argument("--no-cube", action="store_true", help="skip the 64^3 grid")
    ap.add_argument("--grid", default=None,
                    help="chute cells nx x ny x nz over the same box (16x8x150: the coarser gas grid); with "
                         "--compare a comma-separated list (default 16x15x150,16x8x150)")
    ap.add_argument("--tol-sweep", action="store_true", help="only the tolerance sweep (mg, chute bed)")
    ap.add_argument("--defect-sweep", action="store_true", help="only the defect_tol sweep (mg, chute)")
    ap.add_argument("--json", action="store_true", help="print the results as one JSON line at the end")
    ap.add_argument("--compare", metavar="DIR", help="before/after: alternate runs with the cfddem package in DIR")
    ap.add_argument("--particles", metavar="CHECKPOINT",
                    help="with --compare: also time the particle step of the chute (no gas, 1 thread) from this "
                         "developed checkpoint (copied), to 1.76 s")
    ap.add_argument("--record", nargs=2, metavar=("CHECKPOINT", "FILE"),
                    help="record the gas steps of the coupled chute from CHECKPOINT into FILE")
    ap.add_argument("--interval", type=int, default=10, help="--record: gas coupling interval (particle steps)")
    ap.add_argument("--warm", type=int, default=100, help="--record: gas steps skipped before recording")
    ap.add_argument("--replay", metavar="FILE", help="time the gas steps recorded in FILE")
    ap.add_argument("--flush", type=float, default=0.0, metavar="MB",
                    help="--replay: write MB megabytes between the steps (outside the timing) to evict the "
                         "caches as the coupled run's particle steps do (512 reproduces the run; default 0)")
    ap.add_argument("--default-guess", action="store_true",
                    help="--replay: only the solver's default initial guess (used by --compare)")
    a = ap.parse_args(argv)
    if a.record:
        set_threads(int((a.threads or "1").split(",")[0]))
        record(a.record[0], a.record[1], a.grid or "16x15x150", a.interval, a.steps or 40, a.warm)
        return
    if a.replay and a.tol_sweep:
        set_threads(1)
        replay_tol_sweep(a.replay, flush_mb=a.flush)
        return
    if a.replay and a.compare:
        compare_replay(a.compare, a.replay, a.repeats, a.threads or "1", a.flush)
        return
    if a.replay:
        set_threads(int((a.threads or "1").split(",")[0]))
        replay(a.replay, a.repeats, (None,) if a.default_guess else ("scaled", "previous", "zero"), a.json,
               a.flush)
        return
    a.steps = a.steps or 20
    if a.compare:
        compare(a.compare, a.repeats, a.steps, tuple((a.grid or "16x15x150,16x8x150").split(",")),
                a.threads or "1")
        if a.particles:
            particle_step_cost(a.particles)
        return
    threads = tuple(int(t) for t in (a.threads or "1,2").split(","))
    solvers = ("mg",) if a.no_amg else ("mg", "amg")
    nt = set_threads(threads[0])
    print(f"numba threads: {threads}, pressure tolerance {a.tol:g}, {a.steps} steps x {a.repeats} repeats; "
          f"times: range over the repeats")
    if a.tol_sweep:
        tol_sweep(a.steps)
        return
    if a.defect_sweep:
        defect_sweep(a.steps)
        return
    dt = 1e-3
    shape = tuple(int(v) for v in (a.grid or "16x15x150").split("x"))
    g, _ = chute_solver(shape)
    n = a.steps + 4
    out = {}
    for kind in ("eps1", "bed"):
        out[kind] = bench_pair(f"chute {kind}", lambda sv: chute_solver(shape, tol=a.tol, solver=sv),
                               chute_fields(g, kind, n), a.steps, dt, a.repeats, threads, solvers)
    if not a.no_cube:
        gc, _ = cube_solver()
        cs = max(3, a.steps // 4)
        out["cube"] = bench_pair("64^3", lambda sv: cube_solver(tol=a.tol, solver=sv),
                                 cube_fields(gc, cs + 4, 2e-3), cs, 2e-3, max(1, a.repeats - 1), threads, solvers)
        for sv in solvers:
            key = f"{sv}{threads[0]}"
            c = min(x["cpu"] for x in out["cube"][key]) / min(x["cpu"] for x in out["bed"][key])
            print(f"cost growth {sv}: cells x{gc.ncells / g.ncells:.1f} -> CPU time x{c:.1f}")
    if a.json:
        import json
        print(json.dumps(out))


if __name__ == "__main__":
    main()
