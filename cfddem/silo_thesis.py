"""The flat-bottomed planar-silo studies of the blending thesis's chapter 5 (silo-studies.md §2,
docs/silo-thesis.md) on ``cases/silo_thesis_small``:

    python -m cfddem.silo_thesis front-back  [--values 0,0.2,0.3,0.5,0.75,1] [--no-periodic] ...
    python -m cfddem.silo_thesis friction    [--mu 0.15,0.57] [--mu-r 0,0.1,0.2] ...
    python -m cfddem.silo_thesis restitution [--values 1e-4,0.6,1] ...
    python -m cfddem.silo_thesis floor-drop  [--values 0,0.00025,0.0005,0.001,0.0019] ...
    python -m cfddem.silo_thesis floor-speed [--values 0.001,0.005,0.025] [--depth 0.001] ...
    (each also takes --replicas N --case CASE --out DIR --set K=V ... --workers N --threads T)

* ``front-back``: the friction of the front and back walls (``silo.front_back.mu``) over the
  values, and the variant with a periodic depth instead of those walls
  (``silo.depth_boundary = "periodic"``);
* ``friction``: particle-particle sliding friction (``contact.particle_particle.mu``) times
  rolling friction (``contact.particle_particle.mu_r``);
* ``restitution``: the restitution coefficient of every contact (``contact.particle_particle.e_n``
  and ``contact.particle_wall.e_n`` together);
* ``floor-drop``: the depth of the floor's settlement once the fill has settled
  (``silo.floor_drop``, m; every variant with ``silo.gate = "settled"``, so that 0 is the same
  fill and gate without the drop); the front/back friction is the case's (``--set``).  Besides
  the charts below it draws ``<study>_mobilised.png``: the weight carried by each wall group,
  the friction the walls carry and the vertical stress against Janssen's, against the depth;
* ``floor-speed``: the speed of that settlement (``silo.floor_drop_speed``, m/s) at one depth
  (``--depth``, m, default 1 mm), every variant with the settled gate; the same charts, against
  the speed (log axis).  A slower drop takes longer: give ``time.end_time`` room for the slowest
  (settled fill + depth / speed + ``silo.floor_drop_wait`` + the discharge).

Each study is a sweep (:func:`cfddem.sweep.run_sweep`: Dask, one run folder per variant,
finished runs reused) into ``--out`` (default ``CASE/<study>``).  ``--replicas N`` fills each
variant N times (``particles.seed`` + 0, ..., N - 1: other jitters of the fill; the first is the
unreplicated run): the tables then give mean ± standard deviation and ``<study>_runs.csv`` every
run, and the charts draw the means with error bars (combine_replicas, mean_measurements).  From each run's results.h5
(the silo scene's ``/measurements``: docs/silo.md) it writes ``<study>.csv`` and ``<study>.md``
(per variant: mass flow rate, bulk density, flow pattern, the kinematic model's B at each profile
height, the flow-channel width there, the vertical stress on the floor region against Janssen's,
status and wall time), ``<study>_profiles.png`` (the time-averaged vertical-velocity profiles
across the width at each height, depth-averaged and in the layer at the front wall, one line per
variant) and ``<study>.png`` (B and the channel width against height, the centreline velocity
against time, the flow rate against the swept value, the vertical stress at the end of the fill
with Janssen's curve) and, for runs that stored the wall profile, ``<study>_walls.png`` (the
friction the walls carry against height at the end of the fill, and the front/back walls' normal
stress).
"""

from __future__ import annotations

import argparse
import math
import os
import warnings
from pathlib import Path

import numpy as np

from .errors import CaseError
from .measure.stats import mean_sd
from .silo_prisms import (PP, PW, _floats, _fmt, _plt, _save, add_study_arguments, load_study_case, run_study,
                          write_table)

CASE = Path(__file__).resolve().parent.parent / "cases" / "silo_thesis_small"
STUDIES = ("front-back", "friction", "restitution", "floor-drop", "floor-speed")
DEFAULTS = {"front-back": [0.0, 0.2, 0.3, 0.5, 0.75, 1.0], "mu": [0.15, 0.57], "mu_r": [0.0, 0.1, 0.2],
            "restitution": [1e-4, 0.6, 1.0], "floor-drop": [0.0, 0.00025, 0.0005, 0.001, 0.0019],
            "floor-speed": [0.001, 0.005, 0.025]}
DROP_DEPTH = 0.001  # floor-speed: the default depth of the drop (m)


def study_variants(study: str, values=None, periodic: bool = True, mu=None, mu_r=None,
                   depth: float = DROP_DEPTH) -> list[dict]:
    """The variants of a study: dicts with ``label`` (legend text), ``group`` (one line per group
    in the flow-rate chart), ``x`` (the swept value on that chart's axis; NaN for the periodic
    variant) and ``overrides`` (the case keys)."""
    if study == "front-back":
        out = [{"label": f"front/back mu {v:g}", "group": "walls", "x": float(v),
                "overrides": {"silo.front_back.mu": float(v)}} for v in (values or DEFAULTS["front-back"])]
        if periodic:
            out.append({"label": "periodic depth", "group": "periodic", "x": math.nan,
                        "overrides": {"silo.depth_boundary": "periodic"}})
        return out
    if study == "friction":
        return [{"label": f"mu {m:g}, mu_r {r:g}", "group": f"mu_pp {m:g}", "x": float(r),
                 "overrides": {PP + "mu": float(m), PP + "mu_r": float(r)}}
                for m in (mu or DEFAULTS["mu"]) for r in (mu_r or DEFAULTS["mu_r"])]
    if study == "restitution":
        return [{"label": f"e {e:g}", "group": "e", "x": float(e), "overrides": {PP + "e_n": float(e), PW + "e_n": float(e)}}
                for e in (values or DEFAULTS["restitution"])]
    if study == "floor-drop":
        return [{"label": f"floor drop {1e3 * v:g} mm", "group": "floor drop", "x": 1e3 * float(v),
                 "overrides": {"silo.floor_drop": float(v), "silo.gate": "settled"}}
                for v in (values if values is not None else DEFAULTS["floor-drop"])]
    if study == "floor-speed":
        return [{"label": f"drop at {1e3 * v:g} mm/s", "group": f"floor drop {1e3 * depth:g} mm", "x": 1e3 * float(v),
                 "overrides": {"silo.floor_drop": float(depth), "silo.floor_drop_speed": float(v), "silo.gate": "settled"}}
                for v in (values or DEFAULTS["floor-speed"])]
    raise CaseError("study", f"{study!r}: one of {', '.join(STUDIES)}")


def replicate(variants: list[dict], replicas: int, seed0: int) -> list[dict]:
    """Each variant ``replicas`` times, one after the other: replica k with ``particles.seed``
    = seed0 + k (another jitter of the fill lattice, or of each poured layer); replica 0 with
    the case's own seed and no override, so that it is the unreplicated study's run (reused)."""
    if replicas < 1:
        raise CaseError("--replicas", f"needs at least 1, got {replicas}")
    out = []
    for v in variants:
        for k in range(replicas):
            ov = dict(v["overrides"])
            if k:
                ov["particles.seed"] = seed0 + k
            out.append(dict(v, overrides=ov, replica=k, seed=seed0 + k))
    return out


_NOT_AVERAGED = ("label", "group", "x", "status", "wall_time", "m", "flow_pattern", "replica", "seed")


def combine_replicas(runs: list[dict], replicas: int) -> list[dict]:
    """One table row per variant from its ``replicas`` consecutive run rows: every number the
    mean over the replicas that have it, with ``<key>_sd`` its standard deviation (ddof 1);
    ``<key>_n`` how many replicas have it, ``n_measured`` the replicas with a flow rate; the flow patterns with their counts when they
    differ; the wall times summed; ``m`` the replicas' measurements averaged (mean_measurements).
    With one replica the rows come back as they are."""
    if replicas == 1:
        return runs
    out = []
    for i in range(0, len(runs), replicas):
        grp = runs[i:i + replicas]
        t = {k: grp[0][k] for k in ("label", "group", "x")}
        done = sum(g["status"] in ("done", "done (reused)") for g in grp)
        t["status"] = f"{done} of {len(grp)} done"
        t["wall_time"] = float(sum(g["wall_time"] for g in grp if math.isfinite(g["wall_time"])))
        keys = [k for g in grp for k in g if k not in _NOT_AVERAGED]
        for k in dict.fromkeys(keys):
            t[k], t[f"{k}_sd"], n = mean_sd([g.get(k, math.nan) for g in grp])
            t[f"{k}_n"] = n
            if k == "flow_rate":
                t["n_measured"] = n
        pats = [g["flow_pattern"] for g in grp if g["flow_pattern"]]
        t["flow_pattern"] = pats[0] if len(set(pats)) == 1 else ", ".join(
            f"{p} {pats.count(p)}" for p in dict.fromkeys(pats))
        t["m"] = mean_measurements([g["m"] for g in grp if g["m"] is not None])
        t["replicas"] = len(grp)
        out.append(t)
    return out


def mean_measurements(ms: list[dict]):
    """The silo measurements of several replicas averaged, for the charts: arrays and numbers of
    the same shape in every replica are averaged (NaN-aware), anything else is the first
    replica's; the kinematic B's error bars become the standard deviation of B over the
    replicas.  None without measurements, the dict itself for one."""
    if not ms:
        return None
    if len(ms) == 1:
        return ms[0]

    def avg(vals):
        if all(isinstance(v, dict) for v in vals):
            return {k: avg([v[k] for v in vals]) if all(k in v for v in vals) else vals[0][k] for k in vals[0]}
        try:
            a = [np.asarray(v, float) for v in vals]
        except (TypeError, ValueError):
            return vals[0]
        if any(x.shape != a[0].shape for x in a):
            return vals[0]
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN entries stay NaN
            return np.nanmean(np.stack(a), axis=0)

    m = avg(ms)
    for layer in ("depth", "front"):
        try:
            B = np.stack([np.asarray(x["profiles"][layer]["B"], float) for x in ms])
        except (KeyError, TypeError, ValueError):
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            m["profiles"][layer]["B_err"] = np.nanstd(B, axis=0, ddof=1)
    return m


X_LABEL = {"front-back": "front/back wall friction mu", "friction": "rolling friction mu_r (particle-particle)",
           "restitution": "restitution coefficient e", "floor-drop": "floor drop once settled (mm)",
           "floor-speed": "speed of the floor's descent (mm/s)"}


def _num(v) -> float:
    try:
        return float(np.asarray(v))
    except (TypeError, ValueError):
        return math.nan


def _text(v) -> str:
    return v.decode() if isinstance(v, bytes) else str(v) if v is not None else ""


def _status(st: str) -> str:
    """A variant's status for the tables: the sweep's "skipped" (a finished run found in the
    study folder and reused, cfddem.sweep) reads "done (reused)"."""
    return "done (reused)" if st == "skipped" else st


def read_variant(row: dict, variant: dict) -> dict:
    """One table row from a sweep row and its run's results.h5 (NaN and "" where missing)."""
    from .io.results import read_measurements

    out = {"label": variant["label"], "group": variant["group"], "x": variant["x"],
           "status": _status(row.get("status", "")), "wall_time": _num(row.get("wall_time", math.nan)), "m": None}
    h5 = Path(row["out_dir"]) / "results.h5"
    m = read_measurements(h5) if h5.is_file() else {}
    s = m.get("silo", {})
    out.update(flow_rate=_num(m.get("mass_flow_rate")), bulk_density=_num(m.get("bulk_density")),
               clogged=int(_num(m.get("clogged", 0)) == 1), fill_height=_num(s.get("fill_height")),
               flow_pattern=_text(s.get("flow_pattern", "")))
    p = s.get("profiles")
    if p is not None:
        out["m"] = s
        det = p.get("flow_pattern_details", {}) or {}
        out["h_t_over_H"] = _num(det.get("h_t_over_H", math.nan))
        for k, z in enumerate(np.asarray(p["heights"], float)):
            tag = f"{z * 1e3:g}"
            out[f"B_{tag}"] = float(p["depth"]["B"][k]) * 1e3
            out[f"B_err_{tag}"] = float(p["depth"]["B_err"][k]) * 1e3
            out[f"B_front_{tag}"] = float(p["front"]["B"][k]) * 1e3
            out[f"channel_{tag}"] = float(p["channel"]["width"][k]) * 1e3
    st = s.get("stress")
    if st is not None:
        y, pr, jz, H = (np.asarray(st[k], float) for k in ("y", "pressure", "janssen", "H"))
        band = (y > 0.1 * H) & (y < 0.2 * H)  # away from the floor's kernel edge
        out["stress_low"] = float(pr[band].mean()) if band.any() else math.nan
        out["janssen_low"] = float(jz[band].mean()) if band.any() else math.nan
        if "hydrostatic" in st:
            hy = np.asarray(st["hydrostatic"], float)
            out["hydrostatic_low"] = float(hy[band].mean()) if band.any() else math.nan
        out["z_c"] = _num(st["z_c"])
        for k in ("K_x", "K_z"):  # the measured lateral pressure ratios (runs from before they were stored: NaN)
            out[k] = float(np.nanmean(np.asarray(st[k], float)[band])) if k in st and band.any() else math.nan
        out["janssen_low_K"] = janssen_measured_k(st, band, out["K_x"], out["K_z"])
    wl = s.get("fill_wall_load")
    if wl is not None:  # runs from before it was stored: NaN
        labels = [_text(x) for x in np.atleast_1d(wl["labels"])]
        out.update(wall_shares(labels, np.atleast_1d(wl["share"])))
        out.update(mobilised_friction(labels, np.asarray(wl["force"], float).reshape(-1, 3),
                                      np.asarray(wl["load"], float).reshape(-1)))
    fd = s.get("floor_drop")
    out["floor_drop"] = 1e3 * _num(fd["depth"]) if fd is not None else 0.0
    out["floor_drop_speed"] = 1e3 * _num(fd["speed"]) if fd is not None else math.nan
    return out


def janssen_measured_k(st: dict, band, K_x: float, K_z: float) -> float:
    """Janssen's vertical stress over ``band`` (mean, Pa) with the measured lateral pressure
    ratios instead of K from the bulk friction: K_x against the side walls, K_z against the
    front and back walls (z_c = W T / (2 (K_x mu_side T + K_z mu_front W))), the bed's weight
    density from the stored hydrostatic line (NaN where either ratio is)."""
    from .measure.coarse import janssen

    if not (band.any() and math.isfinite(K_x) and math.isfinite(K_z)):
        return math.nan
    y = np.asarray(st["y"], float)[band]
    H, W, T = (float(st[k]) for k in ("H", "W", "T"))
    gamma = float(np.mean(np.asarray(st["hydrostatic"], float)[band] / (H - y)))
    return float(np.mean(janssen(y, H, gamma, W, T, 1.0, K_x * float(st["mu_side"]), K_z * float(st["mu_front"]))))


def mobilised_friction(labels: list[str], force, load) -> dict:
    """How much of their friction the walls carry at the end of the fill: for the front and
    back walls together, and for the side walls, their force along gravity (``load``, the
    weight they hold up) over their horizontal force (the normal load on a vertical wall), from
    /measurements/silo/fill_wall_load.  At most the wall friction mu; Janssen's analysis
    assumes mu (fully mobilised).  NaN for walls that are absent or carry no normal load."""
    from .scenes.silo import WALL_PAIRS  # (not at import, as in wall_shares)

    force, load = np.asarray(force, float), np.asarray(load, float)
    out = {}
    for pair, names in WALL_PAIRS.items():
        key = f"mobilised_{pair}"
        idx = [i for i, k in enumerate(labels) if k in names]
        # the horizontal part of each wall's force (load is its component along gravity)
        horiz = np.sqrt(np.maximum(np.sum(force[idx] ** 2, axis=1) - load[idx] ** 2, 0.0))
        n = float(horiz.sum())
        out[key] = float(load[idx].sum()) / n if n > 0 else math.nan
    return out


def wall_shares(labels: list[str], share) -> dict:
    """The walls' shares of the weight at the end of the fill (/measurements/silo/fill_wall_load),
    in per cent, grouped: the front and back walls, the side walls (left, right), and the rest
    (bottom plates or hopper walls, lips, gate, internals)."""
    from .scenes.silo import WALL_PAIRS  # (not at import: the scenes start numba, and the study sets its threads)

    share = np.asarray(share, float)
    fb = sum(float(v) for k, v in zip(labels, share) if k in WALL_PAIRS["front_back"])
    sd = sum(float(v) for k, v in zip(labels, share) if k in WALL_PAIRS["sides"])
    return {"share_front_back": 100 * fb, "share_sides": 100 * sd, "share_floor": 100 * (float(share.sum()) - fb - sd)}


def study_table(rows: list[dict], variants: list[dict]) -> list[dict]:
    return [read_variant(r, v) for r, v in zip(rows, variants)]


def _heights(table: list[dict]) -> list[str]:
    for t in table:
        if t["m"] is not None:
            return [f"{z * 1e3:g}" for z in np.asarray(t["m"]["profiles"]["heights"], float)]
    return []


def machine_notes() -> list[str]:
    """The CPU model and the load average when the tables were written."""
    cpu = ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    la = os.getloadavg() if hasattr(os, "getloadavg") else (math.nan,) * 3
    return [f"machine: {cpu or 'CPU unknown'}, {os.cpu_count()} cores; load average {la[0]:.2f}, {la[1]:.2f}, "
            f"{la[2]:.2f} (1, 5, 15 min) when the table was written"]


def write_study(study: str, table: list[dict], out: Path, notes: list[str], runs: list[dict] | None = None
                ) -> list[Path]:
    """The study's tables and charts (module doc).  With ``runs`` (the rows of every replica;
    ``table`` then holds their means, combine_replicas) the Markdown table reads mean ± s.d.,
    the CSV has each column's s.d. beside it, ``<study>_runs.csv`` lists every run, and the
    charts draw the means with error bars of one s.d."""
    hs = _heights(table)
    cols = [("label", "variant", ""), ("flow_rate", "flow rate (kg/s)", "{:.4g}"),
            ("bulk_density", "bulk density (kg/m3)", "{:.4g}"), ("flow_pattern", "flow pattern", ""),
            ("h_t_over_H", "h_t/H", "{:.2f}")]
    cols += [(f"B_{h}", f"B at {h} mm (mm)", "{:.3g}") for h in hs]
    cols += [(f"channel_{h}", f"channel at {h} mm (mm)", "{:.3g}") for h in hs]
    cols += [("stress_low", "sigma_v 0.1-0.2 H (Pa)", "{:.4g}"), ("janssen_low", "Janssen (Pa)", "{:.4g}"),
             ("share_front_back", "weight on front/back walls (%)", "{:.3g}"),
             ("share_sides", "weight on side walls (%)", "{:.3g}"),
             ("mobilised_front_back", "friction carried, front/back walls", "{:.3f}"),
             ("mobilised_sides", "friction carried, side walls", "{:.3f}"),
             ("status", "status", ""), ("wall_time", "wall time (s)", "{:.0f}")]
    extra = [("x", "swept value", ""), ("fill_height", "fill height (m)", ""), ("clogged", "clogged", ""),
             ("z_c", "Janssen z_c (m)", ""), ("K_x", "K_x measured", ""), ("K_z", "K_z measured", ""),
             ("share_floor", "weight on the floor, lips, gate and other walls (%)", ""),
             ("janssen_low_K", "Janssen with the measured K_x, K_z (Pa)", ""),
             ("hydrostatic_low", "hydrostatic rho_b g (H - y) 0.1-0.2 H (Pa)", ""),
             ("floor_drop", "floor drop (mm)", ""), ("floor_drop_speed", "floor drop speed (mm/s)", "")]
    extra += [(f"B_err_{h}", f"B error at {h} mm (mm)", "") for h in hs]
    extra += [(f"B_front_{h}", f"B front layer at {h} mm (mm)", "") for h in hs]
    for t in table:
        for c, _, _ in cols + extra:
            t.setdefault(c, math.nan)
    title = f"Silo study '{study}' (thesis chapter 5)"
    files = [out / f"{study}.csv", out / f"{study}.md"]
    if runs is not None:  # replicas: the CSV also has each number's standard deviation
        sd = [(f"{c}_sd", f"{h} s.d.", "") for c, h, _ in cols[:-2] + extra
              if c not in ("label", "flow_pattern", "x") and any(f"{c}_sd" in t for t in table)]
        for t in table:
            for c, _, _ in sd:
                t.setdefault(c, math.nan)
        write_table(out / study, cols[:-2] + extra + sd + [("replicas", "replicas", ""), ("n_measured", "n", "")]
                    + cols[-2:], table, title, notes)
        rcols = [("label", "variant", ""), ("seed", "particles.seed", "")] + cols[1:-2] + extra + cols[-2:]
        for t in runs:
            for c, _, _ in rcols:
                t.setdefault(c, math.nan)
        write_table(out / f"{study}_runs", rcols, runs, title + ", every run", notes)
        (out / f"{study}_runs.md").unlink()
        files.insert(1, out / f"{study}_runs.csv")
        shown = [{c: (_pm(t, c, f) if f"{c}_sd" in t else _fmt(t[c], f)) if f else t[c] for c, _, f in cols}
                 for t in table]  # (the wall time: the fills' sum)
        mcols = [(c, h, "") for c, h, _ in cols]
    else:
        write_table(out / study, cols[:-2] + extra + cols[-2:], table, title, notes)
        shown, mcols = table, cols
    # the CSV with every column; the Markdown table with the main ones
    short = write_table(out / f"{study}_short", mcols, shown, title, notes)
    short[1].replace(out / f"{study}.md")
    short[0].unlink()
    files += plot_study(study, table, out)
    return files


def _pm(t: dict, key: str, spec: str) -> str:
    """``mean ± s.d.`` of a replicated number: the s.d. to two significant digits and the mean to
    the same decimal place (``0.1133 ± 0.0020``, ``587 ± 30``); ``mean ± 0`` where the fills
    agree to one digit more than ``spec`` shows; "(one fill)" where only one fill measured it,
    "(k fills)" where k of more did (a B fit that is not meaningful in the others)."""
    mean, sd = t[key], t.get(f"{key}_sd", math.nan)
    if not (isinstance(mean, (int, float)) and math.isfinite(mean)):
        return _fmt(mean, spec)
    if not math.isfinite(sd):
        return f"{_fmt(mean, spec)} (one fill)"
    digits = int(spec[spec.index(".") + 1:-2]) if "." in spec else 3
    # the decimals the column shows, and one more
    shown = digits + 1 if spec.endswith("f}") or not mean else digits - math.floor(math.log10(abs(mean)))
    d = max(0, 1 - math.floor(math.log10(sd))) if sd > 0 else shown + 1
    text = f"{_fmt(mean, spec)} ± 0" if d > shown else f"{mean:.{d}f} ± {sd:.{d}f}"
    n, of = t.get(f"{key}_n"), t.get("replicas")
    return f"{text} ({n} fills)" if n is not None and of is not None and n < of else text  # the fills that have it


def swept_panel(a, study: str, groups: dict, col: dict, key: str, scale: float, unit: str, ylabel: str,
                title: str) -> None:
    """One line per group of ``key`` x ``scale`` against the swept value; a group without one
    (the periodic depth) as horizontal dashed lines."""
    for g, ts in groups.items():
        xs = np.array([t["x"] for t in ts])
        ys = np.array([t[key] for t in ts]) * scale
        es = np.array([t.get(f"{key}_sd", math.nan) for t in ts]) * scale  # replicas: 1 s.d.
        if np.all(np.isnan(xs)):
            for y, e in zip(ys, es):
                c = col[ts[0]["label"]]
                a.axhline(y, color=c, ls="--", label=f"{g}: {y:.4g}" + (f" ± {e:.2g}" if np.isfinite(e) else "")
                          + f" {unit}")
                if np.isfinite(e):
                    a.axhspan(y - e, y + e, color=c, alpha=0.12)
        elif np.isfinite(es).any():
            a.errorbar(xs, ys, yerr=np.nan_to_num(es), fmt="o-", capsize=3, label=f"{g} (1 s.d. over replicas)")
        else:
            a.plot(xs, ys, "o-", label=g)
    swept_axis(a, study, [t["x"] for ts in groups.values() for t in ts])
    # values read as they are (no "+5.834e2" offset), on an axis at least 4 % of their size tall, so
    # that two nearly equal values do not look like a trend
    a.ticklabel_format(axis="y", useOffset=False, style="plain")
    ys = np.array([t[key] for ts in groups.values() for t in ts], float) * scale
    es = np.nan_to_num(np.array([t.get(f"{key}_sd", math.nan) for ts in groups.values() for t in ts], float)) * scale
    ys = np.concatenate([ys - es, ys + es])
    ys = ys[np.isfinite(ys)]
    if ys.size:
        mid, half = 0.5 * (ys.max() + ys.min()), 0.5 * (ys.max() - ys.min())
        half = max(1.15 * half, 0.02 * abs(mid))
        if half > 0.0:
            a.set_ylim(mid - half, mid + half)
    a.set_xlabel(X_LABEL[study])
    a.set_ylabel(ylabel)
    a.set_title(title, fontsize=9)
    a.legend(fontsize=7)


def plot_study(study: str, table: list[dict], out: Path) -> list[Path]:
    """``<study>_profiles.png`` and ``<study>.png`` (module doc)."""
    plt = _plt()
    have = [t for t in table if t["m"] is not None]
    if not have:
        return []
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    col = {t["label"]: colours[i % len(colours)] for i, t in enumerate(table)}
    p0 = have[0]["m"]["profiles"]
    heights = np.asarray(p0["heights"], float)
    nh = len(heights)
    fig, axes = plt.subplots(2, nh, figsize=(3.2 * nh, 6.4), sharey="row", squeeze=False)
    for t in have:
        p = t["m"]["profiles"]
        x = (np.asarray(p["x"], float) - 0.5 * (p["x"][0] + p["x"][-1])) * 1e3
        for r, layer in enumerate(("depth", "front")):
            for k in range(nh):
                axes[r, k].plot(x, -np.asarray(p[layer]["vy"], float)[k] * 1e3, "-", color=col[t["label"]],
                                label=t["label"])
    for r, layer in enumerate(("depth-averaged", "front-wall layer (z < d)")):
        for k in range(nh):
            ax = axes[r, k]
            ax.set_title(f"{heights[k] * 1e3:g} mm above the outlet, {layer}", fontsize=8)
            ax.set_xlabel("x from the centreline (mm)")
            ax.grid(alpha=0.3)
        axes[r, 0].set_ylabel("downward velocity -v_y (mm/s)")
    axes[0, 0].legend(fontsize=7)
    w = np.asarray(p0["window"], float)
    nrep = max(int(t.get("replicas", 1)) for t in have)
    fig.suptitle(f"{study}: vertical-velocity profiles averaged {w[0]:g}-{w[1]:g} s after the gate opening"
                 + (f", mean of {nrep} fills a variant" if nrep > 1 else ""), fontsize=10)
    files = [_save(fig, out / f"{study}_profiles.png")]

    fig, ax = plt.subplots(2, 3, figsize=(15, 8.5))
    a = ax[0, 0]
    for t in have:
        p = t["m"]["profiles"]
        a.errorbar(np.asarray(p["heights"]) * 1e3, np.asarray(p["depth"]["B"]) * 1e3,
                   yerr=np.asarray(p["depth"]["B_err"]) * 1e3, fmt="o-", color=col[t["label"]], capsize=3,
                   label=t["label"])
    a.set_xlabel("height above the outlet z (mm)")
    a.set_ylabel("kinematic B (mm), depth-averaged")
    a.set_title("B of v = v0 exp(-x^2 / (4 B z)) (no point: fit not meaningful)"
                + ("\nmean over the fills, error bars 1 s.d. over them" if nrep > 1 else ""), fontsize=9)
    a.legend(fontsize=7)
    a = ax[0, 1]
    for t in have:
        p = t["m"]["profiles"]
        a.plot(np.asarray(p["heights"]) * 1e3, np.asarray(p["channel"]["width"]) * 1e3, "o-", color=col[t["label"]],
               label=t["label"])
    xs = np.asarray(p0["x"], float)
    a.axhline((xs[-1] - xs[0]) * 1e3, color="k", ls=":", lw=1, label="outermost cell centres")
    a.set_xlabel("height above the outlet z (mm)")
    a.set_ylabel("flow-channel width (mm)")
    a.set_title(f"channel: downward speed > {float(p0['channel']['fraction']):g} of the centreline", fontsize=9)
    a.legend(fontsize=7)
    a = ax[0, 2]
    k = nh // 2
    for t in have:
        c = t["m"]["centreline_series"]
        a.plot(np.asarray(c["time"]), -np.asarray(c["vy"])[:, k] * 1e3, "-", color=col[t["label"]], label=t["label"])
    a.axvspan(w[0], w[1], color="0.9", label="profile window")
    a.set_xlabel("time after the gate opening (s)")
    a.set_ylabel(f"centreline downward velocity at {heights[k] * 1e3:g} mm (mm/s)")
    a.set_title("centreline velocity (box d x d around the centre line, full depth)", fontsize=9)
    a.legend(fontsize=7)
    groups = {}
    for t in table:
        groups.setdefault(t["group"], []).append(t)
    swept_panel(ax[1, 0], study, groups, col, "flow_rate", 1e3, "g/s", "mass flow rate (g/s)", "steady mass flow rate")
    swept_panel(ax[1, 1], study, groups, col, "bulk_density", 1.0, "kg/m3", "bulk density after filling (kg/m3)",
                "bulk density (labels: flow pattern)")
    for t in table:
        if math.isfinite(t["x"]) and t["flow_pattern"]:
            ax[1, 1].annotate(t["flow_pattern"], (t["x"], t["bulk_density"]), fontsize=6, rotation=30,
                              textcoords="offset points", xytext=(3, 3))
    a = ax[1, 2]
    for t in have:
        st = t["m"].get("stress")
        if st is None:
            continue
        a.plot(np.asarray(st["pressure"]), np.asarray(st["y"]) * 1e3, "-", color=col[t["label"]], label=t["label"])
        a.plot(np.asarray(st["janssen"]), np.asarray(st["y"]) * 1e3, "--", color=col[t["label"]], lw=1)
        if "hydrostatic" in st:
            a.plot(np.asarray(st["hydrostatic"]), np.asarray(st["y"]) * 1e3, ":", color=col[t["label"]], lw=1)
    a.set_xlim(left=0.0)
    a.set_ylim(bottom=0.0)
    a.set_xlabel("vertical pressure -sigma_yy (Pa), cross-section average")
    a.set_ylabel("height above the floor (mm)")
    a.set_title("end of the fill: coarse-grained (solid), Janssen (dashed),\nhydrostatic rho_b g (H - y) (dotted)", fontsize=9)
    a.legend(fontsize=7)
    for a in ax.ravel():
        a.grid(alpha=0.3)
    fig.suptitle(f"silo study '{study}'", fontsize=11)
    files.append(_save(fig, out / f"{study}.png"))
    walls = plot_walls(study, table, col, out)
    files += [walls] if walls else []
    if study in ("floor-drop", "floor-speed"):
        files.append(plot_mobilised(study, table, out))
    return files


def plot_mobilised(study: str, table: list[dict], out: Path) -> Path:
    """``<study>_mobilised.png`` (the floor-drop and floor-speed studies): against the depth (the
    speed, on a log axis) of the drop, the weight
    carried by each wall group, the friction the vertical walls carry, and the vertical stress
    0.1-0.2 H above the floor with Janssen's and the hydrostatic values."""
    plt = _plt()
    ts = sorted((t for t in table if math.isfinite(t["x"])), key=lambda t: t["x"])
    x = np.array([t["x"] for t in ts])
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.6))
    col = lambda k: np.array([t.get(k, math.nan) for t in ts], float)  # noqa: E731

    def line(a, k, fmt, lab):  # with replicas: error bars of 1 s.d.
        e = col(f"{k}_sd")
        if np.isfinite(e).any():
            a.errorbar(x, col(k), yerr=np.nan_to_num(e), fmt=fmt, capsize=3, label=lab)
        else:
            a.plot(x, col(k), fmt, label=lab)

    for k, lab in (("share_front_back", "front/back walls"), ("share_sides", "side walls"),
                   ("share_floor", "floor, lips, gate")):
        line(ax[0], k, "o-", lab)
    ax[0].set_ylabel("share of the bed's weight (%)")
    ax[0].set_title("who carries the weight at the gate opening", fontsize=9)
    for k, lab in (("mobilised_front_back", "front/back walls"), ("mobilised_sides", "side walls")):
        line(ax[1], k, "o-", lab)
    ax[1].set_ylabel("friction carried: wall force along gravity / normal force")
    ax[1].set_title("the walls' friction mobilised", fontsize=9)
    for k, lab, fmt in (("stress_low", "coarse-grained", "o-"), ("hydrostatic_low", "hydrostatic", "k:"),
                        ("janssen_low", "Janssen, K from the bulk friction", "s--"),
                        ("janssen_low_K", "Janssen, measured K", "^--")):
        if np.isfinite(col(k)).any():
            line(ax[2], k, fmt, lab)
    ax[2].set_ylim(bottom=0.0)
    ax[2].set_ylabel("vertical stress 0.1-0.2 H above the floor (Pa)")
    ax[2].set_title("vertical stress at the gate opening", fontsize=9)
    for a in ax:
        a.set_xlabel(X_LABEL[study])
        swept_axis(a, study, x)
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    fig.suptitle(f"silo study '{study}': the floor's settlement and the walls", fontsize=11)
    return _save(fig, out / f"{study}_mobilised.png")


def swept_axis(a, study: str, xs) -> None:
    """The x axis of a panel against the study's swept value: linear, but log for the
    restitution (1e-4 to 1: matplotlib's decade ticks) and for the floor's speed (ticks at the
    swept speeds, written as plain numbers: 1, 5, 25)."""
    if study == "restitution":
        a.set_xscale("log")
    if study != "floor-speed":
        return
    from matplotlib.ticker import NullFormatter, NullLocator

    xs = sorted({float(v) for v in xs if math.isfinite(v) and v > 0})
    a.set_xscale("log")
    a.set_xticks(xs, [f"{v:g}" for v in xs])
    a.xaxis.set_minor_locator(NullLocator())
    a.xaxis.set_minor_formatter(NullFormatter())


def plot_walls(study: str, table: list[dict], col: dict, out: Path) -> Path | None:
    """``<study>_walls.png``: the wall stresses against height at the end of the fill
    (/measurements/silo/fill_wall_load/profile): the friction the front/back and side walls
    carry (shear over normal stress; the walls' mu as thin vertical lines), and the front/back
    walls' normal stress beside the coarse-grained -sigma_zz next to them.  None when no run has
    the profile (runs made before it was stored)."""
    rows = [t for t in table if t["m"] is not None and "profile" in (t["m"].get("fill_wall_load") or {})]
    if not rows:
        return None
    plt = _plt()
    fig, ax = plt.subplots(1, 2, figsize=(11, 5.2), sharey=True)
    for t in rows:
        pr, c = t["m"]["fill_wall_load"]["profile"], col[t["label"]]
        y = np.asarray(pr["y"], float) * 1e3
        for key, ls, what in (("front_back", "-", "front/back"), ("sides", "--", "sides")):
            tau, sig = (np.asarray(pr[f"{k}_{key}"], float) for k in ("tau", "sigma"))
            with np.errstate(invalid="ignore", divide="ignore"):
                ratio = np.where(sig > 0, tau / sig, np.nan)
            ax[0].plot(ratio, y, ls, color=c, label=f"{t['label']}, {what}")
        st = t["m"].get("stress")
        ax[1].plot(np.asarray(pr["sigma_front_back"], float), y, "-", color=c, label=f"{t['label']}, front/back walls")
        if st is not None and "pressure_z" in st:
            ax[1].plot(np.asarray(st["pressure_z"], float), np.asarray(st["y"], float) * 1e3, ":", color=c,
                       label=f"{t['label']}, -sigma_zz (coarse-grained)")
        if st is not None:
            for mu, ls in ((st.get("mu_front"), "-"), (st.get("mu_side"), "--")):
                if mu is not None and math.isfinite(float(mu)):
                    ax[0].axvline(float(mu), color=c, ls=ls, lw=0.6, alpha=0.6)
    ax[0].set_xlabel("friction carried: wall shear / wall normal stress")
    ax[0].set_ylabel("height above the floor (mm)")
    ax[0].set_title("end of the fill: friction the walls carry (thin lines: their mu)", fontsize=9)
    ax[1].set_xlabel("normal stress on the front/back walls (Pa)")
    ax[1].set_title("front/back walls' normal stress, and the bed's -sigma_zz", fontsize=9)
    ax[1].set_xlim(left=0.0)
    for a in ax:
        a.grid(alpha=0.3)
        a.legend(fontsize=7)
        a.set_ylim(bottom=0.0)
    fig.suptitle(f"silo study '{study}': wall stresses against height (2 d bins)", fontsize=10)
    return _save(fig, out / f"{study}_walls.png")


def _depth(text: str) -> float:
    """``--depth``: one positive number (m); the case checks it against d / 2."""
    v = _floats(text, "--depth")
    if len(v) != 1 or not v[0] > 0.0:
        raise CaseError("--depth", f"one depth in m above 0, got {text!r}")
    return float(v[0])


def _study(args) -> tuple[list, list[dict]]:
    """Run the study of the parsed ``args``: (files written, sweep rows)."""
    from .sweep import run_sweep

    base = load_study_case(args)
    if not base.silo.profile_heights:
        raise CaseError("silo.profile_heights", "is empty: the study needs the profile heights")
    if args.study != "front-back" and args.no_periodic:
        raise CaseError("--no-periodic", "only for the front-back study")
    if args.study != "friction" and (args.mu or args.mu_r):
        raise CaseError("--mu", "--mu and --mu-r are for the friction study")
    if args.study != "floor-speed" and args.depth is not None:
        raise CaseError("--depth", "only for the floor-speed study (the floor-drop study sweeps the depth: --values)")
    if args.study == "friction" and args.values:
        raise CaseError("--values", "the friction study takes --mu and --mu-r")
    values = _floats(args.values, "--values") if args.values else None
    variants = study_variants(args.study, values, not args.no_periodic,
                              _floats(args.mu, "--mu") if args.mu else None,
                              _floats(args.mu_r, "--mu-r") if args.mu_r else None,
                              DROP_DEPTH if args.depth is None else _depth(args.depth))
    n = args.replicas
    variants = replicate(variants, n, int(base.particles.seed))
    out = Path(args.out).resolve() if args.out else Path(args.case).resolve() / args.study
    rows = run_sweep(args.case, [v["overrides"] for v in variants], out, common=args.overrides,
                     workers=args.workers, threads=args.threads, chart="mass_flow_rate")
    runs = study_table(rows, variants)
    for t, v in zip(runs, variants):
        t["seed"] = v["seed"]
    table = combine_replicas(runs, n)
    notes = [f"case {Path(args.case).resolve().name}" + (f" with {' '.join(args.overrides)}" if args.overrides
                                                         else ""),
             "B in mm (NaN/-: fit not meaningful, see the run's /measurements/silo/profiles B_notes); channel: "
             "flow-channel width at each height; sigma_v: coarse-grained vertical stress at the end of the fill, "
             "mean over 0.1-0.2 of the fill height, and Janssen's there"] + machine_notes()
    if n > 1:
        notes.insert(1, f"{n} fills a variant (particles.seed {base.particles.seed}-{base.particles.seed + n - 1}): "
                     "mean ± standard deviation over them; every run in the _runs.csv table")
    files = write_study(args.study, table, out, notes, runs if n > 1 else None)
    return files, rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m cfddem.silo_thesis", description=__doc__.split("\n\n")[0])
    ap.add_argument("study", choices=STUDIES)
    ap.add_argument("--values", help="front-back: wall friction values; restitution: e values; floor-drop: depths "
                    "in m; floor-speed: speeds in m/s (comma-separated)")
    ap.add_argument("--depth", help="floor-speed: depth of the floor drop in m (default 0.001)")
    ap.add_argument("--no-periodic", action="store_true", help="front-back: leave out the periodic-depth variant")
    ap.add_argument("--mu", help="friction: particle-particle sliding friction values (default 0.15,0.57)")
    ap.add_argument("--mu-r", help="friction: particle-particle rolling friction values (default 0,0.1,0.2)")
    ap.add_argument("--replicas", type=int, default=1, help="fills per variant (particles.seed + 0, 1, ...; "
                    "the tables give mean ± s.d., the charts error bars)")
    add_study_arguments(ap, CASE)
    return run_study("silo_thesis", _study, ap.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
