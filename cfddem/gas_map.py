"""The gas-effect map: the gas's effect on the beads of the chute against the particle diameter and
the rotation rate, on the streamwise-periodic chute segment (``cases/chute_segment``,
:mod:`cfddem.scenes.chute_segment`; docs/chute-study.md, "The gas effect against diameter and
rotation").

    python -m cfddem.gas_map run OUT [--case cases/chute_segment] [--diameters 3,2,1.5,1]
                                     [--rpm 0,16,32] [--replicas 2] [--workers 2] [--set KEY=VALUE ...]
    python -m cfddem.gas_map report OUT

``run`` runs every (diameter, rpm, replica) with and without gas from the same initial state
(one process per run, ``--workers`` at once, one numba thread each) into
``OUT/d<mm>_rpm<rpm>_seed<s>_<gas|nogas>``; a run already complete with the same configuration
is skipped (:func:`cfddem.sweep.run_is_complete`; the others run through
:func:`cfddem.sweep.run_variant`).  Per diameter d against the case's d_ref:

* stiffness ``k_n = k_ref (d/d_ref)^2`` (particle-particle and particle-wall): the overlap under
  the weight of a fixed number of layers stays the same fraction of d;
* ``dt = dt_ref sqrt(d/d_ref)``: the collision time scales as sqrt(m/k) ~ sqrt(d), so every
  diameter resolves a collision in the same number of steps; the gas step stays the case's
  (the coupling interval becomes ``round(dt_g / dt)``);
* periodic length ``segment.length = length_d x d`` and the gas cells along z so that they stay
  about as long as the case's; the bed depth stays the case's (more layers of smaller beads).

Replica r uses ``particles.seed = 1 + r`` (another jitter of the placed bed).

``report`` reads the runs and writes ``OUT/gas_map.csv``, ``OUT/gas_map.md`` and
``OUT/gas_map.png``: per (d, rpm) the gas effect ``v_gas / v_nogas - 1`` of the mean streamwise
particle velocity at the end time (mean over the replicas), its scatter over the replicas (the
standard deviation; with one replica none), the run-to-run scatter of the gas-free end velocity
itself (standard deviation over the replicas, relative), the direct effect
``(gas impulse on the beads / bead mass) / v_nogas`` (series ``gas_impulse_z``: drag, pressure
and the imposed mean pressure gradient; what the gas's own force changed, free of the chaotic
scatter of the other forces), its scatter and the part of it from the imposed mean pressure
gradient alone (``-G t / (rho_p v_nogas)``, the beads' buoyancy of the full chute), the mean slip of the bed and of the
surface layer against the gas (``/measurements/momentum_budget``, averaged from
``measurements.start_time``), the mean gas velocity at the end, and the wall times.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from .errors import CaseError
from .sweep import _common_overrides

DEFAULT_CASE = Path(__file__).resolve().parents[1] / "cases" / "chute_segment"


def run_name(d: float, rpm: float, seed: int, gas: bool) -> str:
    return f"d{d * 1e3:g}mm_rpm{rpm:g}_seed{seed}_{'gas' if gas else 'nogas'}"


def scaled_overrides(case, d: float, length_d: float) -> dict:
    """The case's overrides for diameter d (module docstring)."""
    d_ref = float(case.particles.diameter)
    r = case.resolved
    s = d / d_ref
    dt = float(case.time.dt) * math.sqrt(s)
    dt_g = float(case.time.dt) * int(case.gas.coupling_interval)
    L = length_d * d
    nx, ny, nz = (int(v) for v in case.gas.cells)
    cz = float(case.segment.length) / nz
    return {"particles.diameter": d, "time.dt": dt,
            "contact.particle_particle.k_n": r["contact"]["particle_particle"]["k_n"] * s * s,
            "contact.particle_wall.k_n": r["contact"]["particle_wall"]["k_n"] * s * s,
            "gas.coupling_interval": max(1, int(round(dt_g / dt))), "segment.length": L,
            "gas.cells": [nx, ny, max(2, int(round(L / cz)))]}


def plan(case_path, diameters, rpms, replicas, length_d, common) -> list[tuple[str, dict]]:
    """(run name, overrides) of every run, the most expensive (smallest d) first."""
    from .config import load_case

    base = load_case(case_path, overrides=common)
    jobs = []
    for d in sorted(diameters):
        sc = scaled_overrides(base, d, length_d)
        for rpm in rpms:
            for k in range(replicas):
                for gas in (True, False):
                    ov = dict(common)
                    ov.update(sc)
                    ov.update({"frame.rpm": rpm, "particles.seed": 1 + k, "gas.enabled": gas,
                               "study.compare_without_gas": False})
                    jobs.append((run_name(d, rpm, 1 + k, gas), ov))
    return jobs


def run_map(out, case_path=DEFAULT_CASE, diameters=(0.003, 0.002, 0.0015, 0.001), rpms=(0.0, 16.0, 32.0),
            replicas=2, workers=2, length_d=8.0, common=None, echo=print) -> list[dict]:
    """Run the map into ``out`` (module docstring); returns the sweep rows of the runs."""
    from .config import load_case
    from .sweep import run_is_complete, run_variant

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    jobs = plan(case_path, diameters, rpms, replicas, length_d, dict(common or {}))
    (out / "plan.csv").write_text("name\n" + "\n".join(n for n, _ in jobs) + "\n")
    rows, todo = [], []
    for n, ov in jobs:
        if run_is_complete(out / n, load_case(case_path, overrides=ov)):
            echo(f"[{n}] skipped: complete run found")
        else:
            todo.append((n, ov))
    with ProcessPoolExecutor(max_workers=workers) as ex:
        futs = [(n, ex.submit(run_variant, str(case_path), ov, str(out / n), 1)) for n, ov in todo]
        for n, f in futs:
            row = f.result()
            rows.append(row)
            echo(f"[{n}] {row['status']} in {row['wall_time']:.0f} s {row.get('error', '')}")
    return rows


# ------------------------------------------------------------------------------ report
def _read(run: Path) -> dict | None:
    import json

    import h5py

    try:
        info = json.loads((run / "run.json").read_text())
        with h5py.File(run / "results.h5", "r") as f:
            s = f["series"]
            out = {"t": s["time"][()], "v": s["mean_velocity_z"][()], "n": s["n_particles"][()],
                   "wall": float(info["wall_time"]), "status": info["status"], "message": info.get("message", "")}
            if "gas_mean_velocity_z" in s:
                out["u"] = s["gas_mean_velocity_z"][()]
            if "gas_impulse_z" in s:  # the gas's impulse per unit bead mass (M from t = 0, all at one velocity)
                out["dv"] = s["gas_impulse_z"][()] * s["mean_velocity_z"][0] / s["particle_momentum_z"][0]
            if "gas_impulse_z" in s:  # the imposed mean pressure gradient's part of it, -G t / rho_p
                from .config import load_case
                from .scenes.chute_segment import ChuteSegmentScene

                case = load_case(run / "case.resolved.toml")
                out["dv_gradient"] = (-ChuteSegmentScene.mean_pressure_gradient(case) * s["time"][()]
                                      / case.particles.density)
            b = f.get("measurements/momentum_budget")
            if b is not None:
                for k in ("slip_bed", "slip_surface", "drag", "pressure", "gravity"):
                    if k in b:
                        out[k] = np.asarray(b[k][()], float).sum()
    except (OSError, KeyError, ValueError):
        return None
    return out


def collect(out) -> tuple[list[dict], dict, list]:
    """One row per (d, rpm), the effect histories ``{(d_mm, rpm): (t, mean effect, mean direct
    effect)}`` and the pairs left out ``(name, why)`` (a run failed or unfinished)."""
    out = Path(out)
    runs, skipped = {}, []
    for p in sorted(out.iterdir()):
        if p.is_dir() and p.name.startswith("d") and p.name.endswith("_gas"):
            stem = p.name[: -len("_gas")]
            g, ng = _read(p), _read(out / f"{stem}_nogas")
            if g is None or ng is None or g["status"] != "done" or ng["status"] != "done":
                bad = [x for x in (g, ng) if x is not None and x["status"] != "done"]
                skipped.append((stem, bad[0]["message"] if bad else "unfinished or unreadable"))
                continue
            if g["n"][-1] != g["n"][0] or ng["n"][-1] != ng["n"][0]:
                skipped.append((stem, "beads left the segment (over a side wall)"))
                continue
            dpart, rpart, spart = stem.split("_")
            key = (float(dpart[1:-2]), float(rpart[3:]))
            runs.setdefault(key, []).append((int(spart[4:]), g, ng))
    rows, hist = [], {}
    for (dmm, rpm), reps in sorted(runs.items()):
        eff, vng, slipb, slips, ug, walls, effs_t, direct, dir_t, grad = [], [], [], [], [], [], [], [], [], []
        for _, g, ng in reps:
            n = min(len(g["t"]), len(ng["t"]))
            e_t = g["v"][:n] / ng["v"][:n] - 1.0
            effs_t.append(e_t)
            eff.append(e_t[-1])
            dir_t.append(g["dv"][:n] / ng["v"][:n] if "dv" in g else np.full(n, np.nan))
            direct.append(dir_t[-1][-1])
            grad.append(g["dv_gradient"][n - 1] / ng["v"][n - 1] if "dv_gradient" in g else np.nan)
            vng.append(ng["v"][n - 1])
            slipb.append(g.get("slip_bed", np.nan))
            slips.append(g.get("slip_surface", np.nan))
            ug.append(g["u"][n - 1] if "u" in g else np.nan)
            walls += [g["wall"], ng["wall"]]
        n = min(len(e) for e in effs_t)
        hist[(dmm, rpm)] = (reps[0][1]["t"][:n], np.mean([e[:n] for e in effs_t], axis=0),
                            np.mean([e[:n] for e in dir_t], axis=0))
        k = len(reps)
        rows.append({
            "d_mm": dmm, "rpm": rpm, "replicas": k, "particles": int(reps[0][1]["n"][0]),
            "end_time_s": float(reps[0][1]["t"][min(len(reps[0][1]["t"]), len(reps[0][2]["t"])) - 1]),
            "v_nogas_m_s": float(np.mean(vng)),
            "gas_effect_pct": 100 * float(np.mean(eff)),
            "effect_scatter_pct": 100 * float(np.std(eff, ddof=1)) if k > 1 else float("nan"),
            "v_nogas_scatter_pct": 100 * float(np.std(vng, ddof=1) / np.mean(vng)) if k > 1 else float("nan"),
            "direct_effect_pct": 100 * float(np.mean(direct)),
            "direct_scatter_pct": 100 * float(np.std(direct, ddof=1)) if k > 1 else float("nan"),
            "gradient_part_pct": 100 * float(np.mean(grad)),
            "gas_velocity_m_s": float(np.nanmean(ug)),
            "slip_bed_m_s": float(np.nanmean(slipb)), "slip_surface_m_s": float(np.nanmean(slips)),
            "wall_s_per_run": float(np.mean(walls)),
        })
    return rows, hist, skipped


def write_report(out, echo=print) -> list[Path]:
    out = Path(out)
    rows, hist, skipped = collect(out)
    if not rows:
        raise CaseError("OUT", f"{out} holds no pair of finished runs (with and without gas)")
    cols = list(rows[0])
    with open(out / "gas_map.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=cols)
        w.writeheader()
        w.writerows(rows)
    fmt = {"d_mm": "{:g}", "rpm": "{:g}", "replicas": "{}", "particles": "{:,}", "end_time_s": "{:.3g}",
           "v_nogas_m_s": "{:.4f}", "gas_effect_pct": "{:+.3f}", "effect_scatter_pct": "{:.3f}",
           "v_nogas_scatter_pct": "{:.3f}", "direct_effect_pct": "{:+.3f}",
           "direct_scatter_pct": "{:.1g}", "gradient_part_pct": "{:+.3f}", "gas_velocity_m_s": "{:.3f}", "slip_bed_m_s": "{:+.3f}",
           "slip_surface_m_s": "{:+.3f}", "wall_s_per_run": "{:.0f}"}
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        lines.append("| " + " | ".join("-" if isinstance(r[c], float) and math.isnan(r[c]) else fmt[c].format(r[c])
                                       for c in cols) + " |")
    if skipped:
        lines += ["", "Left out (a run of the pair did not finish):", ""]
        lines += [f"- {name}: {why}" for name, why in skipped]
    (out / "gas_map.md").write_text("\n".join(lines) + "\n")
    png = _chart(rows, hist, out / "gas_map.png")
    echo(f"gas map: {len(rows)} (d, rpm) points; {out / 'gas_map.md'}, {png}")
    return [out / "gas_map.csv", out / "gas_map.md", png]


def _chart(rows, hist, path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.8))
    rpms = sorted({r["rpm"] for r in rows})
    for i, rpm in enumerate(rpms):
        sel = sorted((r for r in rows if r["rpm"] == rpm), key=lambda r: r["d_mm"])
        d = np.array([r["d_mm"] for r in sel])
        e = np.array([r["gas_effect_pct"] for r in sel])
        err = np.array([r["effect_scatter_pct"] for r in sel])
        sc = np.array([r["v_nogas_scatter_pct"] for r in sel])
        off = 1.0 + 0.02 * (i - 0.5 * (len(rpms) - 1))  # spread the error bars apart
        a1.errorbar(d * off, e, yerr=np.nan_to_num(err), marker="o", capsize=4, color=f"C{i}",
                    label=f"{rpm:g} rpm: v_gas / v_nogas - 1 (bars: replica scatter)")
        de = np.array([r["direct_effect_pct"] for r in sel])
        a1.plot(d * off, de, ls="--", marker="s", mfc="none", color=f"C{i}", label=f"{rpm:g} rpm: direct (gas impulse / M v)")
        a1.fill_between(d, -sc, sc, alpha=0.10, color=f"C{i}")
    a1.axhline(0.0, color="k", lw=0.6)
    a1.set_xscale("log")
    ds = sorted({r["d_mm"] for r in rows})
    a1.set_xticks(ds)
    a1.set_xticklabels([f"{v:g}" for v in ds])
    a1.minorticks_off()
    a1.set_xlabel("particle diameter d [mm]")
    a1.set_ylabel("gas effect on the mean streamwise velocity [%]")
    a1.set_title(f"At t = {rows[0]['end_time_s']:.2g} s (band: run-to-run scatter of v without gas)", fontsize=10)
    a1.legend(fontsize=7, loc="upper left", ncol=1)
    rpm_h = 16.0 if 16.0 in rpms else rpms[0]
    for j, dmm in enumerate(ds):
        if (dmm, rpm_h) in hist:
            t, e, de = hist[(dmm, rpm_h)]
            a2.plot(t, 100 * e, color=f"C{j}", label=f"d = {dmm:g} mm")
            a2.plot(t, 100 * de, color=f"C{j}", ls="--", label=f"d = {dmm:g} mm, direct")
    a2.axhline(0.0, color="k", lw=0.6)
    a2.set_xlabel("time t [s]")
    a2.set_ylabel("gas effect v_gas / v_nogas - 1 [%]")
    a2.set_title(f"History at {rpm_h:g} rpm (mean of the replicas; dashed: direct)")
    a2.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m cfddem.gas_map", description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="run the map")
    r.add_argument("out")
    r.add_argument("--case", default=str(DEFAULT_CASE))
    r.add_argument("--diameters", default="3,2,1.5,1", help="mm, comma-separated")
    r.add_argument("--rpm", default="0,16,32")
    r.add_argument("--replicas", type=int, default=2)
    r.add_argument("--workers", type=int, default=2)
    r.add_argument("--length-d", type=float, default=8.0, help="periodic length in diameters")
    r.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override for every run")
    p = sub.add_parser("report", help="table and chart of a finished (or partial) map")
    p.add_argument("out")
    a = ap.parse_args(argv)
    try:
        if a.cmd == "run":
            if a.replicas < 1:
                raise CaseError("--replicas", f"{a.replicas} must be at least 1")
            if a.workers < 1:
                raise CaseError("--workers", f"{a.workers} must be at least 1")
            try:
                ds = [float(x) * 1e-3 for x in a.diameters.split(",")]
                rpms = [float(x) for x in a.rpm.split(",")]
            except ValueError:
                raise CaseError("--diameters/--rpm", "comma-separated numbers expected") from None
            run_map(a.out, a.case, ds, rpms, a.replicas, a.workers, a.length_d, _common_overrides(a.set))
        write_report(a.out)
    except CaseError as e:
        print(f"cfddem.gas_map: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
