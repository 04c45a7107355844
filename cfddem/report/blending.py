"""One report for a blending study: ``cfddem blending-report SWEEP_DIR [--out DIR]``.

A blending study is a :mod:`cfddem.sweep` over silo-blender variants (the two flow patterns of
``cases/blender_flat_*``, the three inserts of ``cases/blender_multiflow``, batch fractions,
sub-layers...).  This module reads every finished variant's ``results.h5`` and writes, into one
folder:

* ``blending_concentration.png``: the tracer concentration in the outflow against the number of
  recirculations N_r = t / t_mean (against time where t_mean is unknown), one line per variant,
  with the mean tracer fraction of the silo content dashed (where it tends to);
* ``blending_vrr.png``: the variance reduction ratio against N_r (log axis), or per variant when
  only the scalar over the analysed window was stored;
* ``blending_rtd.png``: the residence time distributions E(theta) and F(theta) per variant;
* ``blending_fields.png``: the time-averaged speed per variant with the flow-channel boundary
  and the flow-pattern class;
* ``blending_report.md`` and ``blending_summary.json``: one row per variant: flow pattern, VRR,
  t_mean, the recirculations reached, RTD first appearance and peak, particles, simulated time,
  wall time and the cost per simulated second.

It reads the contract of the blending issue: ``/measurements/blending/{time, concentration_out,
vrr}`` and, where they exist, ``/measurements/blending/{n_recirculations, t_mean,
tracer_fraction_inventory (the mean the outflow tends to), vrr_recirculations,
vrr_by_recirculation}``, ``/measurements/rtd/{theta, E,
F}``, ``/measurements/flow_pattern`` and the silo's velocity field and channel
(``/measurements/silo/field``, ``/measurements/silo/channel``).  A variant without blending
measurements is listed with its status and left out of the plots.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..errors import CaseError


def _f(x, default=math.nan) -> float:
    try:
        v = float(np.asarray(x).reshape(-1)[0]) if np.asarray(x).size else default
    except (TypeError, ValueError):
        return default
    return v


def _s(x) -> str:
    if isinstance(x, bytes):
        return x.decode()
    if isinstance(x, np.ndarray) and x.shape == ():
        return _s(x[()])
    return str(x)


def _silo_rtd(m: dict, release_fraction: float, h5) -> tuple[dict, str, float]:
    """A run without an RTD (a silo discharge): virtual tracers released on a line at
    ``release_fraction`` of the fill height, flux-weighted, through the silo's time-averaged field
    to the outlet plane, t_mean = mass present at the gate opening (``/series/mass_present``) /
    steady mass flow rate; and its flow
    pattern.  ({} , "", nan) where the run has no field or flow rate."""
    from ..measure import blending as bl

    silo = m.get("silo", {})
    f = silo.get("field")
    rate = _f(m.get("mass_flow_rate", math.nan))
    fill = _f(silo.get("fill_height", math.nan))
    if not isinstance(f, dict) or not np.isfinite(np.asarray(f.get("vy", [np.nan]), float)).any():
        return {}, "", math.nan
    x, y, vx, vy = (np.asarray(f[k], float) for k in ("x", "y", "vx", "vy"))
    pattern = ""
    try:
        pattern = bl.classify_flow_pattern(x, y, vy, fill_height=fill if math.isfinite(fill) else None)["pattern"]
    except ValueError:
        pass
    from ..io.results import read_series

    ser = read_series(h5)
    t_gate = _f(silo.get("gate_open_time", math.nan))
    content = math.nan
    if "mass_present" in ser and len(ser["time"]) and math.isfinite(t_gate):
        content = float(ser["mass_present"][int(np.argmin(np.abs(ser["time"] - t_gate)))])
    t_mean = content / rate if math.isfinite(content) and rate > 0 else math.nan
    if not (math.isfinite(fill) and math.isfinite(t_mean)):
        return {}, pattern, t_mean
    try:
        start = bl.release_line(x, release_fraction * fill, 400)
        v = bl.virtual_tracer_rtd(x, y, vx, vy, start, 0.0, t_mean=t_mean)
    except ValueError:
        return {}, pattern, t_mean
    return {"theta": v["theta"], "E": v["E"], "F": v["F"], "first_appearance": v["theta_s"], "peak": v["peak"],
            "mean": v["mean"], "variance": v["variance"],
            "n_stuck": v["n_stuck"], "n_arrived": v["n_arrived"]}, pattern, t_mean


def read_blend_run(run_dir, release_fraction: float = 0.9) -> dict | None:
    """The blending measurements of one run folder (None without ``results.h5``).  A silo run
    without an RTD of its own gets one from virtual tracers released at ``release_fraction`` of
    its fill height (:func:`_silo_rtd`)."""
    from ..io.results import read_measurements, read_metadata

    run_dir = Path(run_dir)
    h5 = run_dir / "results.h5"
    if not h5.exists():
        return None
    m = read_measurements(h5)
    b = m.get("blending", {})
    r: dict = {"name": run_dir.name, "dir": str(run_dir), "has_blending": "concentration_out" in b}
    r["time"] = np.asarray(b.get("time", []), float)
    r["c_out"] = np.asarray(b.get("concentration_out", []), float)
    r["mass_by_label"] = np.asarray(b.get("mass_by_label", np.zeros((0, 2))), float)
    r["vrr"] = _f(b.get("vrr", math.nan))
    r["t_mean"] = _f(b.get("t_mean", math.nan))
    nr = b.get("n_recirculations")
    if nr is not None and np.asarray(nr).shape == r["time"].shape:
        r["n_r"] = np.asarray(nr, float)
    elif math.isfinite(r["t_mean"]) and r["t_mean"] > 0:
        r["n_r"] = r["time"] / r["t_mean"]
    else:
        r["n_r"] = None
    r["content_fraction"] = _f(b.get("tracer_fraction_inventory", math.nan))
    r["vrr_nr"] = np.asarray(b.get("vrr_recirculations", []), float)
    r["vrr_by_nr"] = np.asarray(b.get("vrr_by_recirculation", []), float)
    r["vrr_limit"] = np.asarray(b.get("vrr_sampling_limit", []), float)
    rtd = m.get("rtd", {})
    r["rtd_note"] = ""
    if not rtd:
        rtd, pattern, t_mean = _silo_rtd(m, release_fraction, h5)
        if pattern and "flow_pattern" not in m:
            m["flow_pattern"] = pattern
        if not math.isfinite(r["t_mean"]):
            r["t_mean"] = t_mean
        if rtd:
            r["rtd_note"] = (f"virtual tracers from {release_fraction:g} of the fill height "
                             f"({int(rtd['n_stuck'])} stuck of {int(rtd['n_stuck']) + int(rtd['n_arrived'])} kept)")
    r["theta"] = np.asarray(rtd.get("theta", []), float)
    r["E"] = np.asarray(rtd.get("E", []), float)
    r["F"] = np.asarray(rtd.get("F", []), float)
    r["rtd_first"] = _f(rtd.get("first_appearance", math.nan))
    r["rtd_peak"] = _f(rtd.get("peak", math.nan))
    r["rtd_mean"] = _f(rtd.get("mean", math.nan))
    r["rtd_var"] = _f(rtd.get("variance", math.nan))
    r["flow_pattern"] = _s(m["flow_pattern"]) if "flow_pattern" in m else ""
    silo = m.get("silo", {})
    r["field"] = silo.get("field")
    r["channel"] = silo.get("channel")
    info = json.loads((run_dir / "run.json").read_text()) if (run_dir / "run.json").exists() else {}
    r["wall_time"] = _f(info.get("wall_time", read_metadata(h5).get("wall_time", math.nan)))
    r["sim_time"] = _f(info.get("time", math.nan))
    r["n_particles"] = _f(info.get("n_particles", math.nan))
    return r


def _cost_row(r: dict) -> dict:
    wall, sim = r["wall_time"], r["sim_time"]
    per_s = wall / sim if (math.isfinite(wall) and math.isfinite(sim) and sim > 0) else math.nan
    return {"wall_time_s": wall, "simulated_time_s": sim, "wall_per_simulated_s": per_s,
            "hours_per_simulated_s": per_s / 3600.0}


def _xaxis(r: dict):
    return (r["n_r"], "number of recirculations N_r = t / t_mean") if r["n_r"] is not None else \
        (r["time"], "time (s)")


def _blocks(r: dict, x):
    """Tracer mass fraction of the outflow in blocks of about t_mean / 20
    (:func:`cfddem.measure.blending.block_concentration`), at the blocks' mean x; (None, None)
    without the per-label masses or t_mean."""
    from ..measure.blending import block_concentration

    M, t = r["mass_by_label"], r["time"]
    if M.ndim != 2 or M.shape[0] != len(t) or M.shape[1] < 2 or len(t) < 4 or not (r["t_mean"] > 0):
        return None, None
    k = max(1, int(round(0.05 * r["t_mean"] / float(np.median(np.diff(t))))))
    if len(t) // k < 2:
        return None, None
    _, cb = block_concentration(t, M, k)
    nb = len(cb)
    return np.asarray(x[: nb * k], float).reshape(nb, k).mean(axis=1), cb


def _short(name: str) -> str:
    """A legend label: the sweep's folder name without the key prefixes (blender.batch_fraction=0.25
    -> batch 0.25)."""
    for a, b in (("blender.batch_fraction=", "batch "), ("blender.sublayers=", "layers "), ("blender.", ""),
                 ("silo.", ""), ("__", ", ")):
        name = name.replace(a, b)
    return name


def _plots(runs: list[dict], out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files: list[Path] = []
    blend = [r for r in runs if r["has_blending"] and len(r["time"])]
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    col = {r["name"]: colours[i % len(colours)] for i, r in enumerate(blend)}
    if blend:
        # one panel per sweep folder (the part of the name before "/"), sharing the axes
        groups: dict[str, list] = {}
        for r in blend:
            groups.setdefault(r["name"].split("/")[0] if "/" in r["name"] else "", []).append(r)
        fig, axes = plt.subplots(len(groups), 1, figsize=(10, 3.4 * len(groups) + 0.8), squeeze=False,
                                 sharex=True)
        xl = ""
        for ax, (g, rs) in zip(axes[:, 0], groups.items()):
            for r in rs:
                x, xl = _xaxis(r)
                xb, cb = _blocks(r, x)
                lab = _short(r["name"].split("/", 1)[1] if g else r["name"])
                if xb is None:
                    ax.plot(x, r["c_out"], "-", lw=1.2, color=col[r["name"]], label=lab)
                else:  # the sampling intervals faint, blocks of a twentieth of t_mean as the line
                    ax.plot(x, r["c_out"], ".", ms=2, alpha=0.25, color=col[r["name"]])
                    ax.plot(xb, cb, "-", lw=1.5, color=col[r["name"]], label=lab)
                if math.isfinite(r["content_fraction"]):
                    ax.axhline(r["content_fraction"], ls="--", lw=1, color=col[r["name"]])
            ax.set_ylabel("tracer mass fraction\nin the outflow")
            ax.set_ylim(-0.02, 1.02)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), title=g or None,
                      title_fontsize=8)
        axes[-1, 0].set_xlabel(xl)
        axes[0, 0].set_title("outflow concentration: dots per record interval, lines per 1/20 of t_mean; "
                             "dashed: the silo content's mean", fontsize=9)
        fig.tight_layout()
        files.append(out / "blending_concentration.png")
        fig.savefig(files[-1], dpi=120, bbox_inches="tight")
        plt.close(fig)

        fig, ax = plt.subplots(figsize=(9, 4.2))
        curves = [r for r in blend if len(r["vrr_nr"]) and len(r["vrr_nr"]) == len(r["vrr_by_nr"])]
        if curves:
            for r in curves:
                ok = np.isfinite(r["vrr_by_nr"]) & (r["vrr_by_nr"] > 0)
                ax.plot(r["vrr_nr"][ok], r["vrr_by_nr"][ok], "o-", color=col[r["name"]], label=_short(r["name"]))
            lim = np.concatenate([r["vrr_limit"] for r in curves]) if curves else np.zeros(0)
            lim = lim[np.isfinite(lim)]
            if len(lim):
                ax.axhspan(float(lim.min()), float(lim.max()), color="0.85", zorder=0,
                           label="counting limit (a perfect blend)")
            ax.set_xlabel("number of recirculations N_r")
            ax.xaxis.get_major_locator().set_params(integer=True)
        else:
            names = [r["name"] for r in blend]
            vals = [r["vrr"] if math.isfinite(r["vrr"]) and r["vrr"] > 0 else np.nan for r in blend]
            ax.bar(range(len(names)), vals, color=[col[n] for n in names])
            ax.set_xticks(range(len(names)), names, rotation=30, ha="right", fontsize=8)
        ax.set_yscale("log")
        ax.set_ylabel("variance reduction ratio VRR")
        ax.grid(alpha=0.3, which="both")
        if curves:
            ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
        fig.tight_layout()
        files.append(out / "blending_vrr.png")
        fig.savefig(files[-1], dpi=120, bbox_inches="tight")
        plt.close(fig)

    rtd = [r for r in runs if len(r["theta"]) and len(r["E"]) == len(r["theta"])]
    if rtd:
        fig, (a1, a2) = plt.subplots(1, 2, figsize=(9, 3.8))
        for r in rtd:
            c = col.get(r["name"])
            a1.plot(r["theta"], r["E"], "-", color=c, label=_short(r["name"]))
            if len(r["F"]) == len(r["theta"]):
                a2.plot(r["theta"], r["F"], "-", color=c, label=_short(r["name"]))
        a1.set_xlabel("theta = t / t_mean")
        a1.set_ylabel("E(theta)")
        a2.set_xlabel("theta = t / t_mean")
        a2.set_ylabel("F(theta)")
        a2.set_ylim(-0.02, 1.02)
        for a in (a1, a2):
            a.grid(alpha=0.3)
        a2.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
        fig.tight_layout()
        files.append(out / "blending_rtd.png")
        fig.savefig(files[-1], dpi=120, bbox_inches="tight")
        plt.close(fig)

    fld = [r for r in runs if isinstance(r["field"], dict) and np.any(np.isfinite(r["field"].get("vx", [np.nan])))]
    if fld:
        from matplotlib.colors import LogNorm

        k = len(fld)
        ncol = min(k, 5)
        nrow = (k + ncol - 1) // ncol
        fig, axes = plt.subplots(nrow, ncol, figsize=(2.9 * ncol + 1.2, 5.4 * nrow), squeeze=False,
                                 gridspec_kw={"hspace": 0.55})
        vmax = max(float(np.nanmax(np.hypot(r["field"]["vx"], r["field"]["vy"]))) for r in fld)
        # log colours: the slow bed and the fast stream falling onto the heap span decades
        norm = LogNorm(vmin=1e-3 * vmax, vmax=vmax)
        im = None
        for a, r in zip(axes.ravel(), fld):
            f = r["field"]
            x, y = np.asarray(f["x"]), np.asarray(f["y"])
            sp = np.hypot(f["vx"], f["vy"])
            dx, dy = x[1] - x[0], y[1] - y[0]
            ext = [(x[0] - dx / 2) * 1e3, (x[-1] + dx / 2) * 1e3, (y[0] - dy / 2) * 1e3, (y[-1] + dy / 2) * 1e3]
            im = a.imshow(np.ma.masked_invalid(np.clip(sp, 1e-3 * vmax, None)), origin="lower", extent=ext,
                          aspect="equal", cmap="viridis", norm=norm)
            ch = r["channel"]
            if isinstance(ch, dict) and "x_left" in ch:
                a.plot(np.asarray(ch["x_left"]) * 1e3, np.asarray(ch["y"]) * 1e3, "r-", lw=1.3)
                a.plot(np.asarray(ch["x_right"]) * 1e3, np.asarray(ch["y"]) * 1e3, "r-", lw=1.3)
            a.set_title(_short(r["name"]).replace("/", "\n").replace(", ", "\n")
                        + (f"\n{r['flow_pattern']} flow" if r["flow_pattern"] else ""), fontsize=8)
            a.set_xlabel("x (mm)")
            a.set_ylabel("y (mm)")
        for a in axes.ravel()[k:]:
            a.set_visible(False)
        fig.colorbar(im, ax=list(axes.ravel()), label="time-averaged speed (m/s, log scale)", shrink=0.8)
        files.append(out / "blending_fields.png")
        fig.savefig(files[-1], dpi=110, bbox_inches="tight")
        plt.close(fig)
    return files


def _fmt(v, spec=".3g") -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, spec)


def blending_report(sweep_dirs, out=None) -> dict:
    """Read every variant of one or more sweep folders (their ``summary.csv``; e.g. one sweep per
    flow pattern) and write the report; returns ``{"rows": [...], "files": [...]}``.  With
    several folders a variant is named ``FOLDER/VARIANT``."""
    from .speed_accuracy import _read_rows

    dirs = [Path(d) for d in ([sweep_dirs] if isinstance(sweep_dirs, (str, Path)) else sweep_dirs)]
    if not dirs:
        raise CaseError("SWEEP_DIR", "give at least one sweep folder")
    sweep_dir = dirs[0]
    out = Path(out) if out else sweep_dir / "blending_report"
    runs, table = [], []
    for d in dirs:
        rows = [{"name": "", "status": "done"}] if (d / "results.h5").exists() else _read_rows(d)
        for row in rows:
            r = read_blend_run(d / row["name"] if row["name"] else d)
            name = (row["name"] or d.name) if len(dirs) == 1 or not row["name"] else f"{d.name}/{row['name']}"
            entry = {"name": name, "status": row.get("status", "")}
            if r is not None:
                r["name"] = name
                runs.append(r)
                n_r_end = float(r["n_r"][-1]) if r["n_r"] is not None and len(r["n_r"]) else math.nan
                entry.update(flow_pattern=r["flow_pattern"], vrr=r["vrr"], t_mean_s=r["t_mean"],
                             recirculations=n_r_end, rtd_first_theta=r["rtd_first"], rtd_peak_theta=r["rtd_peak"],
                             rtd_mean_theta=r["rtd_mean"], rtd_variance=r["rtd_var"],
                             n_particles=r["n_particles"], has_blending=r["has_blending"], rtd_note=r["rtd_note"],
                             **_cost_row(r))
                for k, v in zip(r["vrr_nr"], r["vrr_by_nr"]):
                    entry[f"vrr_after_{int(k)}"] = float(v)
            table.append(entry)
    if not runs:
        raise CaseError("SWEEP_DIR", f"{', '.join(map(str, dirs))}: no variant with a results.h5")
    out.mkdir(parents=True, exist_ok=True)
    files = _plots(runs, out)
    nmax = max([int(k.rsplit("_", 1)[1]) for e in table for k in e if k.startswith("vrr_after_")], default=0)
    lines = ["# Blending study", "", "Sweep folder(s): " + ", ".join(f"`{d}`" for d in dirs), "",
             "| variant | status | flow pattern | VRR | " + "".join(f"VRR after {k} | " for k in range(1, nmax + 1))
             + "t_mean (s) | N_r reached | RTD first (theta) | RTD peak (theta) | RTD mean (theta) | RTD variance | "
             "particles at the end | simulated (s) | wall (s) | h per simulated s |",
             "|---|---|---|---|" + "---|" * nmax + "---|---|---|---|---|---|---|---|---|---|"]
    for e in table:
        lines.append("| " + " | ".join([
            e["name"], e["status"], e.get("flow_pattern") or "-", _fmt(e.get("vrr")),
            *[_fmt(e.get(f"vrr_after_{k}")) for k in range(1, nmax + 1)], _fmt(e.get("t_mean_s")),
            _fmt(e.get("recirculations"), ".2f"), _fmt(e.get("rtd_first_theta")), _fmt(e.get("rtd_peak_theta")),
            _fmt(e.get("rtd_mean_theta")), _fmt(e.get("rtd_variance")),
            _fmt(e.get("n_particles"), ".0f"), _fmt(e.get("simulated_time_s")), _fmt(e.get("wall_time_s"), ".0f"),
            _fmt(e.get("hours_per_simulated_s"))]) + " |")
    notes = [f"- {e['name']}: RTD from {e['rtd_note']}" for e in table if e.get("rtd_note")]
    lines += ["", *notes, "", "VRR: over the whole record; VRR after k: in the k-th window of one mean residence time "
              "(a row's windows are limited by counting noise where the scene's vrr_sampling_limit is near).",
              "", *[f"![{f.stem}]({f.name})" for f in files], ""]
    (out / "blending_report.md").write_text("\n".join(lines))
    (out / "blending_summary.json").write_text(json.dumps(
        [{k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in e.items()} for e in table],
        indent=1))
    return {"rows": table, "files": [out / "blending_report.md", *files]}
