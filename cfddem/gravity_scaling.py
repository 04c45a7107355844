"""Gravity scaling of a silo discharge (docs/blending.md, "Gravity scaling").

The same silo run at several gravities (a sweep over ``gravity.g``, e.g. with the variants file
``docs/blending/gravity_scaling.toml``).  A Beverloo-type discharge has the velocity scale
sqrt(g d) and the time scale sqrt(d / g), so the mass flow rate W ~ sqrt(g) and the discharge
time T ~ 1 / sqrt(g): W / sqrt(g) and T sqrt(g) should be constant, the time-averaged velocity
field in units of sqrt(g d) and the RTD in theta = t / t_mean invariant.  What should NOT
scale: the packing and the overlaps (Hertz: the relative overlap grows as (rho g H / E)^(2/3)),
the number of steps per discharge at a fixed dt (~ 1 / sqrt(g)) and the ratio of the collision
time (Hertz, at the impact speed sqrt(g d): ~ g^(-1/10)) to the flow time sqrt(d / g).

:func:`run_quantities` reads one finished silo run folder (``results.h5``);
:func:`gravity_table` groups runs by g (mean and seed-to-seed spread);
:func:`write_gravity_outputs` writes ``gravity_scaling.csv``, ``gravity_scaling.md`` and
``gravity_scaling.png``.  Command::

    python -m cfddem.gravity_scaling SWEEP_DIR [--out DIR]
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from pathlib import Path

import numpy as np

from .errors import CaseError
from .io.results import list_snapshots, read_config, read_measurements, read_series, read_snapshot
from .measure.blending import classify_flow_pattern, release_line, virtual_tracer_rtd
from .measure.silo import bulk_density
from .particles.contact.hertz_mindlin import HertzMindlinContact

#: heights (in particle diameters above the outlet plane) of the velocity profiles
PROFILE_HEIGHTS_D = (3.0, 6.0, 10.0)


def _fill_snapshot(h5: Path, t_gate: float) -> dict | None:
    """The last snapshot taken at or before the gate opening (the settled fill), or None."""
    snaps = [s for s in list_snapshots(h5) if s[1] <= t_gate + 1e-9]
    return read_snapshot(h5, snaps[-1][0]) if snaps else None


def fill_packing(pos, radius, density: float, xc: float, b: float, fill_height: float, depth: float) -> dict:
    """Bulk density and overlaps of a settled fill (spheres).

    Bulk density in the box |x - xc| <= b/2 - d, y in [3 d, H - 3 d], full depth (a box above
    the slot that stays clear of the hopper walls of a hopper silo and works below its top,
    where the scene's own box does not exist); overlaps over every touching sphere pair:
    mean and maximum of delta / R (R the smaller radius)."""
    from scipy.spatial import cKDTree

    pos = np.asarray(pos, float)
    r = np.asarray(radius, float)
    d = 2.0 * float(r.max())
    mass = density * 4.0 / 3.0 * math.pi * r ** 3
    lo = np.array([xc - 0.5 * b + d, 3 * d, 0.0])
    hi = np.array([xc + 0.5 * b - d, fill_height - 3 * d, depth])
    rho, k = bulk_density(pos, mass, lo, hi) if hi[1] > lo[1] and hi[0] > lo[0] else (math.nan, 0)
    pairs = cKDTree(pos).query_pairs(d, output_type="ndarray")
    if len(pairs):
        dist = np.linalg.norm(pos[pairs[:, 0]] - pos[pairs[:, 1]], axis=1)
        delta = r[pairs[:, 0]] + r[pairs[:, 1]] - dist
        rmin = np.minimum(r[pairs[:, 0]], r[pairs[:, 1]])
        ratio = (delta / rmin)[delta > 0]
    else:
        ratio = np.zeros(0)
    return {"bulk_density": rho, "n_in_box": k, "mean_overlap": float(ratio.mean()) if len(ratio) else math.nan,
            "max_overlap": float(ratio.max()) if len(ratio) else math.nan, "contacts": int(len(ratio))}


def discharge_duration(t, m, t_gate: float) -> float:
    """Time from the gate opening to the last increase of the discharged mass (s)."""
    t, m = np.asarray(t, float), np.asarray(m, float)
    if len(m) < 2 or not m[-1] > m[0]:
        return math.nan
    last = int(np.nonzero(m >= m[-1] - 1e-12 * max(abs(m[-1]), 1.0))[0][0])
    return float(t[last] - t_gate)


def run_quantities(run_dir, heights_d=PROFILE_HEIGHTS_D, n_tracers: int = 200) -> dict:
    """The gravity-scaling quantities of one finished silo run folder (module doc)."""
    h5 = Path(run_dir) / "results.h5"
    if not h5.is_file():
        raise CaseError("SWEEP_DIR", f"{run_dir}: no results.h5")
    _, cfg = read_config(h5)
    m = read_measurements(h5)
    if "silo" not in m:
        raise CaseError("SWEEP_DIR", f"{run_dir}: not a silo run (no /measurements/silo)")
    s = m["silo"]
    g = float(cfg["gravity"]["g"])
    d = float(cfg["particles"]["diameter"])
    rho_p = float(cfg["particles"]["density"])
    dt = float(cfg["time"]["dt"])
    sc = cfg["silo"]
    W_s, b, L = float(sc["width"]), float(sc["outlet_width"]), float(sc["depth"])
    xc = 0.5 * W_s
    t_gate = float(s["gate_open_time"])
    H = float(s["fill_height"])
    rate = float(m["mass_flow_rate"])
    T = discharge_duration(s["discharge_time"], s["discharge_mass"], t_gate)
    u = math.sqrt(g * d)  # velocity scale
    out = {"run": Path(run_dir).name, "g": g, "seed": int(cfg["particles"].get("seed", 0)), "d": d, "dt": dt,
           "W": rate, "W_sqrt_g": rate / math.sqrt(g), "T": T, "T_sqrt_g": T * math.sqrt(g),
           "steps_discharge": T / dt, "fill_height": H, "t_gate": t_gate, "clogged": int(m.get("clogged", 0))}
    # packing and overlaps of the settled fill; the largest overlap during the run after the gate
    snap = _fill_snapshot(h5, t_gate)
    if snap is not None:
        out.update({f"fill_{k}" if k in ("contacts", "n_in_box") else k: v for k, v in
                    fill_packing(snap["pos"], snap["radius"], rho_p, xc, b, H, L).items()})
    ser = read_series(h5)
    if "max_overlap_ratio" in ser:
        after = ser["time"] >= t_gate
        out["max_overlap_discharge"] = float(np.max(ser["max_overlap_ratio"][after])) if after.any() else math.nan
    # collision time at the impact speed sqrt(g d) against the flow time sqrt(d / g)
    pp = cfg["contact"]["particle_particle"]
    if cfg["contact"].get("model") == "hertz_mindlin":
        law = HertzMindlinContact(E=float(pp["E"]), nu=float(pp["nu"]), e=float(pp["e"]), mu=float(pp["mu"]))
        m_p = rho_p * math.pi * d ** 3 / 6.0
        out["t_c"] = law.collision_time(0.5 * m_p, 0.25 * d, u)
    else:
        k_n, e_n = float(pp["k_n"]), float(pp["e_n"])
        out["t_c"] = math.sqrt(0.5 * rho_p * math.pi * d ** 3 / 6.0 * (math.pi ** 2 + math.log(e_n) ** 2) / k_n)
    out["t_c_over_t_flow"] = out["t_c"] / math.sqrt(d / g)
    # the time-averaged field: vy / sqrt(g d) profiles, flow pattern, channel, RTD
    f = s["field"]
    x, y, vx, vy = (np.asarray(f[k], float) for k in ("x", "y", "vx", "vy"))
    out["x"] = x
    out["profiles"] = {}
    for h in heights_d:
        j = int(np.argmin(np.abs(y - h * d)))
        out["profiles"][h] = vy[j] / u
    fp = classify_flow_pattern(x, y, vy, fill_height=H, xc=xc)
    out["pattern"] = fp["pattern"]
    out["stagnant_fraction"] = fp["stagnant_fraction"]
    j = int(np.argmin(np.abs(y - heights_d[-1] * d)))
    out["channel_width_d"] = float((fp["x_right"][j] - fp["x_left"][j]) / d)
    rtd = virtual_tracer_rtd(x, y, vx, vy, release_line(x, 0.8 * H, n_tracers), 0.0)
    out["rtd_theta"], out["rtd_E"] = np.asarray(rtd["theta"]), np.asarray(rtd["E"])
    out["t_mean"] = float(rtd["t_mean"])
    out["t_mean_sqrt_g"] = out["t_mean"] * math.sqrt(g)
    out["theta_var"] = float(rtd["variance"])
    out["tracers"] = f"{rtd['n_arrived']}/{rtd['n_released']}"
    return out


def find_runs(sweep_dir) -> list[Path]:
    """Run folders (holding results.h5) directly under ``sweep_dir``, in name order."""
    p = Path(sweep_dir)
    if not p.is_dir():
        raise CaseError("SWEEP_DIR", f"no folder {p}")
    runs = sorted(q for q in p.iterdir() if (q / "results.h5").is_file())
    if not runs:
        raise CaseError("SWEEP_DIR", f"{p}: no run folder with a results.h5")
    return runs


#: scalar columns of the table: (key, header, format)
COLUMNS = (("W", "W (kg/s)", "{:.4g}"), ("W_sqrt_g", "W/sqrt(g) (kg s^-1 / (m/s2)^0.5)", "{:.4g}"),
           ("T", "T (s)", "{:.4g}"), ("T_sqrt_g", "T sqrt(g)", "{:.4g}"),
           ("t_mean_sqrt_g", "t_mean sqrt(g)", "{:.4g}"), ("theta_var", "var(theta)", "{:.3g}"),
           ("channel_width_d", "channel width / d (top profile)", "{:.3g}"),
           ("bulk_density", "bulk density (kg/m3)", "{:.4g}"), ("mean_overlap", "mean overlap / R (fill)", "{:.3g}"),
           ("max_overlap", "max overlap / R (fill)", "{:.3g}"),
           ("max_overlap_discharge", "max overlap / R (discharge)", "{:.3g}"),
           ("steps_discharge", "steps per discharge", "{:.4g}"), ("t_c_over_t_flow", "t_c / sqrt(d/g)", "{:.3g}"))


def gravity_table(runs: list[dict]) -> list[dict]:
    """One row per gravity: the mean of each column over the runs (seeds) at that g, its
    spread (max - min, NaN for a single run), the seeds, the flow patterns."""
    rows = []
    for g in sorted({r["g"] for r in runs}):
        at = [r for r in runs if r["g"] == g]
        row = {"g": g, "g_over_g0": g / 9.81, "n_runs": len(at), "seeds": ",".join(str(r["seed"]) for r in at),
               "pattern": ",".join(sorted({r["pattern"] for r in at}))}
        for k, _, _ in COLUMNS:
            v = np.array([r.get(k, math.nan) for r in at], float)
            row[k] = float(np.mean(v))
            row[k + "_spread"] = float(v.max() - v.min()) if len(v) > 1 else math.nan
        rows.append(row)
    return rows


def _cell(v, fmt, spread=math.nan) -> str:
    if isinstance(v, float) and not math.isfinite(v):
        return "-"
    s = fmt.format(v)
    return s + (f" +- {fmt.format(0.5 * spread)}" if isinstance(spread, float) and math.isfinite(spread) else "")


def write_gravity_outputs(runs: list[dict], out) -> list[Path]:
    """``gravity_scaling.csv`` (one row per run), ``gravity_scaling.md`` (one row per g, mean
    +- half the seed-to-seed range) and ``gravity_scaling.png`` into ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    keys = ["run", "g", "seed", "pattern", "tracers", "t_gate", "fill_height"] + [k for k, _, _ in COLUMNS]
    with (out / "gravity_scaling.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(keys)
        for r in sorted(runs, key=lambda r: (r["g"], r["seed"])):
            w.writerow([r.get(k, "") for k in keys])
    table = gravity_table(runs)
    lines = ["| g (m/s2) | g/g0 | runs (seeds) | flow pattern | " + " | ".join(h for _, h, _ in COLUMNS) + " |",
             "|" + "---|" * (4 + len(COLUMNS))]
    for row in table:
        cells = [f"{row['g']:g}", f"{row['g_over_g0']:.3g}", f"{row['n_runs']} ({row['seeds']})", row["pattern"]]
        cells += [_cell(row[k], fmt, row[k + "_spread"]) for k, _, fmt in COLUMNS]
        lines.append("| " + " | ".join(cells) + " |")
    (out / "gravity_scaling.md").write_text("\n".join(lines) + "\n")
    return [out / "gravity_scaling.csv", out / "gravity_scaling.md", _chart(runs, table, out / "gravity_scaling.png")]


def _against_g(ax, g0: float, title: str, log_y: bool) -> None:
    """Log g axis, values relative to those at the lowest g ``g0``."""
    ax.set_xscale("log")
    if log_y:
        ax.set_yscale("log")
    ax.set_xlabel("g (m/s$^2$)")
    ax.set_ylabel(f"value / value at g = {g0:g}")
    ax.set_title(title)
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3, which="both")


def _chart(runs: list[dict], table: list[dict], path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    gs = np.array([r["g"] for r in table])
    fig, ax = plt.subplots(2, 2, figsize=(11, 8.5))
    # (a) what should scale: normalised by its value at the lowest g
    a = ax[0, 0]
    for k, lab, mk in (("W_sqrt_g", "W / sqrt(g)", "o"), ("T_sqrt_g", "T sqrt(g)", "s"),
                       ("t_mean_sqrt_g", "t_mean sqrt(g) (RTD)", "^")):
        v = np.array([r[k] for r in table])
        e = np.array([0.5 * r[k + "_spread"] for r in table])
        a.errorbar(gs, v / v[0], yerr=np.nan_to_num(e / v[0]), marker=mk, capsize=3, label=lab)
    a.axhline(1.0, color="k", lw=0.8)
    _against_g(a, gs[0], "(a) should be constant if the flow scales", log_y=False)
    # (b) what should not scale, on log axes, each over its value at the lowest g
    b = ax[0, 1]
    for k, lab, mk in (("max_overlap", "max overlap / R (fill)", "o"), ("mean_overlap", "mean overlap / R (fill)", "s"),
                       ("steps_discharge", "steps per discharge", "v"), ("t_c_over_t_flow", "t_c / sqrt(d/g)", "^"),
                       ("bulk_density", "bulk density", "D")):
        v = np.array([r[k] for r in table])
        if np.isfinite(v).all() and v[0] > 0:
            b.plot(gs, v / v[0], marker=mk, label=lab)
    gg = np.geomspace(gs[0], gs[-1], 20)
    b.plot(gg, (gg / gs[0]) ** (2 / 3), "k:", lw=1, label="g$^{2/3}$ (Hertz overlap)")
    b.plot(gg, (gg / gs[0]) ** -0.5, "k--", lw=1, label="g$^{-1/2}$")
    b.plot(gg, (gg / gs[0]) ** 0.4, "k-.", lw=1, label="g$^{2/5}$")
    _against_g(b, gs[0], "(b) should not scale", log_y=True)
    # (c) velocity profiles vy / sqrt(g d), one line style per height, one colour per g
    c = ax[1, 0]
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    styles = ("-", "--", ":", "-.")
    for r in sorted(runs, key=lambda r: (r["g"], r["seed"])):
        ci = colours[list(gs).index(r["g"]) % len(colours)]
        first = r is min((q for q in runs if q["g"] == r["g"]), key=lambda q: q["seed"])
        for i, (h, p) in enumerate(r["profiles"].items()):
            c.plot(r["x"] * 1e3, p, styles[i % len(styles)], color=ci, lw=1.2,
                   label=f"g = {r['g']:g}, y = {h:g} d" if first else None)
    c.set_xlabel("x (mm)")
    c.set_ylabel("time-averaged v$_y$ / sqrt(g d)")
    c.set_title("(c) velocity profiles (all seeds)")
    c.legend(fontsize=6, ncol=2)
    c.grid(alpha=0.3)
    # (d) RTD from virtual tracers
    dd = ax[1, 1]
    for r in sorted(runs, key=lambda r: (r["g"], r["seed"])):
        ci = colours[list(gs).index(r["g"]) % len(colours)]
        dd.plot(r["rtd_theta"], r["rtd_E"], color=ci, lw=1.2, label=f"g = {r['g']:g}, seed {r['seed']}")
    dd.set_xlabel("theta = t / t_mean")
    dd.set_ylabel("E(theta)")
    dd.set_title("(d) RTD, virtual tracers from 0.8 H")
    dd.legend(fontsize=7)
    dd.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m cfddem.gravity_scaling",
                                 description="Read a sweep of a silo case over gravity.g and write the gravity-scaling "
                                             "table (CSV, markdown) and chart.")
    ap.add_argument("sweep_dir", help="the sweep folder (one run folder per gravity and seed)")
    ap.add_argument("--out", help="output folder (default: SWEEP_DIR)")
    args = ap.parse_args(argv)
    try:
        runs = [run_quantities(p) for p in find_runs(args.sweep_dir)]
        files = write_gravity_outputs(runs, args.out or args.sweep_dir)
    except CaseError as e:
        print(f"cfddem: error: {e}", file=sys.stderr)
        return 2
    print((Path(files[1])).read_text(), end="")
    for f in files:
        print(f"wrote {f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
