"""Speed against accuracy: wall time against the deviation from the most accurate run.

Input: a sweep folder written by ``cfddem sweep`` (``summary.csv`` plus one run folder per
variant).  For every finished variant the time-averaged chute measurements are compared with
those of the reference run (the most accurate one: by default the variant with the smallest
``time.dt``, else the most expensive one; ``--reference NAME`` chooses it):

* bed height: the root-mean-square difference over the left/centre/right sensors and all
  streamwise positions where both runs have a bed, in mm, against the experimental error band
  of 1.5 mm;
* surface velocity: the root-mean-square difference of the streamwise surface velocity over
  the measurement cells where both runs have particles, relative to the reference's RMS
  surface velocity, against the experimental band of 2 %;
* gas velocity (runs with gas only): the root-mean-square difference of the time-averaged
  streamwise gas velocity, the variant's field interpolated (trilinearly, between cell
  centres) onto the reference's cell centres, relative to the reference's RMS streamwise gas
  velocity.  It resolves the gas grid and the coupling interval, whose effect on the
  particles may stay below the scatter of the particle measurements.  No experimental band.

Each row also gives ``velocity_end`` (the mean streamwise particle velocity over the last
0.1 m of the chute, as ``cfddem compare``) and its relative difference from the reference's,
``velocity_end_rel``: for a gas-free variant against a reference with gas, the gas effect.

Variants that failed (blow-up: time step too large, explicit drag unstable...) are marked on
the chart at their wall time as "unstable" with their varied values.  Writes
``speed_accuracy.png``, ``speed_accuracy.csv`` and ``speed_accuracy.json`` into the sweep
folder (or ``--out``).

    cfddem sweep cases/chute_16rpm --vary time.dt=2.5e-6,5e-6,1e-5,2e-5,4e-5 --set time.end_time=2 \\
        --set measurements.start_time=1 --out runs/dt_study
    cfddem accuracy runs/dt_study
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

from ..errors import CaseError

BED_BAND_MM = 1.5
VELOCITY_BAND = 0.02


def _read_rows(sweep_dir: Path) -> list[dict]:
    f = sweep_dir / "summary.csv"
    if not f.exists():
        raise CaseError("SWEEP_DIR", f"no summary.csv in {sweep_dir} (run cfddem sweep first)")
    with f.open() as fh:
        return list(csv.DictReader(fh))


def _run(run_dir: Path):
    """The run folder read once (:class:`cfddem.report.compare.Run`: chute and gas
    measurements, configuration), or None without results or time-averaged chute measurements."""
    from .compare import Run

    if not (run_dir / "results.h5").exists():
        return None
    try:
        return Run(run_dir)
    except CaseError:
        return None


def deviations(ref: dict, run: dict) -> tuple[float, float]:
    """(bed-height RMS difference in mm, relative RMS surface-velocity difference)."""
    hb_r = np.asarray(ref["bed_height_sensor"], float)
    hb = np.asarray(run["bed_height_sensor"], float)
    ok = np.isfinite(hb_r) & np.isfinite(hb) & ((hb_r > 0) | (hb > 0))
    bed = float(np.sqrt(np.mean((hb[ok] - hb_r[ok]) ** 2)) * 1e3) if ok.any() else math.nan
    vr = np.asarray(ref["surface_vz"], float)
    v = np.asarray(run["surface_vz"], float)
    ok = np.isfinite(vr) & np.isfinite(v)
    if ok.any():
        scale = float(np.sqrt(np.mean(vr[ok] ** 2)))
        vel = float(np.sqrt(np.mean((v[ok] - vr[ok]) ** 2))) / scale if scale > 0 else math.nan
    else:
        vel = math.nan
    return bed, vel


def _gas(run) -> dict | None:
    """The run's time-averaged gas field, if it has one with its cell-centre coordinates."""
    g = run.gas
    if not g or "mean_velocity" not in g or not all(k in g for k in ("x", "y", "z")):
        return None
    return g


def gas_deviation(ref: dict, run: dict) -> float:
    """Relative RMS difference of the time-averaged streamwise gas velocity, ``run``'s field
    (nx, ny, nz, 3 at the cell centres ``x, y, z``) interpolated onto ``ref``'s cell centres;
    outside ``run``'s outermost centres the nearest centre's value is used."""
    from scipy.interpolate import RegularGridInterpolator

    wr = np.asarray(ref["mean_velocity"], float)[..., 2]
    w = np.asarray(run["mean_velocity"], float)[..., 2]
    axes = [np.asarray(run[k], float) for k in ("x", "y", "z")]
    pts = [np.clip(np.asarray(ref[k], float), a[0], a[-1]) for k, a in zip(("x", "y", "z"), axes)]
    # an axis of one cell cannot be interpolated along: take its only value
    keep = [i for i, a in enumerate(axes) if a.size > 1]
    vals = w.reshape([a.size for a in axes])
    sq = tuple(0 if axes[i].size == 1 else slice(None) for i in range(3))
    interp = RegularGridInterpolator([axes[i] for i in keep], vals[sq], method="linear")
    mesh = np.meshgrid(*[pts[i] for i in keep], indexing="ij")
    wi = interp(np.stack([m.ravel() for m in mesh], axis=1)).reshape(mesh[0].shape)
    shape = [wr.shape[i] if i in keep else 1 for i in range(3)]
    wi = np.broadcast_to(wi.reshape(shape), wr.shape)
    scale = float(np.sqrt(np.mean(wr**2)))
    return float(np.sqrt(np.mean((wi - wr) ** 2))) / scale if scale > 0 else math.nan


def _num(x: str) -> float:
    try:
        return float(x)
    except (TypeError, ValueError):
        return math.nan


def speed_accuracy(sweep_dir: str | Path, reference: str | None = None, out: str | Path | None = None) -> dict:
    """Compute the deviations of every variant and write the chart; returns the table."""
    sweep_dir = Path(sweep_dir)
    out = Path(out) if out else sweep_dir
    out.mkdir(parents=True, exist_ok=True)
    rows = _read_rows(sweep_dir)
    # the varied keys are the columns between name and status
    cols = list(rows[0].keys()) if rows else []
    varied = cols[1:cols.index("status")] if "status" in cols else []
    done = [r for r in rows if r["status"] in ("done", "skipped")]
    runs = {r["name"]: _run(sweep_dir / r["name"]) for r in done}
    done = [r for r in done if runs[r["name"]] is not None]
    if not done:
        raise CaseError("SWEEP_DIR", f"{sweep_dir}: no finished variant with chute measurements")
    if reference is None:
        if "time.dt" in varied:
            ref_row = min(done, key=lambda r: _num(r["time.dt"]))
        else:
            ref_row = max(done, key=lambda r: _num(r.get("wall_time")))
    else:
        cand = [r for r in done if r["name"] == reference]
        if not cand:
            raise CaseError("--reference", f"no finished variant named {reference!r}; have: "
                                           + ", ".join(r["name"] for r in done))
        ref_row = cand[0]
    ref_run = runs[ref_row["name"]]
    ref_gas = _gas(ref_run)
    ref_v_end = ref_run.velocity_end()
    table = []
    for r in rows:
        entry = {"name": r["name"], "status": r["status"], "wall_time": _num(r.get("wall_time")),
                 **{k: r[k] for k in varied}}
        run = runs.get(r["name"])
        if run is not None:
            bed, vel = deviations(ref_run.chute, run.chute)
            entry.update(bed_height_rms_mm=bed, surface_velocity_rel_rms=vel,
                         within_bands=bool(bed <= BED_BAND_MM and vel <= VELOCITY_BAND))
            v_end = run.velocity_end()
            entry.update(velocity_end=v_end, velocity_end_rel=(v_end - ref_v_end) / ref_v_end)
            g = _gas(run) if ref_gas is not None else None
            entry["gas_velocity_rel_rms"] = gas_deviation(ref_gas, g) if g is not None else math.nan
        else:
            entry.update(bed_height_rms_mm=math.nan, surface_velocity_rel_rms=math.nan, within_bands=False,
                         gas_velocity_rel_rms=math.nan, velocity_end=math.nan, velocity_end_rel=math.nan,
                         error=r.get("error", ""))
        table.append(entry)
    result = {"reference": ref_row["name"], "varied": varied, "rows": table,
              "bands": {"bed_height_mm": BED_BAND_MM, "surface_velocity_rel": VELOCITY_BAND}}
    (out / "speed_accuracy.json").write_text(json.dumps(result, indent=1, allow_nan=True))
    with (out / "speed_accuracy.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        head = ["name", *varied, "status", "wall_time", "bed_height_rms_mm", "surface_velocity_rel_rms",
                "within_bands", "gas_velocity_rel_rms", "velocity_end", "velocity_end_rel"]
        w.writerow(head)
        for e in table:
            w.writerow([e.get(h, "") for h in head])
    _chart(result, out / "speed_accuracy.png")
    return result


def _label(e: dict, varied: list[str]) -> str:
    """``coupling_interval=9, cells=[8, 8, 75]``: the varied values a row sets (empty cells of a
    mixed variants file are the case's values and are left out)."""
    return ", ".join(f"{k.split('.')[-1]}={e[k]}" for k in varied if e.get(k) not in ("", None))


def _chart(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = result["rows"]
    varied = result["varied"]
    specs = [("bed_height_rms_mm", "bed height RMS deviation [mm]", BED_BAND_MM),
             ("surface_velocity_rel_rms", "surface velocity RMS deviation [-]", VELOCITY_BAND)]
    if any(np.isfinite(e.get("gas_velocity_rel_rms", np.nan)) for e in rows):
        specs.append(("gas_velocity_rel_rms", "gas streamwise velocity RMS deviation [-]", None))
    fig, axes = plt.subplots(1, len(specs), figsize=(6 * len(specs), 4.8))
    for ax, (key, label, band) in zip(axes, specs):
        good = [e for e in rows if np.isfinite(e.get(key, np.nan)) and e["name"] != result["reference"]]
        bad = [e for e in rows if e["status"] == "failed"]
        if band is not None:
            ax.axhspan(0, band, color="tab:green", alpha=0.12, label="experimental error band")
        for e in good:
            ax.plot(e["wall_time"], e[key], "o", color="tab:blue")
            ax.annotate(_label(e, varied), (e["wall_time"], e[key]),
                        fontsize=7, xytext=(4, 3), textcoords="offset points")
        ymax = max([band * 1.5 if band is not None else 1e-3] + [e[key] for e in good])
        for e in bad:
            wt = e["wall_time"] if np.isfinite(e["wall_time"]) else 0.0
            ax.plot(wt, ymax * 1.1, "x", color="tab:red", ms=9)
            ax.annotate("unstable: " + _label(e, varied), (wt, ymax * 1.1),
                        fontsize=7, color="tab:red", xytext=(4, -10), textcoords="offset points")
        ref = [e for e in rows if e["name"] == result["reference"]]
        if ref:
            ax.axvline(ref[0]["wall_time"], color="0.5", ls="--", label=f"reference: {ref[0]['name']}")
        ax.set_xlabel("wall time [s]")
        ax.set_ylabel(label)
        ax.set_ylim(0, ymax * 1.25)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="upper right")
    fig.suptitle("Speed against accuracy (deviation from the most accurate run)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
