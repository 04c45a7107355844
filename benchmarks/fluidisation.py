"""Fluidisation curve of a CFD-DEM bed for the five drag closures.

    python benchmarks/fluidisation.py --out DIR [--closures beetstra,wen_yu] [--bed deep|wide] [--t-average 0.8]
    python benchmarks/fluidisation.py --out DIR --plot-only      # chart from DIR/fluidisation_*.json

The column (:func:`build_column`, :func:`cfddem.coupling.exchange.column_gas`): glass spheres
(``rho_p`` = 2550 kg/m3) in air (1.2 kg/m3, 1.8e-5 Pa s), periodic across x and z, resting on a
floor wall at y = 0 through which the gas enters with a prescribed superficial velocity U
(an ideal distributor plate: each bottom cell receives the flux U times its area; the
particles cannot pass), pressure outlet p = 0 on top (y = Ly), and a lid wall there for the
particles.  Two beds (:data:`BEDS`), both pseudo-2-D with 16 gas cells of 1.5 mm across
(24 mm wide, 1.5 mm deep) and particles of 0.5 mm, in which bubbles form:

* ``deep`` (the default, :data:`DEEP`): 6400 particles, 16 x 40 x 1 cells (60 mm high), bed
  about 18 mm = 12 cells high (H/W about 0.75); plateau read at 1.5, 2.0, 2.5 U_mf;
* ``wide`` (:data:`WIDE`, the default until the plateau study of docs/fluidisation/README.md):
  3200 particles, 16 x 20 x 1 cells (30 mm high), bed about 9 mm = 6 cells high (H/W about
  0.4); plateau read at 1.3, 1.7, 2.2 U_mf.

The distributor carries a load of about 4 Pa in both (particles falling back into the voids
that bubbles leave at the distributor and onto the bed after eruptions pass that momentum
down the dense bottom layer to the plate): about 3 % of the wide bed's weight, 1.3 % of the
deep bed's (docs/fluidisation/README.md).  Narrower columns (2 x 2 or 3 x 3 cells) and shallow
beds (2-3 cells high) slug, the bed rising as a plug and falling back onto the distributor, so
that the floor carried 3 to 15 % of the weight on average (docs/coupling.md, "The
fluidisation plateau").

Measured quantities (:func:`sample`):

* ``dp = p_b - p_out - rho_g |g| (y_out - y_b)``: the gas pressure at the distributor face
  ``y_b = 0`` minus the pressure at the outlet face ``y_out = Ly`` (above the bed; p_out = 0
  is prescribed there), less the hydrostatic head of the gas itself.  ``p_b`` is the mean
  over the bottom cell row of ``p_0 - (p_1 - p_0)/2`` (the first two cell-centre rows
  extrapolated to the face, see :mod:`cfddem.coupling.exchange` step 5b).
* ``W = sum_a m_a |g| (1 - rho_g/rho_p) / A``: the buoyant bed weight per cross-section A
  (:func:`bed_weight`).
* ``floor``: the downward force of the particles on the floor wall per area.  Momentum
  balance of the bed: ``dp + floor = W`` on time average (less the rate of change of the
  particles' momentum, zero on average), so the plateau ``dp = W`` needs ``floor -> 0``.

Both are sampled after every second gas step (``every=2`` coupling intervals) and averaged
over ``t_average`` after a transient ``t_transient``; the standard error of the mean is that
of ``n_blocks`` consecutive block means (:func:`block_sem`; blocks longer than the bubble
period, so they are roughly independent).

Expected (physics.md section 4): below the minimum fluidisation velocity the fixed-bed pressure
drop of the closure, ``dp = sum_a K_a(eps_a, Re) U/eps_a^2 / A`` (``K = 3 pi mu d eps F``,
``Re = rho_g U d/mu``, at each particle's interpolated porosity), rising with U; above it dp
levels off at W.  The measured U_mf is where the fit ``dp = a U + b U^2`` of the fixed-bed
points reaches W (:func:`umf_from_curve`); it is compared with
:func:`drag.minimum_fluidisation_velocity` at the mean porosity the particles see before the
gas is switched on (each row's ``eps_seen_before`` is that porosity when its U was switched on:
in the deep bed the soft contacts unload as the gas takes the weight, 0.395 at rest to 0.401
at 0.85 U_mf, and U_mf moves with it, docs/fluidisation/README.md).

Writes DIR/fluidisation_<closure>.json per closure and DIR/fluidisation.json (all) and
DIR/fluidisation.png (dp/W against U/U_mf, with the weight line, and dp against U); prints a
table and the wall time per closure.
"""

from __future__ import annotations

import argparse
import glob
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

RHO_G, MU, G, RHO_P = 1.2, 1.8e-5, 9.81, 2550.0

#: the wide bed (pseudo-2-D, 16 x 20 x 1 cells of 1.5 mm, 3200 spheres of 0.5 mm, bed about 9 mm high):
#: it bubbles, but the distributor carries about 4 Pa = 3 % of its weight (docs/coupling.md)
WIDE = dict(n_particles=3200, cells=(16, 20, 1), d=5e-4, h=1.5e-3, k_n=10.0, dt=1.25e-5, coupling_interval=8)
#: the deep bed (the default): the same width and particles, twice as deep (6400 spheres, bed about
#: 18 mm = 12 cells high, H/W about 0.75) in a column of 16 x 40 x 1 cells (60 mm): the distributor's
#: share, about 4 Pa whatever the depth, falls to about 1.3 % of the weight
DEEP = dict(WIDE, n_particles=6400, cells=(16, 40, 1))
#: bed name -> (column, U/U_mf steps: fixed-bed points below 0.95, plateau points above, settling
#: time with the gas at rest [s]; the deep bed is poured from twice the height)
BEDS = {"deep": (DEEP, (0.2, 0.4, 0.6, 0.75, 0.85, 1.5, 2.0, 2.5), 0.25),
        "wide": (WIDE, (0.2, 0.4, 0.6, 0.75, 0.85, 1.3, 1.7, 2.2), 0.2)}
DEFAULT = DEEP


def build_column(n_particles=3200, d=1e-3, rho_p=RHO_P, closure="beetstra", cells=(16, 20, 1), h=3e-3,
                 k_n=20.0, dt=2.5e-5, coupling_interval=8, seed=0, e_n=0.9, e_t=0.5, mu=0.3):
    """Particles on a loose jittered simple-cubic lattice (spacing 1.15 d) filled from the
    bottom of the column, at rest; gas at rest.  Returns ``(system, coupled_gas)``."""
    Lx, Ly, Lz = cells[0] * h, cells[1] * h, cells[2] * h
    law = LinearContact(k_n=k_n, e_n=e_n, e_t=e_t, mu=mu)
    walls = [PlaneWall(contact=law, point=(0.0, 0.0, 0.0), normal=(0.0, 1.0, 0.0), name="floor"),
             PlaneWall(contact=law, point=(0.0, Ly, 0.0), normal=(0.0, -1.0, 0.0), name="lid")]
    sys_ = ParticleSystem(pp=law, walls=walls, dt=dt, gravity=(0.0, -G, 0.0),
                          periodic=((0.0, Lx), None, (0.0, Lz)))
    rng = np.random.default_rng(seed)
    r = d / 2
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


def area(cg) -> float:
    return float(cg.grid.lengths[0] * cg.grid.lengths[2])


def bed_weight(sys_, cg) -> float:
    """Buoyant bed weight per area ``W = sum m |g| (1 - rho_g/rho_p) / A`` [Pa]."""
    rho_p = sys_.mass / (4.0 / 3.0 * np.pi * sys_.radius**3)
    return float(np.sum(sys_.mass * G * (1.0 - RHO_G / rho_p))) / area(cg)


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
    return float(-sys_.wall_forces()[0, 1]) / area(cg)


def bed_porosity_seen(sys_, cg) -> float:
    """Mean porosity interpolated at the particles (what the closures see)."""
    plan = MappingPlan(cg.grid, np.ascontiguousarray(sys_.pos), cg.gas.bc)
    return float(plan.interpolate(cg.gas.eps.interior, "ccc").mean())


def closure_pressure_drop(sys_, cg, U, closure="beetstra"):
    """Fixed-bed pressure drop from the closure at each particle's own porosity: the gas
    balance ``eps grad p = drag density`` gives dp = sum_a K(eps_a, Re) (U/eps_a) / (eps_a A),
    Re = rho U d / mu (the superficial Reynolds number of the closures)."""
    plan = MappingPlan(cg.grid, np.ascontiguousarray(sys_.pos), cg.gas.bc)
    eps_a = plan.interpolate(cg.gas.eps.interior, "ccc")
    d = 2.0 * sys_.radius
    re = RHO_G * U * d / MU
    K = drag.drag_force_factor(eps_a, re, MU, d, closure)
    return float(np.sum(K * U / eps_a**2)) / area(cg)


def run(sys_, cg, t):
    n = int(round(t / sys_.dt))
    st = cg.advance(n)
    if not st.ok:
        raise RuntimeError(st.message)


def block_sem(x, n_blocks=10) -> float:
    """Standard error of the mean of a correlated series from ``n_blocks`` consecutive block
    means: ``std(block means, ddof=1) / sqrt(n_blocks)``."""
    x = np.asarray(x, dtype=float)
    m = len(x) // n_blocks
    if m < 1 or n_blocks < 2:
        return float("nan")
    b = x[: m * n_blocks].reshape(n_blocks, m).mean(axis=1)
    return float(b.std(ddof=1) / math.sqrt(n_blocks))


def sample(sys_, cg, t_average, every=2, n_blocks=10) -> dict:
    """Advance ``t_average`` seconds, recording dp and the floor load after every ``every``
    coupling intervals; returns their means and block standard errors, and the 95th
    percentile of the particle heights (mean over the samples)."""
    n_chunk = every * cg.N
    n = max(1, int(round(t_average / (n_chunk * sys_.dt))))
    dp, fl, top = np.empty(n), np.empty(n), np.empty(n)
    for i in range(n):
        st = cg.advance(n_chunk)
        if not st.ok:
            raise RuntimeError(st.message)
        dp[i] = pressure_drop(cg)
        fl[i] = floor_load(sys_, cg)
        top[i] = np.percentile(sys_.pos[:, 1], 95)
    return dict(dp=float(dp.mean()), dp_sem=block_sem(dp, n_blocks), dp_std=float(dp.std()),
                floor=float(fl.mean()), floor_sem=block_sem(fl, n_blocks), bed_top_95=float(top.mean()),
                n_samples=n, t_average=float(n * n_chunk * sys_.dt))


def curve(sys_, cg, velocities, u_mf, closure="beetstra", t_settle=0.2, t_fixed=(0.03, 0.03),
          t_fluid=(0.2, 1.0), fixed_below=0.95):
    """Settle (gas at rest), then step the superficial velocity through ``velocities``
    (increasing).  Points below ``fixed_below * u_mf`` are fixed-bed points (steady: transient
    and average ``t_fixed``); the others get ``t_fluid = (transient, average)``.  Each row also
    holds the closure's fixed-bed prediction at the bed as it was when U was switched on.
    Returns ``(rows, W)``."""
    run(sys_, cg, t_settle)
    W = bed_weight(sys_, cg)
    rows = []
    for U in velocities:
        cg.set_superficial_inlet("y-", U)
        eps_seen = bed_porosity_seen(sys_, cg)
        pred = closure_pressure_drop(sys_, cg, U, closure)
        t_tr, t_av = t_fixed if U < fixed_below * u_mf else t_fluid
        run(sys_, cg, t_tr)
        row = dict(U=float(U), U_over_umf=float(U / u_mf), closure_dp=pred, eps_seen_before=eps_seen)
        row.update(sample(sys_, cg, t_av))
        rows.append(row)
    return rows, W


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


FACTORS = BEDS["deep"][1]


def run_closure(name, factors=None, t_average=0.8, t_transient=0.15, bed="deep", **column):
    """The stepped curve for one closure on bed ``bed`` (a key of :data:`BEDS`, its column
    updated by ``column``; ``factors`` default: the bed's U/U_mf steps); returns the JSON-able
    result dict."""
    t0 = time.perf_counter()
    base, bed_factors, t_settle = BEDS[bed]
    factors = bed_factors if factors is None else factors
    cfg = dict(base)
    cfg.update(column)
    sys_, cg = build_column(closure=name, **cfg)
    run(sys_, cg, t_settle)
    eps_mf = bed_porosity_seen(sys_, cg)
    d = float(2 * sys_.radius[0])
    u_mf = drag.minimum_fluidisation_velocity(eps_mf, RHO_P, RHO_G, d, MU, closure=name)
    rows, W = curve(sys_, cg, u_mf * np.asarray(factors), u_mf, closure=name, t_settle=0.0,
                    t_fluid=(t_transient, t_average))
    try:
        umf, fit = umf_from_curve(rows, W)
    except ValueError:
        umf, fit = float("nan"), (float("nan"), float("nan"))
    wall = time.perf_counter() - t0
    cfg["cells"] = list(cfg["cells"])
    return dict(closure=name, bed=bed, column=cfg, rows=rows, weight_per_area=W, eps_mf=eps_mf, umf=umf,
                umf_closure=u_mf, fit=list(fit), wall_time=wall, t_average=t_average, t_transient=t_transient)


def summary_line(r) -> str:
    W = r["weight_per_area"]
    fixed = [f'{x["dp"] / x["closure_dp"] - 1:+.1%}' for x in r["rows"] if x["U_over_umf"] < 0.95]
    plateau = [f'{x["U_over_umf"]:.1f}: {x["dp"] / W:.3f}+-{x["dp_sem"] / W:.3f} (floor {x["floor"] / W:.3f})'
               for x in r["rows"] if x["U_over_umf"] > 1.2]
    return (f'{r["closure"]:15s} W {W:6.1f} Pa  eps_mf {r["eps_mf"]:.3f}  U_mf {r["umf"]:.3f} vs closure '
            f'{r["umf_closure"]:.3f} m/s ({r["umf"] / r["umf_closure"] - 1:+.1%}); fixed bed vs closure '
            f'{", ".join(fixed)}; plateau dp/W {"; ".join(plateau)}; wall {r["wall_time"]:.0f} s')


def plot(results, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colors = dict(beetstra="k", wen_yu="tab:blue", ergun_gidaspow="tab:orange", di_felice="tab:green",
                  koch_hill="tab:red")
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4.5))
    for name, r in results.items():
        U = np.array([x["U"] for x in r["rows"]])
        dp = np.array([x["dp"] for x in r["rows"]])
        sem = np.array([x["dp_sem"] for x in r["rows"]])
        pred = np.array([x["closure_dp"] for x in r["rows"]])
        W = r["weight_per_area"]
        c = colors.get(name)
        ax.errorbar(U, dp, yerr=2 * sem, marker="o", ms=4, color=c, capsize=2,
                    label=f"{name}: U_mf {r['umf']:.3f} (closure {r['umf_closure']:.3f}) m/s")
        fixed = U < 0.95 * r["umf_closure"]
        ax.plot(U[fixed], pred[fixed], ls="none", marker="x", color=c, ms=6)
        ax.axvline(r["umf_closure"], color=c, ls=":", lw=0.8)
        bx.errorbar(U / r["umf_closure"], dp / W, yerr=2 * sem / W, marker="o", ms=4, color=c, capsize=2,
                    label=name)
        bx.plot(U / r["umf_closure"], np.array([x["floor"] for x in r["rows"]]) / W, ls="--", marker=".",
                color=c, lw=0.8)
    W = next(iter(results.values()))["weight_per_area"]
    ax.axhline(W, color="grey", ls="--", label="bed weight / area W")
    ax.set_xlabel("superficial gas velocity U [m/s]")
    ax.set_ylabel("pressure drop dp [Pa]")
    ax.set_ylim(bottom=0.0)
    ax.legend(fontsize=7)
    ax.set_title("dp (o, +-2 SEM) and closure fixed-bed dp (x)", fontsize=9)
    bx.axhline(1.0, color="grey", ls="--")
    bx.axhspan(0.97, 1.03, color="grey", alpha=0.15, label="W +- 3 %")
    bx.set_xlabel("U / U_mf (closure)")
    bx.set_ylabel("dp / W (o);  floor load / W (dashed)")
    bx.legend(fontsize=7)
    col = next(iter(results.values()))["column"]
    fig.suptitle(f"Fluidisation of {col['n_particles']} glass spheres, d = {col['d'] * 1e3:g} mm, "
                 f"{col['cells'][0]} x {col['cells'][1]} x {col['cells'][2]} cells of {col['h'] * 1e3:g} mm "
                 f"(periodic in x, z)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--closures", default=",".join(drag.CLOSURES))
    ap.add_argument("--bed", default="deep", choices=sorted(BEDS), help="column (BEDS): deep (default) or wide")
    ap.add_argument("--particles", type=int, default=None, help="number of particles (default: the bed's)")
    ap.add_argument("--cells", default=None, help="gas cells nx,ny,nz (default: the bed's)")
    ap.add_argument("--t-average", type=float, default=0.8, help="averaging time per fluidised point [s]")
    ap.add_argument("--t-transient", type=float, default=0.15, help="transient after each step [s]")
    ap.add_argument("--factors", default=None, help="U / U_mf(closure) steps (default: the bed's)")
    ap.add_argument("--plot-only", action="store_true", help="only merge DIR/fluidisation_*.json and plot")
    args = ap.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    if not args.plot_only:
        column = {}
        if args.particles is not None:
            column["n_particles"] = args.particles
        if args.cells is not None:
            column["cells"] = tuple(int(c) for c in args.cells.split(","))
        factors = None if args.factors is None else [float(f) for f in args.factors.split(",")]
        for name in args.closures.split(","):
            r = run_closure(name, factors=factors, t_average=args.t_average, t_transient=args.t_transient,
                            bed=args.bed, **column)
            with open(os.path.join(args.out, f"fluidisation_{name}.json"), "w") as f:
                json.dump(r, f, indent=1)
            print(summary_line(r), flush=True)
    results = {}
    for name in drag.CLOSURES:
        p = os.path.join(args.out, f"fluidisation_{name}.json")
        if os.path.exists(p):
            with open(p) as f:
                results[name] = json.load(f)
    if not results:
        raise SystemExit(f"no fluidisation_*.json in {args.out}")
    with open(os.path.join(args.out, "fluidisation.json"), "w") as f:
        json.dump(results, f, indent=1)
    plot(results, os.path.join(args.out, "fluidisation.png"))
    for r in results.values():
        print(summary_line(r))
    print("wrote", os.path.join(args.out, "fluidisation.png"))


if __name__ == "__main__":
    main()
