"""Outlet-width study of a silo case: ``cfddem beverloo CASE --widths B1,B2,...``.

Runs the case once per slot width ``silo.outlet_width`` (as a sweep: :func:`cfddem.sweep.run_sweep`,
Dask, one run folder per width, finished runs reused), reads each run's
``/measurements/mass_flow_rate``, ``/measurements/bulk_density`` and ``/measurements/clogged``,
and fits the Beverloo law for a slot

    W = C rho_b sqrt(g) L (b - k d)^(3/2)

(:func:`cfddem.measure.silo.fit_beverloo`; L = ``silo.depth``, d = ``particles.diameter``,
g = ``gravity.g``, rho_b = the mean of the runs' measured bulk densities) to the widths that
discharged without clogging.  Writes into the study folder (default ``CASE/beverloo``):

* ``beverloo.csv`` / ``beverloo.md``: outlet width, measured flow rate, bulk density, clogged,
  status, the fitted law's rate and the relative deviation; the fitted C, k (with standard
  errors) and the rho_b, L, d used;
* ``beverloo.png``: measured flow rate against outlet width with the fitted curve;
* the sweep's own ``summary.csv``/``summary.md`` and one run folder per width.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from .errors import CaseError


def _finite(v) -> float:
    try:
        x = float(v)
    except (TypeError, ValueError):
        return math.nan
    return x


def beverloo_table(rows: list[dict], rho_b: float | None, L: float, d: float, g: float) -> dict:
    """From sweep rows (``values['silo.outlet_width']`` and ``measurements``) to the table and
    the fit.  rho_b None: the mean of the measured bulk densities."""
    from .measure.silo import beverloo_rate, fit_beverloo

    table = []
    for r in rows:
        m = r.get("measurements", {}) or {}
        table.append({"outlet_width": float(r["values"]["silo.outlet_width"]),
                      "mass_flow_rate": _finite(m.get("mass_flow_rate")),
                      "bulk_density": _finite(m.get("bulk_density")),
                      "clogged": int(_finite(m.get("clogged", 0)) == 1),
                      "status": r.get("status", "")})
    table.sort(key=lambda x: x["outlet_width"])
    rhos = [t["bulk_density"] for t in table if math.isfinite(t["bulk_density"])]
    if rho_b is None:
        rho_b = float(np.mean(rhos)) if rhos else math.nan
    use = [t for t in table if not t["clogged"] and math.isfinite(t["mass_flow_rate"]) and t["mass_flow_rate"] > 0
           and t["status"] in ("done", "skipped")]
    fit = None
    if len(use) >= 2 and math.isfinite(rho_b):
        fit = fit_beverloo([t["outlet_width"] for t in use], [t["mass_flow_rate"] for t in use], rho_b, L, d, g)
        for t in table:
            t["beverloo_rate"] = float(beverloo_rate(t["outlet_width"], fit["C"], fit["k"], rho_b, L, d, g))
            t["deviation"] = (t["mass_flow_rate"] / t["beverloo_rate"] - 1.0
                              if t["beverloo_rate"] > 0 and math.isfinite(t["mass_flow_rate"]) else math.nan)
    return {"table": table, "fit": fit, "rho_b": rho_b, "L": L, "d": d, "g": g, "n_fitted": len(use)}


def write_beverloo_outputs(study: dict, out: Path, title: str = "Beverloo study") -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    cols = ["outlet_width", "mass_flow_rate", "bulk_density", "clogged", "status", "beverloo_rate", "deviation"]
    fit = study["fit"]
    head = [f"rho_b = {study['rho_b']:.6g} kg/m3, L = {study['L']:g} m, d = {study['d']:g} m, g = {study['g']:g} m/s2"]
    if fit:
        head.append(f"C = {fit['C']:.4g} +- {fit['C_err']:.2g}, k = {fit['k']:.4g} +- {fit['k_err']:.2g} "
                    f"(rms relative residual {fit['rms_rel_residual']:.3g}; {study['n_fitted']} widths fitted)")
    else:
        head.append(f"no fit: {study['n_fitted']} width(s) discharged without clogging (2 needed)")
    csv_path = out / "beverloo.csv"
    with open(csv_path, "w", newline="") as f:
        for h in head:
            f.write(f"# {h}\n")
        w = csv.writer(f)
        w.writerow(cols)
        for t in study["table"]:
            w.writerow([("" if (isinstance(t.get(c), float) and not math.isfinite(t[c])) else
                         (f"{t[c]:.6g}" if isinstance(t.get(c), float) else t.get(c, ""))) for c in cols])
    md = [f"# {title}", "", "W = C rho_b sqrt(g) L (b - k d)^(3/2)", ""] + [f"- {h}" for h in head] + [""]
    md.append("| outlet width b (mm) | flow rate (kg/s) | bulk density (kg/m3) | clogged | status | Beverloo fit (kg/s) | deviation |")
    md.append("|---|---|---|---|---|---|---|")
    for t in study["table"]:
        def fm(v, fmt):
            return fmt.format(v) if isinstance(v, float) and math.isfinite(v) else "-"
        md.append(f"| {t['outlet_width'] * 1e3:.4g} | {fm(t['mass_flow_rate'], '{:.4g}')} | "
                  f"{fm(t['bulk_density'], '{:.4g}')} | {t['clogged']} | {t['status']} | "
                  f"{fm(t.get('beverloo_rate', math.nan), '{:.4g}')} | {fm(t.get('deviation', math.nan), '{:+.1%}')} |")
    md_path = out / "beverloo.md"
    md_path.write_text("\n".join(md) + "\n")
    files = [csv_path, md_path]
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        from .measure.silo import beverloo_rate

        fig, ax = plt.subplots(figsize=(6, 4.2))
        tb = study["table"]
        ok = [t for t in tb if math.isfinite(t["mass_flow_rate"]) and not t["clogged"]]
        cl = [t for t in tb if t["clogged"]]
        ax.plot([t["outlet_width"] * 1e3 for t in ok], [t["mass_flow_rate"] * 1e3 for t in ok], "o", label="simulated")
        if cl:
            ax.plot([t["outlet_width"] * 1e3 for t in cl], [0.0] * len(cl), "x", color="r", label="clogged")
        if fit:
            bmin = max(fit["k"] * study["d"], 0.0)
            bb = np.linspace(bmin, max(t["outlet_width"] for t in tb) * 1.1, 200)
            ax.plot(bb * 1e3, beverloo_rate(bb, fit["C"], fit["k"], study["rho_b"], study["L"], study["d"],
                                            study["g"]) * 1e3, "-",
                    label=f"Beverloo fit C = {fit['C']:.3g}, k = {fit['k']:.3g}")
        ax.set_xlabel("outlet width b (mm)")
        ax.set_ylabel("mass flow rate (g/s)")
        ax.set_title(title)
        ax.grid(alpha=0.3)
        ax.legend()
        fig.tight_layout()
        png = out / "beverloo.png"
        fig.savefig(png, dpi=120)
        plt.close(fig)
        files.append(png)
    except ImportError:  # pragma: no cover - matplotlib is a dependency
        pass
    return files


def run_beverloo_study(case, widths: list[float], out=None, *, common=None, scheduler=None, workers=None,
                       threads=None, echo=print) -> dict:
    """Run ``case`` at each outlet width (m) and fit the Beverloo law (module doc)."""
    from .config import case_file, load_case
    from .sweep import run_sweep

    if len(widths) < 2:
        raise CaseError("--widths", "give at least two outlet widths")
    if any(not (b > 0) for b in widths):
        raise CaseError("--widths", f"outlet widths must be positive, got {widths}")
    base = load_case(case, overrides=list(common or []))
    if base.geometry.type != "silo":
        raise CaseError("geometry.type", f"'{base.geometry.type}': the Beverloo study needs a silo case")
    if base.silo.walls == "mesh":
        raise CaseError("silo.walls", "'mesh': the study varies silo.outlet_width and the slot of the mesh walls is "
                                      "fixed in their files; run it on an analytic silo")
    case_dir = case_file(case).parent.resolve()
    out = Path(out).resolve() if out is not None else case_dir / "beverloo"
    variants = [{"silo.outlet_width": float(b)} for b in widths]
    rows = run_sweep(case, variants, out, common=common, scheduler=scheduler, workers=workers, threads=threads,
                     chart="mass_flow_rate", echo=echo)
    study = beverloo_table(rows, None, base.silo.depth, base.particles.diameter, base.gravity.g)
    files = write_beverloo_outputs(study, out, title=f"Beverloo study of {case_dir.name}")
    if echo:
        f = study["fit"]
        echo(f"beverloo: C = {f['C']:.4g}, k = {f['k']:.4g} (rho_b = {study['rho_b']:.4g} kg/m3)" if f else
             "beverloo: no fit (fewer than two widths discharged)")
        echo("beverloo: " + ", ".join(str(p) for p in files))
    study["files"] = files
    study["rows"] = rows
    return study


def add_beverloo_parser(subparsers):
    s = subparsers.add_parser("beverloo", help="silo: flow rate against outlet width with a fitted Beverloo law",
                              description="Run a silo case at several outlet widths (Dask, as cfddem sweep) and "
                                          "fit W = C rho_b sqrt(g) L (b - k d)^1.5; writes beverloo.csv/.md/.png.")
    s.add_argument("case", help="silo case folder or case.toml")
    s.add_argument("--widths", required=True, metavar="B1,B2,...", help="outlet widths (m), comma-separated")
    s.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a key in every run (as for cfddem run)")
    s.add_argument("--out", help="study folder (default: CASE/beverloo)")
    s.add_argument("--scheduler", metavar="ADDRESS", help="submit to an existing Dask cluster")
    s.add_argument("--workers", type=int, help="local worker processes (default: min(widths, cores))")
    s.add_argument("--threads", type=int, help="numba threads per run (default: cores // workers)")
    return s


def run_beverloo_from_args(args) -> int:
    try:
        widths = [float(x) for x in args.widths.split(",") if x.strip()]
    except ValueError:
        raise CaseError("--widths", f"{args.widths!r}: expected numbers separated by commas") from None
    study = run_beverloo_study(args.case, widths, args.out, common=args.overrides, scheduler=args.scheduler,
                               workers=args.workers, threads=args.threads)
    return 0 if study["fit"] is not None else 3


def write_silo_plots(h5, out) -> list[Path]:
    """Two PNGs of a finished silo run: ``silo_discharge.png`` (discharged mass against time,
    the fitted line over its window) and ``silo_field.png`` (the time-averaged speed on the x-y
    grid with velocity arrows and the flow-channel boundary; not drawn before any velocity
    sample, e.g. when the gate never opened)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .io.results import read_measurements

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    m = read_measurements(h5)
    s = m["silo"]
    files = []
    fig, ax = plt.subplots(figsize=(6, 4))
    t, mm = s["discharge_time"], s["discharge_mass"]
    ax.plot(t, mm * 1e3, "-", label="discharged")
    rate = float(m["mass_flow_rate"])
    t_lo, t_hi, m_lo, m_hi = s["fit_window"]
    if math.isfinite(rate):
        sel = (t >= t_lo) & (t <= t_hi)
        c = float(np.mean(mm[sel] - rate * t[sel]))
        tt = np.array([t_lo, t_hi])
        ax.plot(tt, (rate * tt + c) * 1e3, "--", lw=2, label=f"fit: {rate * 1e3:.1f} g/s")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("discharged mass (g)")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    files.append(out / "silo_discharge.png")
    fig.savefig(files[-1], dpi=110)
    plt.close(fig)
    f = s["field"]
    if not np.any(np.isfinite(f["vx"])):  # no velocity sample yet (the gate never opened)
        return files
    x, y, vx, vy = f["x"], f["y"], f["vx"], f["vy"]
    speed = np.hypot(vx, vy)
    fig, ax = plt.subplots(figsize=(4.5, 6))
    ext = [x[0] - 0.5 * (x[1] - x[0]), x[-1] + 0.5 * (x[1] - x[0]), y[0] - 0.5 * (y[1] - y[0]),
           y[-1] + 0.5 * (y[1] - y[0])]
    im = ax.imshow(np.ma.masked_invalid(speed), origin="lower", extent=[e * 1e3 for e in ext], aspect="equal",
                   cmap="viridis")
    fig.colorbar(im, ax=ax, label="mean speed (m/s)", shrink=0.6)
    X, Y = np.meshgrid(x, y)
    ok = np.isfinite(vx)
    ax.quiver(X[ok] * 1e3, Y[ok] * 1e3, vx[ok], vy[ok], color="w", scale=None, width=0.003)
    ch = s["channel"]
    ax.plot(ch["x_left"] * 1e3, ch["y"] * 1e3, "r-", lw=1.5, label=f"channel ({float(ch['fraction']):g} of centre)")
    ax.plot(ch["x_right"] * 1e3, ch["y"] * 1e3, "r-", lw=1.5)
    top = float(np.nanmax(np.where(f["count"] > 0, Y, np.nan))) if np.any(f["count"] > 0) else y[-1]
    ax.set_ylim(ext[2] * 1e3, (top + (y[1] - y[0])) * 1e3)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    files.append(out / "silo_field.png")
    fig.savefig(files[-1], dpi=110)
    plt.close(fig)
    return files
