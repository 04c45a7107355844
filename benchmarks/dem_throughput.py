"""DEM throughput on the periodic inclined chute of /work/shared/peers/liggghts (30 deg, 0.9 m).

    python benchmarks/dem_throughput.py [--particles N] [--threads T] [--steps S] [--peer]
                                        [--dev-steps D] [--flow-check]

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
--peer also runs the peer (NP=1 and NP=2) in the same command and prints the ratio.
"""

from __future__ import annotations

import argparse
import math
import os
import random
import re
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

D, RHO, W = 0.003, 2550.0, 0.08
PEER = "/work/shared/peers/liggghts"


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


def run_peer():
    res = {}
    for np_ in (1, 2):
        env = dict(os.environ, NP=str(np_), NBENCH="4000" if np_ == 2 else "20000")
        out = subprocess.run(["bash", f"{PEER}/run_bench.sh"], env=env, capture_output=True, text=True)
        print(out.stdout.strip())
        if out.returncode != 0:
            print(out.stderr[-2000:])
            continue
        m = re.findall(r"^liggghts np=(\d+).*psteps_per_s=([0-9.e+]+)", out.stdout, re.M)
        if m:
            res[np_] = float(m[-1][1])
    return res


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--particles", type=int, default=30000)
    ap.add_argument("--threads", type=int, default=None, help="one thread count (default: 1 then 2)")
    ap.add_argument("--steps", type=int, default=4000)
    ap.add_argument("--dev-steps", type=int, default=None,
                    help="steps before timing (default 20000 at 30,000 particles, scaled ~1/N otherwise)")
    ap.add_argument("--flow-check", action="store_true", help="run on to t = 0.4 s and print the flow state")
    ap.add_argument("--peer", action="store_true")
    ap.add_argument("--omp-wait", choices=["passive", "active"], default="passive",
                    help="OMP_WAIT_POLICY for numba's OpenMP threads (default passive)")
    ap.add_argument("--threading-layer", choices=["omp", "tbb", "workqueue"], default="omp")
    a = ap.parse_args(argv)

    threads = [a.threads] if a.threads else [1, min(2, numba.config.NUMBA_NUM_THREADS)]
    numba.set_num_threads(max(threads))
    s = build(a.particles)
    print(f"particles={s.n} periodic_length={s._plen[2]:.4f} m threads={threads} "
          f"OMP_WAIT_POLICY={os.environ.get('OMP_WAIT_POLICY')}")
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
    if a.peer:
        peer = run_peer()
        for t in sorted(rates):
            if t in peer:
                print(f"ratio ours/peer at {t} thread(s)/rank(s): {rates[t] / peer[t]:.3f} "
                      f"(ours {rates[t]:.4g}, peer {peer[t]:.4g})")
    print(f"particle_steps_per_s={rates[threads[-1]]:.6g}")


if __name__ == "__main__":
    main()
