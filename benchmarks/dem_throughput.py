"""DEM throughput on the periodic inclined chute of /work/shared/peers/liggghts (30 deg, 0.9 m).

    python benchmarks/dem_throughput.py [--particles N] [--threads T] [--steps S] [--peer]
                                        [--rounds R] [--dev-steps D] [--flow-check]

Same case as the LIGGGHTS peer (README.md, chute_common.in, gen_init.py): jittered lattice start
(same algorithm and seed, regenerated here; for N != 30,000 the lattice is 20 x 6 across/normal
and N/120 cells downstream, the periodic length scaled to keep the 3.6 mm spacing), d = 3 mm,
rho = 2550, k_n = 1000 N/m, e = 0.97 (pp and pw), k_t = 2/7 k_n (our law with e_t = e_n gives
exactly that), mu 0.12 pp / 0.22 pw, dt = 1e-5, skin 0.3 d, floor + 2 side walls, gravity tilted
30 deg.  Difference: the peer's tangential dashpot equals its normal one (LIGGGHTS hooke
default, gamma_t = gamma_n), ours is physics.md's eta_t with m_t = 2/7 m* (smaller).

Axes here: x across the chute (side walls at x = 0, 0.08), y normal to the floor (y = 0), z
downstream (periodic).  The flow is developed for D steps first (compile time excluded), then S
steps are timed for 1 and 2 threads (or --threads T); the last line is
``particle_steps_per_s=<number>`` for the last thread count.  --flow-check runs on to t = 0.4 s
and prints the peer's check quantities (mean downstream velocity, 2 <y>) at 0.2 and 0.4 s.

--peer: the side-by-side comparison.  LAMMPS and LIGGGHTS (../shared/peers, installed by their
scripts) run the same chute from their own developed state (20,000 steps from the same lattice,
cached by the peers' scripts); R rounds (--rounds, default 3), each timing ours and then each
peer at 1 thread / 1 rank and 2 threads / 2 ranks over the same number of steps (the order
alternates from round to round); ours restarts every round from the same developed state, so
every round times the same work.  Prints the CPU model and the load before and after, each
round's rates, the ratios ours/peer per round and their median, and the pairs per particle of
each side (ours: the half list with skin; LAMMPS: "Ave neighs/atom" of its half list).
"""

from __future__ import annotations

import argparse
import math
import os
import random
import re
import statistics
import subprocess
import sys
import time

# OpenMP threads that spin while waiting at the end of each parallel loop lose badly when the
# cores are shared with other processes; passive waiting is the robust choice (--omp-wait).
if "--omp-wait" in sys.argv:
    os.environ["OMP_WAIT_POLICY"] = sys.argv[sys.argv.index("--omp-wait") + 1].upper()
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
# pin the threading layer: installing the peer (apt liggghts) pulls in libtbb, after which numba
# would silently switch from OpenMP to TBB between two runs of this script (--threading-layer)
if "--threading-layer" in sys.argv:
    os.environ["NUMBA_THREADING_LAYER"] = sys.argv[sys.argv.index("--threading-layer") + 1]
os.environ.setdefault("NUMBA_THREADING_LAYER", "omp")

import numba  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

from cfddem.particles import LinearContact, ParticleSystem, PlaneWall  # noqa: E402

from machine import cpu_model  # noqa: E402

D, RHO, W = 0.003, 2550.0, 0.08
PEERS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "shared", "peers")


def lattice(n_particles: int, seed: int = 12345):
    """gen_init.py's jittered lattice, in our axes (x across, y normal, z downstream)."""
    ny, nz = 20, 6
    nx = max(1, int(round(n_particles / (ny * nz))))
    L = 0.0036 * nx  # 0.9 m for nx = 250
    r = D / 2
    dx = L / nx
    dy = (W - D) / ny
    dz = 0.0036
    z0 = r + 0.0005
    jit = 0.25e-3
    rng = random.Random(seed)
    out = []
    for k in range(nz):
        for j in range(ny):
            for ix in range(nx):
                x = (ix + 0.5) * dx + rng.uniform(-jit, jit)
                y = r + (j + 0.5) * dy + rng.uniform(-jit, jit)
                z = z0 + k * dz + rng.uniform(-jit, jit)
                out.append((y, z, x % L))  # ours: (across, normal, downstream)
    return np.array(out), L


def build(n_particles: int):
    pos, L = lattice(n_particles)
    pp = LinearContact(k_n=1000.0, e_n=0.97, e_t=0.97, mu=0.12)
    pw = LinearContact(k_n=1000.0, e_n=0.97, e_t=0.97, mu=0.22)
    walls = [PlaneWall(contact=pw, point=(0, 0, 0), normal=(0, 1, 0), name="floor"),
             PlaneWall(contact=pw, point=(0, 0, 0), normal=(1, 0, 0), name="side0"),
             PlaneWall(contact=pw, point=(W, 0, 0), normal=(-1, 0, 0), name="side1")]
    th = math.radians(30.0)
    s = ParticleSystem(pp=pp, walls=walls, dt=1e-5, gravity=(0.0, -9.81 * math.cos(th), 9.81 * math.sin(th)),
                       periodic=(None, None, (0.0, L)), skin=0.3 * D, capacity=len(pos) + 16)
    s.add_particles(pos, 0.0, D / 2, RHO)
    return s


def flow_state(s):
    return float(s.vel[:, 2].mean()), 2.0 * float(s.pos[:, 1].mean())


def run_steps(s, n, chunk=1000):
    done = 0
    while done < n:
        k = min(chunk, n - done)
        st = s.step(k)
        if not st.ok:
            raise SystemExit(st.message)
        done += k


def run_peer(name: str, np_: int, steps: int) -> dict | None:
    """One timed run of peer ``name`` ('lammps' or 'liggghts') on ``np_`` ranks: its script's
    result line as a dict (psteps_per_s, wall_s, ...), None if it failed."""
    script = os.path.join(PEERS, name, "run_bench.sh")
    env = dict(os.environ, NP=str(np_), NBENCH=str(steps), ANALYZE="0", WORK=f"/tmp/{name}_chute")
    out = subprocess.run(["bash", script], env=env, capture_output=True, text=True)
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith(f"{name} np=")]
    if out.returncode != 0 or not lines:
        print(f"{name} np={np_} failed: {out.stderr[-800:]}")
        return None
    res = dict(kv.split("=", 1) for kv in lines[-1].split()[1:] if "=" in kv)
    res["psteps_per_s"] = float(res["psteps_per_s"])
    log = os.path.join(f"/tmp/{name}_chute", f"bench_np{np_}_dt1e-5_n{steps}_r1.log")
    res["neigh_per_atom"] = _lammps_neighbours(log) if name == "lammps" else None
    return res


def _lammps_neighbours(log: str):
    try:
        txt = open(log).read()
    except OSError:
        return None
    m = re.findall(r"Ave neighs/atom = ([0-9.eE+-]+)", txt)
    return float(m[-1]) if m else None


def load() -> str:
    return "load average " + ", ".join(f"{x:.2f}" for x in os.getloadavg())


def timed(s, state, threads, steps):
    """Our rate (particle-steps/s) over ``steps`` steps from ``state`` at ``threads`` threads."""
    numba.set_num_threads(threads)
    s.set_state(state)
    s.step(2)  # warm this thread count
    r0 = s.n_rebuilds
    t0 = time.perf_counter()
    run_steps(s, steps)
    el = time.perf_counter() - t0
    return s.n * steps / el, s.n_rebuilds - r0


def compare(s, threads, steps, rounds, peers):
    """Alternating rounds of ours and the peers (module docstring)."""
    state = s.get_state()
    print(f"CPU: {cpu_model()}; {os.cpu_count()} cores; {load()}")
    print(f"ours: {s.n_pairs / s.n:.2f} pairs per particle (half list with skin {s.skin * 1e3:.2f} mm)")
    ratios = {(p, t): [] for p in peers for t in threads}
    rates = {("ours", t): [] for t in threads}
    for r in range(rounds):
        order = ["ours"] + list(peers)
        if r % 2:
            order = order[::-1]
        for t in threads:
            got = {}
            for who in order:
                if who == "ours":
                    got[who], nreb = timed(s, state, t, steps)
                    print(f"round {r + 1} ours threads={t}: {got[who]:.4g} particle-steps/s "
                          f"({1e9 / got[who]:.1f} ns) rebuilds={nreb}")
                else:
                    res = run_peer(who, t, steps)
                    if res is None:
                        continue
                    got[who] = res["psteps_per_s"]
                    nb = res.get("neigh_per_atom")
                    print(f"round {r + 1} {who} ranks={t}: {got[who]:.4g} particle-steps/s "
                          f"({1e9 / got[who]:.1f} ns) pair%={res.get('pair%')} neigh%={res.get('neigh%')} "
                          f"modify%={res.get('modify%')} builds={res.get('nbuilds')}"
                          + (f" neighs/atom={nb:.2f}" if nb else ""))
            rates[("ours", t)].append(got["ours"])
            for p in peers:
                if p in got:
                    ratios[(p, t)].append(got["ours"] / got[p])
                    print(f"round {r + 1} ratio ours/{p} at {t}: {got['ours'] / got[p]:.3f}")
    print(f"after: {load()}")
    for (p, t), v in ratios.items():
        if v:
            print(f"ratio ours/{p} at {t} thread(s)/rank(s): median {statistics.median(v):.3f} "
                  f"(rounds: {', '.join(f'{x:.3f}' for x in v)})")
    return {t: statistics.median(rates[("ours", t)]) for t in threads}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--particles", type=int, default=30000)
    ap.add_argument("--threads", type=int, default=None, help="one thread count (default: 1 then 2)")
    ap.add_argument("--steps", type=int, default=4000)
    ap.add_argument("--dev-steps", type=int, default=None,
                    help="steps before timing (default 20000 at 30,000 particles, scaled ~1/N otherwise)")
    ap.add_argument("--flow-check", action="store_true", help="run on to t = 0.4 s and print the flow state")
    ap.add_argument("--peer", action="store_true", help="side by side with LAMMPS and LIGGGHTS (module docstring)")
    ap.add_argument("--peers", default="lammps,liggghts", help="which peers with --peer (comma list)")
    ap.add_argument("--rounds", type=int, default=3, help="alternating rounds with --peer")
    ap.add_argument("--omp-wait", choices=["passive", "active"], default="passive",
                    help="OMP_WAIT_POLICY for numba's OpenMP threads (default passive)")
    ap.add_argument("--threading-layer", choices=["omp", "tbb", "workqueue"], default="omp")
    a = ap.parse_args(argv)

    threads = [a.threads] if a.threads else [1, min(2, numba.config.NUMBA_NUM_THREADS)]
    numba.set_num_threads(max(threads))
    s = build(a.particles)
    print(f"particles={s.n} periodic_length={s._plen[2]:.4f} m threads={threads} "
          f"OMP_WAIT_POLICY={os.environ.get('OMP_WAIT_POLICY')} GOMP_SPINCOUNT={os.environ.get('GOMP_SPINCOUNT')}")
    t0 = time.perf_counter()
    s.step(5)  # compile (excluded)
    try:
        layer = numba.threading_layer()
    except ValueError:
        layer = "none (serial kernels)"
    print(f"compile+first steps: {time.perf_counter() - t0:.1f} s; threading layer {layer}")
    dev = a.dev_steps
    if dev is None:
        dev = 20000 if a.particles <= 30000 else max(1000, int(20000 * 30000 / a.particles))
    dev = max(dev - 5, 0)
    t0 = time.perf_counter()
    run_steps(s, dev)
    print(f"developed {s.step_count} steps (t = {s.time:.3f} s) in {time.perf_counter() - t0:.1f} s; "
          f"pairs/particle = {s.n_pairs / s.n:.2f}")
    if abs(s.time - 0.2) < 1e-9:
        vz, h = flow_state(s)
        print(f"flow t=0.200 s: mean downstream velocity {vz:.3f} m/s (peer 0.698), 2<y> = {1e3 * h:.2f} mm (peer 11.0)")
    rates = {}
    if a.peer:
        rates = compare(s, threads, a.steps, a.rounds, [p for p in a.peers.split(",") if p])
    else:
        for t in threads:
            numba.set_num_threads(t)
            s.step(2)  # warm this thread count
            r0 = s.n_rebuilds
            t0 = time.perf_counter()
            run_steps(s, a.steps)
            el = time.perf_counter() - t0
            rates[t] = s.n * a.steps / el
            print(f"threads={t} steps={a.steps} wall_s={el:.3f} particle_steps_per_s={rates[t]:.4g} "
                  f"ns_per_particle_step={1e9 / rates[t]:.1f} rebuilds={s.n_rebuilds - r0}")
    if a.flow_check:
        rem = int(round(0.4 / s.dt)) - s.step_count
        if rem > 0:
            run_steps(s, rem)
        vz, h = flow_state(s)
        print(f"flow t={s.time:.3f} s: mean downstream velocity {vz:.3f} m/s (peer 1.276), 2<y> = {1e3 * h:.2f} mm (peer 11.8)")
    print(f"particle_steps_per_s={rates[threads[-1]]:.6g}")


if __name__ == "__main__":
    main()
