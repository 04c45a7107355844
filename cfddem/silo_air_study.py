"""Silo discharge of fine beads with and without air against the bead diameter (issue #20,
docs/silo-air.md):

    python -m cfddem.silo_air_study run OUT [--diameters 0.125,0.25,0.5,1,2] [--replicas 3]
                                            [--replicas-at D1,..] [--workers 2] [--case cases/silo_air]
    python -m cfddem.silo_air_study report OUT

``run`` runs ``cases/silo_air`` at each bead diameter d (mm) with and without air, the silo
SCALED WITH d (:func:`scaled_overrides`: every length in units of d, the same particle count,
k_n ~ d^2 so that the overlap / d under the hydrostatic load is the same, every time ~ sqrt(d),
so the step count is the same for every d; the gas grid has the same cells, so its cells are
the same in units of d).  The air is not scaled (its density and viscosity are air's): it is the
one thing that breaks the similarity.  Without air the dimensionless flow rate

    W* = W / (rho_b sqrt(g) L (b - k d)^1.5)        (2D slot Beverloo, k = 1.5 fixed)

must then be independent of d (``report`` checks it); with air it falls as d shrinks: the
bed's permeability ~ d^2 (Ergun), so the Darcy velocity u_D = k_perm rho_b g / mu that the
weight of the bed can drive through it falls against the discharge speed sqrt(g b) as d^1.5.
At the ``--replicas-at`` diameters (default: all) the runs are repeated with ``--replicas`` fills in all
(``particles.seed`` the case's, then +1, +2, ...): their scatter gives the error bars.  Each
diameter is one sweep (:func:`cfddem.sweep.run_sweep`, Dask, one run folder per variant,
finished runs reused) in ``OUT/d=<d>mm``.

``report`` reads every run and writes into OUT: ``silo_air.csv`` (one row per run),
``silo_air.md`` (per diameter: W with and without air, their ratio, W*, the Beverloo rate, the
Darcy ratio, the outlet budget of the runs with air: the air's force on the particles within
b/2, b and 2 b of the slot centre against their weight, and the air that flows through the slot
and through the open top against the particles' volume flow; wall times), ``silo_air_flow.png`` (W against d with and
without air and the Beverloo line, log axes; W_air / W_noair against d) and
``silo_air_outlet.png`` (the outlet budget against d).  Since b / d is the same for every run,
only C (b/d - k)^1.5 is determined: k is fixed at 1.5 and C fitted to the runs without air.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import tomllib
from pathlib import Path

import numpy as np

from .errors import CaseError
from .measure.stats import mean_sd
from .silo_prisms import _floats, _plt, _save

CASE = Path(__file__).resolve().parent.parent / "cases" / "silo_air"
DIAMETERS_MM = (0.125, 0.25, 0.5, 1.0, 2.0)
BEVERLOO_K = 1.5

#: keys scaled by a length factor f: lengths x f, times x sqrt(f), stiffness x f^2, ...
LENGTHS = ("particles.diameter", "particles.skin", "silo.width", "silo.depth", "silo.height", "silo.outlet_width",
           "silo.lip", "silo.removal_depth", "silo.field_cell", "silo.pour_height")
TIMES = ("time.dt", "time.end_time", "output.series_interval", "output.snapshot_interval", "output.vtk_interval",
         "silo.gate_time", "silo.settle_check_interval", "silo.clog_time", "silo.field_interval", "silo.field_start")
WALL_GROUPS = ("contact.particle_particle", "contact.particle_wall", "silo.front_back", "silo.sides", "silo.bottom",
               "silo.gate_wall")
POWERS = {**dict.fromkeys(LENGTHS, 1.0), **dict.fromkeys(TIMES, 0.5),
          **{f"{g}.k_n": 2.0 for g in WALL_GROUPS},  # k_n ~ d^2: the same overlap / d under rho g H d^2
          **{f"{g}.E": 1.0 for g in WALL_GROUPS},  # Hertz: E sqrt(R) delta^1.5 ~ d^3 needs E ~ d
          "silo.settle_energy": 4.0,  # m g d
          "silo.clog_speed": 0.5, "silo.pour_rate": 2.5}
#: dimensional keys the scaling leaves as they are (the air, gravity, the material density, wall-clock)
KEPT = ("gravity.g", "particles.density", "gas.density", "gas.viscosity", "time.wall_time_limit",
        "output.progress_interval", "checkpoint.wall_interval")


def _get(d: dict, key: str):
    for p in key.split("."):
        if not isinstance(d, dict) or p not in d:
            return None
        d = d[p]
    return d


def _unit(key: str) -> str:
    from .config import SCHEMA

    spec = _get(SCHEMA, key)
    return getattr(spec, "unit", "-") if spec is not None else "-"


def _set_keys(raw: dict, prefix: str = "") -> list[str]:
    out = []
    for k, v in raw.items():
        if isinstance(v, dict):
            out += _set_keys(v, f"{prefix}{k}.")
        else:
            out.append(prefix + k)
    return out


def scaled_overrides(case, factor: float) -> dict:
    """Overrides that scale the silo case ``case`` (a loaded :class:`~cfddem.config.Case`) to
    particles ``factor`` times larger, keeping its dimensionless state: each key of
    :data:`POWERS` present in the case times factor^power (lengths 1, times 1/2, k_n 2, E 1,
    settle_energy 4, ...).  A dimensional key set in the case file that is neither scaled nor
    in :data:`KEPT` is refused (CaseError): the scaling would silently break the similarity."""
    if not factor > 0:
        raise CaseError("--diameters", f"scale factor {factor!r} must be positive")
    raw = tomllib.loads(case.raw_text) if case.raw_text else {}
    for k in _set_keys(raw) + list(case.overrides):
        u = _unit(k)
        if u not in ("-", "", "deg", "d") and k not in POWERS and k not in KEPT:
            raise CaseError(k, f"({u}) is set in the case and the diameter scaling does not know how to scale it")
    out = {}
    for k, p in POWERS.items():
        v = _get(case.resolved, k)
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            out[k] = float(v) * factor ** p
    return out


def variants(seed: int, replicas: int) -> list[dict]:
    return [{"gas.enabled": gas, "particles.seed": seed + i} for i in range(replicas) for gas in (True, False)]


def run_study(out, diameters_mm, replicas_at=(), replicas: int = 3, case=CASE, workers: int = 2,
              echo=print) -> list[dict]:
    from .config import load_case
    from .sweep import run_sweep

    base = load_case(case)
    d0 = base.particles.diameter
    rows = []
    for dmm in diameters_mm:
        f = dmm * 1e-3 / d0
        common = dict(scaled_overrides(base, f), **{"study.compare_without_gas": False, "output.vtk": False,
                                                     "output.plots": False})
        n = replicas if any(math.isclose(dmm, r, rel_tol=1e-9) for r in replicas_at) else 1
        echo(f"silo_air_study: d = {dmm:g} mm (scale {f:g}), {n} fill(s), with and without air")
        rows += run_sweep(case, variants(base.particles.seed, n), Path(out) / f"d={dmm:g}mm", common=common,
                          workers=workers, threads=1, chart="mass_flow_rate", echo=echo)
    return rows


# ---------------------------------------------------------------------------------------------- report
def ergun_permeability(d: float, eps: float) -> float:
    """k = d^2 eps^3 / (150 (1 - eps)^2) (m^2)."""
    return d * d * eps ** 3 / (150.0 * (1.0 - eps) ** 2)


def read_run(run_dir) -> dict | None:
    """One finished run folder: d, gas, seed, W, rho_b, the outlet budget (runs with air),
    wall time; None if it has no results or is still running."""
    from .io.results import read_measurements

    run_dir = Path(run_dir)
    h5 = run_dir / "results.h5"
    r = json.loads((run_dir / "run.json").read_text()) if (run_dir / "run.json").is_file() else {}
    if not h5.is_file() or r.get("status", "running") == "running":
        return None  # (opening a file that a run is writing would lock it out of its own file)
    import h5py

    with h5py.File(h5, "r") as f:
        cfg = json.loads(f["config/resolved.json"][()])
    m = read_measurements(h5)
    s = cfg["silo"]
    row = {"run": run_dir.name, "d": cfg["particles"]["diameter"], "gas": bool(cfg["gas"]["enabled"]),
           "seed": int(cfg["particles"]["seed"]), "b": s["outlet_width"], "L": s["depth"], "g": cfg["gravity"]["g"],
           "rho_p": cfg["particles"]["density"], "mu": cfg["gas"]["viscosity"],
           "W": float(m.get("mass_flow_rate", math.nan)), "rho_b": float(m.get("bulk_density", math.nan)),
           "clogged": int(np.asarray(m.get("clogged", 0))), "status": r.get("status", ""),
           "wall": float(r.get("wall_time", math.nan) or math.nan)}
    sm = m.get("silo", {})
    dm = np.asarray(sm.get("discharge_mass", []), float)
    m_fill = int(np.asarray(sm.get("fill_particles", 0))) * row["rho_p"] * math.pi / 6 * row["d"] ** 3
    row["discharged_fraction"] = float(dm[-1] / m_fill) if len(dm) and m_fill > 0 else math.nan
    o = sm.get("outlet")
    if o is not None:
        rb = np.asarray(o["radii_in_slot_widths"], float)
        for i, x in enumerate(rb):
            for k in ("drag", "pressure", "weight", "air_force_ratio"):
                row[f"{k}_r{x:g}"] = float(np.asarray(o[f"mean_{k}"])[i])
        row.update(q_slot=float(o["mean_q_slot"]), q_top=float(o["mean_q_top"]), q_particles=float(o["q_particles"]),
                   slot_air_ratio=float(o["slot_air_ratio"]))
    return row


def find_runs(out) -> list[dict]:
    rows = [read_run(p.parent) for p in sorted(Path(out).glob("d=*mm/*/results.h5"))]
    return [r for r in rows if r is not None]


def _flowed(r: dict) -> bool:
    """A steady flow rate was measured.  A flat-bottomed silo ends with heaps, and a bead left
    lying in the slot's x range below 2 d at the end flags the run 'clogged' after the
    discharge; the rate is the fit over fit_range of what did discharge either way."""
    return math.isfinite(r["W"]) and r["W"] > 0


def dimensionless_rate(r: dict, k: float = BEVERLOO_K) -> float:
    """W / (rho_b sqrt(g) L (b - k d)^1.5) with the run's own bulk density."""
    return r["W"] / (r["rho_b"] * math.sqrt(r["g"]) * r["L"] * max(r["b"] - k * r["d"], 0.0) ** 1.5)


def fit_beverloo_c(rows: list[dict], k: float = BEVERLOO_K) -> dict:
    """C of W = C rho_b sqrt(g) L (b - k d)^1.5 with k fixed: the geometric mean of the runs'
    W* (least squares in log W); its standard error; and the exponent n of a power law W ~ d^n
    fitted in log-log (2.5 for the scaled silo when W* does not depend on d)."""
    ws = np.array([dimensionless_rate(r, k) for r in rows])
    ok = np.isfinite(ws) & (ws > 0)
    lw = np.log(ws[ok])
    C = float(np.exp(lw.mean())) if ok.any() else math.nan
    err = float(C * lw.std(ddof=1) / math.sqrt(ok.sum())) if ok.sum() > 1 else math.nan
    d = np.array([r["d"] for r in rows])[ok]
    W = np.array([r["W"] for r in rows])[ok]
    n = float(np.polyfit(np.log(d), np.log(W), 1)[0]) if len(set(d)) > 1 else math.nan
    return {"C": C, "C_err": err, "k": k, "exponent": n, "n_runs": int(ok.sum())}


def diameter_table(runs: list[dict], fit: dict) -> list[dict]:
    """One row per diameter: means (std, count) of W with and without air, the ratio and its
    standard error (from the replicas' spreads, the runs not paired), W*, the Beverloo rate,
    Darcy velocity / discharge speed, the outlet budget (runs with air, R = 1 slot width)."""
    table = []
    for d in sorted({r["d"] for r in runs}):
        ra = [r for r in runs if r["d"] == d and r["gas"] and _flowed(r)]
        rn = [r for r in runs if r["d"] == d and not r["gas"] and _flowed(r)]
        if not ra and not rn:
            continue  # nothing finished at this diameter (yet)
        wa, sa, na = mean_sd([r["W"] for r in ra])
        wn, sn, nn = mean_sd([r["W"] for r in rn])
        ratio = wa / wn if wn > 0 else math.nan
        rel = [s / w / math.sqrt(n) for s, w, n in ((sa, wa, na), (sn, wn, nn)) if n > 1 and math.isfinite(s)]
        ratio_err = ratio * math.sqrt(sum(x * x for x in rel)) if len(rel) == 2 else math.nan
        rho_b, _, _ = mean_sd([r["rho_b"] for r in rn + ra])
        r0 = (rn + ra)[0]
        eps = 1.0 - rho_b / r0["rho_p"]
        u_d = ergun_permeability(d, eps) * rho_b * r0["g"] / r0["mu"]
        bev = fit["C"] * rho_b * math.sqrt(r0["g"]) * r0["L"] * max(r0["b"] - fit["k"] * d, 0.0) ** 1.5
        row = {"d_mm": d * 1e3, "W_air": wa, "W_air_std": sa, "n_air": na, "W_noair": wn, "W_noair_std": sn,
               "n_noair": nn, "ratio": ratio, "ratio_err": ratio_err, "Wstar_air": mean_sd(
                   [dimensionless_rate(r) for r in ra])[0], "Wstar_noair": mean_sd([dimensionless_rate(r) for r in rn])[0],
               "W_beverloo": bev, "rho_b": rho_b, "darcy_ratio": u_d / math.sqrt(r0["g"] * r0["b"]),
               "discharged": mean_sd([r["discharged_fraction"] for r in ra + rn])[0],
               "wall_air": mean_sd([r["wall"] for r in ra])[0], "wall_noair": mean_sd([r["wall"] for r in rn])[0]}
        for k in ("air_force_ratio_r0.5", "air_force_ratio_r1", "air_force_ratio_r2", "drag_r0.5", "pressure_r0.5",
                  "weight_r0.5", "slot_air_ratio", "q_slot", "q_top", "q_particles"):
            row[k] = mean_sd([r.get(k, math.nan) for r in ra])[0]
        row["top_air_ratio"] = -row["q_top"] / row["q_particles"] if row["q_particles"] > 0 else math.nan
        table.append(row)
    return table


def scaling_check(table: list[dict], tol: float) -> dict:
    """Whether W* without air is the same at every diameter: the largest relative deviation
    from their mean, against ``tol``."""
    w = np.array([t["Wstar_noair"] for t in table if math.isfinite(t["Wstar_noair"])])
    dev = float(np.max(np.abs(w / w.mean() - 1.0))) if len(w) else math.nan
    return {"max_deviation": dev, "tol": tol, "ok": bool(len(w) > 1 and dev <= tol)}


COLUMNS = [("d_mm", "d (mm)", "{:g}"), ("W_noair", "W no air (g/s)", "{:.4g}"), ("W_air", "W air (g/s)", "{:.4g}"),
           ("ratio", "W_air / W_noair", "{:.3f}"), ("ratio_err", "+-", "{:.3f}"), ("n_air", "fills", "{:d}"),
           ("Wstar_noair", "W* no air", "{:.3f}"), ("Wstar_air", "W* air", "{:.3f}"),
           ("W_beverloo", "Beverloo (g/s)", "{:.4g}"), ("darcy_ratio", "u_D / sqrt(g b)", "{:.3g}"),
           ("air_force_ratio_r0.5", "air force / weight, R = b/2", "{:.4f}"),
           ("air_force_ratio_r1", "R = b", "{:.4f}"), ("air_force_ratio_r2", "R = 2 b", "{:.4f}"),
           ("slot_air_ratio", "air up through slot / bead volume flow", "{:.2f}"),
           ("top_air_ratio", "air down through top / bead volume flow", "{:.2f}"),
           ("discharged", "discharged fraction", "{:.2f}"), ("wall_air", "wall air (s, loaded)", "{:.0f}"),
           ("wall_noair", "wall no air (s, loaded)", "{:.0f}")]
GRAMS = ("W_noair", "W_air", "W_beverloo")


def _pooled(table: list[dict], key: str) -> float:
    """sqrt of the mean squared relative standard deviation of ``key`` over the rows with a std."""
    rel = [t[f"{key}_std"] / t[key] for t in table if math.isfinite(t.get(f"{key}_std", math.nan))]
    return math.sqrt(sum(r * r for r in rel) / len(rel)) if rel else math.nan


def _cell(t: dict, key: str, fmt: str) -> str:
    v = t.get(key, math.nan)
    if isinstance(v, float) and not math.isfinite(v):
        return "-"
    return fmt.format(v * 1e3 if key in GRAMS else v)


def write_report(out, tol: float = 0.05) -> tuple[list[Path], dict]:
    """``silo_air.csv`` (one row per run), ``silo_air.md`` (one row per diameter),
    ``silo_air_flow.png`` and ``silo_air_outlet.png`` in ``out`` (module doc); returns the
    files and :func:`scaling_check`."""
    out = Path(out)
    runs = find_runs(out)
    if not runs:
        raise CaseError("report", f"no finished runs under {out}/d=*mm/")
    fit = fit_beverloo_c([r for r in runs if not r["gas"] and _flowed(r)])
    fit_air = fit_beverloo_c([r for r in runs if r["gas"] and _flowed(r)])
    table = diameter_table(runs, fit)
    check = scaling_check(table, tol)
    keys = list(dict.fromkeys(k for r in runs for k in r))
    with open(out / "silo_air.csv", "w", newline="") as f:
        w = csv.DictWriter(f, keys)
        w.writeheader()
        w.writerows(runs)
    md = ["# Silo discharge of fine beads with and without air (silo scaled with d)", "",
          f"- Beverloo, 2D slot, k = {fit['k']:g} fixed (b / d = {runs[0]['b'] / runs[0]['d']:g} in every run: "
          f"only C (b/d - k)^1.5 is determined): C = {fit['C']:.4g} +- {fit['C_err']:.2g} from {fit['n_runs']} runs "
          "without air",
          f"- power law W ~ d^n: n = {fit['exponent']:.3f} without air (2.5 if W* does not depend on d), "
          f"n = {fit_air['exponent']:.3f} with air",
          f"- fill-to-fill scatter of W (relative standard deviation, pooled over the diameters with more than one "
          f"fill): {_pooled(table, 'W_noair'):.1%} without air, {_pooled(table, 'W_air'):.1%} with air",
          f"- scaling check: W* without air the same at every d within {tol:.0%}: largest deviation "
          f"{check['max_deviation']:.1%}, {'PASS' if check['ok'] else 'FAIL'}",
          "- W* = W / (rho_b sqrt(g) L (b - 1.5 d)^1.5), rho_b measured at the gate opening; +- the standard error "
          "of the ratio from the fills' scatter (the runs with and without air are not paired); "
          "u_D = k_Ergun rho_b g / mu; outlet: the air's drag and pressure force on the beads within R of the slot "
          "centre (up) over their weight, and the air drawn in through the slot over the beads' volume flow W / rho_p",
          "", "| " + " | ".join(c[1] for c in COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    md += ["| " + " | ".join(_cell(t, k, f) for k, _, f in COLUMNS) + " |" for t in table]
    (out / "silo_air.md").write_text("\n".join(md) + "\n")
    files = [out / "silo_air.csv", out / "silo_air.md", _flow_chart(table, runs, fit, out / "silo_air_flow.png"),
             _outlet_chart(table, out / "silo_air_outlet.png")]
    return files, check


def _flow_chart(table, runs, fit, path: Path) -> Path:
    plt = _plt()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4.2))
    for gas, mk, lab in ((False, "s", "without air"), (True, "o", "with air")):
        rr = [r for r in runs if r["gas"] == gas and _flowed(r)]
        a1.plot([r["d"] * 1e3 for r in rr], [r["W"] * 1e3 for r in rr], mk, mfc="none", label=f"{lab} (each fill)")
    d = np.array([t["d_mm"] for t in table]) * 1e-3
    r0 = runs[0]
    dd = np.geomspace(d.min() / 1.3, d.max() * 1.3, 50)
    rho_b = float(np.nanmean([t["rho_b"] for t in table]))
    bev = fit["C"] * rho_b * math.sqrt(r0["g"]) * (r0["L"] / r0["d"] * dd) * ((r0["b"] / r0["d"] - fit["k"]) * dd) ** 1.5
    a1.plot(dd * 1e3, bev * 1e3, "k-", lw=1, label=f"Beverloo C = {fit['C']:.3g}, k = {fit['k']:g} (fit, no air)")
    _d_ticks(a1, [t["d_mm"] for t in table])
    a1.set_yscale("log")
    a1.set_xlabel("bead diameter d (mm); silo scaled with d")
    a1.set_ylabel("mass flow rate W (g/s)")
    a1.grid(alpha=0.3, which="both")
    a1.legend(fontsize=8)
    x = [t["d_mm"] for t in table]
    y = [t["ratio"] for t in table]
    e = [t["ratio_err"] if math.isfinite(t["ratio_err"]) else 0.0 for t in table]
    a2.errorbar(x, y, yerr=e, fmt="o-", capsize=4, label="W_air / W_noair (bars: replicas' standard error)")
    a2.axhline(1.0, color="k", lw=0.8)
    _d_ticks(a2, x)
    a2.set_xlabel("bead diameter d (mm)")
    a2.set_ylabel("W with air / W without")
    a2.grid(alpha=0.3, which="both")
    a2.legend(fontsize=8)
    top = a2.secondary_xaxis("top", functions=(lambda v: v, lambda v: v))
    from matplotlib.ticker import NullFormatter, NullLocator

    top.set_xticks(x)
    top.set_xticklabels([f"{t['darcy_ratio']:.2g}" for t in table], fontsize=7)
    top.xaxis.set_minor_locator(NullLocator())
    top.xaxis.set_minor_formatter(NullFormatter())
    top.set_xlabel("u_D / sqrt(g b)", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _d_ticks(ax, x) -> None:
    """Log x axis with a tick at each diameter (mm), no minor labels."""
    from matplotlib.ticker import FixedLocator, NullFormatter, NullLocator

    ax.set_xscale("log")
    ax.xaxis.set_major_locator(FixedLocator(list(x)))
    ax.xaxis.set_major_formatter(lambda v, _: f"{v:g}")
    ax.xaxis.set_minor_locator(NullLocator())
    ax.xaxis.set_minor_formatter(NullFormatter())


def _against_d(ax, x, ylabel: str, title: str = "") -> None:
    """A panel against the bead diameter: log x, the zero line, labels, grid, legend."""
    ax.axhline(0.0, color="k", lw=0.8)
    _d_ticks(ax, x)
    ax.set_xlabel("bead diameter d (mm)")
    ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)


def _outlet_chart(table, path: Path) -> Path:
    plt = _plt()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4.0))
    x = [t["d_mm"] for t in table]
    for key, lab in (("air_force_ratio_r0.5", "R = b/2"), ("air_force_ratio_r1", "R = b"), ("air_force_ratio_r2", "R = 2 b")):
        a1.plot(x, [t[key] for t in table], "o-", label=lab)
    ref = [t for t in table if math.isclose(t["d_mm"], 1.0)] or table[-1:]
    if ref and math.isfinite(ref[0]["air_force_ratio_r0.5"]):
        xx = np.geomspace(min(x), max(x), 50)
        a1.plot(xx, ref[0]["air_force_ratio_r0.5"] * (xx / ref[0]["d_mm"]) ** -1.5, "k--", lw=0.8,
                label="~ d^-1.5 (Darcy: ~ sqrt(g b) / u_D)")
    _against_d(a1, x, "air force on the beads (up) / their weight", "beads within R of the slot centre")
    a2.plot(x, [t["slot_air_ratio"] for t in table], "o-", label="through the slot (up into the silo)")
    a2.plot(x, [t["top_air_ratio"] for t in table], "s-",
            label="through the open top (down into the silo)")
    _against_d(a2, x, "air volume flow / beads' volume flow", "where the air that replaces the beads comes from")
    return _save(fig, path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m cfddem.silo_air_study", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="run the scaled silo at each diameter with and without air")
    r.add_argument("out", help="study folder")
    r.add_argument("--diameters", default=",".join(f"{d:g}" for d in DIAMETERS_MM), help="bead diameters (mm)")
    r.add_argument("--replicas-at", help="diameters (mm) run with --replicas fills (default: every diameter)")
    r.add_argument("--replicas", type=int, default=3, help="fills at the --replicas-at diameters (default 3)")
    r.add_argument("--workers", type=int, default=2, help="runs at once (1 numba thread each; default 2)")
    r.add_argument("--case", default=str(CASE), help="the silo case (default cases/silo_air)")
    p = sub.add_parser("report", help="tables and charts of a finished study")
    p.add_argument("out", help="study folder")
    p.add_argument("--tol", type=float, default=0.05,
                   help="largest relative deviation of W* without air between diameters (default 0.05)")
    args = ap.parse_args(argv)
    try:
        if args.cmd == "run":
            if args.replicas < 1:
                raise CaseError("--replicas", f"{args.replicas} must be at least 1")
            ds = _floats(args.diameters, "--diameters")
            at = _floats(args.replicas_at, "--replicas-at") if args.replicas_at is not None else ds
            rows = run_study(args.out, ds, at, args.replicas, args.case, args.workers)
            return 0 if all(x.get("status") in ("done", "skipped") for x in rows) else 3
        files, check = write_report(args.out, args.tol)
    except CaseError as e:
        print(f"cfddem: error: {e}", file=sys.stderr)
        return 2
    print("silo_air_study: " + ", ".join(str(f) for f in files))
    print(f"scaling check (W* without air the same at every d within {check['tol']:.0%}): "
          f"largest deviation {check['max_deviation']:.1%}: {'PASS' if check['ok'] else 'FAIL'}")
    return 0 if check["ok"] else 4


if __name__ == "__main__":
    raise SystemExit(main())
