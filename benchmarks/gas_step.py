"""Time one gas step (cfddem.gas.GasSolver) on the chute grid and on 64^3 cells.

Chute grid: 16 x 15 x 150 cells over 0.08 x 0.045 x 0.9 m, inclined 30 deg, rotating at
16 rpm about the vertical axis, no-slip floor and side walls, lid cross-wind on the open
top, co-flow inlet, pressure outlet; porosity from a random packed-bed-like field
(eps ~ 0.4 in a bed of varying depth with noise, rising to 1 above it), slowly moving so
that d(eps)/dt != 0 and the AMG hierarchy is reused/rebuilt as in a coupled run; implicit
drag K on, as the coupling will use it.  Compile time is excluded (warm-up steps).

Usage: python benchmarks/gas_step.py [--steps 30] [--threads N] [--tol 1e-8]
Prints time per step (total, momentum+projection bookkeeping, pressure solve), pressure
iterations per step, and cost per cell for the two grids.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from cfddem._jit import set_threads
from cfddem.gas import GasSolver, Inlet, LidCrossWind, NoSlip, Periodic, PressureOutlet, StaggeredGrid


def bed_porosity(g, t, rng_field):
    X, Y, Z = g.mesh("ccc")
    H = g.lengths[1]
    depth = 0.4 * H * (1.0 + 0.3 * np.sin(2 * np.pi * (Z / g.lengths[2] - 2.0 * t)))
    solid = 0.6 / (1.0 + np.exp((Y - depth) / (0.05 * H)))
    return np.clip(1.0 - solid + 0.08 * rng_field, 0.4, 1.0)


def chute_solver(shape=(16, 15, 150), lengths=(0.08, 0.045, 0.9), tol=1e-8, solver="mg"):
    th = np.radians(30.0)
    up = np.array([0.0, np.cos(th), -np.sin(th)])
    omega = tuple(16 * 2 * np.pi / 60 * up)
    axis = (0.04, 0.0, 0.035)
    gvec = tuple(-9.81 * up)
    g = StaggeredGrid(shape, lengths)
    bcs = {"x-": NoSlip(), "x+": NoSlip(), "y-": NoSlip(), "y+": LidCrossWind(omega=omega, axis_point=axis),
           "z-": Inlet(speed=1.0), "z+": PressureOutlet(p=lambda x, y, z: 1.2 * (gvec[1] * y + gvec[2] * z))}
    return g, GasSolver(g, rho=1.2, mu=1.8e-5, bcs=bcs, gravity=gvec, omega=omega, axis_point=axis, tol=tol,
                        pressure_solver=solver)


def cube_solver(n=64, tol=1e-8):
    g = StaggeredGrid((n, n, n), (1.0, 1.0, 1.0))
    bcs = {"x-": NoSlip(), "x+": NoSlip(), "y-": NoSlip(), "y+": LidCrossWind(omega=(0, 1.7, 0), axis_point=(0.5, 0, 0.5)),
           "z-": Periodic(), "z+": Periodic()}
    return g, GasSolver(g, rho=1.2, mu=1.8e-5, bcs=bcs, gravity=(0, -9.81, 0), omega=(0, 1.7, 0),
                        axis_point=(0.5, 0, 0.5), tol=tol)


def bench(name, g, s, steps, dt):
    rng = np.random.default_rng(1)
    noise = rng.uniform(-1.0, 1.0, g.shape)
    shapes = [g.interior_shape(loc) for loc in ("fcc", "cfc", "ccf")]
    K = tuple(np.full(sh, 30.0) for sh in shapes)
    Up = (np.zeros(shapes[0]), np.zeros(shapes[1]), np.full(shapes[2], 1.0))
    s.set_porosity(bed_porosity(g, 0.0, noise))
    for i in range(3):  # warm-up: compilation and first AMG build
        s.set_porosity(bed_porosity(g, (i + 1) * dt, noise))
        s.step(dt, drag_K=K, drag_Up=Up)
    t_solve = 0.0
    iters = []
    rebuilds0 = s.psolver.n_rebuilds
    orig_solve = s.psolver.solve

    def timed_solve(*a, **k):
        nonlocal t_solve
        t0 = time.perf_counter()
        out = orig_solve(*a, **k)
        t_solve += time.perf_counter() - t0
        return out

    s.psolver.solve = timed_solve
    t0 = time.perf_counter()
    for i in range(steps):
        s.set_porosity(bed_porosity(g, (i + 4) * dt, noise))
        info = s.step(dt, drag_K=K, drag_Up=Up)
        if not info.ok:
            raise SystemExit(f"{name}: {info.message}")
        iters.append(info.pressure_iterations)
    total = (time.perf_counter() - t0) / steps
    s.psolver.solve = orig_solve
    n = g.ncells
    res = dict(name=name, cells=n, ms_step=1e3 * total, ms_pressure=1e3 * t_solve / steps,
               ms_rest=1e3 * (total - t_solve / steps), iters=float(np.mean(iters)), max_iters=int(np.max(iters)),
               rebuilds=s.psolver.n_rebuilds - rebuilds0, us_per_cell=1e6 * total / n,
               div=s.divergence_residual(), cfl=info.cfl)
    print(f"{name:>12s}: {n:7d} cells  {res['ms_step']:8.2f} ms/step  (pressure solve {res['ms_pressure']:7.2f} ms, "
          f"rest {res['ms_rest']:6.2f} ms)  pressure iterations {res['iters']:.1f} (max {res['max_iters']}), "
          f"AMG rebuilds {res['rebuilds']}/{steps}, {res['us_per_cell']:.3f} us/cell, "
          f"div residual {res['div']:.1e}, CFL {res['cfl']:.2f}")
    return res


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--threads", type=int, default=0, help="numba threads (0: all)")
    ap.add_argument("--tol", type=float, default=1e-8)
    ap.add_argument("--no-cube", action="store_true", help="skip the 64^3 grid")
    a = ap.parse_args(argv)
    nt = set_threads(a.threads)
    print(f"numba threads: {nt}, pressure tolerance {a.tol:g}")
    g, s = chute_solver(tol=a.tol)
    r1 = bench("chute", g, s, a.steps, 1e-3)
    if not a.no_cube:
        g, s = cube_solver(tol=a.tol)
        r2 = bench("64^3", g, s, max(5, a.steps // 3), 2e-3)
        ratio = r2["ms_step"] / r1["ms_step"]
        print(f"cost growth: cells x{r2['cells'] / r1['cells']:.1f} -> time x{ratio:.1f} "
              f"(per cell x{r2['us_per_cell'] / r1['us_per_cell']:.2f})")


if __name__ == "__main__":
    main()
