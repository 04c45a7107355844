"""Fluidisation curve of a CFD-DEM column for the five drag closures.

    python benchmarks/fluidisation.py --out DIR [--particles 600] [--cells 2,16,2] [--closures beetstra,wen_yu]

A column of glass spheres (d = 1 mm, 2550 kg/m3) in air, periodic across (x, z), resting on a
floor wall at y = 0 through which the gas enters uniformly (a velocity inlet over the whole
bottom: an ideal distributor plate that the particles cannot pass), pressure outlet on top
(:func:`cfddem.coupling.exchange.column_gas`).  The bed is poured and settled with the gas at
rest, then the superficial gas velocity U is raised in steps; at each step the pressure drop
``dp = p_b - p_out - rho_g |g| (y_out - y_b)`` (p_b the pressure extrapolated to the
distributor face; the gas's own hydrostatic part removed) is averaged over the second half of the step.

Expected (physics.md section 4): below the minimum fluidisation velocity the fixed-bed
pressure drop of the closure, ``dp = L (1 - eps) beta(eps, Re) U / eps^2 ...`` (rising with
U); above it ``dp`` levels off at the buoyant bed weight per area ``W (1 - rho_g/rho_p) / A``.
The measured U_mf is where the quadratic fit of the fixed-bed points through the origin
reaches the weight line; it is compared with :func:`drag.minimum_fluidisation_velocity`
at the bed porosity that the particles see (their mean interpolated eps) just before
fluidisation.

Writes DIR/fluidisation.png (dp against U per closure, with the bed-weight line and the
predicted U_mf marks) and DIR/fluidisation.json (all numbers); prints a table and the wall
time per closure.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time

import numpy as np

from cfddem.coupling import drag
from cfddem.coupling.exchange import column_gas
from cfddem.coupling.mapping import MappingPlan
from cfddem.particles.contact import LinearContact
from cfddem.particles.system import ParticleSystem
from cfddem.particles.walls import PlaneWall

RHO_G, MU, G = 1.2, 1.8e-5, 9.81


def build_column(n_particles=1000, d=1e-3, rho_p=2550.0, closure="beetstra", cells=(3, 16, 3), h=3e-3,
                 k_n=20.0, dt=2.5e-5, coupling_interval=4, seed=0, e_n=0.9):
    """Particles placed at random (no overlaps) in the lower part of the column, at rest."""
    Lx, Ly, Lz = cells[0] * h, cells[1] * h, cells[2] * h
    law = LinearContact(k_n=k_n, e_n=e_n, e_t=0.5, mu=0.3)
    walls = [PlaneWall(contact=law, point=(0.0, 0.0, 0.0), normal=(0.0, 1.0, 0.0), name="floor"),
             PlaneWall(contact=law, point=(0.0, Ly, 0.0), normal=(0.0, -1.0, 0.0), name="lid")]
    sys_ = ParticleSystem(pp=law, walls=walls, dt=dt, gravity=(0.0, -G, 0.0),
                          periodic=((0.0, Lx), None, (0.0, Lz)))
    rng = np.random.default_rng(seed)
    r = d / 2
    # a loose simple-cubic lattice with jitter, filled from the bottom
    s = 1.15 * d
    nx, nz = int(Lx / s), int(Lz / s)
    ny = int(math.ceil(n_particles / (nx * nz)))
    if (ny + 1) * s > 0.8 * Ly:
        raise ValueError("column too short for this many particles")
    pts = [((i + 0.5) * Lx / nx, r * 1.05 + j * s, (k + 0.5) * Lz / nz)
           for j in range(ny) for i in range(nx) for k in range(nz)][:n_particles]
    P = np.array(pts) + rng.uniform(-0.05, 0.05, (n_particles, 3)) * d * np.array([1, 0, 1])
    sys_.add_particles(P, 0.0, r, rho_p)
    cg = column_gas(sys_, lengths=(Lx, Ly, Lz), cells=cells, inlet_velocity=0.0, rho=RHO_G, mu=MU,
                    gravity=(0.0, -G, 0.0), closure=closure, coupling_interval=coupling_interval)
    return sys_, cg


def pressure_drop(cg) -> float:
    """Pressure at the distributor minus the outlet pressure, less the gas's own hydrostatic
    part: ``p_b - p_out - rho_g g (y_out - y_b)`` with ``p_b = <p_0 - (h/2) (p_1 - p_0)/h>``
    (the first cell row extrapolated to the inlet face, see exchange.py step 5b)."""
    grid = cg.grid
    p = cg.gas.p.interior
    pb = float((p[:, 0, :] - 0.5 * (p[:, 1, :] - p[:, 0, :])).mean())
    y_out = grid.origin[1] + grid.lengths[1]
    return pb - 0.0 - RHO_G * G * (y_out - grid.origin[1])


def floor_load(sys_, cg) -> float:
    """Downward force of the particles on the floor wall (the distributor plate) per area [Pa]."""
    A = cg.grid.lengths[0] * cg.grid.lengths[2]
    return float(-sys_.wall_forces()[0, 1]) / A


def bed_porosity_seen(sys_, cg) -> float:
    """Mean porosity interpolated at the particles (what the closures see)."""
    plan = MappingPlan(cg.grid, np.ascontiguousarray(sys_.pos), cg.periodic)
    return float(plan.interpolate(cg.gas.eps.interior, "ccc").mean())


def run(sys_, cg, t):
    n = int(round(t / sys_.dt))
    st = cg.advance(n)
    if not st.ok:
        raise RuntimeError(st.message)


def curve(sys_, cg, velocities, t_step=0.15, t_settle=0.25, samples=20):
    """Settle, then step U through ``velocities``; returns a list of dicts."""
    run(sys_, cg, t_settle)
    out = []
    A = cg.grid.lengths[0] * cg.grid.lengths[2]
    for U in velocities:
        cg.set_superficial_inlet("y-", U)
        eps_seen = bed_porosity_seen(sys_, cg)
        run(sys_, cg, 0.5 * t_step)
        dps, tops, floor = [], [], []
        for _ in range(samples):
            run(sys_, cg, 0.5 * t_step / samples)
            dps.append(pressure_drop(cg))
            floor.append(floor_load(sys_, cg))
            tops.append(float(np.percentile(sys_.pos[:, 1], 95)))
        out.append(dict(U=float(U), dp=float(np.mean(dps)), dp_std=float(np.std(dps)), floor=float(np.mean(floor)),
                        eps_seen_before=eps_seen,
                        bed_top_95=float(np.mean(tops)), mean_vy=float(np.mean(np.abs(sys_.vel[:, 1])))))
    weight = float(np.sum(sys_.mass)) * G * (1.0 - RHO_G / float(sys_.mass[0] / (4 / 3 * np.pi * sys_.radius[0] ** 3))) / A
    return out, weight


def umf_from_curve(rows, weight, fixed_fraction=0.8):
    """U where the fit dp = a U + b U^2 of the fixed-bed points (dp < fixed_fraction * weight)
    reaches the weight."""
    U = np.array([r["U"] for r in rows])
    dp = np.array([r["dp"] for r in rows])
    m = dp < fixed_fraction * weight
    if m.sum() < 2:
        raise ValueError("need two fixed-bed points")
    Amat = np.stack([U[m], U[m] ** 2], axis=1)
    a, b = np.linalg.lstsq(Amat, dp[m], rcond=None)[0]
    if abs(b) < 1e-12:
        return weight / a, (a, b)
    disc = a * a + 4 * b * weight
    return (-a + math.sqrt(disc)) / (2 * b), (a, b)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--particles", type=int, default=600)
    ap.add_argument("--cells", default="2,16,2", help="gas cells nx,ny,nz (3 mm each)")
    ap.add_argument("--closures", default=",".join(drag.CLOSURES))
    ap.add_argument("--t-step", type=float, default=0.2)
    args = ap.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    results = {}
    for name in args.closures.split(","):
        t0 = time.perf_counter()
        sys_, cg = build_column(args.particles, closure=name, cells=tuple(int(c) for c in args.cells.split(",")))
        # velocities relative to the closure's U_mf at eps 0.4
        u_ref = drag.minimum_fluidisation_velocity(0.43, 2550.0, RHO_G, 1e-3, MU, closure=name)
        vels = u_ref * np.array([0.2, 0.4, 0.6, 0.75, 0.9, 1.1, 1.3, 1.5, 1.7])
        rows, weight = curve(sys_, cg, vels, t_step=args.t_step)
        eps_mf = rows[0]["eps_seen_before"]
        try:
            umf, fit = umf_from_curve(rows, weight)
        except ValueError:
            umf, fit = float("nan"), (float("nan"), float("nan"))
        umf_pred = drag.minimum_fluidisation_velocity(eps_mf, 2550.0, RHO_G, 1e-3, MU, closure=name)
        wall = time.perf_counter() - t0
        results[name] = dict(rows=rows, weight_per_area=weight, eps_mf=eps_mf, umf=umf, umf_closure=umf_pred,
                             fit=list(fit), wall_time=wall)
        plateau = [f'{r["dp"] / weight:.3f} (floor {r["floor"] / weight:.3f})' for r in rows
                   if r["U"] > 1.25 * umf_pred]
        print(f"{name:15s} weight {weight:7.2f} Pa  eps_mf {eps_mf:.3f}  U_mf measured {umf:.3f} m/s, closure "
              f"{umf_pred:.3f} m/s ({umf / umf_pred - 1:+.1%}); plateau dp/weight "
              f"{', '.join(plateau)}; wall {wall:.0f} s", flush=True)
    with open(os.path.join(args.out, "fluidisation.json"), "w") as f:
        json.dump(results, f, indent=1)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    colors = dict(beetstra="k", wen_yu="tab:blue", ergun_gidaspow="tab:orange", di_felice="tab:green",
                  koch_hill="tab:red")
    for name, r in results.items():
        U = [x["U"] for x in r["rows"]]
        dp = [x["dp"] for x in r["rows"]]
        err = [x["dp_std"] for x in r["rows"]]
        c = colors.get(name)
        ax.errorbar(U, dp, yerr=err, marker="o", ms=4, color=c, label=f"{name} (U_mf closure {r['umf_closure']:.2f})")
        ax.axvline(r["umf_closure"], color=c, ls=":", lw=0.8)
    w = next(iter(results.values()))["weight_per_area"]
    ax.axhline(w, color="grey", ls="--", label="bed weight / area")
    ax.set_xlabel("superficial gas velocity U [m/s]")
    ax.set_ylabel("pressure drop [Pa]")
    ax.set_title(f"Fluidisation of {args.particles} glass spheres, d = 1 mm")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(os.path.join(args.out, "fluidisation.png"), dpi=120)
    print("wrote", os.path.join(args.out, "fluidisation.png"))


if __name__ == "__main__":
    main()
