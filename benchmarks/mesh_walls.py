"""Mesh walls against analytic walls on the hopper silo (issue #18: mesh <= 1.2 x analytic).

    python benchmarks/mesh_walls.py [--particles N] [--develop T] [--steps S] [--rounds K]
                                    [--threads T] [--max-edge M]

One developed state, two walls: cases/silo_hopper (analytic rectangles) and
cases/silo_hopper_stl (the same container from its STL files; with --max-edge M the container
is re-triangulated into cells no longer than M metres, to see the cost grow with the triangles).
The analytic case, reduced to N particles, is filled and its gate opened at 0.3 s
(``silo.gate = "time"``), then run T seconds more (the hopper discharging); from its particles
(positions, velocities, spins) two particle systems are built, the scene's walls in each with
the gate open, and each is stepped a few steps (compilation, neighbour lists) and its state
saved.  Then K rounds, alternating which goes first: each system is restored to its saved state
and S steps of it are timed (so every round of a system does the same work).  Printed: the CPU
model and load (lscpu, uptime), the numba threads, the triangles and the mesh search's numbers
(bin entries, candidate triangles per particle, contacts), the cost per particle-step of both
(median and fastest round), the ratio, and the extra cost per triangle and per candidate
(particle, triangle) pair.  The last line is ``ratio_mesh_over_analytic=<median ratio>``.
Timings mean something only on a quiet machine.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
os.environ.setdefault("NUMBA_THREADING_LAYER", "omp")

import numba  # noqa: E402
import numpy as np  # noqa: E402

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
sys.path.insert(0, ROOT)

from cfddem.config import load_case  # noqa: E402
from cfddem.particles import MeshWall, ParticleSystem  # noqa: E402
from cfddem.scenes.common import gravity_vector, wall_specs  # noqa: E402
from cfddem.scenes.silo import container_meshes  # noqa: E402
from cfddem.simulation import Simulation, contact_law, engine_wall  # noqa: E402
from machine import cpu_model  # noqa: E402  (benchmarks/machine.py)


def machine() -> str:
    model = cpu_model()
    try:
        up = subprocess.run(["uptime"], capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        up = "?"
    return f"cpu: {model}; {os.cpu_count()} logical cpus\nuptime: {up}"


def developed_state(n: int, develop: float):
    """The analytic hopper silo of n particles, gate opened at 0.3 s, run to 0.3 + develop s."""
    over = [f"silo.n_particles={n}", 'silo.gate="time"', "silo.gate_time=0.3", f"time.end_time={0.3 + develop}",
            "output.vtk=false", "output.plots=false", "output.snapshot_interval=100.0",
            "output.series_interval=0.05", "checkpoint.wall_interval=1e9"]
    case = load_case(os.path.join(ROOT, "cases", "silo_hopper"), overrides=over)
    with tempfile.TemporaryDirectory() as tmp:
        sim = Simulation(case, os.path.join(tmp, "o"), echo=False, progress=False)
        sim.run()
        s = sim.system
        return case, s.pos.copy(), s.vel.copy(), s.omega.copy(), s.radius.copy()


def build(case, walls, state):
    pos, vel, om, rad = state
    s = ParticleSystem(pp=contact_law(case.resolved["contact"]["particle_particle"], case.contact.model),
                       walls=walls, dt=case.time.dt, gravity=gravity_vector(case),
                       skin=case.particles.skin or None, capacity=len(pos) + 16)
    s.add_particles(pos, vel, rad, case.particles.density, omega=om)
    s.set_wall_active("gate", False)
    return s


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--particles", type=int, default=35000, help="fill of the silo (default 35000, the case's)")
    ap.add_argument("--develop", type=float, default=0.2, help="seconds of discharge before timing (default 0.2)")
    ap.add_argument("--steps", type=int, default=500, help="steps per timed round (default 500)")
    ap.add_argument("--rounds", type=int, default=5, help="timed rounds of each (default 5)")
    ap.add_argument("--threads", type=int, default=1, help="numba threads (default 1)")
    ap.add_argument("--max-edge", type=float, default=0.0,
                    help="re-triangulate the container into cells no longer than this (m); 0: the case's STL files")
    a = ap.parse_args(argv)
    numba.set_num_threads(a.threads)
    print(machine())
    print(f"numba threads: {numba.get_num_threads()} ({numba.threading_layer() if a.threads > 1 else 'serial'})")
    t0 = time.perf_counter()
    case_a, *state = developed_state(a.particles, a.develop)
    print(f"developed: {len(state[0])} particles in the silo at t = {0.3 + a.develop:g} s "
          f"({time.perf_counter() - t0:.0f} s)")
    over = [f"silo.n_particles={a.particles}"]
    case_m = load_case(os.path.join(ROOT, "cases", "silo_hopper_stl"), overrides=over)
    walls_a = [engine_wall(w, case_a.contact.model) for w in wall_specs(case_a)]
    walls_m = [engine_wall(w, case_m.contact.model) for w in wall_specs(case_m)]
    if a.max_edge > 0:
        meshes = container_meshes(case_a, a.max_edge)
        walls_m = [MeshWall(*meshes[w.name], w.contact, name=w.name) if isinstance(w, MeshWall) else w
                   for w in walls_m]
    systems = {"analytic": build(case_a, walls_a, state), "mesh": build(case_m, walls_m, state)}
    saved = {}
    for k, s in systems.items():
        st = s.step(20)  # compile, build the lists
        assert st.ok, st.message
        saved[k] = s.get_state()
    ms = systems["mesh"].mesh_stats()
    print(f"mesh walls: {', '.join(m.name for m in systems['mesh'].meshes)}: {ms['triangles']} triangles; "
          f"{ms['bin_entries']} (cell, triangle) bin entries, {ms['candidates']} candidate (particle, triangle) "
          f"pairs ({ms['candidates_per_particle']:.3g} per particle), {ms['contacts']} mesh contacts")
    print(f"analytic walls: {len(systems['analytic'].walls)} rectangles")
    times = {k: [] for k in systems}
    n = len(state[0])
    for r in range(a.rounds):
        order = list(systems) if r % 2 == 0 else list(systems)[::-1]
        for k in order:
            s = systems[k]
            s.set_state(saved[k])
            t = time.perf_counter()
            st = s.step(a.steps)
            times[k].append(time.perf_counter() - t)
            assert st.ok, st.message
        print(f"round {r + 1}: " + ", ".join(f"{k} {times[k][-1]:.3f} s" for k in systems))
    cost = {k: np.array(v) / (n * a.steps) for k, v in times.items()}
    for k in systems:
        print(f"{k}: {np.median(cost[k]) * 1e9:.1f} ns per particle-step (median of {a.rounds} rounds; fastest "
              f"{cost[k].min() * 1e9:.1f} ns), {a.steps} steps of {n} particles")
    ratio = float(np.median(np.array(times["mesh"]) / np.array(times["analytic"])))
    extra = (np.median(times["mesh"]) - np.median(times["analytic"])) / a.steps
    print(f"extra cost of the meshes per step: {extra * 1e6:.1f} us = {extra / ms['triangles'] * 1e9:.1f} ns per "
          f"triangle, {extra / max(ms['candidates'], 1) * 1e9:.2f} ns per candidate pair "
          "(negative: the meshes cost less than the rectangles)")
    print(f"mesh / analytic per particle-step: {ratio:.3f} (median of the rounds' ratios; the issue's target: "
          "<= 1.2)")
    print(f"ratio_mesh_over_analytic={ratio:.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
