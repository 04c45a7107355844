"""``cfddem compare OUT_A OUT_B``: the gas-against-no-gas (or any A-against-B) report.

The report follows what the runs measured (their ``/measurements`` groups), not the scene's
name: runs with time-averaged chute measurements (``/measurements/chute``) get the chute
report below; runs with a silo discharge (``/measurements/silo`` and ``mass_flow_rate``) get
the silo report (:func:`_silo_report`: mass flow rate, discharge curve, bulk density,
clogging, wall times and the gas solver).

Chute report.  Reads two run folders (``results.h5`` each) and writes, into ``--out DIR``:

* ``report.md`` with PNG figures beside it and ``report.html`` (one self-contained file, the
  figures embedded as base64 PNG);
* ``summary.json`` with at least ``velocity_end_a``, ``velocity_end_b`` (mean streamwise
  particle velocity over the last 0.1 m of the chute, m/s), ``relative_difference_end``
  ((b - a)/a), ``wall_time_a``, ``wall_time_b`` (s), the cost split of each run, and
  ``gas_solver_a``/``_b`` (the gas steps' count, CG iterations, largest residual, mass-balance
  defect and Courant number over the run; null without gas).

Figures: mean streamwise velocity along the chute (both runs); bed height along the chute at the
left, centre and right sensors; streamwise and spanwise surface velocity across the width at
z = 0, 0.2, 0.4, 0.6 m; depth profiles of streamwise velocity (whole width, or left and right
halves when the frame rotates) and of solid fraction in the left, centre and right slices; a top
view of the flow coloured by the surface velocity with the gas velocity above the bed as arrows
(when a run has gas); wall time of both runs and their cost split.  Left and right are seen in
the direction of flow (the x = 0 side is the right; :mod:`cfddem.measure.chute`), and the report
says so in one line (:data:`cfddem.measure.chute.CONVENTION`).
"""

from __future__ import annotations

import base64
import html
import json
import math
from pathlib import Path

import numpy as np

from ..errors import CaseError
from ..measure.chute import CENTRE, CONVENTION, SIDE_AT_X0, SIDE_AT_XW, sensor_names, side_label, x_label

END_LENGTH = 0.1  # m: "velocity at the chute end" = mean over the last 0.1 m
STATIONS = (0.0, 0.2, 0.4, 0.6)


def _mpl():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


class Run:
    """What the report needs from one run folder."""

    def __init__(self, folder: str | Path, label: str | None = None):
        from ..io.results import read_config, read_measurements, read_metadata, read_series

        self.folder = Path(folder)
        h5 = self.folder / "results.h5"
        if not h5.exists():
            raise CaseError("OUT", f"no results.h5 in {self.folder}")
        self.series = read_series(h5)
        self.meas = read_measurements(h5)
        self.meta = read_metadata(h5)
        _, self.config = read_config(h5)
        self.chute = self.meas.get("chute", {})
        self.silo = self.meas.get("silo", {})
        self.budget = self.meas.get("momentum_budget", {})
        if int(np.asarray(self.budget.get("n_samples", 0))) == 0:
            self.budget = {}
        # the gas's momentum budget over its domain (runs with gas), with its attributes (side names)
        self.gas_budget = read_measurements(h5, with_attrs=True).get("gas_budget", {}) if "gas_budget" in self.meas else {}
        if int(np.asarray(self.gas_budget.get("n_steps", 0))) == 0:
            self.gas_budget = {}
        if int(np.asarray(self.chute.get("n_samples", 0))) > 0:
            self.kind = "chute"
        elif self.silo and "mass_flow_rate" in self.meas:
            self.kind = "silo"
        else:
            raise CaseError("OUT", f"{self.folder}: the run holds no time-averaged chute measurements "
                                   "(did it reach measurements.start_time?) and no silo discharge (/measurements/silo)")
        self.gas = self.meas.get("gas", {})
        gas_on = bool(self.config.get("gas", {}).get("enabled", False))
        self.label = label or ("with gas" if gas_on else "no gas")
        self.rpm = float(self.config.get("frame", {}).get("rpm", 0.0))
        self.exit_z = float(self.config.get("exit", {}).get("z") or np.nan)
        self.wall_time = float(self.meta.get("wall_time", np.nan))
        self.timings = {k[len("time_"):]: float(v) for k, v in self.meta.items() if k.startswith("time_")}
        # the wall time without numba's first compilation of the kernels (the first run on a
        # fresh machine pays it; runs written before it was timed: the whole wall time)
        self.compile_time = self.timings.get("compile", 0.0)
        self.net_wall_time = self.wall_time - self.compile_time
        # the gas solver over the run (Simulation stores CoupledGas.run_stats(); absent without gas)
        keys = ("gas_steps", "gas_cg_iterations_mean", "gas_cg_iterations_max", "gas_pressure_residual_max",
                "gas_mass_defect_max", "gas_cfl_max")
        self.gas_solver = {k: float(self.meta[k]) for k in keys} if all(k in self.meta for k in keys) else {}

    def gas_solver_line(self) -> str | None:
        g = self.gas_solver
        if not g.get("gas_steps"):
            return None
        return (f"gas solver ({self.label}): {int(g['gas_steps'])} gas steps, pressure CG iterations mean "
                f"{g['gas_cg_iterations_mean']:.2f} (max {int(g['gas_cg_iterations_max'])}), mass-balance defect "
                f"at most {g['gas_mass_defect_max']:.2e}, Courant number at most {g['gas_cfl_max']:.3g}")

    def velocity_end(self) -> float:
        """Mean streamwise particle velocity over the last 0.1 m of the chute (cells weighted
        equally; the time average of the per-cell means)."""
        z = np.asarray(self.chute["mean_vz_z"])
        v = np.asarray(self.chute["mean_vz"])
        sel = (z >= self.exit_z - END_LENGTH) & (z <= self.exit_z) & np.isfinite(v)
        return float(np.mean(v[sel])) if sel.any() else math.nan


def _width(run) -> float:
    """The chute width: the case's ``geometry.width``, else the last measurement cell edge."""
    w = run.config.get("geometry", {}).get("width")
    if w is None and "x_edges" in run.chute:
        w = np.asarray(run.chute["x_edges"])[-1]
    return float(w) if w is not None else math.nan


def _station_index(z_centres, z):
    return int(np.argmin(np.abs(np.asarray(z_centres) - z)))


def _fig_velocity(runs, path):
    plt = _mpl()
    fig, ax = plt.subplots(figsize=(7, 4))
    for r in runs:
        ax.plot(r.chute["mean_vz_z"], r.chute["mean_vz"], label=r.label)
    ze = runs[0].exit_z
    ax.axvspan(ze - END_LENGTH, ze, color="0.9", label="chute end (last 0.1 m)")
    ax.set_xlabel("z along the chute [m]")
    ax.set_ylabel("mean streamwise particle velocity [m/s]")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _fig_bed(runs, path):
    plt = _mpl()
    x = np.asarray(runs[0].chute["sensor_x"])
    W = _width(runs[0])
    names = sensor_names(x, W)
    order = np.argsort(-x)  # as seen looking down the chute: left, centre, right
    fig, axes = plt.subplots(1, len(x), figsize=(4 * len(x), 4.2), sharey=True, squeeze=False)
    for ax, i in zip(axes[0], order):
        for r in runs:
            ax.plot(r.chute["sensor_z"], 1e3 * np.asarray(r.chute["bed_height_sensor"])[i], label=r.label)
        ax.set_title(f"{side_label(names[i], W)}\nsensor at x = {1e3 * x[i]:.0f} mm", fontsize=10)
        ax.set_xlabel("z [m]")
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("bed height [mm]")
    axes[0, 0].legend()
    fig.text(0.5, 0.005, CONVENTION, ha="center", va="bottom", fontsize=7)
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _fig_surface(runs, path):
    plt = _mpl()
    fig, axes = plt.subplots(2, len(STATIONS), figsize=(13, 6), sharex=True)
    for j, zs in enumerate(STATIONS):
        for r in runs:
            k = _station_index(r.chute["z_centres"], zs)
            x = 1e3 * np.asarray(r.chute["x_centres"])
            axes[0, j].plot(x, np.asarray(r.chute["surface_vz"])[:, k], marker=".", label=r.label)
            axes[1, j].plot(x, np.asarray(r.chute["surface_vx"])[:, k], marker=".", label=r.label)
        axes[0, j].set_title(f"z = {zs:g} m")
        axes[1, j].set_xlabel(x_label(_width(runs[0])), fontsize=7)
        for a in axes[:, j]:
            a.grid(alpha=0.3)
    axes[0, 0].set_ylabel("streamwise surface velocity [m/s]")
    axes[1, 0].set_ylabel("spanwise surface velocity [m/s]")
    axes[0, 0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _fig_profiles(runs, path):
    plt = _mpl()
    rotating = any(r.rpm != 0 for r in runs)
    vel_slices = (f"{SIDE_AT_XW}_half", f"{SIDE_AT_X0}_half") if rotating else ("whole",)
    phi_slices = (SIDE_AT_XW, CENTRE, SIDE_AT_X0)
    st = np.asarray(runs[0].chute["stations"])
    fig, axes = plt.subplots(2, len(st), figsize=(13, 7), sharey=True)
    axes = np.atleast_2d(axes)
    y = 1e3 * np.asarray(runs[0].chute["profile_y"])
    styles = ("-", "--", ":")
    for j in range(len(st)):
        for r, ls in zip(runs, ("-", "--")):
            for sl, c in zip(vel_slices, ("C0", "C1")):
                key = f"profile_{sl}_vz"
                if key in r.chute:
                    axes[0, j].plot(np.asarray(r.chute[key])[j], y, ls, color=c,
                                    label=f"{r.label}, {side_label(sl, _width(r))}")
            for sl, c in zip(phi_slices, ("C2", "C3", "C4")):
                key = f"profile_{sl}_phi"
                if key in r.chute:
                    axes[1, j].plot(np.asarray(r.chute[key])[j], y, ls, color=c,
                                    label=f"{r.label}, {side_label(sl, _width(r))}")
        axes[0, j].set_title(f"z = {st[j]:g} m")
        axes[0, j].set_xlabel("streamwise velocity [m/s]")
        axes[1, j].set_xlabel("solid fraction [-]")
        for a in axes[:, j]:
            a.grid(alpha=0.3)
    axes[0, 0].set_ylabel("height above the floor [mm]")
    axes[1, 0].set_ylabel("height above the floor [mm]")
    axes[0, 0].legend(fontsize=7)
    axes[1, 0].legend(fontsize=7)
    del styles
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _gas_top_arrows(run):
    """(x, z, ux, uz) of the time-averaged gas velocity in the top layer of gas cells (just
    below the open top, above the bed), or None when the run has no gas."""
    g = run.gas
    if not g or "mean_velocity" not in g:
        return None
    vel = np.asarray(g["mean_velocity"])
    x = np.asarray(g.get("x", []))
    z = np.asarray(g.get("z", []))
    if vel.ndim != 4 or len(x) != vel.shape[0] or len(z) != vel.shape[2]:
        return None
    top = vel[:, -1, :, :]
    return x, z, top[..., 0], top[..., 2]


def _fig_top(runs, path):
    plt = _mpl()
    fig, axes = plt.subplots(1, len(runs), figsize=(5 * len(runs), 8), sharey=True)
    axes = np.atleast_1d(axes)
    vmax = max(np.nanmax(np.asarray(r.chute["surface_vz"])) for r in runs)
    im = None
    for ax, r in zip(axes, runs):
        xe = 1e3 * np.asarray(r.chute["x_edges"])
        ze = np.asarray(r.chute["z_edges"])
        speed = np.hypot(np.asarray(r.chute["surface_vz"]), np.asarray(r.chute["surface_vx"]))
        im = ax.pcolormesh(xe, ze, speed.T, cmap="viridis", vmin=0, vmax=vmax, shading="flat")
        arrows = _gas_top_arrows(r)
        if arrows is not None:
            x, z, ux, uz = arrows
            X, Z = np.meshgrid(1e3 * x, z, indexing="ij")
            step = max(1, len(z) // 30)
            # x is drawn in mm and z in m: scale the components alike so that arrows point
            # along the true direction; the fastest arrow spans 20 mm across / 0.02 m along
            k = 0.02 / max(float(np.nanmax(np.hypot(ux, uz))), 1e-12)
            ax.quiver(X[:, ::step], Z[:, ::step], 1e3 * k * ux[:, ::step], k * uz[:, ::step], color="w",
                      scale_units="xy", angles="xy", scale=1.0, width=0.004)
            ax.set_title(f"{r.label}: surface speed,\ngas velocity below the open top (arrows)", fontsize=9)
        else:
            ax.set_title(f"{r.label}: surface speed", fontsize=9)
        ax.set_xlabel(x_label(_width(r)), fontsize=7)
    axes[0].invert_yaxis()  # shared y axis: invert once; the entrance at the top
    axes[0].set_ylabel("z down the chute [m]")
    fig.colorbar(im, ax=list(axes), label="surface particle speed [m/s]")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _fig_cost(runs, path):
    plt = _mpl()
    parts = ["particles", "gas", "coupling", "inlet_exit", "measurements", "output", "checkpoints"]
    fig, ax = plt.subplots(figsize=(6, 3.5))
    left = np.zeros(len(runs))
    for p in parts:
        vals = np.array([r.timings.get(p, 0.0) for r in runs])
        if vals.sum() == 0:
            continue
        ax.barh([r.label for r in runs], vals, left=left, label=p)
        left += vals
    ax.set_xlabel("wall time [s]")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# ------------------------------------------------------------------ silo
def _silo(run) -> dict:
    """The silo numbers of a run: flow rate, bulk density, clogging, the discharge record."""
    m, s = run.meas, run.silo
    t = np.asarray(s.get("discharge_time", []), float)
    mass = np.asarray(s.get("discharge_mass", []), float)
    return {"mass_flow_rate": float(np.asarray(m.get("mass_flow_rate", np.nan))),
            "bulk_density": float(np.asarray(m.get("bulk_density", np.nan))),
            "clogged": bool(int(np.asarray(m.get("clogged", 0)))),
            "gate_open_time": float(np.asarray(s.get("gate_open_time", np.nan))),
            "discharged_mass": float(mass[-1]) if mass.size else math.nan,
            "fit_window": [float(v) for v in np.asarray(s.get("fit_window", [np.nan] * 4), float)],
            "fit_residual_rel": float(np.asarray(s.get("fit_residual_rel", np.nan))),
            "t": t, "m": mass}


def _fig_discharge(runs, path):
    plt = _mpl()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for r, c in zip(runs, ("C0", "C1")):
        d = _silo(r)
        t0 = d["gate_open_time"]
        t, m = d["t"] - t0, d["m"]
        axes[0].plot(t, 1e3 * m, color=c, label=r.label)
        lo, hi = d["fit_window"][0] - t0, d["fit_window"][1] - t0
        sel = (t >= lo) & (t <= hi)
        if sel.any() and math.isfinite(d["mass_flow_rate"]):
            b = float(np.mean(m[sel] - d["mass_flow_rate"] * t[sel]))
            axes[0].plot(t[sel], 1e3 * (b + d["mass_flow_rate"] * t[sel]), "--", color=c,
                         label=f"fit: {1e3 * d['mass_flow_rate']:.3g} g/s")
        if t.size > 2:
            # rate over a sliding window of 5 records (the record interval is settle_check_interval)
            k = min(5, t.size - 1)
            axes[1].plot(0.5 * (t[k:] + t[:-k]), 1e3 * (m[k:] - m[:-k]) / (t[k:] - t[:-k]), color=c, label=r.label)
    axes[0].set_xlabel("time since the gate opened [s]")
    axes[0].set_ylabel("discharged mass [g]")
    axes[1].set_xlabel("time since the gate opened [s]")
    axes[1].set_ylabel("mass flow rate [g/s] (5-record window)")
    for a in axes:
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _fig_silo_field(runs, path):
    plt = _mpl()
    fig, axes = plt.subplots(1, len(runs), figsize=(4.5 * len(runs), 5), sharey=True)
    axes = np.atleast_1d(axes)
    fields = [r.silo.get("field", {}) for r in runs]
    vmax = max((float(np.nanmax(np.abs(np.asarray(f["vy"])))) for f in fields if "vy" in f and np.size(f["vy"])
                and np.isfinite(np.asarray(f["vy"])).any()), default=1.0)
    im = None
    for ax, r, f in zip(axes, runs, fields):
        ax.set_title(r.label, fontsize=9)
        ax.set_xlabel("x [mm]")
        if "vy" not in f or not np.size(f["vy"]):
            continue
        x, y, vy = (np.asarray(f[k], float) for k in ("x", "y", "vy"))
        if vy.shape == (x.size, y.size) and x.size != y.size:
            vy = vy.T  # (y, x) for pcolormesh
        im = ax.pcolormesh(1e3 * x, 1e3 * y, vy, cmap="viridis_r", vmin=-vmax, vmax=0.0, shading="nearest")
        ax.set_aspect("equal")
    axes[0].set_ylabel("y [mm]")
    if im is not None:
        fig.colorbar(im, ax=list(axes), label="time-averaged vertical particle velocity [m/s]")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _silo_report(ra, rb, out: Path) -> dict:
    """The silo report of runs ``ra`` and ``rb`` (same kind) into ``out``."""
    runs = [ra, rb]
    figs = {
        "discharge.png": ("Discharged mass and mass flow rate against time", _fig_discharge),
        "velocity_field.png": ("Time-averaged vertical particle velocity during the discharge", _fig_silo_field),
        "cost.png": ("Wall time and cost split", _fig_cost),
    }
    for name, (_, fn) in figs.items():
        fn(runs, out / name)
    da, db = _silo(ra), _silo(rb)
    qa, qb = da["mass_flow_rate"], db["mass_flow_rate"]
    rel = (qb - qa) / qa if qa else math.nan
    summary = {"kind": "silo", "run_a": str(ra.folder), "run_b": str(rb.folder), "label_a": ra.label,
               "label_b": rb.label}
    for key in ("mass_flow_rate", "bulk_density", "clogged", "gate_open_time", "discharged_mass", "fit_window",
                "fit_residual_rel"):
        summary[f"{key}_a"], summary[f"{key}_b"] = da[key], db[key]
    summary.update({
        "relative_difference_flow": rel,
        "wall_time_a": ra.wall_time, "wall_time_b": rb.wall_time,
        "compile_time_a": ra.compile_time, "compile_time_b": rb.compile_time,
        "wall_time_ratio": _net_ratio(ra, rb),
        "cost_a": ra.timings, "cost_b": rb.timings,
        "gas_solver_a": ra.gas_solver or None, "gas_solver_b": rb.gas_solver or None,
    })
    summary["headline"] = (f"silo mass flow rate {1e3 * qa:.4g} g/s ({ra.label}), {1e3 * qb:.4g} g/s ({rb.label}) "
                           f"({100 * rel:+.2f} %)")
    (out / "summary.json").write_text(json.dumps(summary, indent=1, allow_nan=True))

    def clog(d):
        return "clogged" if d["clogged"] else "not clogged"

    md = [f"# {ra.label} against {rb.label}: silo discharge", "",
          f"- A: `{ra.folder}` ({ra.label}); B: `{rb.folder}` ({rb.label})",
          f"- steady mass flow rate (linear fit of the discharged mass): A {1e3 * qa:.4g} g/s, B {1e3 * qb:.4g} g/s, "
          f"relative difference (B - A)/A = {100 * rel:+.2f} % (fit residual rms / range: A {da['fit_residual_rel']:.2g}, "
          f"B {db['fit_residual_rel']:.2g})",
          f"- discharged mass: A {1e3 * da['discharged_mass']:.4g} g, B {1e3 * db['discharged_mass']:.4g} g; "
          f"A {clog(da)}, B {clog(db)}",
          f"- bulk density at the gate opening: A {da['bulk_density']:.1f} kg/m3, B {db['bulk_density']:.1f} kg/m3 "
          f"(gate at A {da['gate_open_time']:.4g} s, B {db['gate_open_time']:.4g} s)"]
    _write_report(md, runs, figs, out, summary)
    return summary


def compare_runs(a: str | Path, b: str | Path, out: str | Path, labels=(None, None)) -> dict:
    """Write the comparison report of runs ``a`` and ``b`` into ``out``; return the summary
    (its ``headline``: one sentence on the main difference, for ``cfddem run``)."""
    ra, rb = Run(a, labels[0]), Run(b, labels[1])
    if ra.kind != rb.kind:
        raise CaseError("OUT", f"cannot compare a {ra.kind} run ({ra.folder}) with a {rb.kind} run ({rb.folder})")
    if ra.label == rb.label:
        ra.label, rb.label = f"A: {ra.label}", f"B: {rb.label}"
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    runs = [ra, rb]
    if ra.kind == "silo":
        return _silo_report(ra, rb, out)
    figs = {
        "velocity_along_chute.png": ("Mean streamwise particle velocity along the chute", _fig_velocity),
        "bed_height.png": ("Bed height at the left, centre and right sensors", _fig_bed),
        "surface_velocity.png": ("Surface velocity across the width", _fig_surface),
        "depth_profiles.png": ("Depth profiles of streamwise velocity and solid fraction", _fig_profiles),
        "top_view.png": ("Top view of the flow", _fig_top),
        "cost.png": ("Wall time and cost split", _fig_cost),
    }
    if _budget_filled(runs):
        figs["momentum_budget.png"] = ("Streamwise momentum budget of the particles", _fig_budget)
    for name, (_, fn) in figs.items():
        fn(runs, out / name)
    va, vb = ra.velocity_end(), rb.velocity_end()
    summary = {
        "run_a": str(ra.folder), "run_b": str(rb.folder), "label_a": ra.label, "label_b": rb.label,
        "velocity_end_a": va, "velocity_end_b": vb,
        "relative_difference_end": (vb - va) / va if va else math.nan,
        "wall_time_a": ra.wall_time, "wall_time_b": rb.wall_time,
        "compile_time_a": ra.compile_time, "compile_time_b": rb.compile_time,
        "wall_time_ratio": _net_ratio(ra, rb),
        "cost_a": ra.timings, "cost_b": rb.timings,
        "rpm_a": ra.rpm, "rpm_b": rb.rpm,
        "gas_solver_a": ra.gas_solver or None, "gas_solver_b": rb.gas_solver or None,
    }
    summary["headline"] = (f"mean streamwise velocity over the last {END_LENGTH:g} m {va:.4f} m/s ({ra.label}), "
                           f"{vb:.4f} m/s ({rb.label}) ({100 * summary['relative_difference_end']:+.2f} %)")
    md = [f"# {ra.label} against {rb.label}", "",
          f"- A: `{ra.folder}` ({ra.label}, {ra.rpm:g} rpm); B: `{rb.folder}` ({rb.label}, {rb.rpm:g} rpm)",
          f"- mean streamwise particle velocity over the last {END_LENGTH:g} m: A {va:.4f} m/s, "
          f"B {vb:.4f} m/s, relative difference (B - A)/A = {100 * summary['relative_difference_end']:+.2f} %",
          f"- {CONVENTION} (the x = 0 wall is the right wall)"]
    tail = _budget_section(runs, summary) if ra.budget and rb.budget else []
    for r, tag in zip(runs, ("a", "b")):
        if r.gas_budget:
            tail += gas_budget_section(r, summary, tag)
    (out / "summary.json").write_text(json.dumps(summary, indent=1, allow_nan=True))
    _write_report(md, runs, figs, out, summary, tail)
    return summary


# ------------------------------------------------------------------ momentum budget
BUDGET_ROWS = (("gravity", "gravity"), ("walls", "walls (all)"), ("contacts", "particle contacts across bin faces"),
               ("drag", "gas drag"), ("pressure", "gas pressure gradient"), ("coriolis", "Coriolis"),
               ("centrifugal", "centrifugal"), ("flux", "momentum flux in - out"), ("storage", "storage d<P>/dt"),
               ("residual", "residual"))


def _budget_totals(b) -> dict:
    """Whole-window sums over the bins of each term, with the block errors added in quadrature
    over the bins (an upper bound when bins are correlated: they share particles' contacts)."""
    out = {}
    for k, _ in BUDGET_ROWS:
        v = np.asarray(b.get(k, np.zeros(1)), float)
        e = np.asarray(b.get(f"{k}_err", np.zeros_like(v)), float)
        out[k] = (float(v.sum()), float(np.sqrt(np.nansum(e**2))))
    for name in sorted(k for k in b if k.startswith("wall_") and not k.endswith("_err")):
        v = np.asarray(b[name], float)
        e = np.asarray(b.get(f"{name}_err", np.zeros_like(v)), float)
        out[name] = (float(v.sum()), float(np.sqrt(np.nansum(e**2))))
    return out


def _gas_run(runs):
    """(the run with gas, the run without), or None unless exactly one has gas."""
    has = [bool(r.config.get("gas", {}).get("enabled", False)) for r in runs]
    if has.count(True) != 1:
        return None
    return (runs[0], runs[1]) if has[0] else (runs[1], runs[0])


def budget_sentence(tot_gas: dict, tot_free: dict, dv_rel: float) -> str:
    """One plain sentence: which terms carry the gas's effect on the particles, with sizes
    (``tot_*``: :func:`_budget_totals` of the run with and without gas; ``dv_rel`` the relative
    change of the end velocity)."""
    g = tot_gas["gravity"][0]
    drag, pres = tot_gas["drag"][0], tot_gas["pressure"][0]
    direct = drag + pres
    parts = [f"the gas acts on the particles in the chute through drag ({drag * 1e3:+.3g} mN, "
             f"{100 * drag / g:+.2g} % of the streamwise gravity {g * 1e3:.4g} mN) and the pressure gradient "
             f"({pres * 1e3:+.3g} mN, {100 * pres / g:+.2g} %)"]
    # indirect: terms that moved by more than twice their combined error
    moved = []
    for k, name in BUDGET_ROWS:
        if k in ("drag", "pressure", "residual", "gravity"):
            continue
        (a, ea), (b, eb) = tot_gas[k], tot_free[k]
        if abs(a - b) > 2.0 * math.hypot(ea, eb) and abs(a - b) > 1e-12:
            moved.append(f"{name} {1e3 * (a - b):+.3g} mN")
    txt = "With gas, " + parts[0]
    txt += (f"; together {100 * direct / g:+.2g} % of gravity, and the end velocity changes by {100 * dv_rel:+.2f} %. ")
    if moved:
        txt += "Terms that differ from the gas-free run by more than twice their error: " + ", ".join(moved) + "."
    else:
        txt += ("No other term differs from the gas-free run by more than twice its error: the flow adjusts to the gas's "
                "force within the noise of the particle terms.")
    return txt


def _budget_filled(runs) -> bool:
    """Whether both runs have a budget whose bins held particles in the window (a short run's
    may not: no particle reached the bins yet)."""
    return all(r.budget and _budget_totals(r.budget)["gravity"][0] != 0.0 for r in runs)


def _budget_section(runs, summary: dict) -> list[str]:
    """The budget table (terms summed over the bins, both runs), the sentence, the slip table,
    and ``drag_force_total`` / ``budget_residual_relative`` in the summary (the figure:
    :func:`_fig_budget`)."""
    ra, rb = runs
    tots = [_budget_totals(r.budget) for r in runs]
    if not _budget_filled(runs):
        summary["budget_residual_relative"] = math.nan
        return ["## Streamwise momentum budget of the particles", "",
                "No particle was in the budget bins during the measurement window of "
                + " and ".join(r.label for r, t in zip(runs, tots) if t["gravity"][0] == 0.0) + ".", ""]
    md = ["## Streamwise momentum budget of the particles", "",
          f"Sums over the budget bins (z = {ra.budget['edges'][0]:.3g} to {ra.budget['edges'][-1]:.3g} m), "
          "time-averaged over the measurement window, force on the particles along the chute in mN; "
          "errors: block averages (10 blocks), added over the bins.", "",
          "| term | " + " | ".join(r.label for r in runs) + " | B - A |", "|---|---|---|---|"]
    names = [k for k, _ in BUDGET_ROWS] + sorted({k for t in tots for k in t if k.startswith("wall_")})
    label = dict(BUDGET_ROWS)
    for k in names:
        (a, ea), (b, eb) = tots[0].get(k, (math.nan, math.nan)), tots[1].get(k, (math.nan, math.nan))
        nm = label.get(k, f"wall '{side_label(k[5:], _width(ra))}'")
        md.append(f"| {nm} | {1e3 * a:.4g} ± {1e3 * ea:.2g} | {1e3 * b:.4g} ± {1e3 * eb:.2g} | {1e3 * (b - a):+.3g} |")
    md.append("")
    pair = _gas_run(runs)
    if pair is not None:
        rg, rf = pair
        tg, tf = (tots[0], tots[1]) if rg is ra else (tots[1], tots[0])
        vg, vf = rg.velocity_end(), rf.velocity_end()
        sentence = budget_sentence(tg, tf, (vg - vf) / vf if vf else math.nan)
        md += [sentence, ""]
        summary["budget_sentence"] = sentence
        from ..measure.budget import SLIP_CLASSES, SLIP_EDGES

        lo = (0.0,) + tuple(SLIP_EDGES)
        hi = tuple(SLIP_EDGES) + (1.0,)
        md += ["Streamwise slip u - v between the gas and the particles (run with gas), time-averaged over the "
               "gas steps, by the porosity at the particle's centre:", "",
               "| particles | porosity | mean number | slip [m/s] |", "|---|---|---|---|"]
        for j, name in enumerate(SLIP_CLASSES):
            sl = float(rg.budget.get(f"slip_{name}", math.nan))
            cnt = float(rg.budget.get(f"slip_{name}_count", 0.0))
            md.append(f"| {name} | {lo[j]:g} to {hi[j]:g} | {cnt:.0f} | {sl:+.3f} |")
            summary[f"slip_{name}"] = sl
        md.append("")
        summary["drag_force_total"] = float(rg.budget.get("drag_all", tg["drag"][0]))
        summary["pressure_force_total"] = float(rg.budget.get("pressure_all", tg["pressure"][0]))
        summary["budget_residual_relative"] = abs(tg["residual"][0]) / abs(tg["gravity"][0]) if tg["gravity"][0] else math.nan
    else:
        summary["budget_residual_relative"] = abs(tots[0]["residual"][0]) / abs(tots[0]["gravity"][0]) \
            if tots[0]["gravity"][0] else math.nan
    return md


GAS_BUDGET_ROWS = {
    "drag": "reaction to the drag on the particles", "pressure_particles": "reaction to the particles' pressure force",
    "source": "boundary half-cells (pressure and weight)", "gravity": "gravity", "coriolis": "Coriolis",
    "centrifugal": "centrifugal", "mass_imbalance": "mass imbalance of the advection form",
}
_GAS_SIDE_ROWS = {"pressure": "pressure on", "flux": "momentum flux through", "viscous": "normal viscous stress on",
                  "shear": "shear on"}


def gas_budget_rows(gb) -> list:
    """``(key, label)`` of the gas budget's terms in its own order (attribute ``terms``), then
    storage and residual; the sides labelled with the domain's names (attribute ``side_names``)."""
    at = gb.get("@attrs", {})
    terms = [t for t in str(at.get("terms", "")).split(",") if t] or [k for k in GAS_BUDGET_ROWS if k in gb]
    names = dict(kv.split("=", 1) for kv in str(at.get("side_names", "")).split(",") if "=" in kv)
    rows = []
    for t in terms:
        if t in GAS_BUDGET_ROWS:
            rows.append((t, GAS_BUDGET_ROWS[t]))
        else:
            kind, side = t.split("_", 1)
            nm = names.get(side, side)
            if kind == "flux" and float(np.asarray(gb.get(t, np.nan))) == 0.0:
                continue  # a wall: nothing flows through it
            rows.append((t, f"{_GAS_SIDE_ROWS.get(kind, kind)} {nm}" + (f" ({side})" if side not in nm else "")))
    return rows + [("storage", "storage dP/dt"), ("residual", "residual")]


def gas_budget_section(run, summary: dict, tag: str = "a") -> list[str]:
    """The gas's budget table of one run (terms with their sizes: mN and % of the largest
    term), its closure and the check of the drag reaction against the particles; ``summary``
    gains ``gas_budget_<tag>`` (the terms, N) and ``gas_budget_residual_relative_<tag>``."""
    gb = run.gas_budget
    at = gb.get("@attrs", {})
    rows = gas_budget_rows(gb)
    val = {k: float(np.asarray(gb.get(k, np.nan))) for k, _ in rows}
    big = max((abs(v) for k, v in val.items() if k not in ("storage", "residual") and math.isfinite(v)), default=0.0)
    ax = at.get("axis", "z")
    md = [f"## Momentum budget of the gas ({run.label})", "",
          f"The whole gas domain, force on the gas along {ax} in mN, time-averaged over the {int(gb['n_steps'])} gas "
          f"steps from t = {float(gb['t_first']):.4g} to {float(gb['t_last']):.4g} s; errors: block averages "
          f"({int(at.get('n_blocks', 10))} blocks); planes of a wall or an inlet: the first cell centre, of an "
          "outlet: half a cell outside (docs/gas.md, 'Momentum budget').", "",
          "| term | force [mN] | of the largest term |", "|---|---|---|"]
    for k, name in rows:
        v, e = val[k], float(np.asarray(gb.get(f"{k}_err", np.nan)))
        err = f" ± {1e3 * e:.2g}" if math.isfinite(e) and k != "residual" else ""
        md.append(f"| {name} | {1e3 * v:.4g}{err} | {100 * v / big:+.3g} % |" if big else f"| {name} | {1e3 * v:.4g} | |")
    md.append("")
    pd = float(np.asarray(gb.get("particle_drag", np.nan)))
    line = (f"The budget closes to {float(gb['residual_relative']):.1e} of the largest term (round-off: the terms are "
            f"the solver's own update, regrouped). The drag reaction {1e3 * val['drag']:.4g} mN is minus the drag on all "
            f"particles {1e3 * pd:.4g} mN")
    if run.budget and "drag_all" in run.budget:
        free = float(np.asarray(run.budget["drag_all"]))
        line += (f"; of this the free particles (the particle budget's total) take {1e3 * free:.4g} mN and the held "
                 f"feed particles {1e3 * (pd - free):.4g} mN")
    line += "."
    mi = val.get("mass_imbalance", 0.0)
    if big and abs(mi) > 0.01 * big:
        line += (f" The advection form's mass imbalance (u times the control volumes' mass imbalance between the "
                 f"step's fluxes and the porosity change) adds {1e3 * mi:.3g} mN, "
                 f"{100 * abs(mi) / abs(val['drag']):.3g} % of the drag reaction: momentum the gas solver's advection does not "
                 "conserve where the porosity's rate of change changes from one gas step to the next." if val.get("drag") else "")
    md += [line, ""]
    summary[f"gas_budget_{tag}"] = dict(val)
    summary[f"gas_budget_residual_relative_{tag}"] = float(np.asarray(gb["residual_relative"]))
    return md


def _fig_budget(runs, path):
    """Each term per bin along the chute (both runs: solid A, dashed B), with error bars."""
    plt = _mpl()
    fig, ax = plt.subplots(figsize=(8, 4.8))
    colours = dict(zip([k for k, _ in BUDGET_ROWS], plt.rcParams["axes.prop_cycle"].by_key()["color"] * 2))
    for r, ls in zip(runs, ("-", "--")):
        b = r.budget
        z = np.asarray(b["z"])
        for k, name in BUDGET_ROWS:
            if k == "storage":
                continue
            v = 1e3 * np.asarray(b[k])
            e = 1e3 * np.asarray(b.get(f"{k}_err", np.zeros_like(v)))
            ax.errorbar(z, v, yerr=e, ls=ls, color=colours[k], marker="o" if k == "residual" else None, ms=3,
                        capsize=2, lw=2.2 if k == "residual" else 1.3,
                        label=f"{name} ({r.label})" if r is runs[0] or k in ("drag", "pressure") else None)
    ax.axhline(0.0, color="0.5", lw=0.8)
    ax.set_xlabel("z along the chute (bin centre) [m]")
    ax.set_ylabel("streamwise force on the bin's particles [mN]")
    ax.set_title(f"solid: {runs[0].label}, dashed: {runs[1].label}", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _net_ratio(ra, rb) -> float:
    """B's wall time over A's, each without numba's compilation of the kernels."""
    return rb.net_wall_time / ra.net_wall_time if ra.net_wall_time > 0 else math.nan


def _write_report(md: list, runs, figs: dict, out: Path, summary: dict, tail=()) -> None:
    """The wall times, the gas solver lines, the cost table, the lines ``tail`` and the figures
    after the lines ``md``; report.md and the self-contained report.html."""
    ra, rb = runs
    jit = (f" (without numba's first compilation of the kernels: {ra.compile_time:.1f} s in A, "
           f"{rb.compile_time:.1f} s in B)" if max(ra.compile_time, rb.compile_time) >= 0.1 else "")
    md.append(f"- wall time: A {ra.wall_time:.1f} s, B {rb.wall_time:.1f} s, ratio B/A = "
              f"{summary['wall_time_ratio']:.3f}{jit}")
    md += [f"- {line}" for line in (ra.gas_solver_line(), rb.gas_solver_line()) if line]
    md.append("")
    md.append("| cost [s] | " + " | ".join(r.label for r in runs) + " |")
    md.append("|---|---|---|")
    for p in sorted(set(ra.timings) | set(rb.timings)):
        md.append(f"| {p} | {ra.timings.get(p, 0.0):.1f} | {rb.timings.get(p, 0.0):.1f} |")
    md.append("")
    md += list(tail)
    for name, (title, _) in figs.items():
        md += [f"## {title}", "", f"![{title}]({name})", ""]
    (out / "report.md").write_text("\n".join(md))
    # one self-contained HTML file
    body = []
    block = None  # the open list or table
    for line in md:
        kind = "ul" if line.startswith("- ") else "table" if line.startswith("|") else None
        if block and kind != block:
            body.append(f"</{block}>")
            block = None
        if kind and not block:
            body.append("<ul>" if kind == "ul" else "<table border=1 cellpadding=3>")
            block = kind
        if line.startswith("# "):
            body.append(f"<h1>{html.escape(line[2:])}</h1>")
        elif line.startswith("## "):
            body.append(f"<h2>{html.escape(line[3:])}</h2>")
        elif kind == "ul":
            body.append(f"<li>{html.escape(line[2:]).replace('`', '')}</li>")
        elif line.startswith("!["):
            name = line[line.index("(") + 1:-1]
            data = base64.b64encode((out / name).read_bytes()).decode()
            body.append(f'<img style="max-width:100%" src="data:image/png;base64,{data}"/>')
        elif kind == "table":
            if not line.startswith("|---"):
                cells = [c.strip() for c in line.strip("|").split("|")]
                body.append("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in cells) + "</tr>")
        elif line.strip():
            body.append(f"<p>{html.escape(line).replace('`', '')}</p>")
    if block:
        body.append(f"</{block}>")
    text = "\n".join(body)
    (out / "report.html").write_text(
        "<!DOCTYPE html><html><head><meta charset='utf-8'><title>cfddem comparison</title>"
        "<style>body{font-family:sans-serif;max-width:1100px;margin:auto}</style></head><body>\n"
        + text + "\n</body></html>\n")
