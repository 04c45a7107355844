"""The three studies of the spheropolygon hopper-silo paper on ``cases/silo_prisms`` (issue #22,
docs/silo-prisms.md; set-up in silo-studies.md §1):

    python -m cfddem.silo_prisms silos       [--replicas N] [--out DIR] [--set K=V]...
    python -m cfddem.silo_prisms clogging    [--replicas N] [--angles A,..] [--widths B,..] ...
    python -m cfddem.silo_prisms sensitivity [--replicas N] ...

* ``silos``: the 16 silos, hopper walls at 60, 45, 30 deg from the horizontal and flat (0),
  outlets 40, 60, 100, 150 mm; per silo the discharge time (``/measurements/silo/
  discharge_duration``: gate opening to the last discharged particle; a flat bottom keeps its
  heaps, so this is when the last particle left) of the runs that did not clog, and how many
  clogged.  Chart: discharge time against outlet width, one line per hopper angle, log axis.
* ``clogging``: the same silos at the outlets where they clog (default 40 and 60 mm, all four
  angles), ``--replicas`` fills each (``particles.seed`` 1..N: another jitter of the fill
  lattice); the clogging frequency with its 95 % Wilson interval.  Chart: frequency against
  b/d per angle, the interval as error bars.
* ``sensitivity``: the 60 deg / 150 mm silo with one parameter changed at a time: k_n x1/16,
  x1/4, x4 (the time step scaled by 1/sqrt of the factor), k_t/k_n 0.05-0.5, particle-particle
  friction 0.1-0.5, restitution 0.02-0.86 (particle-particle and particle-wall), tangential
  damping per unit mass 0-100 1/s (turned into e_t per contact table: :func:`e_t_for_damping`).
  Chart: discharge time against each parameter, the base value marked.

Each study is a sweep (:func:`cfddem.sweep.run_sweep`: Dask, one run folder per variant, finished
runs reused) into ``--out`` (default ``cases/silo_prisms/<study>``) and writes
``<study>.csv``, ``<study>.md`` and ``<study>.png`` there besides the sweep's own summary.
``--set`` applies to every run (e.g. a softer k_n with its time step for cheaper replicas).
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from pathlib import Path

import numpy as np

from .errors import CaseError

CASE = Path(__file__).resolve().parent.parent / "cases" / "silo_prisms"
ANGLES = (60.0, 45.0, 30.0, 0.0)
WIDTHS = (0.04, 0.06, 0.10, 0.15)
PP, PW = "contact.particle_particle.", "contact.particle_wall."


def e_t_for_damping(gamma_t: float, m_eff: float, k_t: float) -> float:
    """The linear law's e_t that gives the tangential damping eta_t = gamma_t m* (a damping
    'per unit mass' gamma_t in 1/s, as DEM papers state it): c_t = eta_t / sqrt(m* k_t) =
    gamma_t sqrt(m*/k_t), and c_t = 2 L sqrt(2/7) / sqrt(pi^2 + L^2) with L = -ln e_t, so
    L = c_t pi / sqrt(8/7 - c_t^2)."""
    c = gamma_t * math.sqrt(m_eff / k_t)
    if not c * c < 8.0 / 7.0:
        raise CaseError("tangential damping", f"{gamma_t:g} 1/s is beyond critical for m* = {m_eff:.3g} kg, "
                                              f"k_t = {k_t:.3g} N/m")
    return math.exp(-c * math.pi / math.sqrt(8.0 / 7.0 - c * c))


def _seeds(n: int) -> list[int]:
    if n < 1:
        raise CaseError("--replicas", f"{n} must be at least 1")
    return list(range(1, n + 1))


def silo_variants(angles, widths, replicas: int) -> list[dict]:
    return [{"silo.hopper_angle_deg": float(a), "silo.outlet_width": float(b), "particles.seed": s}
            for a in angles for b in widths for s in _seeds(replicas)]


def base_values(base) -> dict[str, float]:
    """The case's own value of each parameter of the sensitivity study (its point in each panel)."""
    from .particles.contact import contact_law

    pp = base.resolved["contact"]["particle_particle"]
    m = base.particles.density * math.pi / 6.0 * base.particles.diameter ** 3
    law = contact_law(pp, "linear")
    return {"k_n factor": 1.0, "k_t/k_n": law.k_t / law.k_n, "friction mu_pp": pp["mu"], "restitution e_n": pp["e_n"],
            "tangential damping (1/s)": law.derived(0.5 * m)["eta_t"] / (0.5 * m)}


def sensitivity_variants(base, replicas: int, base_replicas: int = 3) -> list[tuple[str, float, dict]]:
    """(parameter, value, overrides) of the one-at-a-time study around ``base`` (the loaded
    case); the base itself first, as ('base', 0, {}), with at least ``base_replicas`` seeds:
    their spread is the scale against which a change counts."""
    pp, pw = base.resolved["contact"]["particle_particle"], base.resolved["contact"]["particle_wall"]
    kn, dt = pp["k_n"], base.time.dt
    m = base.particles.density * math.pi / 6.0 * base.particles.diameter ** 3
    out = [("base", 0.0, {})]
    for f in (1 / 16, 1 / 4, 4.0):
        out.append(("k_n factor", f, {PP + "k_n": kn * f, PW + "k_n": pw["k_n"] * f, "time.dt": dt / math.sqrt(f)}))
    for r in (0.05, 0.1, 0.25, 0.5):
        out.append(("k_t/k_n", r, {PP + "k_t_ratio": r, PW + "k_t_ratio": r}))
    for mu in (0.1, 0.2, 0.3, 0.5):
        out.append(("friction mu_pp", mu, {PP + "mu": mu}))
    for e in (0.02, 0.2, 0.86):
        out.append(("restitution e_n", e, {PP + "e_n": e, PW + "e_n": e}))
    for g in (0.0, 30.0, 100.0):
        out.append(("tangential damping (1/s)", g, {
            PP + "e_t": e_t_for_damping(g, 0.5 * m, pp["k_t_ratio"] * pp["k_n"]) if pp["k_t_ratio"] else None,
            PW + "e_t": e_t_for_damping(g, m, pw["k_t_ratio"] * pw["k_n"]) if pw["k_t_ratio"] else None}))
    for _, _, o in out:
        if any(v is None for v in o.values()):
            raise CaseError(PP + "k_t_ratio", "the tangential-damping variants need k_t_ratio set in the case")
    return [(p, v, dict(o, **{"particles.seed": s})) for p, v, o in out
            for s in _seeds(max(replicas, base_replicas) if p == "base" else replicas)]


def _measured(row: dict) -> dict:
    m = row.get("measurements", {}) or {}

    def f(k):
        try:
            return float(m.get(k, math.nan))
        except (TypeError, ValueError):
            return math.nan

    clogged = int(f("clogged") == 1)
    # finished: the discharge ended (a clog before any particle left has no duration, NaN)
    return {"duration": f("silo/discharge_duration"), "clogged": clogged, "rate": f("mass_flow_rate"),
            "rho_b": f("bulk_density"),
            "ok": row.get("status") in ("done", "skipped") and (clogged or math.isfinite(f("silo/discharge_duration"))),
            "status": row.get("status", ""), "wall": float(row.get("wall_time", math.nan) or math.nan),
            "left": row.get("n_particles", math.nan)}


def wilson(k: int, n: int) -> tuple[float, float]:
    """95 % Wilson score interval of a frequency k/n."""
    from scipy.stats import binomtest

    ci = binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
    return float(ci.low), float(ci.high)


def group_rows(rows: list[dict], key) -> dict:
    """Rows grouped by key(row['values']) -> list of :func:`_measured`, in first-seen order."""
    groups: dict = {}
    for r in rows:
        groups.setdefault(key(r["values"]), []).append(_measured(r))
    return groups


def summarise(runs: list[dict]) -> dict:
    """n, clogged, frequency with Wilson interval, mean and std of the discharge time of the runs
    that did not clog, runs that did not finish, total wall time."""
    n = len(runs)
    done = [r for r in runs if r["ok"]]
    k = sum(r["clogged"] for r in done)
    free = [r["duration"] for r in done if not r["clogged"]]
    lo, hi = wilson(k, len(done)) if done else (math.nan, math.nan)
    return {"runs": n, "finished": len(done), "clogged": k, "clog_freq": k / len(done) if done else math.nan,
            "wilson_lo": lo, "wilson_hi": hi, "t_mean": float(np.mean(free)) if free else math.nan,
            "t_std": float(np.std(free, ddof=1)) if len(free) > 1 else math.nan,
            "t_min": min(free) if free else math.nan, "t_max": max(free) if free else math.nan,
            "left": float(np.mean([r["left"] for r in done])) if done else math.nan,
            "rate": float(np.mean([r["rate"] for r in done if not r["clogged"]])) if len(free) else math.nan,
            "rho_b": float(np.nanmean([r["rho_b"] for r in done])) if done else math.nan,
            "wall": float(np.nansum([r["wall"] for r in runs]))}


def _fmt(v, spec="{:.3g}") -> str:
    return spec.format(v) if isinstance(v, (int, float)) and math.isfinite(v) else "-"


def write_table(path_stem: Path, cols: list[tuple[str, str, str]], table: list[dict], title: str,
                notes: list[str]) -> list[Path]:
    """``stem.csv`` (full precision) and ``stem.md`` of ``table`` with columns (key, header, format)."""
    csv_path = path_stem.with_suffix(".csv")
    with open(csv_path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow([c[0] for c in cols])
        for t in table:
            w.writerow([repr(t[c[0]]) if isinstance(t[c[0]], float) else t[c[0]] for c in cols])
    md = [f"# {title}", ""] + [f"- {n}" for n in notes] + ["", "| " + " | ".join(c[1] for c in cols) + " |",
                                                             "|" + "---|" * len(cols)]
    md += ["| " + " | ".join(_fmt(t[c[0]], c[2]) if c[2] else str(t[c[0]]) for c in cols) + " |" for t in table]
    md_path = path_stem.with_suffix(".md")
    md_path.write_text("\n".join(md) + "\n")
    return [csv_path, md_path]


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path, dpi: int = 120) -> Path:
    """Lay out, write and close ``fig``."""
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    _plt().close(fig)
    return path


ANGLE_LABEL = {60.0: "hopper 60 deg", 45.0: "hopper 45 deg", 30.0: "hopper 30 deg", 0.0: "flat bottom"}


def beverloo_notes(table: list[dict], d: float, depth: float) -> list[str]:
    """Per hopper angle, the Beverloo law W = C rho_b sqrt(g) L (b - k d)^1.5 fitted to the
    steady flow rates of the outlets that did not clog (at least two; rho_b the mean bulk
    density at the gate opening, L the silo depth)."""
    from .measure.silo import fit_beverloo

    notes = []
    for a in ANGLES:
        tb = [t for t in table if t["angle"] == a and math.isfinite(t["rate"]) and t["rate"] > 0]
        rho = float(np.nanmean([t["rho_b"] for t in tb])) if tb else math.nan
        if len(tb) < 2 or not math.isfinite(rho):
            continue
        f = fit_beverloo([t["b_mm"] * 1e-3 for t in tb], [t["rate"] for t in tb], rho, depth, d)
        notes.append(f"{ANGLE_LABEL[a]}: Beverloo fit to {len(tb)} outlets: C = {f['C']:.3g}, k = {f['k']:.3g} "
                     f"(rms relative residual {f['rms_rel_residual']:.2g}; rho_b = {rho:.4g} kg/m3)")
    return notes


def silos_study(rows: list[dict], out: Path, d: float, depth: float = 0.022) -> list[Path]:
    groups = group_rows(rows, lambda v: (v["silo.hopper_angle_deg"], v["silo.outlet_width"]))
    table = [dict(angle=a, b_mm=b * 1e3, b_over_d=b / d, **summarise(r)) for (a, b), r in groups.items()]
    cols = [("angle", "hopper angle (deg from horizontal, 0 flat)", "{:g}"), ("b_mm", "outlet (mm)", "{:g}"),
            ("b_over_d", "b/d", "{:.2g}"), ("runs", "runs", ""), ("clogged", "clogged", ""),
            ("t_mean", "discharge time (s), runs that did not clog", "{:.3g}"), ("t_std", "std (s)", "{:.2g}"),
            ("rate", "steady mass flow rate (kg/s)", "{:.3g}"), ("left", "particles left in the silo (mean)", "{:.3g}"), ("wall", "wall time of the runs (s)", "{:.0f}")]
    notes = ["discharge time: gate opening to the last discharged particle", f"d = {d * 1e3:g} mm"]
    notes += beverloo_notes(table, d, depth)
    files = write_table(out / "silos", cols, table, "Discharge time of the 16 silos (cases/silo_prisms)", notes)
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    for i, a in enumerate(ANGLES):
        tb = sorted((t for t in table if t["angle"] == a), key=lambda t: t["b_mm"])
        if not tb:
            continue
        ok = [t for t in tb if math.isfinite(t["t_mean"])]
        line, = ax.plot([t["b_mm"] for t in ok], [t["t_mean"] for t in ok], "o-", label=ANGLE_LABEL.get(a, f"{a:g} deg"))
        for t in ok:
            if t["clogged"]:
                ax.annotate(f"{t['clogged']}/{t['finished']} clogged", (t["b_mm"], t["t_mean"]), fontsize=7,
                            xytext=(4, 4), textcoords="offset points", color=line.get_color())
        cl = [t for t in tb if t["clogged"] == t["finished"] and t["finished"]]
        if cl:  # side by side per angle
            ax.plot([t["b_mm"] + 2.5 * (i - 1.5) for t in cl], [0.02] * len(cl), "x", ms=9, mew=2,
                    color=line.get_color(), transform=ax.get_xaxis_transform(), clip_on=False)
    ax.set_yscale("log")
    from matplotlib.ticker import ScalarFormatter

    for axis in (ax.yaxis,):
        axis.set_major_formatter(ScalarFormatter())
        axis.set_minor_formatter(ScalarFormatter())
    ax.set_xlabel("outlet width b (mm)")
    ax.set_ylabel("discharge time (s)")
    ax.set_title("Discharge time, runs that did not clog (x at the bottom: all clogged)", fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend()
    return files + [_save(fig, out / "silos.png")]


def clogging_study(rows: list[dict], out: Path, d: float) -> list[Path]:
    groups = group_rows(rows, lambda v: (v["silo.hopper_angle_deg"], v["silo.outlet_width"]))
    table = [dict(angle=a, b_mm=b * 1e3, b_over_d=b / d, **summarise(r)) for (a, b), r in groups.items()]
    cols = [("angle", "hopper angle (deg)", "{:g}"), ("b_mm", "outlet (mm)", "{:g}"), ("b_over_d", "b/d", "{:.2g}"),
            ("finished", "runs", ""), ("clogged", "clogged", ""), ("clog_freq", "clogging frequency", "{:.2f}"),
            ("wilson_lo", "95 % Wilson low", "{:.2f}"), ("wilson_hi", "95 % Wilson high", "{:.2f}"),
            ("wall", "wall time of the runs (s)", "{:.0f}")]
    files = write_table(out / "clogging", cols, table, "Clogging frequency over replicas (cases/silo_prisms)",
                        ["replicas: particles.seed 1..N (another jitter of the fill lattice)",
                         "a clog: no outflow for clog_time with the particles over the outlet at rest"])
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    angles = [a for a in ANGLES if any(t["angle"] == a for t in table)]
    for i, a in enumerate(angles):
        tb = sorted((t for t in table if t["angle"] == a and t["finished"]), key=lambda t: t["b_mm"])
        x = np.array([t["b_over_d"] for t in tb]) + 0.04 * (i - 0.5 * (len(angles) - 1))  # side by side
        y = np.array([t["clog_freq"] for t in tb])
        err = np.array([[t["clog_freq"] - t["wilson_lo"] for t in tb], [t["wilson_hi"] - t["clog_freq"] for t in tb]])
        ax.errorbar(x, y, yerr=err, fmt="o-", capsize=4, label=ANGLE_LABEL.get(a, f"{a:g} deg"))
    n = max((t["finished"] for t in table), default=0)
    ax.set_xlabel("outlet width / particle diameter b/d")
    ax.set_ylabel("clogging frequency")
    ax.set_ylim(-0.05, 1.05)
    ax.set_title(f"Clogging frequency, {n} replicas per silo (95 % Wilson intervals)")
    ax.grid(alpha=0.3)
    ax.legend()
    return files + [_save(fig, out / "clogging.png")]


def sensitivity_study(rows: list[dict], labels: list[tuple[str, float]], out: Path,
                      base_at: dict[str, float] | None = None) -> list[Path]:
    by: dict = {}
    for r, lab in zip(rows, labels):
        by.setdefault(lab, []).append(_measured(r))
    table = [dict(parameter=p, value=v, **summarise(runs)) for (p, v), runs in by.items()]
    base = next((t for t in table if t["parameter"] == "base"), None)
    t0 = base["t_mean"] if base else math.nan
    base_runs = [r["duration"] for r in by.get(("base", 0.0), []) if r["ok"] and not r["clogged"]]
    for t in table:
        t["change"] = t["t_mean"] / t0 - 1.0 if math.isfinite(t0) else math.nan
    cols = [("parameter", "parameter", ""), ("value", "value", "{:g}"), ("finished", "runs", ""),
            ("clogged", "clogged", ""), ("t_mean", "discharge time (s)", "{:.3g}"), ("t_std", "std (s)", "{:.2g}"),
            ("left", "left in silo", "{:.3g}"), ("change", "change from base", "{:+.1%}"), ("wall", "wall time (s)", "{:.0f}")]
    files = write_table(out / "sensitivity", cols, table, "Sensitivity of the discharge time, 60 deg hopper, 150 mm",
                        ["one parameter at a time around the case (cases/silo_prisms); 'base' is the case itself"])
    plt = _plt()
    params = [p for p in dict.fromkeys(t["parameter"] for t in table) if p != "base"]
    fig, axes = plt.subplots(1, len(params), figsize=(3.0 * len(params), 3.4), sharey=True, squeeze=False)
    for ax, p in zip(axes[0], params):
        tb = [t for t in table if t["parameter"] == p]
        if base and base_at and p in base_at:
            tb.append(dict(base, value=base_at[p]))
        tb.sort(key=lambda t: t["value"])
        ax.plot([t["value"] for t in tb], [t["t_mean"] for t in tb], "o-")
        if math.isfinite(t0):
            ax.axhline(t0, color="k", lw=0.8, ls="--", label="the case")
        if len(base_runs) > 1:
            ax.axhspan(min(base_runs), max(base_runs), color="0.85", label=f"the case, {len(base_runs)} fills")
        if base and base_at and p in base_at:
            ax.plot([base_at[p]], [t0], "s", color="k", ms=6)
        ax.set_xlabel(p)
        if p == "k_n factor":
            ax.set_xscale("log", base=2)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("discharge time (s)")
    axes[0][0].legend(fontsize=8)
    fig.suptitle("Discharge time of the 60 deg / 150 mm silo, one parameter at a time (square, dashed: the case, "
                 "mean of its fills; grey: their range)")
    return files + [_save(fig, out / "sensitivity.png", dpi=110)]


def _floats(text: str, key: str) -> list[float]:
    try:
        return [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise CaseError(key, f"{text!r}: expected numbers separated by commas") from None


def add_study_arguments(ap, case: Path) -> None:
    """The arguments every silo study command takes: --case, --set, --out, --workers, --threads."""
    ap.add_argument("--case", default=str(case), help=f"the silo case (default cases/{case.name})")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                    help="override a key in every run")
    ap.add_argument("--out", help="study folder (default CASE/<study>)")
    ap.add_argument("--workers", type=int, help="local worker processes")
    ap.add_argument("--threads", type=int, default=1, help="numba threads per run (default 1)")


def run_study(prog: str, study, args) -> int:
    """Run ``study(args)`` -> (files, rows) of a study command: a bad input is one line and exit
    code 2; otherwise the files written are printed, exit code 0 when every run finished (or
    was reused), else 3."""
    try:
        files, rows = study(args)
    except CaseError as e:
        print(f"cfddem: error: {e}", file=sys.stderr)
        return 2
    print(f"{prog}: " + ", ".join(str(p) for p in files))
    return 0 if all(r.get("status") in ("done", "skipped") for r in rows) else 3


def load_study_case(args):
    """The study's case (``args.case`` with ``args.overrides``), refused unless a silo."""
    from .config import load_case

    base = load_case(args.case, overrides=args.overrides)
    if base.geometry.type != "silo":
        raise CaseError("geometry.type", f"{base.geometry.type!r}: the study needs a silo case")
    return base


def _study(args) -> tuple[list, list[dict]]:
    """Run the study of the parsed ``args``: (files written, sweep rows)."""
    from .sweep import run_sweep

    base = load_study_case(args)
    out = Path(args.out).resolve() if args.out else Path(args.case).resolve() / args.study
    d = base.particles.diameter
    if args.study == "sensitivity":
        trip = sensitivity_variants(base, args.replicas)
        variants, labels = [o for _, _, o in trip], [(p, v) for p, v, _ in trip]
    else:
        angles = _floats(args.angles, "--angles") if args.angles else list(ANGLES)
        widths = (_floats(args.widths, "--widths") if args.widths else
                  list(WIDTHS) if args.study == "silos" else [0.04, 0.06])
        variants = silo_variants(angles, widths, args.replicas)
    rows = run_sweep(args.case, variants, out, common=args.overrides, workers=args.workers,
                     threads=args.threads, chart="silo/discharge_duration")
    if args.study == "silos":
        files = silos_study(rows, out, d, base.silo.depth)
    elif args.study == "clogging":
        files = clogging_study(rows, out, d)
    else:
        files = sensitivity_study(rows, labels, out, base_values(base))
    return files, rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m cfddem.silo_prisms", description=__doc__.split("\n\n")[0])
    ap.add_argument("study", choices=("silos", "clogging", "sensitivity"))
    ap.add_argument("--replicas", type=int, default=1, help="fills per silo or variant (particles.seed 1..N)")
    ap.add_argument("--angles", help="hopper angles (deg from the horizontal, 0 flat), comma-separated")
    ap.add_argument("--widths", help="outlet widths (m), comma-separated")
    add_study_arguments(ap, CASE)
    return run_study("silo_prisms", _study, ap.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
