"""``cfddem calibrate``: bulk (or wall) friction of a shear-cell case against the contact
friction coefficients, the usual DEM calibration: choose mu (and mu_r) so that the simulated
Jenike test gives the measured bulk friction.

The sweep's x axis is either ``--mu`` (``contact.particle_particle.mu``; the case's variant
``bulk``: ``/measurements/bulk_friction``) or ``--mu-wall`` (``shear.plate.mu``, the flat plate of
the variant ``wall``: ``/measurements/wall_friction``).  For each x the sweep runs every
``--mu-r`` (the rolling friction of the same contact: ``contact.particle_particle.mu_r``, or
``shear.plate.mu_r``), every ``--rotation`` (``free`` and/or ``locked``:
``particles.rotation``) and ``--replicas`` fills (``particles.seed`` + 0, 1, ...; a replica is
another random packing of the same sample).  Runs go one after the other, in this process, into
``OUT/<label>_<rotation>_mur<mu_r>_mu<x>_s<seed>/``; a folder that already holds the finished run
of exactly that case is read back, not run again (a study grows by calling the command again).

``--label`` names the sample (default ``spheres``).  Several calls with different labels (for
example spheres, then ``--set particles.clump='"pellet2"' --label clumps``) into the same
``OUT`` add to one study: the table and chart hold every label found in ``OUT/runs.csv``.

Written into OUT: ``runs.csv`` (one row per run), ``calibration.csv`` and ``calibration.md``
(mean, standard deviation and count over the replicas of each point; wall times) and
``calibration.png`` (friction against x, one panel per label, one colour per mu_r, solid lines
free rotation, dashed locked; error bars one standard deviation over the replicas).
``--target`` adds the x that gives a measured friction (linear interpolation of the means).
"""

from __future__ import annotations

import csv
import math
import time
from pathlib import Path

import numpy as np

from .errors import CaseError

RUN_KEYS = ["label", "rotation", "mu_r", "x", "seed", "friction", "rise", "shear_force", "normal_force", "load_error",
            "inertial_number", "n_sample", "solid_fraction", "status", "wall_s", "folder"]
POINT_KEYS = ["label", "rotation", "mu_r", "x", "friction", "friction_std", "n", "rise", "jammed", "shear_force",
              "normal_force", "load_error", "solid_fraction", "wall_s"]
#: a mean ratio above this is no friction of the sample: a shear force larger than the normal load
#: can only be carried by the rings' walls squeezing a sample that locks between them
JAMMED = 1.0


def add_calibrate_parser(sub) -> None:
    c = sub.add_parser("calibrate", help="shear-cell bulk or wall friction against contact friction (table + PNG)")
    c.add_argument("case", help="a shear_cell case folder")
    c.add_argument("--mu", default="", help="comma-separated particle-particle friction values, e.g. 0.1,0.3,0.6,1")
    c.add_argument("--mu-wall", default="", help="instead of --mu: particle-plate friction values (shear.plate.mu; "
                   "sets shear.variant = 'wall')")
    c.add_argument("--mu-r", default="", help="comma-separated rolling friction values of the swept contact "
                   "(default: the case's)")
    c.add_argument("--rotation", default="free", help="'free', 'locked' or 'free,locked' (particles.rotation)")
    c.add_argument("--replicas", type=int, default=1, help="fills per point (particles.seed + 0, 1, ...)")
    c.add_argument("--label", default="spheres", help="name of this sample in the study (a panel of the chart)")
    c.add_argument("--out", required=True, help="output folder (a study: finished runs in it are reused)")
    c.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a case key")
    c.add_argument("--target", type=float, default=None, help="friction to match: report the x giving it")
    c.add_argument("--threads", type=int, default=None, help="numba threads")
    c.add_argument("--overwrite", action="store_true", help="run again even where a finished run exists")


def _floats(text: str, key: str) -> list[float]:
    try:
        vals = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise CaseError(key, f"needs comma-separated numbers, got {text!r}") from None
    if any(not (v >= 0 and math.isfinite(v)) for v in vals):
        raise CaseError(key, f"friction values must be finite and >= 0, got {text!r}")
    return vals


def interpolate_target(mu, friction, target: float) -> float:
    """The mu at which the piecewise-linear curve (mu sorted) reaches ``target`` (nan if never)."""
    mu = np.asarray(mu, float)
    f = np.asarray(friction, float)
    o = np.argsort(mu)
    mu, f = mu[o], f[o]
    for k in range(len(mu) - 1):
        a, b = f[k] - target, f[k + 1] - target
        if a == 0:
            return float(mu[k])
        if a * b < 0:
            return float(mu[k] + (mu[k + 1] - mu[k]) * a / (a - b))
    if len(f) and f[-1] == target:
        return float(mu[-1])
    return math.nan


def _folder_name(label: str, rotation: str, mur: float, x: float, seed: int) -> str:
    return f"{label}_{rotation}_mur{mur:g}_mu{x:g}_s{seed}"


def calibrate(case_dir, xs, murs, out, overrides=(), threads=None, overwrite=False, target=None, wall=False,
              rotations=("free",), replicas=1, label="spheres", log=print) -> list[dict]:
    """Run the sweep (module docstring); returns the rows of every run of the study in ``out``
    (this call's and earlier calls' with other labels)."""
    from .config import load_case
    from .io.results import read_measurements
    from .measure.shear import window_rise
    from .simulation import Simulation
    from .sweep import read_run_summary, run_is_complete

    out = Path(out)
    if not label or any(c in label for c in "/\\ ,"):
        raise CaseError("--label", f"needs a name without spaces, commas or slashes, got {label!r}")
    if replicas < 1:
        raise CaseError("--replicas", f"needs at least 1, got {replicas}")
    bad = [r for r in rotations if r not in ("free", "locked")]
    if bad or not rotations:
        raise CaseError("--rotation", f"'free' and/or 'locked', got {','.join(rotations)!r}")
    base_ov = list(overrides) + (['shear.variant="wall"'] if wall else [])
    base = load_case(case_dir, overrides=base_ov)  # validates before any folder is written
    if base.geometry.type != "shear_cell":
        raise CaseError("geometry.type", f"calibrate needs a shear_cell case, got {base.geometry.type!r}")
    if not wall and base.resolved["shear"]["variant"] == "wall":
        raise CaseError("shear.variant", "the case is the wall-friction variant: sweep --mu-wall, not --mu")
    xkey, rkey = (("shear.plate.mu", "shear.plate.mu_r") if wall else
                  ("contact.particle_particle.mu", "contact.particle_particle.mu_r"))
    if not murs:
        plate = base.resolved["shear"]["plate"].get("mu_r") if wall else None
        murs = [float(plate if plate is not None else
                      (base.contact.particle_wall.mu_r if wall else base.contact.particle_particle.mu_r))]
    name = "wall_friction" if wall else "bulk_friction"
    seed0 = int(base.particles.seed)
    out.mkdir(parents=True, exist_ok=True)
    done_here = []
    points_to_run = [(rot, mur, x, k) for rot in rotations for mur in murs for x in xs for k in range(replicas)]
    for rot, mur, x, k in points_to_run:
        if done_here and done_here[-1]["status"].startswith("interrupted"):
            log("interrupted: the sweep stops here (call the command again to continue; finished runs are reused)")
            break  # Ctrl-C or a termination signal stops the sweep, not only its current run
        seed = seed0 + k
        sub = out / _folder_name(label, rot, mur, x, seed)
        ov = base_ov + [f"{xkey}={x}", f"{rkey}={mur}", f'particles.rotation="{rot}"',
                        f"particles.seed={seed}"]
        if threads is not None:
            ov.append(f"time.threads={int(threads)}")
        case = load_case(case_dir, overrides=ov)
        row = {"label": label, "rotation": rot, "mu_r": mur, "x": x, "seed": seed, "friction": math.nan,
               "rise": math.nan, "shear_force": math.nan, "normal_force": math.nan, "load_error": math.nan,
               "inertial_number": math.nan, "n_sample": 0, "solid_fraction": math.nan, "status": "", "wall_s": math.nan,
               "folder": sub.name}
        if not overwrite and run_is_complete(sub, case):
            row["status"] = "done"
            row["wall_s"] = float(read_run_summary(sub).get("wall_time", math.nan))
            how = "reused"
        else:
            t0 = time.perf_counter()
            summary = Simulation(case, sub, overwrite=True, echo=False, progress=False).run()
            row["wall_s"] = time.perf_counter() - t0
            row["status"] = summary.status
            how = f"{row['wall_s']:.0f} s"
        try:
            m = read_measurements(sub / "results.h5")
            sh = m["shear"]
            row.update(friction=float(m[name]), shear_force=float(sh["mean_shear_force"]),
                       normal_force=float(sh["mean_normal_force"]), load_error=float(sh["load_error"]),
                       inertial_number=float(sh["inertial_number"]), n_sample=int(sh["n_samples"]),
                       rise=window_rise(sh["displacement"], sh["shear_force"],
                                        np.asarray(sh["normal_force"], float) + np.asarray(sh["weight_above"], float),
                                        sh["window"]),
                       solid_fraction=float(sh.get("fill_solid_fraction", math.nan)))
        except (KeyError, OSError) as e:
            row["status"] = f"{row['status']} (no measurement: {e})"
        done_here.append(row)
        log(f"{label}, rotation {rot}, mu_r = {mur:g}, {xkey} = {x:g}, seed {seed}: {name} "
            f"{row['friction']:.4g} ({row['status']}, {how})")
    keep = {(r["label"], r["rotation"], r["mu_r"], r["x"], r["seed"]) for r in done_here}
    rows = [r for r in _read_runs(out) if (r["label"], r["rotation"], r["mu_r"], r["x"], r["seed"]) not in keep]
    rows += done_here
    _write(rows, out, name, xkey, target)
    return rows


def _read_runs(out: Path) -> list[dict]:
    """The rows of ``OUT/runs.csv`` (an earlier call's), numbers parsed; [] when absent."""
    p = out / "runs.csv"
    if not p.is_file():
        return []
    rows = []
    with open(p, newline="") as f:
        for r in csv.DictReader(f):
            for k in ("mu_r", "x", "friction", "rise", "shear_force", "normal_force", "load_error", "inertial_number",
                      "solid_fraction", "wall_s"):
                r[k] = float(r.get(k) or "nan")
            r["seed"] = int(r["seed"])
            r["n_sample"] = int(r["n_sample"])
            rows.append(r)
    return rows


def points(rows: list[dict]) -> list[dict]:
    """Mean, standard deviation (ddof 1; NaN for one replica) and count of the finite frictions
    over the replicas of each (label, rotation, mu_r, x), the mean rise across the window;
    ``jammed`` where the mean exceeds :data:`JAMMED`; wall time summed."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault((r["label"], r["rotation"], r["mu_r"], r["x"]), []).append(r)
    pts = []
    for (lab, rot, mur, x), rs in sorted(groups.items()):
        f = np.array([r["friction"] for r in rs], float)
        ok = np.isfinite(f)
        n = int(ok.sum())

        def mean(k):
            v = np.array([r[k] for r in rs], float)[ok]
            return float(np.mean(v)) if n else math.nan

        pts.append({"label": lab, "rotation": rot, "mu_r": mur, "x": x, "friction": mean("friction"),
                    "friction_std": float(np.std(f[ok], ddof=1)) if n > 1 else math.nan, "n": n,
                    "rise": mean("rise"), "jammed": int(n > 0 and mean("friction") > JAMMED),
                    "shear_force": mean("shear_force"), "normal_force": mean("normal_force"),
                    "load_error": mean("load_error"), "solid_fraction": mean("solid_fraction"),
                    "wall_s": float(np.nansum([r["wall_s"] for r in rs]))})
    return pts


def _write(rows, out: Path, name: str, xkey: str, target) -> None:
    with open(out / "runs.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=RUN_KEYS)
        w.writeheader()
        for r in sorted(rows, key=lambda r: (r["label"], r["rotation"], r["mu_r"], r["x"], r["seed"])):
            w.writerow({k: r[k] for k in RUN_KEYS})
    pts = points(rows)
    with open(out / "calibration.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=POINT_KEYS)
        w.writeheader()
        for p in pts:
            w.writerow(p)
    title = name.replace("_", " ")
    lines = [f"# Shear-cell calibration: {title} against `{xkey}`", "",
             "Mean and standard deviation over the replicas (n: runs with a measurement); rise: how much "
             "the ratio still grows from the first to the second half of the window (0: steady); solid fraction: "
             "the scraped sample's at the end of the fill; forces are "
             "means over the window; wall time summed over the replicas.  JAMMED: a ratio above "
             f"{JAMMED:g}, a shear force larger than the normal load, which only the rings' walls can carry "
             "(the sample locks between the rings instead of shearing; not drawn in the chart).", "",
             f"| sample | rotation | mu_r | {xkey} | {title} | std | n | rise | shear force (N) | N + W (N) |"
             " load error | solid fraction | wall (s) |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for p in pts:
        jam = " JAMMED" if p["jammed"] else ""
        lines.append(f"| {p['label']} | {p['rotation']} | {p['mu_r']:g} | {p['x']:g} | {p['friction']:.4f}{jam} | "
                     f"{p['friction_std']:.3f} | {p['n']} | {100 * p['rise']:+.0f} % | {p['shear_force']:.4g} | "
                     f"{p['normal_force']:.4g} | {100 * p['load_error']:.2g} % | {p['solid_fraction']:.3f} | "
                     f"{p['wall_s']:.0f} |")
    bad = [r for r in rows if r["status"] != "done"]
    if bad:
        lines += ["", "Runs that did not finish: " + ", ".join(f"{r['folder']} ({r['status']})" for r in bad)]
    curves = sorted({(p["label"], p["rotation"], p["mu_r"]) for p in pts})
    if target is not None:
        lines += ["", f"Target {title} {target:g}:"]
        for lab, rot, mur in curves:
            sel = [p for p in pts if (p["label"], p["rotation"], p["mu_r"]) == (lab, rot, mur)]
            sel = [p for p in sel if not p["jammed"]]
            m = interpolate_target([p["x"] for p in sel], [p["friction"] for p in sel], target)
            lines.append(f"- {lab}, {rot}, mu_r = {mur:g}: {xkey} = {m:.4g}" if math.isfinite(m) else
                         f"- {lab}, {rot}, mu_r = {mur:g}: not reached in the swept range")
    (out / "calibration.md").write_text("\n".join(lines) + "\n")
    _plot(pts, out / "calibration.png", title, xkey, target)


def _plot(pts, path: Path, title: str, xkey: str, target) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = sorted({p["label"] for p in pts})
    murs = sorted({p["mu_r"] for p in pts})
    colours = plt.cm.viridis(np.linspace(0.0, 0.85, max(len(murs), 1)))
    fig, axes = plt.subplots(1, len(labels), figsize=(4.6 * len(labels) + 0.6, 4.0), sharey=True, squeeze=False)
    for ax, lab in zip(axes[0], labels):
        for rot, ls, mk in (("free", "-", "o"), ("locked", "--", "s")):
            for c, mur in zip(colours, murs):
                sel = sorted([p for p in pts if (p["label"], p["rotation"], p["mu_r"]) == (lab, rot, mur)
                              and not p["jammed"]], key=lambda p: p["x"])
                if not sel:
                    continue
                err = [p["friction_std"] if math.isfinite(p["friction_std"]) else 0.0 for p in sel]
                ax.errorbar([p["x"] for p in sel], [p["friction"] for p in sel], yerr=err, color=c, ls=ls,
                            marker=mk, ms=4, capsize=3, lw=1.3,
                            label=f"mu_r = {mur:g}" + (", rotation locked" if rot == "locked" else ""))
        if target is not None:
            ax.axhline(target, color="k", ls=":", lw=1, label=f"target {target:g}")
        if xkey == "shear.plate.mu":  # pure sliding on the plate gives the contact friction
            xs = [p["x"] for p in pts]
            ax.plot([0.0, max(xs)], [0.0, max(xs)], color="0.6", ls=":", lw=1, label="= plate friction")
        jam = [p for p in pts if p["label"] == lab and p["jammed"]]
        if jam:
            ax.text(0.02, 0.98, "jammed, not drawn:\n" + "\n".join(
                f"{p['rotation']}, mu_r {p['mu_r']:g}, x {p['x']:g}: {p['friction']:.3g}" for p in jam),
                transform=ax.transAxes, va="top", fontsize=7)
        ax.set_title(lab, fontsize=11)
        ax.set_xlabel(xkey.replace("contact.particle_particle.", "particle-particle ").replace(
            "shear.plate.", "particle-plate "), fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7.5, loc="lower right")
    axes[0][0].set_ylabel(f"{title} (error bars: 1 s.d. over replicas)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def run_calibrate_from_args(args) -> int:
    if bool(args.mu) == bool(args.mu_wall):
        raise CaseError("--mu", "give the swept values with --mu (bulk friction) or --mu-wall (wall friction), "
                        "one of the two")
    wall = bool(args.mu_wall)
    xs = _floats(args.mu_wall if wall else args.mu, "--mu-wall" if wall else "--mu")
    if not xs:
        raise CaseError("--mu-wall" if wall else "--mu", "needs at least one value")
    murs = _floats(args.mu_r, "--mu-r") if args.mu_r else []
    rots = [r.strip() for r in args.rotation.split(",") if r.strip()]
    rows = calibrate(args.case, xs, murs, args.out, overrides=args.set, threads=args.threads,
                     overwrite=args.overwrite, target=args.target, wall=wall, rotations=rots, replicas=args.replicas,
                     label=args.label)
    print(f"table: {Path(args.out) / 'calibration.md'}, plot: {Path(args.out) / 'calibration.png'}")
    return 130 if any(r["label"] == args.label and r["status"].startswith("interrupted") for r in rows) else 0
