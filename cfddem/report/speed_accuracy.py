"""Speed against accuracy: wall time against the deviation from the most accurate setting.

Input: a sweep folder written by ``cfddem sweep`` (``summary.csv`` plus one run folder per
variant).  The time-averaged chute measurements of every finished variant are compared with
those of the reference setting (the most accurate one: by default the setting with the
smallest ``time.dt``, else the most expensive one; ``--reference NAME`` names a variant of it).

**Settings and replicas.**  Variants whose varied values (the ``summary.csv`` columns) are
equal apart from the replica keys :data:`REPLICA_KEYS` (``checkpoint.perturb_seed``,
``checkpoint.perturb_velocity``) are replicas of one setting: the same settings branched from
the same checkpoint with another seeded velocity perturbation.  A setting's measurement fields
are the means of its replicas' fields (wall time: the mean wall time).

**Deviations** (of one run, or of a setting's mean fields, from the reference setting's mean
fields):

* bed height: the root-mean-square difference over the left/centre/right sensors and all
  streamwise positions where both have a bed, in mm, against the experimental error band of
  1.5 mm;
* surface velocity: the root-mean-square difference of the streamwise surface velocity over
  the measurement cells where both have particles, relative to the reference's RMS surface
  velocity, against the experimental band of 2 %;
* gas velocity (runs with gas only): the root-mean-square difference of the time-averaged
  streamwise gas velocity, the variant's field interpolated (trilinearly, between cell
  centres) onto the reference's cell centres, relative to the reference's RMS streamwise gas
  velocity.  It resolves the gas grid and the coupling interval.  No experimental band;
* ``velocity_end_rel``: the relative difference of ``velocity_end`` (the mean streamwise
  particle velocity over the last 0.1 m of the chute, as ``cfddem compare``).

**Noise floor.**  With k >= 2 replicas of the reference, each replica is compared with the
mean of the other k - 1 (its row in the table holds that deviation) and the floor ``f`` of a
measure is the root-mean-square of these k deviations: the deviation one run shows from the
reference through run-to-run scatter alone.  If the scatter is independent from point to point
with the per-run RMS ``s``, f^2 = s^2 (1 + 1/(k-1)); the uncertainty of a setting with m
replicas, whose mean fields are compared with the mean of the k reference replicas, is then
``u = s sqrt(1/m + 1/k)`` with s^2 = f^2 (k-1)/k.  Without replicas of the reference the floor
is unknown (u = 0).

**Verdict.**  A setting is inside the experimental bands when its deviation plus its
uncertainty (an upper bound of its systematic deviation, by the triangle inequality) is at most
1.5 mm for the bed height and 2 % for the surface velocity; the reference setting is inside by
definition.  The verdict names the cheapest setting inside (least mean wall time) and whether
it is distinguishable from the reference's scatter: a deviation more than
:data:`DISTINCT_FACTOR` times its uncertainty in the bed height or the surface velocity.

Variants that failed (blow-up: time step too large, explicit drag unstable...) are drawn at
their wall time as a red cross on the top edge of each panel and listed as "unstable: <cause>"
(:func:`cfddem.stability.classify`) or "failed: <error>" (refused input).

Writes into the sweep folder (or ``--out``): ``speed_accuracy.png`` (one panel per measure,
log wall-time axis, numbered points with a side table of the settings, the reference's scatter
as a grey band, the experimental bands in green, the verdict below), ``speed_accuracy.csv``
(one row per run), ``speed_accuracy_settings.csv`` (one row per setting; the ``verdict``
column holds the verdict line in the row of the setting it names), ``speed_accuracy.json`` and
``speed_accuracy.md``.

    cfddem sweep cases/chute_16rpm --variants replicas.toml --vary time.dt=5e-6,1e-5,2e-5 ...
    cfddem accuracy runs/dt_study
"""

from __future__ import annotations

import copy
import csv
import json
import math
import textwrap
from pathlib import Path

import numpy as np

from ..errors import CaseError

BED_BAND_MM = 1.5
VELOCITY_BAND = 0.02
#: variants differing only in these keys are replicas of one setting
REPLICA_KEYS = ("checkpoint.perturb_seed", "checkpoint.perturb_velocity")
#: a deviation above this many times its uncertainty is distinguishable from the scatter
DISTINCT_FACTOR = 2.0
BANDS = {"bed_height_rms_mm": BED_BAND_MM, "surface_velocity_rel_rms": VELOCITY_BAND}
MEASURES = ("bed_height_rms_mm", "surface_velocity_rel_rms", "gas_velocity_rel_rms", "velocity_end_rel")
FONT = 9  # the smallest font on the chart


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


def _num(x) -> float:
    try:
        return float(x)
    except (TypeError, ValueError):
        return math.nan


# ------------------------------------------------------------------------ fields and deviations
def _fields(run) -> dict:
    """What the deviations compare: the chute's bed heights and surface velocities, the gas
    field (or None) and the end velocity."""
    return {"bed_height_sensor": np.asarray(run.chute["bed_height_sensor"], float),
            "surface_vz": np.asarray(run.chute["surface_vz"], float), "gas": _gas(run),
            "velocity_end": run.velocity_end()}


def mean_fields(fields: list[dict], what: str = "setting") -> dict:
    """The mean of several runs' :func:`_fields` (a point where one run has no value has none);
    the gas field only when every run has one."""
    if len(fields) == 1:
        return fields[0]
    out = {}
    for k in ("bed_height_sensor", "surface_vz"):
        shapes = {f[k].shape for f in fields}
        if len(shapes) > 1:
            raise CaseError("SWEEP_DIR", f"{what}: the replicas' {k} have different shapes {sorted(shapes)}")
        out[k] = np.mean([f[k] for f in fields], axis=0)
    out["velocity_end"] = float(np.mean([f["velocity_end"] for f in fields]))
    gas = [f["gas"] for f in fields]
    if all(g is not None for g in gas):
        shapes = {np.shape(g["mean_velocity"]) for g in gas}
        if len(shapes) > 1:
            raise CaseError("SWEEP_DIR", f"{what}: the replicas' gas grids differ {sorted(shapes)}")
        out["gas"] = {**{k: gas[0][k] for k in "xyz"},
                      "mean_velocity": np.mean([np.asarray(g["mean_velocity"], float) for g in gas], axis=0)}
    else:
        out["gas"] = None
    return out


def field_deviations(ref: dict, f: dict) -> dict:
    """The :data:`MEASURES` of fields ``f`` against the reference fields ``ref``."""
    bed, vel = deviations(ref, f)
    gas = gas_deviation(ref["gas"], f["gas"]) if ref["gas"] is not None and f["gas"] is not None else math.nan
    v0 = ref["velocity_end"]
    return {"bed_height_rms_mm": bed, "surface_velocity_rel_rms": vel, "gas_velocity_rel_rms": gas,
            "velocity_end_rel": (f["velocity_end"] - v0) / v0 if v0 else math.nan}


def noise_floor(fields: list[dict]) -> tuple[dict, list[dict]]:
    """(floor per measure, leave-one-out deviations per replica) of the reference replicas'
    fields: each replica against the mean of the others; the floor is the root-mean-square of
    those deviations (nan with fewer than two replicas; ``velocity_end_rel`` in absolute value)."""
    k = len(fields)
    if k < 2:
        return {m: math.nan for m in MEASURES}, [{m: 0.0 for m in MEASURES} for _ in fields]
    loo = [field_deviations(mean_fields(fields[:j] + fields[j + 1:]), fields[j]) for j in range(k)]
    floor = {m: float(np.sqrt(np.mean([d[m] ** 2 for d in loo]))) for m in MEASURES}
    return floor, loo


def uncertainty(floor: float, k: int, m: int, k_ref: int | None = None) -> float:
    """Run-to-run uncertainty of the deviation of a setting with ``m`` replicas from the mean of
    ``k_ref`` reference replicas (default ``k``), the floor ``floor`` measured as the
    leave-one-out floor of ``k`` replicas (of the reference, or of the setting named by
    ``--floor-from``; module docstring); 0 without a floor."""
    if k < 2 or not np.isfinite(floor):
        return 0.0
    k_ref = k if k_ref is None else k_ref
    return float(floor * math.sqrt((k - 1) / k) * math.sqrt(1.0 / m + 1.0 / k_ref))


# ------------------------------------------------------------------------------- settings
def group_settings(rows: list[dict], varied: list[str]) -> list[dict]:
    """The sweep's rows grouped into settings: ``key`` (the varied values other than the replica
    keys), ``names`` (its variants, in sweep order), ``values`` (key -> value)."""
    keys = [k for k in varied if k not in REPLICA_KEYS]
    groups: dict[tuple, dict] = {}
    for r in rows:
        key = tuple(r.get(k, "") for k in keys)
        g = groups.setdefault(key, {"key": key, "names": [], "values": dict(zip(keys, key))})
        g["names"].append(r["name"])
    return list(groups.values())


def _collision_time(run) -> float:
    """cfddem check's collision time of a run's resolved configuration (nan if it does not
    load: a configuration of another cfddem version)."""
    from ..config import build_case
    from ..simulation import collision_time

    cfg = copy.deepcopy(run.config)
    ck = cfg.get("checkpoint", {})
    ck["start_from"] = ""  # the source may be gone; it does not change t_c
    ck.pop("perturb_velocity", None)
    try:
        return float(collision_time(build_case(cfg, case_dir=run.folder)))
    except (CaseError, KeyError, TypeError, ValueError):
        return math.nan


def short_label(values: dict, t_c: float = math.nan) -> str:
    """``dt/t_c = 1/84, coupling_interval=64``: a setting's varied values, ``time.dt`` as a
    fraction of the collision time when it is known, other keys by their last part (empty
    values, the case's own, left out); ``base`` when none is set."""
    parts = []
    for k, v in values.items():
        if v in ("", None):
            continue
        dt = _num(v)
        if k == "time.dt" and np.isfinite(t_c) and dt > 0:
            r = t_c / dt
            parts.append(f"dt/t_c = 1/{r:.0f}" if r >= 1.5 else f"dt/t_c = {1 / r:.2g}")
        else:
            parts.append(f"{k.split('.')[-1]}={v}")
    return ", ".join(parts) or "base"


def _fail_reason(error: str) -> str:
    from ..stability import OTHER, classify

    cause = classify("failed", error or "").cause
    if cause != OTHER:
        return f"unstable: {cause}"
    first = (error or "").strip().splitlines()[0] if (error or "").strip() else "no message"
    return "failed: " + (first if len(first) <= 48 else first[:45] + "...")


def _fmt_dev(m: str, d: float, u: float) -> str:
    if not np.isfinite(d):
        return "-"
    if m == "bed_height_rms_mm":
        return f"{d:.2f} ± {u:.2f} mm" if u > 0 else f"{d:.2f} mm"
    return f"{100 * d:.2f} ± {100 * u:.2f} %" if u > 0 else f"{100 * d:.2f} %"


def _verdict(settings: list[dict], ref: dict, floor_known: bool, n_ref: int,
             floor_of: str | None = None) -> tuple[str, dict | None]:
    inside = [s for s in settings if s["within_bands"] and np.isfinite(s["wall_time"])]
    bands = f"(bed height {BED_BAND_MM:g} mm, surface velocity {100 * VELOCITY_BAND:g} %)"
    if not inside:
        return f"no setting lies inside both experimental bands {bands}", None
    best = min(inside, key=lambda s: s["wall_time"])
    if best is ref:
        others = [s for s in settings if s is not ref and s["status"] == "done"]
        what = "; no other setting is inside" if others else ""
        return (f"cheapest inside the experimental bands {bands}: the reference {best['label']} "
                f"({best['wall_time']:.3g} s){what}"), best
    speed = ref["wall_time"] / best["wall_time"] if best["wall_time"] > 0 else math.nan
    devs = ", ".join(f"{n} {_fmt_dev(m, best[m], best[m + '_unc'])}"
                     for m, n in (("bed_height_rms_mm", "bed"), ("surface_velocity_rel_rms", "surface velocity")))
    if not floor_known:
        tail = "run-to-run scatter unknown (no replicas of the reference)"
    elif best["distinguishable"]:
        tail = ("distinguishable from the reference's run-to-run scatter" if floor_of is None else
                f"distinguishable from the run-to-run scatter ({n_ref} replicas of {floor_of})")
    else:
        tail = (f"not distinguishable from the reference's run-to-run scatter ({n_ref} replicas)" if floor_of is None
                else f"not distinguishable from the run-to-run scatter ({n_ref} replicas of {floor_of})")
    return (f"cheapest inside the experimental bands {bands}: {best['label']} ({best['wall_time']:.3g} s, "
            f"{speed:.3g}x faster than the reference); {devs}; {tail}"), best


def speed_accuracy(sweep_dir: str | Path, reference: str | None = None, out: str | Path | None = None,
                   floor_from: str | None = None) -> dict:
    """Compute the deviations of every variant and setting, write the chart and the tables;
    returns the result (also written as ``speed_accuracy.json``).  ``floor_from``: a variant
    whose setting's replicas give the noise floor instead of the reference's (when the
    reference is too dear to repeat; the floor is then that setting's run-to-run scatter, said
    so on the chart and in the tables)."""
    sweep_dir = Path(sweep_dir)
    out = Path(out) if out else sweep_dir
    out.mkdir(parents=True, exist_ok=True)
    rows = _read_rows(sweep_dir)
    # the varied keys are the columns between name and status
    cols = list(rows[0].keys()) if rows else []
    varied = cols[1:cols.index("status")] if "status" in cols else []
    runs = {r["name"]: _run(sweep_dir / r["name"]) if r["status"] in ("done", "skipped") else None for r in rows}
    if not any(runs.values()):
        raise CaseError("SWEEP_DIR", f"{sweep_dir}: no finished variant with chute measurements")
    by_name = {r["name"]: r for r in rows}
    settings = group_settings(rows, varied)
    for s in settings:
        s["runs"] = [n for n in s["names"] if runs[n] is not None]
        s["wall_time"] = float(np.mean([_num(by_name[n].get("wall_time")) for n in (s["runs"] or s["names"])]))
    done = [s for s in settings if s["runs"]]
    if reference is None:
        if "time.dt" in varied:  # the smallest time step run (an empty cell: the case's), then the dearest
            def dt(s):
                d = _num(runs[s["runs"][0]].config.get("time", {}).get("dt", s["values"]["time.dt"]))
                return (d if np.isfinite(d) else math.inf, -s["wall_time"])

            ref = min(done, key=dt)
        else:
            ref = max(done, key=lambda s: s["wall_time"])
    else:
        cand = [s for s in done if reference in s["runs"]]
        if not cand:
            raise CaseError("--reference", f"no finished variant named {reference!r}; have: "
                                           + ", ".join(n for s in done for n in s["runs"]))
        ref = cand[0]
    fields = {n: _fields(r) for n, r in runs.items() if r is not None}
    ref_fields = [fields[n] for n in ref["runs"]]
    ref_mean = mean_fields(ref_fields, "the reference")
    k_ref = len(ref_fields)
    fsrc = ref
    if floor_from is not None:
        cand = [s for s in done if floor_from in s["runs"]]
        if not cand or len(cand[0]["runs"]) < 2:
            raise CaseError("--floor-from", f"{floor_from!r} is not a finished variant of a setting with at "
                                            "least two finished replicas")
        fsrc = cand[0]
    k = len(fsrc["runs"])
    floor, loo = noise_floor([fields[n] for n in fsrc["runs"]])
    if fsrc is not ref:
        loo = [{m: 0.0 for m in MEASURES} for _ in ref["runs"]]
    t_c_ref = _collision_time(runs[ref["runs"][0]])
    contact_varied = any(v.startswith(("contact.", "particles.")) for v in varied)

    table = []
    for r in rows:
        n = r["name"]
        entry = {"name": n, "status": r["status"], "wall_time": _num(r.get("wall_time")),
                 **{key: r[key] for key in varied}}
        entry["setting"] = next(i for i, s in enumerate(settings) if n in s["names"])
        run = runs[n]
        if run is not None:
            d = loo[ref["runs"].index(n)] if n in ref["runs"] else field_deviations(ref_mean, fields[n])
            entry.update(d)
            entry["within_bands"] = bool(d["bed_height_rms_mm"] <= BED_BAND_MM
                                         and d["surface_velocity_rel_rms"] <= VELOCITY_BAND)
            entry["velocity_end"] = fields[n]["velocity_end"]
            entry["gas_cfl_max"] = float(run.gas_solver.get("gas_cfl_max", math.nan))
        else:
            entry.update({m: math.nan for m in MEASURES}, within_bands=False, velocity_end=math.nan,
                         gas_cfl_max=math.nan, error=r.get("error", ""))
        table.append(entry)

    out_settings = []
    for i, s in enumerate(settings):
        is_ref = s is ref
        first = runs[s["runs"][0]] if s["runs"] else None
        t_c = _collision_time(first) if first is not None and contact_varied else t_c_ref
        e = {"setting": i, "label": short_label(s["values"], t_c), "names": s["names"], "values": s["values"],
             "n_replicas": len(s["runs"]), "n_failed": len(s["names"]) - len(s["runs"]),
             "wall_time": s["wall_time"], "reference": is_ref,
             "status": "done" if s["runs"] else "failed"}
        if s["runs"]:
            m = len(s["runs"])
            d = ({mm: 0.0 for mm in MEASURES} if is_ref
                 else field_deviations(ref_mean, mean_fields([fields[n] for n in s["runs"]], e["label"])))
            for mm in MEASURES:
                e[mm] = d[mm]
                e[mm + "_unc"] = 0.0 if is_ref else uncertainty(floor[mm], k, m, k_ref)
            e["within_bands"] = is_ref or all(e[mm] + e[mm + "_unc"] <= b for mm, b in BANDS.items())
            e["distinguishable"] = (not is_ref and k >= 2
                                    and any(abs(e[mm]) > DISTINCT_FACTOR * e[mm + "_unc"] for mm in BANDS))
            e["velocity_end"] = float(np.mean([fields[n]["velocity_end"] for n in s["runs"]]))
            cfl = [runs[n].gas_solver.get("gas_cfl_max", math.nan) for n in s["runs"]]
            e["gas_cfl_max"] = float(np.max(cfl))
        else:
            e.update({mm: math.nan for mm in MEASURES}, within_bands=False, distinguishable=False,
                     velocity_end=math.nan, gas_cfl_max=math.nan,
                     reason=_fail_reason(by_name[s["names"][0]].get("error", "")))
            e.update({mm + "_unc": math.nan for mm in MEASURES})
        out_settings.append(e)
    ref_e = out_settings[settings.index(ref)]
    floor_label = out_settings[settings.index(fsrc)]["label"]
    verdict, best = _verdict(out_settings, ref_e, k >= 2, k, None if fsrc is ref else floor_label)
    for e in out_settings:
        e["verdict"] = verdict if e is best else ""
    result = {"reference": ref["runs"][0], "reference_setting": ref_e["label"], "reference_runs": ref["runs"],
              "varied": varied, "replica_keys": list(REPLICA_KEYS), "rows": table, "settings": out_settings,
              "noise_floor": {"n_replicas": k, **floor, "setting": floor_label, "of_reference": fsrc is ref},
              "verdict": verdict,
              "verdict_setting": best["setting"] if best is not None else None,
              "bands": {"bed_height_mm": BED_BAND_MM, "surface_velocity_rel": VELOCITY_BAND}}
    (out / "speed_accuracy.json").write_text(json.dumps(result, indent=1, allow_nan=True))
    _write_csv(out / "speed_accuracy.csv", table,
               ["name", *varied, "setting", "status", "wall_time", "bed_height_rms_mm", "surface_velocity_rel_rms",
                "within_bands", "gas_velocity_rel_rms", "velocity_end", "velocity_end_rel", "gas_cfl_max", "error"])
    _write_csv(out / "speed_accuracy_settings.csv", out_settings,
               ["setting", "label", "reference", "n_replicas", "n_failed", "status", "wall_time",
                *[c for mm in MEASURES for c in (mm, mm + "_unc")], "within_bands", "distinguishable",
                "velocity_end", "gas_cfl_max", "reason", "verdict"])
    (out / "speed_accuracy.md").write_text(markdown(result))
    _chart(result, out / "speed_accuracy.png")
    return result


def _write_csv(path: Path, entries: list[dict], head: list[str]) -> None:
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(head)
        for e in entries:
            w.writerow([e.get(h, "") for h in head])


def markdown(result: dict) -> str:
    """The settings table, the noise floor and the verdict in Markdown."""
    fl = result["noise_floor"]
    k = fl["n_replicas"]
    lines = ["# Speed against accuracy", "", f"**Verdict:** {result['verdict']}", "",
             f"Reference: {result['reference_setting']} ({len(result['reference_runs'])} "
             f"run{'s' if len(result['reference_runs']) != 1 else ''}: "
             + ", ".join(result["reference_runs"]) + ")."]
    if k >= 2:
        whose = "a reference replica" if fl.get("of_reference", True) else \
            f"one of the {k} replicas of {fl.get('setting')} (the reference is not repeated)"
        lines += ["", f"Noise floor (RMS deviation of {whose} from the mean of the others): bed height "
                  f"{fl['bed_height_rms_mm']:.3g} mm, surface velocity {100 * fl['surface_velocity_rel_rms']:.3g} %"
                  + (f", gas velocity {100 * fl['gas_velocity_rel_rms']:.3g} %"
                     if np.isfinite(fl["gas_velocity_rel_rms"]) else "") + "."]
    else:
        lines += ["", "No replicas of the reference: the run-to-run scatter is unknown."]
    lines += ["", "| # | setting | runs | wall time [s] | bed height [mm] | surface velocity [%] | gas velocity [%] "
              "| end velocity [%] | inside bands |", "|---|---|---|---|---|---|---|---|---|"]
    for e, num in zip(result["settings"], _numbers(result)):
        if e["status"] == "failed":
            lines.append(f"| {num} | {e['label']} | {len(e['names'])} | {e['wall_time']:.3g} | {e['reason']} "
                         "| | | | no |")
            continue
        if e["reference"]:
            cells = [f"scatter {fl['bed_height_rms_mm']:.2f} mm", f"scatter {100 * fl['surface_velocity_rel_rms']:.2f} %",
                     f"scatter {100 * fl['gas_velocity_rel_rms']:.2f} %", f"scatter {100 * fl['velocity_end_rel']:.2f}"]
            cells = [c if "nan" not in c else "reference" for c in cells]
            lines.append(f"| {num} | {e['label']} | {e['n_replicas']} | {e['wall_time']:.3g} | " + " | ".join(cells)
                         + " | yes |")
            continue
        g = e["gas_velocity_rel_rms"]
        gas = _fmt_dev("gas", g, e["gas_velocity_rel_rms_unc"]) if np.isfinite(g) else "-"
        lines.append(f"| {num} | {e['label']} | {e['n_replicas']} | {e['wall_time']:.3g} "
                     f"| {_fmt_dev('bed_height_rms_mm', e['bed_height_rms_mm'], e['bed_height_rms_mm_unc'])} "
                     f"| {_fmt_dev('v', e['surface_velocity_rel_rms'], e['surface_velocity_rel_rms_unc'])} "
                     f"| {gas} | {100 * e['velocity_end_rel']:+.2f} | {'yes' if e['within_bands'] else 'no'} |")
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------- chart
def _numbers(result: dict) -> list[str]:
    """The settings' chart labels: ``R`` for the reference, the others 1, 2, ... by wall time."""
    order = sorted((i for i, e in enumerate(result["settings"]) if not e["reference"]),
                   key=lambda i: (not np.isfinite(result["settings"][i]["wall_time"]),
                                  result["settings"][i]["wall_time"]))
    nums = ["R"] * len(result["settings"])
    for j, i in enumerate(order):
        nums[i] = str(j + 1)
    return nums


def _overlaps(bb, others, pad: float = 1.0) -> bool:
    return any(bb.x0 < o.x1 + pad and o.x0 < bb.x1 + pad and bb.y0 < o.y1 + pad and o.y0 < bb.y1 + pad
               for o in others)


def text_box(t, renderer):
    """The box of a text in display pixels; of an annotation, its text's without the leader line."""
    from matplotlib.text import Annotation, Text

    if isinstance(t, Annotation):
        t.update_positions(renderer)
    return Text.get_window_extent(t, renderer)


def place_labels(ax, points, texts, renderer, avoid=(), **kw):
    """Annotate each point (data coordinates) with its text, at the first of a ring of offsets
    (growing distance, eight directions) where the text's box overlaps no text placed before,
    no point marker and no box of ``avoid``, and lies inside the axes; where none is free, the
    candidate with the smallest overlap.  A label placed away from its point gets a thin leader
    line.  Returns the annotations."""
    from matplotlib.transforms import Bbox

    ms = renderer.points_to_pixels(4.5)
    markers = [Bbox([[x - ms, y - ms], [x + ms, y + ms]]) for x, y in (ax.transData.transform(p) for p in points)]
    inside = ax.get_window_extent(renderer)
    placed = list(avoid)
    anns = []
    dirs = [(1, 1), (1, -1), (-1, 1), (-1, -1), (1, 0), (0, 1), (-1, 0), (0, -1)]

    def cost(bb):
        c = sum(max(0.0, min(bb.x1, o.x1) - max(bb.x0, o.x0) + 1.0) * max(0.0, min(bb.y1, o.y1) - max(bb.y0, o.y0) + 1.0)
                for o in placed + markers if _overlaps(bb, [o]))
        out = not (inside.x0 <= bb.x0 and bb.x1 <= inside.x1 and inside.y0 <= bb.y0 and bb.y1 <= inside.y1)
        return c + (1e6 if out else 0.0)

    for p, text in zip(points, texts):
        best, best_cost = None, math.inf
        for r in (7, 12, 18, 26, 36, 48, 64):
            for dx, dy in dirs:
                opts = dict(xytext=(r * dx, r * dy), textcoords="offset points",
                            ha="left" if dx > 0 else ("right" if dx < 0 else "center"),
                            va="bottom" if dy > 0 else ("top" if dy < 0 else "center"))
                a = ax.annotate(text, p, fontsize=FONT, annotation_clip=False, **opts, **kw)
                c = cost(a.get_window_extent(renderer))
                a.remove()
                if c < best_cost:
                    best, best_cost = (r, opts), c
                if c == 0.0:
                    break
            if best_cost == 0.0:
                break
        r, opts = best
        arrow = dict(arrowstyle="-", color="0.5", lw=0.7, shrinkA=0, shrinkB=3) if r > 12 else None
        a = ax.annotate(text, p, fontsize=FONT, annotation_clip=False, arrowprops=arrow, **opts, **kw)
        placed.append(text_box(a, renderer))
        anns.append(a)
    return anns


def _chart(result: dict, path: Path) -> None:
    fig, _ = draw_chart(result)
    fig.savefig(path, dpi=120)
    import matplotlib.pyplot as plt

    plt.close(fig)


def draw_chart(result: dict):
    """The figure (one panel per measure with a value, the settings table at the right, the
    verdict below) and the list of its label texts (point numbers and table cells)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sets = result["settings"]
    nums = _numbers(result)
    fl = result["noise_floor"]
    specs = [("bed_height_rms_mm", "bed height deviation [mm]", 1.0),
             ("surface_velocity_rel_rms", "surface velocity deviation [%]", 100.0)]
    if any(np.isfinite(e.get("gas_velocity_rel_rms", np.nan)) and not e["reference"] for e in sets):
        specs.append(("gas_velocity_rel_rms", "gas velocity deviation [%]", 100.0))
    # the settings table (right of the panels): its cells, their widths measured in points
    order = sorted(range(len(sets)), key=lambda i: (nums[i] != "R", int(nums[i]) if nums[i].isdigit() else 0))
    rows = [("#", "setting", "wall [s]", "in bands")]
    for i in order:
        e = sets[i]
        if e["status"] == "failed":
            lab = f"{e['label']}: {e['reason']}"
        else:
            lab = e["label"] + (f" ({e['n_replicas']} runs)" if e["n_replicas"] > 1 else "")
        rows.append((nums[i], _shorten(lab, 48), f"{e['wall_time']:.3g}" if np.isfinite(e["wall_time"]) else "-",
                     "-" if e["status"] == "failed" else ("yes" if e["within_bands"] else "no")))
    legend = ["R: the reference (black diamond)"]
    of_ref = fl.get("of_reference", True)
    if fl["n_replicas"] >= 2 and of_ref:
        legend += ["grey squares: its replicas, each against the others", "grey band: its run-to-run scatter"]
    elif fl["n_replicas"] >= 2:
        legend += [f"grey band: run-to-run scatter of {fl['n_replicas']} replicas", f"  of {_shorten(str(fl['setting']), 40)}"]
    else:
        legend += ["no replicas of it: scatter unknown"]
    legend += ["green band: experimental error", "blue / orange: inside / outside the bands"]
    legend += ["red x: failed or unstable"] if any(e["status"] == "failed" for e in sets) else []
    gap = 8.0  # points between the columns
    widths = [max(_text_width(r[c], bold=True) for r in rows) + gap for c in range(4)]
    w_table = max(sum(widths), max(_text_width(t) for t in legend)) / 72 + 0.5
    w_panel = 3.7
    fig_w = w_panel * len(specs) + w_table
    # room for the table: its rows and the legend's lines, 1.45 lines of 9 pt each
    fig_h = max(5.0, (len(rows) + len(legend) + 1) * FONT * 1.45 / 72 / 0.68)
    fig = plt.figure(figsize=(fig_w, fig_h), dpi=100)
    left, right_edge = 0.75 / fig_w, (fig_w - w_table) / fig_w
    gs = fig.add_gridspec(1, len(specs), left=left, right=right_edge, bottom=0.22, top=0.9, wspace=0.42)
    axes = [fig.add_subplot(gs[0, i]) for i in range(len(specs))]
    renderer = fig.canvas.get_renderer()
    ok = [e for e in sets if e["status"] == "done"]
    walls = [e["wall_time"] for e in sets if np.isfinite(e["wall_time"]) and e["wall_time"] > 0]
    lo, hi = (min(walls), max(walls)) if walls else (1.0, 10.0)
    xlim = (lo / 1.6, hi * 1.6)
    labels = []
    ref_rows = [r for r in result["rows"] if r["name"] in result["reference_runs"]] \
        if fl.get("of_reference", True) else []
    for ax, (key, ylabel, scale) in zip(axes, specs):
        band = BANDS.get(key)
        top = max([band * 1.3 if band is not None else 0.0, fl.get(key, 0.0) * 1.3 if np.isfinite(fl.get(key, np.nan))
                   else 0.0] + [abs(e[key]) + e[key + "_unc"] for e in ok if np.isfinite(e[key])])
        top = (top if top > 0 else 1e-3) * 1.15 * scale
        if band is not None:
            ax.axhspan(0, band * scale, color="tab:green", alpha=0.13, lw=0)
            ax.axhline(band * scale, color="tab:green", lw=1.2)
        if np.isfinite(fl.get(key, np.nan)):
            ax.axhspan(0, fl[key] * scale, color="0.55", alpha=0.3, lw=0)
            for r in ref_rows:
                ax.plot(r["wall_time"], abs(r[key]) * scale, "s", color="0.35", ms=4, zorder=3)
        pts, txt = [], []
        for e, n in zip(sets, nums):
            if e["status"] != "done" or not np.isfinite(e[key]):
                continue
            y = abs(e[key]) * scale
            if e["reference"]:
                ax.plot(e["wall_time"], y, "D", color="k", ms=6, zorder=4, clip_on=False)
            else:
                color = "tab:blue" if e["within_bands"] else "tab:orange"
                ax.errorbar(e["wall_time"], y, yerr=e[key + "_unc"] * scale if e[key + "_unc"] > 0 else None,
                            fmt="o", color=color, ms=6, capsize=3, zorder=4)
            pts.append((e["wall_time"], y))
            txt.append(n)
        for e, n in zip(sets, nums):
            if e["status"] == "failed":
                wt = e["wall_time"] if np.isfinite(e["wall_time"]) and e["wall_time"] > 0 else xlim[0] * 1.2
                ax.plot(wt, top * 0.97, "x", color="tab:red", ms=9, mew=2, clip_on=False, zorder=5)
                pts.append((wt, top * 0.97))
                txt.append(n)
        ax.set_xscale("log")
        ax.set_xlim(*xlim)
        _wall_ticks(ax, xlim)
        ax.set_ylim(0, top)
        ax.set_xlabel("wall time [s]", fontsize=10)
        ax.set_ylabel(ylabel, fontsize=10)
        ax.tick_params(labelsize=FONT)
        ax.grid(alpha=0.3)
        labels += place_labels(ax, pts, txt, renderer, color="0.1", fontweight="bold")
    tax = fig.add_axes([right_edge + 0.35 / fig_w, 0.22, (w_table - 0.45) / fig_w, 0.68])
    tax.axis("off")
    colors = ["k"] + ["tab:red" if sets[i]["status"] == "failed" else "k" for i in order]
    dy = FONT * 1.45 / 72 / (0.68 * fig_h)
    x = 0.0
    for c in range(4):
        labels += [tax.text(x, 1.0 - j * dy, row[c], fontsize=FONT, va="top", color=colors[j],
                            fontweight="bold" if j == 0 else "normal", transform=tax.transAxes)
                   for j, row in enumerate(rows)]
        x += widths[c] / 72 / (w_table - 0.45)
    for j, line in enumerate(legend):
        labels.append(tax.text(0.0, 1.0 - (len(rows) + 0.6 + j) * dy, line, fontsize=FONT, va="top", color="0.3",
                               transform=tax.transAxes))
    fig.suptitle(f"Speed against accuracy: deviation from the reference {result['reference_setting']}",
                 fontsize=11)
    wrap = textwrap.fill("Verdict: " + result["verdict"], width=int((fig_w - 1.0) * 13))
    fig.text(0.75 / fig_w, 0.03, wrap, fontsize=10, va="bottom")
    return fig, labels


def _wall_ticks(ax, xlim) -> None:
    """Wall-time ticks written plainly (200, 500, 1000) at 1-2-5 steps (1-3 steps, or decades,
    over more than two decades), or 1-1.5-2-3-5-7 steps when the range holds fewer than three
    of those; no minor tick labels."""
    from matplotlib.ticker import FixedLocator, FuncFormatter, NullFormatter

    e0, e1 = int(math.floor(math.log10(xlim[0]))), int(math.ceil(math.log10(xlim[1])))
    decades = math.log10(xlim[1] / xlim[0])
    # over more than two decades 1-2-5 ticks crowd a panel (500 and 1000 run into each other)
    first = ((1, 3), (1,)) if decades > 2.2 else ((1, 2, 5),)
    for mant in first + ((1, 1.5, 2, 3, 5, 7), (1, 1.2, 1.5, 2, 2.5, 3, 4, 5, 6, 7, 8, 9)):
        ticks = [m * 10.0**e for e in range(e0, e1 + 1) for m in mant if xlim[0] <= m * 10.0**e <= xlim[1]]
        if len(ticks) >= 3 and (len(ticks) <= 7 or len(mant) == 1):
            break
    ax.xaxis.set_major_locator(FixedLocator(ticks))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.xaxis.set_minor_formatter(NullFormatter())


def _text_width(s: str, bold: bool = False) -> float:
    """The width of a text at the chart's font size, in points."""
    from matplotlib.backends.backend_agg import RendererAgg
    from matplotlib.font_manager import FontProperties

    w, _, _ = RendererAgg(10, 10, 72).get_text_width_height_descent(
        s, FontProperties(size=FONT, weight="bold" if bold else "normal"), ismath=False)
    return float(w)


def _shorten(s: str, n: int) -> str:
    return s if len(s) <= n else s[: n - 3] + "..."
