"""Stability maps: where a choice of time step, drag treatment, coupling interval or gas grid
stops working (issue #23, docs/stability.md).

A map is a grid of settings, each run briefly and classified as *stable* or *unstable with a
cause*, drawn with the stable and unstable regions, the boundary between them (per row of the
grid: between the last stable and the first unstable setting), the analytic or rule limit where
one exists, and the case's own setting.

* ``cfddem stability CASE --vary KEY=V1,V2,... [--vary ...]`` runs the variants of a case (as
  ``cfddem sweep`` does, one run folder each under ``OUT/runs/``) and classifies each run from
  its own diagnosis: the :class:`~cfddem.errors.RunError` message of a failed run (the particle
  engine's "nan" and "overlap" flags, the wall-crossing check, the gas's Courant and
  mass-defect stops, a porosity <= 0) or, for a run that ended normally, an energy-growth check
  (:func:`closed_energy_growth`, :func:`runaway_growth`).  The pseudo-key ``dt/t_c`` sets
  ``time.dt`` to that fraction of the variant's collision time (``cfddem check``'s t_c, so a
  stiffness can be varied beside it); every variant runs with ``time.force = true``.
* ``cfddem stability --map drag|courant|cells`` runs the built-in experiments on the Python
  API: a single particle relaxing in a uniform gas (explicit against implicit drag,
  :func:`drag_map`), the gas alone in a periodic box (Courant number against the advection
  scheme, :func:`courant_map`), and a fixed bed (gas cell size against particle diameter:
  porosity noise and the error of the pressure drop against Ergun, :func:`cell_size_map`).

Outputs in ``OUT``: ``stability.png`` (the map), ``stability.csv`` (one row per setting:
values, stable, cause, detail), ``stability.json`` (points, limits found, limit lines, the
case's own setting) and ``stability.md`` (the limits found as a table).
"""

from __future__ import annotations

import csv
import json
import math
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from .errors import CaseError

DT_KEY = "dt/t_c"  # pseudo-key: time.dt as a fraction of the variant's collision time
ENERGY_FACTOR = 10.0  # runaway: kinetic energy above this many times the case's energy budget
CLOSED_TOLERANCE = 0.01  # closed systems: energy gain above 1 % of lifting all the mass by one diameter

# causes of instability, in the order of the legend
NAN, OVERLAP, WALL, ENERGY, COURANT, DEFECT, POROSITY, GAS, OTHER = (
    "NaN", "overlap", "particle through a wall", "energy growth", "gas Courant", "mass defect",
    "porosity <= 0", "gas solver", "other")
CAUSES = (NAN, OVERLAP, WALL, ENERGY, COURANT, DEFECT, POROSITY, GAS, OTHER)

# (pattern in the run's message, cause): the first match wins
_MESSAGE_CAUSES = (
    (re.compile(r"non-finite"), NAN),
    (re.compile(r"overlap/radius"), OVERLAP),
    (re.compile(r"went through wall"), WALL),
    (re.compile(r"gas CFL number"), COURANT),
    (re.compile(r"mass balance defect"), DEFECT),
    (re.compile(r"porosity \S+ <= 0"), POROSITY),
    (re.compile(r"gas step failed"), GAS),
)
_FLAG_CAUSES = {"nan": NAN, "overlap": OVERLAP, "porosity": POROSITY, "overflow_unrecoverable": OTHER}


@dataclass
class Outcome:
    """Classification of one run: ``stable`` True/False, or None when the run says nothing
    about stability (bad input, stopped by a wall-time or step limit); ``cause`` one of
    :data:`CAUSES` for an unstable run ("" otherwise); ``detail``: the run's message or the
    energy numbers."""

    stable: bool | None
    cause: str = ""
    detail: str = ""

    @property
    def label(self) -> str:
        return "stable" if self.stable else ("undecided" if self.stable is None else f"unstable: {self.cause}")


def classify(status: str, message: str = "", flag: str | None = None, growth: float | None = None,
             growth_detail: str = "") -> Outcome:
    """Classify a run from its own diagnosis.

    ``status``: "done" (or "skipped": a finished run read back), "failed", or anything else
    (stopped, interrupted, bad input: undecided).  A failed run is unstable with the cause named
    by its status ``flag`` (the particle engine's "nan"/"overlap", the coupling's "porosity";
    the coupling's "gas" flag is resolved by the message) or else by its message (the
    :class:`~cfddem.errors.RunError` text: "non-finite" -> NaN, "overlap/radius" -> overlap,
    "went through wall" -> particle through a wall, "gas CFL number" -> gas Courant, "mass
    balance defect" -> mass defect, "porosity ... <= 0", "gas step failed" -> gas solver; anything
    else: other).  A finished run is unstable with cause "energy growth" when ``growth`` > 1
    (a ratio from :func:`closed_energy_growth`, :func:`runaway_growth` or :func:`ratio_growth`:
    1 is the threshold), else stable."""
    if status == "failed":
        cause = _FLAG_CAUSES.get(flag or "")
        if cause is None:
            cause = next((c for p, c in _MESSAGE_CAUSES if p.search(message or "")), OTHER)
        return Outcome(False, cause, message)
    if status in ("done", "skipped"):
        if growth is not None and growth > 1.0:
            return Outcome(False, ENERGY, growth_detail or f"energy growth ratio {growth:.3g}")
        return Outcome(True, "", growth_detail)
    return Outcome(None, "", message or status)


def closed_energy_growth(energy: np.ndarray, mass: float, g: float, d: float,
                         tolerance: float = CLOSED_TOLERANCE) -> float:
    """A closed system (no inlet, gas, moving wall or rotating frame) cannot gain mechanical
    energy (kinetic + potential in gravity; the contacts only dissipate).  Returns the largest
    gain over the series ``energy`` (J, first entry the initial state) divided by ``tolerance``
    times the energy of lifting the whole ``mass`` by one diameter ``d`` against ``g`` (plus
    ``tolerance`` times the initial energy, for a system without gravity): > 1 is energy growth."""
    e = np.asarray(energy, float)
    if e.size < 2:
        return 0.0
    if not np.all(np.isfinite(e)):
        return math.inf
    scale = tolerance * (mass * g * d + abs(e[0]))
    return float(np.max(e - e[0]) / scale) if scale > 0 else 0.0


def runaway_growth(ke_per_mass: np.ndarray, budget: float, factor: float = ENERGY_FACTOR) -> float:
    """An open system (fed, driven, with gas): kinetic energy per unit mass (J/kg) above
    ``factor`` times the case's energy budget per unit mass (half its largest speed squared plus
    g times its size: more than any physical source supplies) is a runaway.  Returns
    max(KE/M) / (factor budget): > 1 is energy growth."""
    e = np.asarray(ke_per_mass, float)
    e = e[~np.isnan(e)]
    if not e.size:
        return 0.0
    return float(np.max(e) / (factor * budget)) if budget > 0 else math.inf


def ratio_growth(values: np.ndarray, factor: float = ENERGY_FACTOR) -> float:
    """A quantity that the physics can only make decay (the slip energy of a particle relaxing
    in a gas, the velocity fluctuation of a gas in a periodic box): its largest value over its
    first, divided by ``factor``; > 1 is energy growth (NaN or inf: inf)."""
    v = np.asarray(values, float)
    if v.size < 2:
        return 0.0
    if not np.all(np.isfinite(v)):
        return math.inf
    return float(np.max(v[1:]) / (factor * v[0])) if v[0] > 0 else 0.0


def verlet_step_limit(zeta: float) -> float:
    """The largest stable omega dt of velocity Verlet on a linear spring-dashpot of damping
    ratio ``zeta``, as the engine integrates it (kick-drift-kick, the damping force taken at the
    half-step velocity v_{n+1/2}, as the tangential spring's increment).  One step maps
    (x_n, v_{n-1/2}) linearly with trace 2 - h^2 - 2 zeta h and determinant 1 - 2 zeta h
    (h = omega dt); both roots stay in the unit circle (Jury's conditions) for
    h <= 2 / (zeta + sqrt(1 + zeta^2)): 2 undamped, less with damping."""
    return 2.0 / (zeta + math.sqrt(1.0 + zeta * zeta))


def verlet_limit(e: float) -> float:
    """The largest stable dt / t_c of one linear contact of restitution ``e``
    (t_c = sqrt(m* (pi^2 + ln^2 e) / k_n), zeta = -ln e / sqrt(pi^2 + ln^2 e),
    :func:`verlet_step_limit`): 2/pi = 0.637 for e = 1, 0.502 for e = 0.5, 0.433 for 0.33."""
    le = math.log(e)
    w_tc = math.sqrt(math.pi**2 + le * le)
    return verlet_step_limit(-le / w_tc) / w_tc


def contact_step_limit(law, m_eff: float, r_eff: float, speed: float) -> dict:
    """The largest stable dt of velocity Verlet on one contact of ``law`` (linear or
    Hertz-Mindlin; Hertz-Mindlin linearised at the largest overlap of a head-on impact at
    ``speed``) for its normal mode (mass m*) and its sticking tangential mode (mass 2/7 m*, a
    sphere rolling against the contact), each with its own damping ratio
    (:func:`verlet_step_limit`), from the law's ``linearised`` springs.  Returns {"normal": dt,
    "tangential": dt}; empty for a law that gives no linearisation."""
    dv = law.linearised(m_eff, r_eff, speed)
    if dv is None:
        return {}
    out = {}
    for name, k, eta, m in (("normal", dv["k_n"], dv["eta_n"], m_eff),
                            ("tangential", dv["k_t"], dv["eta_t"], 2.0 / 7.0 * m_eff)):
        omega = math.sqrt(k / m)
        out[name] = verlet_step_limit(abs(eta) / (2.0 * math.sqrt(k * m))) / omega
    return out


# ----------------------------------------------------------------------------------------------
# limits found and the map drawing
# ----------------------------------------------------------------------------------------------
def _is_num(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)


def _key_text(v) -> str:
    from .sweep import format_value

    return format_value(v) if not _is_num(v) else f"{float(v):.6g}"


def find_limits(points: list[dict], xkey: str, ykey: str | None = None, panel: str | None = None) -> list[dict]:
    """Per row of the map (each value of ``ykey``, each ``panel``): the largest stable x below
    the first unstable one (``last_stable``), that first unstable x (``first_unstable``) with
    its cause, ``estimate`` (their geometric mean, the middle of the grid step on a log axis),
    and ``stable_above``: whether a stable setting lies beyond the first unstable one (the
    region is not a half-line).  None where the row has no such setting."""
    rows: dict[tuple, list[dict]] = {}
    for p in points:
        if p.get("stable") is None or not _is_num(p["values"].get(xkey)):
            continue
        k = (_key_text(p["values"].get(panel)) if panel else "", _key_text(p["values"].get(ykey)) if ykey else "")
        rows.setdefault(k, []).append(p)
    out = []
    for (pn, yk), pts in rows.items():
        pts = sorted(pts, key=lambda p: float(p["values"][xkey]))
        xs = [float(p["values"][xkey]) for p in pts]
        iu = next((i for i, p in enumerate(pts) if not p["stable"]), None)
        last_stable = xs[iu - 1] if iu is not None and iu > 0 else (xs[-1] if iu is None else None)
        first_unstable = xs[iu] if iu is not None else None
        est = None
        if last_stable is not None and first_unstable is not None:
            est = math.sqrt(last_stable * first_unstable) if last_stable > 0 else 0.5 * (last_stable + first_unstable)
        row = {"last_stable": last_stable, "first_unstable": first_unstable,
               "cause": pts[iu]["cause"] if iu is not None else "", "estimate": est,
               "stable_above": bool(iu is not None and any(p["stable"] for p in pts[iu:]))}
        if ykey:
            row["y"] = pts[0]["values"].get(ykey)
        if panel:
            row["panel"] = pts[0]["values"].get(panel)
        out.append(row)
    return out


_MARKERS = {NAN: ("X", "tab:red"), OVERLAP: ("s", "tab:orange"), WALL: ("v", "tab:brown"),
            ENERGY: ("^", "tab:purple"), COURANT: ("D", "tab:pink"), DEFECT: ("P", "tab:olive"),
            POROSITY: ("p", "tab:cyan"), GAS: ("h", "tab:gray"), OTHER: ("*", "black")}


def _axis(values: list) -> tuple[bool, bool, list]:
    """(numeric, log, categories) of an axis from its values."""
    numeric = bool(values) and all(_is_num(v) for v in values)
    if not numeric:
        return False, False, list(dict.fromkeys(_key_text(v) for v in values))
    vs = [float(v) for v in values]
    return True, min(vs) > 0 and max(vs) / min(vs) >= 10.0, []


def draw_map(result: dict, path: str | Path) -> Path:
    """Draw the map of :func:`make_result`'s ``result`` into ``path`` (PNG): one panel per value
    of the panel key; stable settings as green circles, unstable ones with one marker per cause,
    undecided ones grey; the boundary per row (a bar at the middle of the grid step between the
    last stable and the first unstable setting); the limit lines (solid: analytic, dashed: a
    rule of cfddem); the case's own setting as a star."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    xkey, ykey, panel = result["x"], result.get("y"), result.get("panel")
    pts = result["points"]
    panels = list(dict.fromkeys(_key_text(p["values"].get(panel)) for p in pts)) if panel else [""]
    xnum, xlog, xcats = _axis([p["values"][xkey] for p in pts])
    ynum, ylog, ycats = _axis([p["values"][ykey] for p in pts]) if ykey else (False, False, [""])
    fig, axes = plt.subplots(1, len(panels), figsize=(6.4 * len(panels), 4.8), squeeze=False, sharey=True)

    def xpos(v):
        return float(v) if xnum else xcats.index(_key_text(v))

    def ypos(v):
        if not ykey:
            return 0.0
        return float(v) if ynum else ycats.index(_key_text(v))

    yvals = sorted({ypos(p["values"].get(ykey)) for p in pts})

    def yband(y):  # the row's extent: half way to the neighbouring rows
        i = yvals.index(y)
        if len(yvals) == 1:
            return (y * 0.7, y / 0.7) if ylog else (y - 0.4, y + 0.4)
        if ylog:
            lo = math.sqrt(yvals[i - 1] * y) if i > 0 else y * math.sqrt(y / yvals[i + 1])
            hi = math.sqrt(yvals[i + 1] * y) if i + 1 < len(yvals) else y * math.sqrt(y / yvals[i - 1])
        else:
            lo = 0.5 * (yvals[i - 1] + y) if i > 0 else y - 0.5 * (yvals[i + 1] - y)
            hi = 0.5 * (yvals[i + 1] + y) if i + 1 < len(yvals) else y + 0.5 * (y - yvals[i - 1])
        return lo, hi

    for ax, pn in zip(axes[0], panels):
        mine = [p for p in pts if not panel or _key_text(p["values"].get(panel)) == pn]
        seen = set()
        for p in mine:
            x, y = xpos(p["values"][xkey]), ypos(p["values"].get(ykey))
            if p.get("stable") is None:
                m, c, lab = ".", "0.6", "undecided"
            elif p["stable"]:
                m, c, lab = "o", "tab:green", "stable"
            else:
                m, c = _MARKERS.get(p["cause"], _MARKERS[OTHER])
                lab = f"unstable: {p['cause']}"
            ax.plot(x, y, m, color=c, ms=9 if m != "." else 6, mec="k" if m != "." else c, mew=0.5,
                    label=lab if lab not in seen else None, zorder=3)
            seen.add(lab)
        first = True
        for lim in result.get("limits", []):
            if (panel and _key_text(lim.get("panel")) != pn) or lim.get("estimate") is None or not xnum:
                continue
            y = ypos(lim.get("y"))
            lo, hi = yband(y)
            ax.plot([lim["estimate"]] * 2, [lo, hi], "-", color="tab:blue", lw=3, alpha=0.6,
                    label="boundary found (middle of the grid step)" if first else None, zorder=2)
            first = False
        rule_colours = iter(("tab:red", "tab:orange", "tab:purple", "tab:brown", "tab:olive"))
        for line in result.get("lines", []):
            col = line.get("colour") or ("k" if line.get("kind") == "analytic" else next(rule_colours, "tab:red"))
            if line.get("panel") is not None and _key_text(line["panel"]) != pn:
                continue
            style = "-" if line.get("kind") == "analytic" else "--"
            if "x" in line:
                ax.axvline(line["x"], ls=style, color=col, lw=1.3, label=line["label"])
            elif "xy" in line:
                xy = np.asarray(line["xy"], float)
                ax.plot(xy[:, 0], xy[:, 1], ls=style, color=col, lw=1.3, label=line["label"])
        own = result.get("own")
        if own is not None and (not panel or own.get("panel") is None or _key_text(own["panel"]) == pn):
            try:
                ax.plot(xpos(own["x"]), ypos(own.get("y")), "*", ms=18, color="gold", mec="k", mew=1.0,
                        label=own.get("label", "this case's setting"), zorder=4)
            except ValueError:  # the case's value is not on a categorical axis
                pass
        if xlog:
            ax.set_xscale("log")
        if xnum:  # the grid's range (limit lines beyond it are cut)
            xs = [float(p["values"][xkey]) for p in pts]
            pad = 1.3 if xlog else None
            ax.set_xlim((min(xs) / pad, max(xs) * pad) if xlog else
                        (min(xs) - 0.05 * (max(xs) - min(xs) or 1.0), max(xs) + 0.05 * (max(xs) - min(xs) or 1.0)))
        else:
            ax.set_xticks(range(len(xcats)), xcats)
        ax.set_xlabel(result.get("xlabel") or xkey)
        if ykey:
            if ylog:
                ax.set_yscale("log")
            if not ynum:
                ax.set_yticks(range(len(ycats)), ycats)
        else:
            ax.set_yticks([])
        if pn:
            ax.set_title(f"{result.get('panel_label') or panel} = {pn}", fontsize=10)
        ax.grid(alpha=0.3, which="both")
    if ykey:
        axes[0][0].set_ylabel(result.get("ylabel") or ykey)
    handles = {}
    for ax in axes[0]:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(lab, h)
    fig.legend(list(handles.values()), list(handles.keys()), loc="upper left", bbox_to_anchor=(1.0, 0.93),
               fontsize=8, framealpha=0.9)
    fig.suptitle(result.get("title") or "Stability map", fontsize=11)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


def make_result(points: list[dict], x: str, y: str | None = None, panel: str | None = None, **kw) -> dict:
    """The map's record: points, axes, the limits found (:func:`find_limits`) and ``kw``
    (title, xlabel, ylabel, panel_label, lines, own, notes)."""
    res = {"x": x, "y": y, "panel": panel, "points": points}
    res.update(kw)
    res["limits"] = find_limits(points, x, y, panel)
    return res


def _jsonable(v):
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, Path):
        return str(v)
    raise TypeError(type(v))


def write_map(result: dict, out: str | Path, name: str = "stability") -> dict[str, Path]:
    """Write ``NAME.png``, ``NAME.csv``, ``NAME.json`` and ``NAME.md`` into ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = {"png": draw_map(result, out / f"{name}.png")}
    keys = list(dict.fromkeys(k for p in result["points"] for k in p["values"]))
    extra = list(dict.fromkeys(k for p in result["points"] for k in p.get("numbers", {})))
    with (out / f"{name}.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["name", *keys, "stable", "cause", *extra, "detail"])
        for p in result["points"]:
            st = "" if p.get("stable") is None else ("true" if p["stable"] else "false")
            w.writerow([p.get("name", ""), *[p["values"].get(k, "") for k in keys], st, p.get("cause", ""),
                        *[p.get("numbers", {}).get(k, "") for k in extra], p.get("detail", "")])
    files["csv"] = out / f"{name}.csv"
    (out / f"{name}.json").write_text(json.dumps(result, indent=1, default=_jsonable, allow_nan=True))
    files["json"] = out / f"{name}.json"
    (out / f"{name}.md").write_text(limits_markdown(result))
    files["md"] = out / f"{name}.md"
    return files


def _fmt(v) -> str:
    return "-" if v is None else (f"{v:.4g}" if _is_num(v) else str(v))


def limits_markdown(result: dict) -> str:
    """The limits found as a Markdown table, with the limit lines beside them."""
    xl = result["x"]
    lines = [f"# {result.get('title') or 'Stability map'}", ""]
    head = ([result["panel"]] if result.get("panel") else []) + ([result["y"]] if result.get("y") else []) + \
           [f"last stable {xl}", f"first unstable {xl}", "cause", "boundary (grid middle)"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for lim in result["limits"]:
        cells = ([_fmt(lim.get("panel"))] if result.get("panel") else []) + ([_fmt(lim.get("y"))] if result.get("y") else [])
        cells += [_fmt(lim["last_stable"]), _fmt(lim["first_unstable"]), lim["cause"] or "-",
                  _fmt(lim["estimate"]) + (" (stable again above)" if lim["stable_above"] else "")]
        lines.append("| " + " | ".join(cells) + " |")
    if result.get("lines"):
        lines += ["", "Limit lines: " + "; ".join(
            f"{ln['label']} ({ln.get('kind', 'rule')})" for ln in result["lines"])]
    if result.get("notes"):
        lines += ["", result["notes"]]
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------------------------
# maps of a case (cfddem stability CASE --vary ...)
# ----------------------------------------------------------------------------------------------
STABILITY_OVERRIDES = {"time.force": True, "output.vtk": False, "output.plots": False,
                       "checkpoint.wall_interval": 0.0, "study.compare_without_gas": False}


def is_closed(case) -> bool:
    """No energy enters: the scene creates no particles (no inlet, no silo pour, no shear cell
    with its moving ring and loaded lid), no gas, no rotating frame."""
    from .scenes import scene_of

    return not scene_of(case).has_particles(case) and not case.gas.enabled and not case.frame.rpm


def energy_budget(case) -> float:
    """Energy per unit mass (J/kg) the case can give its particles: half the square of its
    largest speed (the expected flow speed, the initial speeds, the shear speed) plus g times
    the largest side of its walls' bounding box."""
    from .scenes.common import gravity_vector, wall_specs, walls_bounding_box
    from .simulation import expected_max_speed

    lo, hi = walls_bounding_box(wall_specs(case), case)
    size = float(np.max(hi - lo)) if np.all(np.isfinite(hi - lo)) else 1.0
    v = [expected_max_speed(case)] + [float(np.linalg.norm(t.get("vel", (0, 0, 0)))) for t in case.particles.initial]
    g = float(np.linalg.norm(gravity_vector(case)))
    return 0.5 * max(v) ** 2 + g * size


def run_energy(out: Path, case) -> tuple[float, str]:
    """The energy-growth ratio of a finished run folder and a sentence with its numbers: a
    closed case from its snapshots (kinetic + potential energy, :func:`closed_energy_growth`),
    any other from the kinetic energy per unit mass of its series (:func:`runaway_growth`)."""
    from .io.results import list_snapshots, read_series, read_snapshot
    from .scenes.common import gravity_vector

    h5 = out / "results.h5"
    g = gravity_vector(case)
    if is_closed(case):
        snaps = list_snapshots(h5)
        E, M = [], 0.0
        for k, _t, _n in snaps:
            s = read_snapshot(h5, k)
            r = np.asarray(s["radius"], float)
            m = case.particles.density * 4.0 / 3.0 * math.pi * r**3
            ke = 0.5 * np.sum(m * np.sum(np.asarray(s["vel"]) ** 2, axis=1)) + \
                0.5 * np.sum(0.4 * m * r * r * np.sum(np.asarray(s["omega"]) ** 2, axis=1))
            E.append(float(ke - np.sum(m * (np.asarray(s["pos"]) @ g))))
            M = max(M, float(np.sum(m)))
        ratio = closed_energy_growth(np.array(E), M, float(np.linalg.norm(g)), case.particles.diameter)
        gain = (max(E) - E[0]) / M if len(E) > 1 and M > 0 else 0.0
        return ratio, (f"closed system: largest energy gain {gain:.3g} J/kg over {len(E)} snapshots "
                       f"({ratio * CLOSED_TOLERANCE:.3g} m g d)")
    s = read_series(h5)
    ke, m = np.asarray(s.get("kinetic_energy", []), float), np.asarray(s.get("mass_present", []), float)
    with np.errstate(all="ignore"):
        kpm = np.where(m > 0, ke / np.where(m > 0, m, 1.0), np.nan)
    budget = energy_budget(case)
    ratio = runaway_growth(kpm, budget)
    top = float(np.nanmax(kpm)) if np.any(np.isfinite(kpm)) else 0.0
    return ratio, f"largest kinetic energy {top:.3g} J/kg against the energy budget {budget:.3g} J/kg"


def resolve_variant(case_arg: str, values: dict, common: dict) -> dict:
    """The overrides of one variant: ``common``, the stability settings, the variant's keys,
    ``dt/t_c`` turned into ``time.dt`` (the variant's collision time), and for a closed case
    snapshots at the series interval (the energy check reads them)."""
    from .config import load_case
    from .simulation import collision_time

    ov = dict(STABILITY_OVERRIDES)
    ov.update(common)
    ov.update({k: v for k, v in values.items() if k != DT_KEY})
    case = load_case(case_arg, overrides=ov)
    if DT_KEY in values:
        r = values[DT_KEY]
        if not _is_num(r) or not r > 0:
            raise CaseError(DT_KEY, f"must be a positive number, got {r!r}")
        ov["time.dt"] = float(r) * collision_time(case)
    if is_closed(case) and "output.snapshot_interval" not in common:
        ov["output.snapshot_interval"] = case.output.series_interval
    return ov


def own_setting(case, key: str | None):
    """The case's own value of a map key (``dt/t_c``: its dt over its collision time)."""
    from .simulation import collision_time

    if key is None:
        return None
    if key == DT_KEY:
        return case.time.dt / collision_time(case)
    d: Any = case.resolved
    for part in key.split("."):
        if not isinstance(d, dict) or part not in d:
            return None
        d = d[part]
    return d


def case_step_limit(case) -> tuple[float, str]:
    """The smallest :func:`contact_step_limit` over the case's contacts (particle-particle with
    m* = m/2, R* = R/2; each wall with m* = m, R* = R; Hertz-Mindlin at cfddem check's impact
    speed) and which contact and mode sets it."""
    from .scenes.common import wall_specs
    from .simulation import contact_law, impact_speed, particle_mass

    m = particle_mass(case)
    r = 0.5 * case.particles.diameter
    v = impact_speed(case)
    model = case.contact.model
    best = (math.inf, "")
    laws = [("particle-particle", contact_law(case.resolved["contact"]["particle_particle"], model), 0.5 * m, 0.5 * r)]
    laws += [(f"wall {w.name}", contact_law(w.params, model), m, r) for w in wall_specs(case)]
    for name, law, me, re_ in laws:
        for mode, dt in contact_step_limit(law, me, re_, v).items():
            if dt < best[0]:
                best = (dt, f"{name}, {mode}")
    return best


# What the maps found (docs/stability.md; the JSON files under docs/stability/ hold every point,
# tests/unit/test_stability.py checks these numbers against them).  Time-step maps: the map's
# folder -> dt/t_c of the one-contact limit drawn on it (:func:`case_step_limit`), and the last
# stable and first unstable setting, the same in both stiffness rows of every map.
DT_MAPS = {
    "verlet": (0.6366, 0.6132, 0.7831),  # undamped linear wall contact (cases/contact_verlet)
    "chute_linear": (0.4329, 0.35, 0.6),  # chute, linear, e_n 0.97, e_t 0.33
    "chute_hm": (0.2816, 0.35, 0.6),  # chute, Hertz-Mindlin, e 0.97: the one-contact limit is conservative
    "shear_linear": (0.5020, 0.35, 0.6),  # shear cell under 4 kPa, linear, e_n = e_t = 0.5
    "shear_hm": (0.0870, 0.07, 0.1),  # shear cell, Hertz-Mindlin with the thesis's e = 1e-4
}
# below this fraction of the one-contact limit every time-step map was stable (0.35 / 0.502)
STABLE_FRACTION = min(lo / lim for lim, lo, hi in DT_MAPS.values() if lo < lim)
# Courant map, TVD advection, gas alone: cell Reynolds number -> (last stable, first unstable) C
COURANT_TVD = {1.0: (0.1392, 0.1957), 10.0: (0.5448, 0.7663), 100.0: (0.3873, 0.5448), 1000.0: (0.2753, 0.3873)}


def predicted_step_limit(case) -> dict:
    """The time step above which the case's run is predicted to fail: velocity Verlet on its
    most limiting contact (:func:`case_step_limit`).  The time-step maps (:data:`DT_MAPS`: the
    undamped contact, the chute and the shear cell under load, linear and Hertz-Mindlin) found
    their boundary within one grid step of this limit (the Hertz-Mindlin chute one step above
    it: there the limit is conservative), the runs beyond it stopped by the overlap check
    (overlap > 0.5 R).  Returns dt, the ratio to cfddem check's t_c, which contact and mode set
    it, the predicted cause, ``sure``: the step below which every map was stable
    (:data:`STABLE_FRACTION` of dt), and a sentence naming the source."""
    from .simulation import collision_time

    dt, where = case_step_limit(case)
    tc = collision_time(case)
    return {"dt": dt, "ratio": dt / tc, "where": where, "cause": OVERLAP, "sure": STABLE_FRACTION * dt,
            "source": f"velocity Verlet on one contact ({where}), where the time-step maps of the chute and the "
                      f"shear cell found their boundary (docs/stability.md)"}


def courant_limit(cell_re: float) -> tuple[float, float]:
    """The TVD advection's Courant limit the Courant map found at the cell Reynolds number
    ``cell_re`` (:data:`COURANT_TVD`, interpolated in log-log between the rows, the end rows
    beyond them): (last stable, first unstable)."""
    res = sorted(COURANT_TVD)
    x = min(max(math.log(max(cell_re, 1e-300)), math.log(res[0])), math.log(res[-1]))
    out = []
    for k in (0, 1):
        ys = [math.log(COURANT_TVD[r][k]) for r in res]
        out.append(math.exp(float(np.interp(x, [math.log(r) for r in res], ys))))
    return out[0], out[1]


def case_lines(case, xkey: str) -> list[dict]:
    """Limit lines of a dt/t_c map: velocity Verlet on one contact of the case
    (:func:`case_step_limit`, analytic; Hertz-Mindlin linearised at the impact speed), cfddem
    check's rules (t_c/20 warning, t_c/5 refusal) and, for Hertz-Mindlin, 0.2 T_R."""
    from .simulation import collision_time, rayleigh_time

    if xkey != DT_KEY:
        return []
    tc = collision_time(case)
    dt, where = case_step_limit(case)
    lines = [{"x": dt / tc, "kind": "analytic",
              "label": f"velocity Verlet on one contact ({where}): {dt / tc:.3g} t_c"}]
    if case.contact.model == "hertz_mindlin":
        tr = rayleigh_time(case)
        lines.append({"x": 0.2 * tr / tc, "kind": "rule", "colour": "tab:purple",
                      "label": f"0.2 T_R (cfddem check warns above): {0.2 * tr / tc:.3g} t_c"})
    lines.append({"x": 0.05, "kind": "rule", "colour": "tab:orange", "label": "t_c/20 (cfddem check warns above)"})
    lines.append({"x": 0.2, "kind": "rule", "colour": "tab:red", "label": "t_c/5 (cfddem check refuses above)"})
    return lines


def run_case_map(case: str | Path, variants: list[dict], out: str | Path | None = None, *,
                 common: list[str] | dict | None = None, x: str | None = None, y: str | None = None,
                 panel: str | None = None, workers: int | None = None, scheduler: str | None = None,
                 threads: int | None = 1, title: str | None = None,
                 echo: Callable[[str], None] | None = print) -> dict:
    """Run the ``variants`` ({key: value}; ``dt/t_c`` allowed) of the case at ``case`` into
    ``OUT/runs/<variant>`` (in this process, one after the other; on Dask with ``workers`` or
    ``scheduler``), classify each run and write the map into ``out`` (default
    ``CASE/stability``).  A variant whose folder already holds a finished run of the same
    configuration is read back, not run again.  Returns the map's record (:func:`make_result`)."""
    from .config import case_file, load_case
    from .sweep import (_common_overrides, _run_on_dask, read_run_summary, run_is_complete, run_variant,
                        variant_names, varied_keys)

    say = echo or (lambda s: None)
    case_arg = str(case_file(case).resolve())
    base_dir = case_file(case).parent.resolve()
    out = Path(out).resolve() if out is not None else base_dir / "stability"
    if not variants:
        raise CaseError("--vary", "no variants to run")
    keys = varied_keys(variants)
    x = x or keys[0]
    y = y if y is not None else (keys[1] if len(keys) > 1 else None)
    if panel is None:  # the first other key that still varies at a fixed (x, y) (not one tied to y)
        for k in keys:
            if k in (x, y):
                continue
            seen: dict = {}
            for v in variants:
                seen.setdefault((_key_text(v.get(x)), _key_text(v.get(y))), set()).add(_key_text(v.get(k)))
            if any(len(s) > 1 for s in seen.values()):
                panel = k
                break
    for k, opt in ((x, "--x"), (y, "--y"), (panel, "--panel")):
        if k is not None and k not in keys:
            raise CaseError(opt, f"{k!r} is not a varied key ({', '.join(keys)})")
    com = _common_overrides(common)
    base = load_case(case_arg, overrides=dict(STABILITY_OVERRIDES, **com))
    names = variant_names(variants)
    rows: list[dict] = []
    todo: list[tuple[int, dict]] = []
    cases: list = []
    for i, (values, name) in enumerate(zip(variants, names)):
        row: dict[str, Any] = {"name": name, "values": dict(values), "out_dir": str(out / "runs" / name)}
        try:
            ov = resolve_variant(case_arg, values, com)
            vcase = load_case(case_arg, overrides=ov)
        except CaseError as e:
            row.update(status="bad input", error=str(e))
            cases.append(None)
        else:
            cases.append(vcase)
            if run_is_complete(row["out_dir"], vcase):
                row.update(read_run_summary(row["out_dir"]), status="skipped")
                say(f"[{name}] finished run found")
            else:
                todo.append((i, ov))
        rows.append(row)
    if todo:
        if workers or scheduler:
            _run_on_dask(case_arg, todo, rows, scheduler=scheduler, workers=workers, threads=threads,
                         connect_timeout=20.0, say=say)
        else:
            for n, (i, ov) in enumerate(todo, 1):
                rows[i].update(run_variant(case_arg, ov, rows[i]["out_dir"], threads))
                say(f"[{n}/{len(todo)}] {rows[i]['name']} {rows[i]['status']}"
                    + (f": {rows[i]['error']}" if rows[i].get("error") else ""))
    points = []
    for row, vcase in zip(rows, cases):
        msg = str(row.get("error") or "")
        msg = msg[len("run failed: "):] if msg.startswith("run failed: ") else msg
        growth, gdetail = None, ""
        if row.get("status") in ("done", "skipped") and vcase is not None:
            try:
                growth, gdetail = run_energy(Path(row["out_dir"]), vcase)
            except (OSError, KeyError, ValueError) as e:
                gdetail = f"energy not read: {e}"
        oc = classify(row.get("status", ""), msg, growth=growth, growth_detail=gdetail)
        numbers = {"dt": vcase.time.dt} if vcase is not None else {}
        if growth is not None:
            numbers["energy_ratio"] = growth
        points.append({"name": row["name"], "values": row["values"], "stable": oc.stable, "cause": oc.cause,
                       "detail": oc.detail, "numbers": numbers})
    own = {"x": own_setting(base, x), "y": own_setting(base, y), "panel": own_setting(base, panel),
           "label": f"{base.name}'s own setting"}
    if own["x"] is None or (y is not None and own["y"] is None):
        own = None
    res = make_result(points, x, y, panel, title=title or f"Stability map of {base.name}",
                      xlabel="dt / t_c (t_c: cfddem check's collision time)" if x == DT_KEY else x,
                      ylabel=y, panel_label=panel, lines=case_lines(base, x), own=own, case=base.name,
                      common=com)
    files = write_map(res, out)
    n_st = sum(1 for p in points if p["stable"])
    n_un = sum(1 for p in points if p["stable"] is False)
    say(f"stability: {n_st} stable, {n_un} unstable, {len(points) - n_st - n_un} undecided of {len(points)}; "
        f"map {files['png']}")
    return res


# ----------------------------------------------------------------------------------------------
# built-in experiments on the Python API
# ----------------------------------------------------------------------------------------------
AIR_RHO, AIR_MU = 1.2, 1.8e-5
_PERIODIC_SIDES = ("x-", "x+", "y-", "y+", "z-", "z+")


def _periodic_bcs() -> dict:
    from .gas import Periodic

    return {s: Periodic() for s in _PERIODIC_SIDES}


def drag_point(d: float, ratio: float, treatment: str, *, rho_p: float = 2550.0, rho: float = AIR_RHO,
               mu: float = AIR_MU, closure: str = "beetstra", n_intervals: int = 40, coupling_interval: int = 10,
               cell_diameters: float = 64.0, re0: float = 0.01) -> dict:
    """One particle of diameter ``d`` relaxing in a uniform gas at rest, coupled every
    ``dt_g = ratio tau``.

    tau = m / K(eps_a, Re0) is the particle's relaxation time from the closure at its initial
    slip (Re0 = 0.01: Stokes drag).  The gas fills a periodic box of 4^3 cells of
    ``cell_diameters`` d (eps_a = 1 - 2e-6 at 64 d; the gas around the particle outweighs it
    ~250 times, so the gas barely moves and the particle relaxes as if alone); viscosity
    implicit in the gas, so no gas limit interferes.  The particle starts at Re0 and is coupled
    ``n_intervals`` times (``coupling_interval`` particle steps each).  Forward Euler
    (``"explicit"``) multiplies the slip by 1 - dt_g/tau per interval: it grows for
    dt_g > 2 tau.  Unstable: the run's own failure, or the slip energy (u - v)^2 growing
    above 10 times its start (:func:`ratio_growth`)."""
    from .coupling import drag
    from .coupling.exchange import CoupledGas
    from .coupling.mapping import interpolate_faces
    from .gas import StaggeredGrid
    from .particles.contact import LinearContact
    from .particles.system import ParticleSystem

    h = cell_diameters * d
    L = 4 * h
    vp = math.pi * d**3 / 6.0
    eps_a = 1.0 - vp / h**3
    v0 = re0 * mu / (rho * eps_a * d)
    m = rho_p * vp
    tau = m / float(drag.drag_force_factor(eps_a, re0, mu, d, closure))
    dtg = ratio * tau
    sys_ = ParticleSystem(pp=LinearContact(k_n=10.0, e_n=0.9, e_t=0.5, mu=0.3), walls=[], dt=dtg / coupling_interval,
                          periodic=((0.0, L),) * 3)
    sys_.add_particles(np.array([[1.5 * h] * 3]), np.array([[v0, 0.0, 0.0]]), d / 2, rho_p)
    cg = CoupledGas(sys_, StaggeredGrid((4, 4, 4), (L,) * 3), _periodic_bcs(), rho=rho, mu=mu, closure=closure,
                    coupling_interval=coupling_interval, drag_treatment=treatment, viscosity="implicit")
    slip2 = [v0 * v0]
    status, message, flag, growth = "done", "", None, 0.0
    with np.errstate(all="ignore"):
        for _ in range(n_intervals):
            st = cg.advance(coupling_interval)
            if not st.ok:
                status, message, flag = "failed", st.message, st.flag
                break
            u = interpolate_faces(cg.grid, cg.gas.u.interior, cg.gas.v.interior, cg.gas.w.interior, sys_.pos,
                                  (True, True, True))
            slip2.append(float(np.sum((u[0] - sys_.vel[0]) ** 2)))
            growth = ratio_growth(np.array(slip2))
            if growth > 1.0:
                break
    s = np.sqrt(np.array(slip2)) / v0
    detail = (f"slip/slip_0 after {len(s) - 1} intervals: {s[-1]:.3g} (largest {np.max(s[1:]) if len(s) > 1 else 1:.3g})"
              if status == "done" else message)
    oc = classify(status, message, flag, growth=growth if status == "done" else None, growth_detail=detail)
    return {"values": {"dt_g/tau": float(ratio), "d [mm]": d * 1e3, "drag": treatment}, "stable": oc.stable,
            "cause": oc.cause, "detail": oc.detail,
            "numbers": {"tau": tau, "dt_g": dtg, "slip_ratio_end": float(s[-1]), "intervals": len(s) - 1}}


def drag_map(diameters=(3e-3, 1e-3, 3e-4, 1e-4), ratios=None, treatments=("explicit", "implicit"),
             echo: Callable[[str], None] | None = None, **kw) -> dict:
    """The explicit/implicit drag map: :func:`drag_point` over ``ratios`` (default 25 values
    from 0.1 to 100, 8 per decade) x ``diameters`` x ``treatments`` (one panel each)."""
    ratios = np.geomspace(0.1, 100.0, 25) if ratios is None else ratios
    pts = []
    for tr in treatments:
        for d in diameters:
            for r in ratios:
                pts.append(drag_point(d, float(r), tr, **kw))
                if echo:
                    echo(f"drag {tr} d = {d * 1e3:g} mm dt_g/tau = {r:.3g}: {Outcome(pts[-1]['stable'], pts[-1]['cause']).label}")
    lines = [{"x": 2.0, "kind": "analytic", "panel": "explicit",
              "label": "forward Euler limit dt_g = 2 tau"}]
    return make_result(pts, "dt_g/tau", "d [mm]", "drag", lines=lines, panel_label="drag treatment",
                       title="Drag treatment: one particle relaxing in a gas at rest, coupled every dt_g",
                       xlabel="dt_g / tau (gas step over the particle relaxation time)",
                       ylabel="particle diameter d [mm] (glass, 2550 kg/m3, in air)")


def _fluctuation_energy(gas) -> float:
    """Sum over the faces of the squared velocity minus its mean (per component)."""
    return float(sum(np.sum((f.interior - f.interior.mean()) ** 2) for f in gas.velocity))


def courant_point(courant: float, cell_re: float, scheme: str, *, steps: int = 400, cells=(16, 4, 4),
                  U: float = 1.0, h: float = 1e-3, amplitude: float = 0.01, seed: int = 1) -> dict:
    """The gas alone in a periodic box of ``cells`` cubes of side ``h``: a uniform stream U
    along x plus a random velocity fluctuation of ``amplitude`` U (seeded), stepped ``steps``
    times at dt = courant h / U with advection ``scheme`` ("central" or "tvd") and the default
    explicit viscosity at the cell Reynolds number U h / nu = ``cell_re`` (air density, the
    viscosity set to match).  Nothing feeds the fluctuation: it can only decay.  Unstable: the
    solver's own failure (NaN), or the fluctuation energy growing above 10 times its value after
    the first step (the first projection removes the divergent part of the random field)."""
    from .gas import GasSolver, StaggeredGrid

    nu = U * h / cell_re
    grid = StaggeredGrid(tuple(cells), tuple(c * h for c in cells), halo=2)
    gas = GasSolver(grid, rho=AIR_RHO, mu=AIR_RHO * nu, bcs=_periodic_bcs(), advection=scheme)
    rng = np.random.default_rng(seed)
    for c, f in enumerate(gas.velocity):
        f.interior[...] = (U if c == 0 else 0.0) + amplitude * U * rng.uniform(-1.0, 1.0, f.interior.shape)
    gas.fill_halos()
    dt = courant * h / U
    energy, status, message, growth = [], "done", "", 0.0
    with np.errstate(all="ignore"):
        for _ in range(steps):
            info = gas.step(dt)
            if not info.ok:
                status, message = "failed", f"gas step failed: {info.message}"
                break
            energy.append(_fluctuation_energy(gas))
            growth = ratio_growth(np.array(energy))
            if growth > 1.0:
                break
    e = np.array(energy)
    detail = (f"fluctuation energy after {len(e)} steps: {e[-1] / e[0]:.3g} x its value after the first step"
              if status == "done" and len(e) else message)
    oc = classify(status, message, growth=growth if status == "done" else None, growth_detail=detail)
    return {"values": {"Courant": float(courant), "cell Reynolds": float(cell_re), "advection": scheme},
            "stable": oc.stable, "cause": oc.cause, "detail": oc.detail,
            "numbers": {"dt": dt, "nu": nu, "steps": len(e), "energy_ratio": float(e[-1] / e[0]) if len(e) else math.nan}}


def courant_map(courants=None, cell_res=(1.0, 10.0, 100.0, 1000.0), schemes=("central", "tvd"),
                echo: Callable[[str], None] | None = None, **kw) -> dict:
    """Courant number against advection scheme (one panel each) and cell Reynolds number:
    :func:`courant_point` over ``courants`` (default 13 values from 0.05 to 3)."""
    courants = np.geomspace(0.05, 3.0, 13) if courants is None else courants
    pts = []
    for sc in schemes:
        for re_h in cell_res:
            for c in courants:
                pts.append(courant_point(float(c), float(re_h), sc, **kw))
                if echo:
                    echo(f"courant {sc} Re_h = {re_h:g} C = {c:.3g}: {Outcome(pts[-1]['stable'], pts[-1]['cause']).label}")
    re = np.geomspace(min(cell_res), max(cell_res), 50)
    lines = [{"xy": np.column_stack([2.0 / re, re]).tolist(), "kind": "analytic", "panel": "central",
              "label": "central + forward Euler: C = 2 / Re_h (von Neumann, 1D)"},
             {"xy": np.column_stack([0.15 * re, re]).tolist(), "kind": "rule",
              "label": "explicit viscosity: C = 0.15 Re_h (max_stable_dt)"},
             {"x": 0.5, "kind": "rule", "label": "C = 0.5 (max_stable_dt: TVD positivity bound)"},
             {"x": 1.0, "kind": "rule", "label": "C = 1 (the coupled run stops: gas CFL)"}]
    steps = kw.get("steps", 400)
    return make_result(pts, "Courant", "cell Reynolds", "advection", lines=lines, panel_label="advection",
                       title=f"Gas step: Courant number against the advection scheme ({steps} steps, periodic box)",
                       xlabel="Courant number C = U dt / h", ylabel="cell Reynolds number U h / nu")


def random_bed(L: float, d: float, solid_fraction: float, seed: int = 1) -> np.ndarray:
    """Centres of non-overlapping spheres of diameter ``d`` in a periodic cube of side ``L`` by
    random sequential addition up to ``solid_fraction`` (below the RSA jamming limit 0.38):
    batches of uniform candidates, each kept when it is at least d from every kept centre."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(seed)
    n_target = int(round(solid_fraction * L**3 / (math.pi * d**3 / 6.0)))
    pts = np.empty((0, 3))
    for _ in range(10000):
        if len(pts) >= n_target:
            break
        cand = rng.uniform(0.0, L, (4096, 3))
        if len(pts):
            dist, _ = cKDTree(pts, boxsize=L).query(cand, k=1)
            cand = cand[dist >= d]
        keep = []
        if len(cand):
            near = cKDTree(cand, boxsize=L).query_pairs(d)
            bad = set()
            for i, j in sorted(near):  # the later candidate of a close pair goes
                if i not in bad:
                    bad.add(j)
            keep = [i for i in range(len(cand)) if i not in bad]
        pts = np.vstack([pts, cand[keep][: n_target - len(pts)]])
    return pts


def lattice_bed(n: int, d: float, gap: float = 0.1, seed: int = 1) -> tuple[np.ndarray, float]:
    """A face-centred cubic lattice of ``n``^3 unit cells (nearest centres d (1 + gap) apart),
    each centre moved by up to 0.028 d per axis at random (never into contact); returns the
    centres and the side of the periodic cube."""
    a = math.sqrt(2.0) * d * (1.0 + gap)
    base = np.array([[0, 0, 0], [0.5, 0.5, 0], [0.5, 0, 0.5], [0, 0.5, 0.5]]) + 0.25
    g = np.arange(n)
    cells = np.array(np.meshgrid(g, g, g, indexing="ij")).reshape(3, -1).T
    pts = (cells[:, None, :] + base[None, :, :]).reshape(-1, 3) * a
    jitter = min(0.028, gap / (2 * math.sqrt(3.0)) * 0.99)
    pts += np.random.default_rng(seed).uniform(-jitter, jitter, pts.shape) * d
    return pts, n * a


def ergun_gradient(U: float, eps: float, d: float, rho: float = AIR_RHO, mu: float = AIR_MU) -> float:
    """Ergun (1952): the pressure gradient (Pa/m) that drives the superficial velocity U
    through a packed bed of porosity eps and particle diameter d:
    150 mu (1 - eps)^2 U / (eps^3 d^2) + 1.75 rho (1 - eps) U^2 / (eps^3 d)."""
    phi = 1.0 - eps
    return 150.0 * mu * phi * phi * U / (eps**3 * d * d) + 1.75 * rho * phi * U * U / (eps**3 * d)


def cell_size_point(h_over_d: float, bed: str, *, d: float = 1e-3, box_d: float = 20.0, G: float = 120.0,
                    closure: str = "ergun_gidaspow", intervals: int = 60, dt_gas: float = 1e-3, seed: int = 1) -> dict:
    """A fixed bed in a periodic cube of about ``box_d`` d with gas cells of about
    ``h_over_d`` d (the cube is cut into n = round(L / (h_over_d d)) cells per side; the actual
    h/d is reported), driven by a mean pressure gradient G (a body force on the gas, as in
    tests/verification/test_coupling_packed_bed.py), ``closure`` Ergun/Gidaspow, trilinear
    mapping.  ``bed``: "lattice" (:func:`lattice_bed`, porosity 0.44) or "random"
    (:func:`random_bed`, porosity 0.65).  After ``intervals`` gas steps (many gas relaxation
    times) the superficial velocity U through the x-faces gives the bed's pressure gradient
    G against Ergun's at U and the bed's mean porosity: ``drag_error`` = G / G_Ergun(U) - 1.
    ``porosity_noise``: the standard deviation of the cell porosity.  Particles of 1e12 kg/m3
    stay put.  A failed run (porosity <= 0, gas failure) is unstable with its cause."""
    import logging

    from .coupling.exchange import CoupledGas
    from .gas import StaggeredGrid
    from .particles.contact import LinearContact
    from .particles.system import ParticleSystem

    if bed == "lattice":
        pts, L = lattice_bed(max(1, int(round(box_d / (math.sqrt(2.0) * 1.1)))), d, seed=seed)
    elif bed == "random":
        L = box_d * d
        pts = random_bed(L, d, 0.35, seed=seed)
    else:
        raise CaseError("bed", f"'lattice' or 'random', got {bed!r}")
    n = max(1, int(round(L / (h_over_d * d))))
    eps_bed = 1.0 - len(pts) * math.pi * d**3 / 6.0 / L**3
    sys_ = ParticleSystem(pp=LinearContact(k_n=10.0, e_n=0.9, e_t=0.5, mu=0.3), walls=[], dt=dt_gas / 10,
                          periodic=((0.0, L),) * 3, capacity=len(pts) + 16)
    sys_.add_particles(pts, np.zeros_like(pts), d / 2, 1e12)
    quiet = logging.getLogger("cfddem.stability.quiet")
    quiet.setLevel(logging.ERROR)
    cg = CoupledGas(sys_, StaggeredGrid((n,) * 3, (L,) * 3), _periodic_bcs(), rho=AIR_RHO, mu=AIR_MU, closure=closure,
                    coupling_interval=10, gravity=(G / AIR_RHO, 0.0, 0.0), log=quiet)
    status, message, flag = "done", "", None
    for _ in range(intervals):
        st = cg.advance(10)
        if not st.ok:
            status, message, flag = "failed", st.message, st.flag
            break
    e = cg.gas.eps.interior
    ef = 0.5 * (e + np.roll(e, 1, axis=0))
    U = float(np.mean(ef * cg.gas.u.interior[:-1]))
    err = G / ergun_gradient(U, eps_bed, d) - 1.0 if status == "done" and U > 0 else math.nan
    noise = float(np.std(e))
    oc = classify(status, message, flag, growth_detail=f"pressure gradient {G:g} Pa/m against Ergun's "
                  f"{ergun_gradient(U, eps_bed, d):.4g} Pa/m at U = {U:.4g} m/s" if status == "done" else "")
    return {"values": {"h/d": L / n / d, "bed": bed}, "stable": oc.stable, "cause": oc.cause, "detail": oc.detail,
            "numbers": {"porosity_noise": noise, "drag_error": err, "eps_bed": eps_bed, "eps_min": float(e.min()),
                        "superficial_velocity": U, "cells": n, "particles": len(pts)}}


def cell_size_map(ratios=(1.0, 1.5, 2.0, 3.0, 4.0, 5.0), beds=("lattice", "random"),
                  echo: Callable[[str], None] | None = None, **kw) -> dict:
    """:func:`cell_size_point` over ``ratios`` x ``beds``."""
    pts = []
    for b in beds:
        for r in ratios:
            pts.append(cell_size_point(r, b, **kw))
            if echo:
                nb = pts[-1]["numbers"]
                echo(f"cells {b} h/d = {pts[-1]['values']['h/d']:.3g}: {Outcome(pts[-1]['stable'], pts[-1]['cause']).label}, "
                     f"porosity noise {nb['porosity_noise']:.3g}, drag error {nb['drag_error']:+.3g}")
    return make_result(pts, "h/d", "bed", None, panel_label=None,
                       title="Gas cell size against particle diameter: fixed bed, trilinear mapping, Ergun",
                       xlabel="gas cell side h / particle diameter d", ylabel="bed")


def draw_cell_size(result: dict, path: str | Path) -> Path:
    """Two panels against h/d, one line per bed: the porosity noise (standard deviation of the
    cell porosity) and the error of the bed's pressure gradient against Ergun's; failed
    settings marked with their cause."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.6))
    beds = list(dict.fromkeys(p["values"]["bed"] for p in result["points"]))
    for b, col in zip(beds, ("tab:blue", "tab:orange", "tab:green")):
        pts = sorted((p for p in result["points"] if p["values"]["bed"] == b), key=lambda p: p["values"]["h/d"])
        eps = np.mean([p["numbers"]["eps_bed"] for p in pts])
        for ax, key in zip(axes, ("porosity_noise", "drag_error")):
            ok = [p for p in pts if p["stable"]]
            ys = [abs(p["numbers"][key]) if key == "drag_error" else p["numbers"][key] for p in ok]
            ax.plot([p["values"]["h/d"] for p in ok], ys, "o-", color=col, label=f"{b} bed, porosity {eps:.2f}")
            for p in pts:
                if p["stable"] is False:
                    m, c = _MARKERS.get(p["cause"], _MARKERS[OTHER])
                    ax.plot(p["values"]["h/d"], ax.get_ylim()[1] if ys else 1.0, m, color=c, ms=9,
                            label=f"{b}: unstable, {p['cause']}")
    axes[0].set_ylabel("porosity noise: std of the cell porosity")
    axes[1].set_ylabel("|pressure gradient / Ergun's - 1|")
    axes[1].set_yscale("log")
    for ax in axes:
        ax.set_xlabel("gas cell side h / particle diameter d")
        ax.axvline(3.0, ls="--", color="tab:red", lw=1.2, label="3 d (cfddem check warns below)")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    fig.suptitle(result.get("title", ""), fontsize=11)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


# ----------------------------------------------------------------------------------------------
# command line
# ----------------------------------------------------------------------------------------------
BUILTIN_MAPS = ("drag", "courant", "cells")


def add_stability_parser(subparsers) -> Any:
    """Add ``cfddem stability`` to an argparse ``subparsers`` object."""
    s = subparsers.add_parser(
        "stability", help="stability map: run a grid of settings, classify each run, draw the map",
        description="Run every variant of a case (the product of the --vary lists, or --variants rows), "
                    "classify each run as stable or unstable with its cause, and draw the map "
                    "(docs/stability.md).  --vary dt/t_c=... sets time.dt to that fraction of the "
                    "variant's collision time.  --map NAME runs a built-in experiment instead of a case.")
    s.add_argument("case", nargs="?", help="case folder (holding case.toml) or a case.toml file")
    s.add_argument("--vary", action="append", default=[], metavar="KEY=V1,V2,...",
                   help="a key and its values; repeat for a grid (first: x axis, second: y axis, third: panels)")
    s.add_argument("--variants", metavar="FILE", help="TOML or CSV file of variants (as cfddem sweep)")
    s.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a key in every variant")
    s.add_argument("--map", choices=BUILTIN_MAPS, help="a built-in map instead of a case: drag (explicit against "
                   "implicit drag), courant (gas Courant number against the advection scheme), cells (gas cell "
                   "size against particle diameter)")
    s.add_argument("--out", help="output folder (default: CASE/stability, or stability_MAP)")
    s.add_argument("--x", help="the varied key on the x axis (default: the first)")
    s.add_argument("--y", help="the varied key on the y axis (default: the second)")
    s.add_argument("--panel", help="the varied key that splits the map into panels (default: the third)")
    s.add_argument("--title", help="title of the map")
    s.add_argument("--workers", type=int, help="run the variants on a local Dask cluster of this many workers")
    s.add_argument("--scheduler", metavar="ADDRESS", help="run the variants on an existing Dask cluster")
    s.add_argument("--threads", type=int, default=1, help="numba threads per run (default 1)")
    return s


def run_builtin_map(name: str, out: str | Path, echo: Callable[[str], None] | None = print) -> dict:
    """Run the built-in map ``name`` (:data:`BUILTIN_MAPS`) with its default grid and write it
    into ``out``."""
    import numba

    numba.set_num_threads(1)
    if name == "drag":
        res = drag_map(echo=echo)
    elif name == "courant":
        res = courant_map(echo=echo)
    elif name == "cells":
        res = cell_size_map(echo=echo)
    else:
        raise CaseError("--map", f"{name!r}: one of {', '.join(BUILTIN_MAPS)}")
    files = write_map(res, out)
    if name == "cells":
        draw_cell_size(res, files["png"])
    return res


def run_stability_from_args(args) -> int:
    """``cfddem stability``: 0 when the map was drawn (unstable settings are its content, not an
    error); bad input raises :class:`CaseError`."""
    from .sweep import combine_variants, parse_vary, read_variants_file

    if args.map:
        if args.case or args.vary or args.variants:
            raise CaseError("--map", "a built-in map takes no CASE, --vary or --variants")
        out = Path(args.out) if args.out else Path(f"stability_{args.map}")
        res = run_builtin_map(args.map, out)
    else:
        if not args.case:
            raise CaseError("CASE", "give a case folder (or --map NAME for a built-in map)")
        varies = [parse_vary(v) for v in args.vary]
        rows = read_variants_file(args.variants) if args.variants else None
        if not varies and not rows:
            raise CaseError("--vary", "give at least one --vary KEY=V1,V2,... or --variants FILE")
        if args.threads is not None and args.threads < 1:
            raise CaseError("--threads", f"{args.threads} must be at least 1")
        res = run_case_map(args.case, combine_variants(rows, varies), args.out, common=list(args.overrides),
                           x=args.x, y=args.y, panel=args.panel, workers=args.workers, scheduler=args.scheduler,
                           threads=args.threads, title=args.title)
        out = Path(args.out) if args.out else None
    for lim in res["limits"]:
        where = ", ".join(f"{k} = {_fmt(lim[k])}" for k in ("panel", "y") if k in lim)
        print(f"{where + ': ' if where else ''}last stable {res['x']} = {_fmt(lim['last_stable'])}, first unstable "
              f"{_fmt(lim['first_unstable'])}" + (f" ({lim['cause']})" if lim["cause"] else ""))
    if out is not None:
        print(f"map: {out / 'stability.png'}")
    return 0


def main(argv: list[str] | None = None) -> int:  # pragma: no cover (python -m cfddem.stability)
    from .cli import main as cli_main

    return cli_main(["stability", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
