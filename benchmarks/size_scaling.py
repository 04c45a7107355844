"""Cost per particle-step against the number of particles (and threads), same flow state.

    python benchmarks/size_scaling.py [--sizes 3000,30000,120000,300000,1200000]
                                      [--threads 1,2] [--rounds 2] [--out DIR]

The periodic 30 deg chute of benchmarks/dem_throughput.py.  The 30,000-particle chute is
developed for 20,000 steps (0.2 s); every larger size is that developed bed repeated along the
periodic axis (k copies end to end in a box k times as long), so each particle sees the same
neighbourhood, pairs per particle and speeds at every size.  Sizes below 30,000 are their own
chute (the same lattice with fewer cells along the flow) developed for 20,000 steps.  Each
size is timed over the same simulated time (a fixed number of steps) from its own start state,
in ``--rounds`` rounds whose order alternates (small to large, then large to small).  Prints
the CPU model and load, a table of ns per particle-step (median of the rounds) with the
pairs per particle and the memory per particle (bytes of every array the system holds), and
writes ``size_scaling.json`` and ``size_scaling.png`` (log-log) to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
os.environ.setdefault("NUMBA_THREADING_LAYER", "omp")

import numba  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import dem_throughput as dt_  # noqa: E402
from machine import cpu_model  # noqa: E402


def developed(n: int, steps: int = 20000):
    s = dt_.build(n)
    dt_.run_steps(s, steps)
    return s


def tiled(base, k: int):
    """A system of ``k`` copies of ``base`` end to end along its periodic axis (z)."""
    L = float(base._plen[2])
    pp = base.pp
    s = dt_.ParticleSystem(pp=pp, walls=base.walls, dt=base.dt, gravity=base.gravity,
                           periodic=(None, None, (0.0, k * L)), skin=base.skin, capacity=k * base.n + 16)
    pos, vel, om, rad = base.pos.copy(), base.vel.copy(), base.omega.copy(), base.radius.copy()
    rho = float(base.mass[0] / (4.0 / 3.0 * np.pi * rad[0] ** 3))
    for c in range(k):
        p = pos.copy()
        p[:, 2] += c * L
        s.add_particles(p, vel, rad, rho, omega=om)
    return s


def memory_per_particle(s) -> float:
    total = 0
    for v in vars(s).values():
        if isinstance(v, np.ndarray):
            total += v.nbytes
        elif isinstance(v, dict):
            total += sum(a.nbytes for a in v.values() if isinstance(a, np.ndarray))
    return total / s.n


def time_steps(state, system, steps: int, threads: int) -> float:
    numba.set_num_threads(threads)
    system.set_state(state)
    system.step(2)
    t0 = time.perf_counter()
    dt_.run_steps(system, steps, chunk=100)
    return 1e9 * (time.perf_counter() - t0) / (steps * system.n)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", default="3000,30000,120000,300000,1200000")
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--steps", type=int, default=None, help="steps per timing (default: about 3e8 / N, 100..2000)")
    ap.add_argument("--out", default="size_scaling")
    a = ap.parse_args(argv)
    sizes = [int(x) for x in a.sizes.split(",")]
    threads = [int(x) for x in a.threads.split(",")]
    numba.set_num_threads(max(threads))
    print(f"CPU: {cpu_model()}; {os.cpu_count()} cores; load average "
          + ", ".join(f"{x:.2f}" for x in os.getloadavg()))
    t0 = time.perf_counter()
    base = developed(30000)
    print(f"developed the 30,000-particle chute in {time.perf_counter() - t0:.0f} s "
          f"({base.n_pairs / base.n:.2f} pairs per particle)")
    systems = {}
    for n in sizes:
        s = developed(n) if n < 30000 else tiled(base, max(1, round(n / 30000)))
        s.step(20)  # lists, contact history settle after the copy
        systems[n] = (s, s.get_state())
        print(f"N = {s.n}: {s.n_pairs / s.n:.2f} pairs per particle, {memory_per_particle(s):.0f} bytes per particle")
    res = {(n, t): [] for n in sizes for t in threads}
    for r in range(a.rounds):
        order = sizes if r % 2 == 0 else sizes[::-1]
        for n in order:
            s, st = systems[n]
            steps = a.steps or int(min(2000, max(100, 3e8 / s.n)))
            for t in threads:
                ns = time_steps(st, s, steps, t)
                res[(n, t)].append(ns)
                print(f"round {r + 1}: N = {s.n} threads = {t}: {ns:.1f} ns per particle-step ({steps} steps)")
    print("load average after: " + ", ".join(f"{x:.2f}" for x in os.getloadavg()))
    os.makedirs(a.out, exist_ok=True)
    rows = []
    print("| particles | pairs per particle | bytes per particle | " + " | ".join(f"ns, {t} thread(s)" for t in threads) + " |")
    for n in sizes:
        s = systems[n][0]
        med = {t: statistics.median(res[(n, t)]) for t in threads}
        rows.append(dict(n=s.n, pairs_per_particle=s.n_pairs / s.n, bytes_per_particle=memory_per_particle(s),
                         ns={str(t): med[t] for t in threads}, rounds={str(t): res[(n, t)] for t in threads}))
        print(f"| {s.n} | {s.n_pairs / s.n:.2f} | {memory_per_particle(s):.0f} | "
              + " | ".join(f"{med[t]:.1f}" for t in threads) + " |")
    with open(os.path.join(a.out, "size_scaling.json"), "w") as f:
        json.dump(dict(cpu=cpu_model(), rows=rows), f, indent=1)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for t in threads:
        x = [r["n"] for r in rows]
        y = [r["ns"][str(t)] for r in rows]
        lo = [min(r["rounds"][str(t)]) for r in rows]
        hi = [max(r["rounds"][str(t)]) for r in rows]
        ax.errorbar(x, y, yerr=[np.subtract(y, lo), np.subtract(hi, y)], marker="o", capsize=3,
                    label=f"{t} thread{'s' if t > 1 else ''}")
    ax.set_xscale("log")
    ax.set_xlabel("particles")
    ax.set_ylabel("wall time per particle-step (ns)")
    ax.set_ylim(bottom=0)
    ax.set_title("Periodic chute, developed flow: cost against size", fontsize=11)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(os.path.join(a.out, "size_scaling.png"), dpi=120)
    print(f"wrote {a.out}/size_scaling.json, size_scaling.png")


if __name__ == "__main__":
    main()
