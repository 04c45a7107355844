"""Cost of the full-size multi-flow blender (cases/blender_multiflow: 606,000 thesis pellets,
1,212,000 spheres) per simulated second on this machine, against the thesis's 32-37 h.

    python benchmarks/blender_cost.py [--threads T] [--chunks K] [--steps S] [--set KEY=VALUE ...]
                                      [--reference RUN_DIR]

The case pours its fill over about 7 s of simulated time, far too long to reach here, so the
pellets are placed at once on a near-touching lattice (``silo.fill = "lattice"``, gap 2 % of the
pellet length, the silo made tall enough to hold it): every pellet present from the first step.
The system is built by a run of one step (set-up, first neighbour list, kernels loaded), then
``ParticleSystem.step(S)`` is timed K times in the same process (default 5 x 100 steps); the
median gives the cost per step.  The lattice falls freely for these steps (no contact yet, one
neighbour list): a packed, flowing bed has more pairs per sphere (``--reference`` counts them in
the last snapshot of a run of packed pellets) and rebuilds its list every few dozen steps, so
this is the cost of the particle engine on this many spheres with the blender's 25 walls, a lower
bound of the discharge's.  Prints the CPU model, the load, the cost per step and per sphere-step,
the cost per simulated second, and the resident and peak memory.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from machine import cpu_model  # noqa: E402  (benchmarks/machine.py)

LATTICE = ['silo.fill="lattice"', "silo.lattice_gap=0.02", "silo.lattice_jitter=0.01", "silo.height=3.0",
           "output.vtk=false", "output.plots=false", "output.snapshot_interval=100.0",
           "output.series_interval=100.0", "checkpoint.wall_interval=0"]


def _mem() -> tuple[float, float]:
    """(resident, peak) memory of this process in MiB (/proc/self/status)."""
    d = {}
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(("VmRSS", "VmHWM")):
                d[line.split(":")[0]] = float(line.split()[1]) / 1024.0
    return d.get("VmRSS", float("nan")), d.get("VmHWM", float("nan"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", default=str(Path(__file__).resolve().parents[1] / "cases" / "blender_multiflow"))
    ap.add_argument("--threads", type=int, default=os.cpu_count())
    ap.add_argument("--chunks", type=int, default=5)
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--set", dest="extra", action="append", default=[])
    ap.add_argument("--out", default="/tmp/blender_cost")
    ap.add_argument("--reference", help="a run folder of packed 2-sphere pellets (its last snapshot: neighbour "
                                        "pairs per sphere within the same cut-off, 2 R + skin)")
    a = ap.parse_args(argv)
    import numpy as np

    from cfddem.config import load_case
    from cfddem.simulation import Simulation

    print(f"CPU: {cpu_model()}, {os.cpu_count()} cores; load before: {os.getloadavg()}")
    case = load_case(a.case, overrides=LATTICE + a.extra + ["time.max_steps=1", f"time.threads={a.threads}"])
    sim = Simulation(case, a.out, overwrite=True, echo=False, progress=False, threads=a.threads)
    t0 = time.perf_counter()
    sim.run()
    print(f"built in {time.perf_counter() - t0:.0f} s", flush=True)
    sys_ = sim.system
    per = []
    for k in range(a.chunks):
        t0 = time.perf_counter()
        st = sys_.step(a.steps)
        per.append((time.perf_counter() - t0) / a.steps)
        print(f"  chunk {k}: {per[-1] * 1e3:.1f} ms per step ({st.flag or 'ok'}), load {os.getloadavg()[0]:.2f}",
              flush=True)
    pi, pj = sys_._cur["pi"][: sys_.n_pairs], sys_._cur["pj"][: sys_.n_pairs]
    gap = np.linalg.norm(sys_._pos[pi] - sys_._pos[pj], axis=1) - sys_._radius[pi] - sys_._radius[pj]
    n = sys_.n
    per_step = float(np.median(per))
    cost_h = per_step / case.time.dt / 3600.0
    rss, peak = _mem()
    print(f"{n} spheres, {sys_.n_pairs} pairs in the list ({sys_.n_pairs / n:.2f} per sphere), "
          f"{int((gap < 0).sum())} touching, {sys_.n_rebuilds} neighbour-list builds")
    print(f"cost per step {per_step:.3f} s (median of {a.chunks} x {a.steps}; {per_step / n * 1e9:.0f} ns per "
          f"sphere-step, {a.threads} threads); dt {case.time.dt:g} s -> {1 / case.time.dt:,.0f} steps per simulated "
          f"second -> {cost_h:.0f} h per simulated second (thesis: 32-37 h); memory {rss:.0f} MiB resident "
          f"({rss * 2**20 / n:.0f} B per sphere), {peak:.0f} MiB peak")
    if a.reference:
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
