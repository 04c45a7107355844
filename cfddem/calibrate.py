"""``cfddem calibrate``: bulk friction of a shear-cell case against the particle friction
coefficients (the usual DEM calibration: choose mu (and mu_r) so that the simulated Jenike test
gives the measured bulk friction).

For every combination of ``--mu`` (contact.particle_particle.mu) and ``--mu-r``
(contact.particle_particle.mu_r) the case is run (one after the other, in this process) into
``OUT/mu<mu>_mur<mu_r>/`` and ``/measurements/bulk_friction`` (or ``wall_friction``) read back.
Written: ``OUT/calibration.csv`` and ``OUT/calibration.md`` (table: mu, mu_r, bulk friction,
mean shear and normal force, load error, status, wall time) and ``OUT/calibration.png`` (bulk
friction against mu, one line per mu_r).  ``--target`` adds the interpolated mu that gives that
bulk friction (per mu_r, linear interpolation between the swept points).
"""

from __future__ import annotations

import csv
import math
import time
from pathlib import Path

import numpy as np

from .errors import CaseError


def add_calibrate_parser(sub) -> None:
    c = sub.add_parser("calibrate", help="shear-cell bulk friction against particle friction (table + PNG)")
    c.add_argument("case", help="a shear_cell case folder")
    c.add_argument("--mu", required=True, help="comma-separated particle-particle friction values, e.g. 0.2,0.4,0.6")
    c.add_argument("--mu-r", default="", help="comma-separated rolling friction values (default: the case's)")
    c.add_argument("--out", required=True, help="output folder")
    c.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a case key")
    c.add_argument("--target", type=float, default=None, help="bulk friction to match: report the mu giving it")
    c.add_argument("--threads", type=int, default=None, help="numba threads")
    c.add_argument("--overwrite", action="store_true", help="replace existing run folders")


def _floats(text: str, key: str) -> list[float]:
    try:
        vals = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise CaseError(key, f"needs comma-separated numbers, got {text!r}") from None
    if any(not (v >= 0 and math.isfinite(v)) for v in vals):
        raise CaseError(key, f"friction values must be finite and >= 0, got {text!r}")
    return vals


def interpolate_target(mu, friction, target: float) -> float:
    """The mu at which the piecewise-linear curve (mu sorted) reaches ``target`` (nan if never)."""
    mu = np.asarray(mu, float)
    f = np.asarray(friction, float)
    o = np.argsort(mu)
    mu, f = mu[o], f[o]
    for k in range(len(mu) - 1):
        a, b = f[k] - target, f[k + 1] - target
        if a == 0:
            return float(mu[k])
        if a * b < 0:
            return float(mu[k] + (mu[k + 1] - mu[k]) * a / (a - b))
    if len(f) and f[-1] == target:
        return float(mu[-1])
    return math.nan


def calibrate(case_dir, mus, murs, out, overrides=(), threads=None, overwrite=False, target=None,
              log=print) -> list[dict]:
    """Run the sweep (module docstring); returns the table rows."""
    from .config import load_case
    from .io.results import read_measurements
    from .simulation import Simulation

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    base = load_case(case_dir, overrides=list(overrides))
    if base.geometry.type != "shear_cell":
        raise CaseError("geometry.type", f"calibrate needs a shear_cell case, got {base.geometry.type!r}")
    if not murs:
        murs = [float(base.contact.particle_particle.mu_r)]
    name = "wall_friction" if base.resolved["shear"]["variant"] == "wall" else "bulk_friction"
    rows = []
    for mur in murs:
        for mu in mus:
            sub = out / f"mu{mu:g}_mur{mur:g}"
            ov = list(overrides) + [f"contact.particle_particle.mu={mu}", f"contact.particle_particle.mu_r={mur}"]
            if threads is not None:
                ov.append(f"time.threads={int(threads)}")
            case = load_case(case_dir, overrides=ov)
            t0 = time.perf_counter()
            summary = Simulation(case, sub, overwrite=overwrite, echo=False, progress=False).run()
            wall = time.perf_counter() - t0
            row = {"mu": mu, "mu_r": mur, "friction": math.nan, "shear_force": math.nan, "normal_force": math.nan,
                   "load_error": math.nan, "inertial_number": math.nan, "status": summary.status, "wall_s": wall,
                   "folder": sub.name}
            try:
                m = read_measurements(sub / "results.h5")
                sh = m["shear"]
                row.update(friction=float(m[name]), shear_force=float(sh["mean_shear_force"]),
                           normal_force=float(sh["mean_normal_force"]), load_error=float(sh["load_error"]),
                           inertial_number=float(sh["inertial_number"]))
            except (KeyError, OSError) as e:
                row["status"] = f"{summary.status} (no measurement: {e})"
            rows.append(row)
            log(f"mu = {mu:g}, mu_r = {mur:g}: {name} {row['friction']:.4g} ({row['status']}, {wall:.0f} s)")
    _write(rows, out, name, target)
    return rows


def _write(rows, out: Path, name: str, target) -> None:
    keys = ["mu", "mu_r", "friction", "shear_force", "normal_force", "load_error", "inertial_number", "status",
            "wall_s", "folder"]
    with open(out / "calibration.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: r[k] for k in keys})
    lines = [f"# Shear-cell calibration: {name.replace('_', ' ')} against particle friction", "",
             f"| mu | mu_r | {name} | mean shear force (N) | mean normal force (N) | load error | I | status | wall (s) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['mu']:g} | {r['mu_r']:g} | {r['friction']:.4f} | {r['shear_force']:.4g} | "
                     f"{r['normal_force']:.4g} | {100 * r['load_error']:.2g} % | {r['inertial_number']:.2g} | "
                     f"{r['status']} | {r['wall_s']:.0f} |")
    if target is not None:
        lines += ["", f"Target {name.replace('_', ' ')} {target:g}:"]
        for mur in sorted({r["mu_r"] for r in rows}):
            sel = [r for r in rows if r["mu_r"] == mur]
            m = interpolate_target([r["mu"] for r in sel], [r["friction"] for r in sel], target)
            lines.append(f"- mu_r = {mur:g}: mu = {m:.4g}" if math.isfinite(m) else
                         f"- mu_r = {mur:g}: not reached in the swept range")
    (out / "calibration.md").write_text("\n".join(lines) + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.6))
    for mur in sorted({r["mu_r"] for r in rows}):
        sel = sorted([r for r in rows if r["mu_r"] == mur], key=lambda r: r["mu"])
        ax.plot([r["mu"] for r in sel], [r["friction"] for r in sel], "o-", label=f"mu_r = {mur:g}")
    if target is not None:
        ax.axhline(target, color="k", ls=":", lw=1, label=f"target {target:g}")
    ax.set_xlabel("particle-particle friction mu")
    ax.set_ylabel(name.replace("_", " "))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "calibration.png", dpi=120)
    plt.close(fig)


def run_calibrate_from_args(args) -> int:
    mus = _floats(args.mu, "--mu")
    if not mus:
        raise CaseError("--mu", "needs at least one value")
    murs = _floats(args.mu_r, "--mu-r") if args.mu_r else []
    calibrate(args.case, mus, murs, args.out, overrides=args.set, threads=args.threads, overwrite=args.overwrite,
              target=args.target)
    print(f"table: {Path(args.out) / 'calibration.md'}, plot: {Path(args.out) / 'calibration.png'}")
    return 0
