"""``cfddem compare OUT_A OUT_B``: the gas-against-no-gas (or any A-against-B) report.

Reads two run folders (``results.h5`` each) and writes, into ``--out DIR``:

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
(when a run has gas); wall time of both runs and their cost split.
"""

from __future__ import annotations

import base64
import html
import json
import math
from pathlib import Path

import numpy as np

from ..errors import CaseError

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
        if int(np.asarray(self.chute.get("n_samples", 0))) == 0:
            raise CaseError("OUT", f"{self.folder}: the run holds no time-averaged chute measurements "
                                   "(did it reach measurements.start_time?)")
        self.gas = self.meas.get("gas", {})
        gas_on = bool(self.config.get("gas", {}).get("enabled", False))
        self.label = label or ("with gas" if gas_on else "no gas")
        self.rpm = float(self.config.get("frame", {}).get("rpm", 0.0))
        self.exit_z = float(self.config.get("exit", {}).get("z", np.nan))
        self.wall_time = float(self.meta.get("wall_time", np.nan))
        self.timings = {k[len("time_"):]: float(v) for k, v in self.meta.items() if k.startswith("time_")}
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
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.8), sharey=True)
    names = ("left", "centre", "right")
    for i, ax in enumerate(axes):
        for r in runs:
            bh = np.asarray(r.chute["bed_height_sensor"])
            if i < bh.shape[0]:
                ax.plot(r.chute["sensor_z"], 1e3 * bh[i], label=r.label)
        x = np.asarray(runs[0].chute["sensor_x"])
        ax.set_title(f"{names[i]} sensor (x = {1e3 * x[i]:.0f} mm)" if i < len(x) else names[i])
        ax.set_xlabel("z [m]")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("bed height [mm]")
    axes[0].legend()
    fig.tight_layout()
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
        axes[1, j].set_xlabel("x across the chute [mm]")
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
    vel_slices = ("left_half", "right_half") if rotating else ("whole",)
    phi_slices = ("left", "centre", "right")
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
                    axes[0, j].plot(np.asarray(r.chute[key])[j], y, ls, color=c, label=f"{r.label}, {sl}")
            for sl, c in zip(phi_slices, ("C2", "C3", "C4")):
                key = f"profile_{sl}_phi"
                if key in r.chute:
                    axes[1, j].plot(np.asarray(r.chute[key])[j], y, ls, color=c, label=f"{r.label}, {sl}")
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
        ax.set_xlabel("x [mm]")
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


def compare_runs(a: str | Path, b: str | Path, out: str | Path, labels=(None, None)) -> dict:
    """Write the comparison report of runs ``a`` and ``b`` into ``out``; return the summary."""
    ra, rb = Run(a, labels[0]), Run(b, labels[1])
    if ra.label == rb.label:
        ra.label, rb.label = f"A: {ra.label}", f"B: {rb.label}"
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    runs = [ra, rb]
    figs = {
        "velocity_along_chute.png": ("Mean streamwise particle velocity along the chute", _fig_velocity),
        "bed_height.png": ("Bed height at the left, centre and right sensors", _fig_bed),
        "surface_velocity.png": ("Surface velocity across the width", _fig_surface),
        "depth_profiles.png": ("Depth profiles of streamwise velocity and solid fraction", _fig_profiles),
        "top_view.png": ("Top view of the flow", _fig_top),
        "cost.png": ("Wall time and cost split", _fig_cost),
    }
    for name, (_, fn) in figs.items():
        fn(runs, out / name)
    va, vb = ra.velocity_end(), rb.velocity_end()
    summary = {
        "run_a": str(ra.folder), "run_b": str(rb.folder), "label_a": ra.label, "label_b": rb.label,
        "velocity_end_a": va, "velocity_end_b": vb,
        "relative_difference_end": (vb - va) / va if va else math.nan,
        "wall_time_a": ra.wall_time, "wall_time_b": rb.wall_time,
        "wall_time_ratio": rb.wall_time / ra.wall_time if ra.wall_time else math.nan,
        "cost_a": ra.timings, "cost_b": rb.timings,
        "rpm_a": ra.rpm, "rpm_b": rb.rpm,
        "gas_solver_a": ra.gas_solver or None, "gas_solver_b": rb.gas_solver or None,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=1, allow_nan=True))
    md = [f"# {ra.label} against {rb.label}", "",
          f"- A: `{ra.folder}` ({ra.label}, {ra.rpm:g} rpm); B: `{rb.folder}` ({rb.label}, {rb.rpm:g} rpm)",
          f"- mean streamwise particle velocity over the last {END_LENGTH:g} m: A {va:.4f} m/s, "
          f"B {vb:.4f} m/s, relative difference (B - A)/A = {100 * summary['relative_difference_end']:+.2f} %",
          f"- wall time: A {ra.wall_time:.1f} s, B {rb.wall_time:.1f} s, ratio B/A = {summary['wall_time_ratio']:.3f}"]
    md += [f"- {line}" for line in (ra.gas_solver_line(), rb.gas_solver_line()) if line]
    md.append("")
    md.append("| cost [s] | " + " | ".join(r.label for r in runs) + " |")
    md.append("|---|---|---|")
    for p in sorted(set(ra.timings) | set(rb.timings)):
        md.append(f"| {p} | {ra.timings.get(p, 0.0):.1f} | {rb.timings.get(p, 0.0):.1f} |")
    md.append("")
    for name, (title, _) in figs.items():
        md += [f"## {title}", "", f"![{title}]({name})", ""]
    (out / "report.md").write_text("\n".join(md))
    # one self-contained HTML file
    body = []
    in_list = False
    for line in md:
        if line.startswith("# "):
            body.append(f"<h1>{html.escape(line[2:])}</h1>")
        elif line.startswith("## "):
            body.append(f"<h2>{html.escape(line[3:])}</h2>")
        elif line.startswith("- "):
            if not in_list:
                body.append("<ul>")
                in_list = True
            body.append(f"<li>{html.escape(line[2:]).replace('`', '')}</li>")
            continue
        elif line.startswith("!["):
            name = line[line.index("(") + 1:-1]
            data = base64.b64encode((out / name).read_bytes()).decode()
            body.append(f'<img style="max-width:100%" src="data:image/png;base64,{data}"/>')
        elif line.startswith("|") and not line.startswith("|---"):
            cells = [c.strip() for c in line.strip("|").split("|")]
            body.append("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in cells) + "</tr>")
            continue
        if in_list and not line.startswith("- "):
            body.append("</ul>")
            in_list = False
    text = "\n".join(body).replace("</ul>\n<tr>", "</ul>\n<table border=1 cellpadding=3><tr>")
    text = text.replace("</tr>\n<h2>", "</tr></table>\n<h2>", 1)
    (out / "report.html").write_text(
        "<!DOCTYPE html><html><head><meta charset='utf-8'><title>cfddem comparison</title>"
        "<style>body{font-family:sans-serif;max-width:1100px;margin:auto}</style></head><body>\n"
        + text + "\n</body></html>\n")
    return summary
