"""Cost of the full-size multi-flow blender (cases/blender_multiflow: 606,000 thesis pellets,
1,212,000 spheres) per simulated second on this machine, against the thesis's 32-37 h.

    python benchmarks/blender_cost.py [--threads T] [--steps A B] [--case DIR] [--set KEY=VALUE ...]

The case pours its fill over about 7 s of simulated time, far too long to reach here, so the
pellets are placed at once on a near-touching lattice (``silo.fill = "lattice"``, gap 2 % of the
pellet length, the silo made tall enough to hold it) and the measurement starts from there: every
pellet present, packed at the lattice's solid fraction, falling and compacting from the first
step.  Two runs of A and B steps (default 3000 and 3400: the 2 % gaps close within about 1,600
steps of free fall, so by A the column has collapsed onto the hopper into contact) give the cost per step without the set-up
(building the system, the first neighbour list, compiling): (wall_B - wall_A) / (B - A), from the
runs' own ``particles`` timing.  The pairs per sphere at the end are printed beside those of a
packed, discharging bed (the reduced case's, when ``--reference`` names a finished run folder) so
that a reader can judge how far the lattice's cost is from a settled bed's.  Prints the CPU model,
the load, the cost per step and per particle-step, the cost per simulated second (steps per second
of simulated time x cost per step) and the peak memory.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

LATTICE = ['silo.fill="lattice"', "silo.lattice_gap=0.02", "silo.lattice_jitter=0.01", "silo.height=3.0",
           "output.vtk=false", "output.plots=false", "output.snapshot_interval=100.0",
           "output.series_interval=100.0", "checkpoint.wall_interval=0"]


def _cpu() -> str:
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True).stdout
        return next(line.split(":", 1)[1].strip() for line in out.splitlines() if line.startswith("Model name"))
    except (OSError, StopIteration):
        return "unknown CPU"


def _one(case_dir, steps, threads, extra, out):
    from cfddem.config import load_case
    from cfddem.simulation import Simulation

    case = load_case(case_dir, overrides=LATTICE + extra + [f"time.max_steps={steps}", f"time.threads={threads}"])
    sim = Simulation(case, out, overwrite=True, echo=False, progress=False, threads=threads)
    t0 = time.perf_counter()
    s = sim.run()
    wall = time.perf_counter() - t0
    info = json.loads((Path(out) / "run.json").read_text())
    sys_ = sim.system
    import numpy as np

    pi, pj = sys_._cur["pi"][: sys_.n_pairs], sys_._cur["pj"][: sys_.n_pairs]
    gap = np.linalg.norm(sys_._pos[pi] - sys_._pos[pj], axis=1) - sys_._radius[pi] - sys_._radius[pj]
    return {"steps": s.steps, "status": s.status, "wall": wall, "particles_time": info["timings"]["particles"],
            "n": sys_.n, "pairs": sys_.n_pairs, "touching": int((gap < 0).sum()), "dt": case.time.dt,
            "rebuilds": sys_.n_rebuilds}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", default=str(Path(__file__).resolve().parents[1] / "cases" / "blender_multiflow"))
    ap.add_argument("--threads", type=int, default=os.cpu_count())
    ap.add_argument("--steps", type=int, nargs=2, default=[3000, 3400])
    ap.add_argument("--set", dest="extra", action="append", default=[])
    ap.add_argument("--out", default="/tmp/blender_cost")
    ap.add_argument("--reference", help="a run folder of packed 2-sphere pellets (its last snapshot: neighbour "
                                        "pairs per sphere within the same cut-off, 2 R + skin)")
    a = ap.parse_args(argv)
    print(f"CPU: {_cpu()}, {os.cpu_count()} cores; load before: {os.getloadavg()}")
    rows = [_one(a.case, n, a.threads, a.extra, f"{a.out}_{n}") for n in a.steps]
    for r in rows:
        print(f"  {r['steps']} steps ({r['status']}): wall {r['wall']:.1f} s, particle engine {r['particles_time']:.1f} s, "
              f"{r['n']} spheres, {r['pairs']} pairs ({r['pairs'] / max(r['n'], 1):.2f} per sphere), "
              f"{r['touching']} touching ({2 * r['touching'] / max(r['n'], 1):.2f} contacts per sphere), "
              f"{r['rebuilds']} neighbour-list builds")
    (ra, rb) = rows
    per_step = (rb["particles_time"] - ra["particles_time"]) / (rb["steps"] - ra["steps"])
    n = rb["n"]
    steps_per_s = 1.0 / rb["dt"]
    cost_h = per_step * steps_per_s / 3600.0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(f"cost per step {per_step:.3f} s ({per_step / n * 1e9:.0f} ns per sphere-step, {a.threads} threads); "
          f"dt {rb['dt']:g} s -> {steps_per_s:,.0f} steps per simulated second -> {cost_h:.0f} h per simulated "
          f"second (thesis: 32-37 h); peak memory {peak:.0f} MiB ({peak * 2**20 / n:.0f} B per sphere)")
    if a.reference:
        import numpy as np
        from scipy.spatial import cKDTree

        from cfddem.io.results import read_snapshot

        snap = read_snapshot(Path(a.reference) / "results.h5", -1)
        r = np.asarray(snap["radius"])
        cut = 2 * r.max() + 0.3 * 2 * r.max()  # the engine's default skin, 0.3 d
        pairs = len(cKDTree(np.asarray(snap["pos"])).query_pairs(cut)) - len(r) // 2  # less each pellet's own pair
        print(f"reference {a.reference} (last snapshot, packed pellets, periodic wrap ignored): "
              f"{pairs / len(r):.2f} pairs per sphere within {cut * 1e3:.2f} mm")
    print(f"load after: {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
