"""PNG plots of chute measurements and run time series (matplotlib, Agg, 120 dpi).

Every function takes plain dicts of numpy arrays: ``meas`` is what
:meth:`cfddem.measure.chute.ChuteMeasurements.results` returns (or
``read_measurements(path)["chute"]``), ``series`` what :func:`cfddem.io.results.read_series`
returns. Lengths are plotted in mm, velocities in m/s. A function raises ``KeyError``
naming the missing array when its data are absent; :func:`write_run_report` turns that
into a logged, listed skip.
"""

from __future__ import annotations

import logging
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

DPI = 120
SURFACE_STATIONS = (0.0, 0.2, 0.4, 0.6)
log = logging.getLogger("cfddem.report")


def _need(d: dict, *keys: str) -> list:
    missing = [k for k in keys if k not in d]
    if missing:
        raise KeyError(f"missing {', '.join(missing)}")
    return [np.asarray(d[k]) for k in keys]


def _save(fig, path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    return path


def _width(meas: dict) -> float:
    """The chute width: the last measurement cell edge (NaN without cells)."""
    return float(np.asarray(meas["x_edges"])[-1]) if "x_edges" in meas else float("nan")


def plot_bed_height(meas: dict, path) -> Path:
    """Sensor bed height along the chute, one line per sensor, named by its side seen in
    the direction of flow (left, centre, right; :mod:`cfddem.measure.chute`)."""
    sx, sz, h = _need(meas, "sensor_x", "sensor_z", "bed_height_sensor")
    from cfddem.measure.chute import CONVENTION, sensor_names, side_label

    fig, ax = plt.subplots(figsize=(7, 4))
    W = _width(meas)
    names = sensor_names(sx, W)
    for j in np.argsort(-sx):  # left, centre, right
        ax.plot(sz * 1e3, h[j] * 1e3, marker=".", label=f"{side_label(names[j], W)}, x = {sx[j] * 1e3:.0f} mm")
    ax.set_xlabel("z along the chute [mm]")
    ax.set_ylabel("bed height [mm]")
    ax.set_title("Bed height (5 x 5 cell sensor average)")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.text(0.5, -0.02, CONVENTION, ha="center", va="top", fontsize=7)
    return _save(fig, path)


def _station_columns(z_centres: np.ndarray, stations) -> list[tuple[float, int]]:
    """(station, index of the nearest z cell) for stations inside the cell range."""
    out = []
    half = 0.5 * (z_centres[1] - z_centres[0]) if z_centres.size > 1 else np.inf
    for s in stations:
        k = int(np.argmin(np.abs(z_centres - s)))
        if abs(z_centres[k] - s) <= half + 1e-12:
            out.append((float(s), k))
    return out


def plot_surface_velocity(meas: dict, path, stations=SURFACE_STATIONS) -> Path:
    """Streamwise and spanwise surface velocity across the width at the stations (the
    measurement cell row nearest each station z; stations off the grid are left out)."""
    x, zc, vz, vx = _need(meas, "x_centres", "z_centres", "surface_vz", "surface_vx")
    cols = _station_columns(zc, stations)
    if not cols:
        raise KeyError(f"no measurement cells at the stations {tuple(stations)}")
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4))
    fig.subplots_adjust(wspace=0.3)
    for s, k in cols:
        a1.plot(x * 1e3, vz[:, k], marker=".", label=f"z = {s:g} m")
        a2.plot(x * 1e3, vx[:, k], marker=".", label=f"z = {s:g} m")
    a1.set_ylabel("streamwise surface velocity v_z [m/s]")
    a2.set_ylabel("spanwise surface velocity v_x [m/s]")
    from cfddem.measure.chute import x_label

    for a in (a1, a2):
        a.set_xlabel(x_label(_width(meas)), fontsize=8)
        a.grid(alpha=0.3)
        a.legend()
    fig.suptitle("Surface velocity (mean of the 6 topmost particles per cell)")
    return _save(fig, path)


def plot_mean_velocity(meas, path, labels=None) -> Path:
    """Mean streamwise particle velocity along the chute; ``meas`` a dict or a list of
    dicts (several runs overlaid, ``labels`` naming them)."""
    runs = meas if isinstance(meas, (list, tuple)) else [meas]
    if labels is None:
        labels = [None] if len(runs) == 1 else [f"run {i + 1}" for i in range(len(runs))]
    if len(labels) != len(runs):
        raise ValueError(f"{len(labels)} labels for {len(runs)} runs")
    data = [_need(m, "mean_vz_z", "mean_vz") for m in runs]
    fig, ax = plt.subplots(figsize=(7, 4))
    for (z, v), lab in zip(data, labels):
        ax.plot(z * 1e3, v, label=lab)
    ax.set_xlabel("z along the chute [mm]")
    ax.set_ylabel("mean streamwise velocity [m/s]")
    ax.set_title("Mean streamwise particle velocity")
    ax.grid(alpha=0.3)
    if any(lab is not None for lab in labels):
        ax.legend()
    return _save(fig, path)


SERIES_PANELS = (
    (("n_particles",), "particles in the domain [-]"),
    (("mass_in", "mass_out"), "mass in / out [kg]"),
    (("kinetic_energy",), "kinetic energy [J]"),
    (("max_overlap_ratio",), "max overlap / radius [-]"),
)


def plot_series(series: dict, path) -> Path:
    """Run time series against time: particle count, mass in and out, kinetic energy,
    maximum overlap ratio. Panels whose series are absent say so; KeyError when none of
    them (or ``time``) is present."""
    (t,) = _need(series, "time")
    if not any(k in series for keys, _ in SERIES_PANELS for k in keys):
        raise KeyError("missing all of " + ", ".join(k for keys, _ in SERIES_PANELS for k in keys))
    fig, axes = plt.subplots(2, 2, figsize=(10, 7), sharex=True)
    for ax, (keys, ylabel) in zip(axes.ravel(), SERIES_PANELS):
        present = [k for k in keys if k in series]
        for k in present:
            ax.plot(t, np.asarray(series[k]), label=k)
        if not present:
            ax.text(0.5, 0.5, f"no data ({', '.join(keys)})", ha="center", va="center",
                    transform=ax.transAxes)
        elif len(keys) > 1:
            ax.legend()
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("time [s]")
    return _save(fig, path)


def plot_depth_profiles(meas: dict, path, slices=("left", "centre", "right", "whole")) -> Path:
    """Streamwise velocity and solid fraction against height, one column per station,
    one line per slice (those present among ``slices`` and the halves), labelled with its
    side seen in the direction of flow."""
    from cfddem.measure.chute import side_label

    stations, y = _need(meas, "stations", "profile_y")
    W = _width(meas)
    names = [s for s in list(slices) + ["left_half", "right_half"]
             if f"profile_{s}_vz" in meas and f"profile_{s}_phi" in meas]
    if not names:
        raise KeyError("missing profile_<slice>_vz / _phi")
    ns = len(stations)
    fig, axes = plt.subplots(2, ns, figsize=(3.2 * ns + 1, 7), squeeze=False, sharey=True)
    for j, s in enumerate(stations):
        for name in names:
            axes[0, j].plot(np.asarray(meas[f"profile_{name}_vz"])[j], y * 1e3, label=side_label(name, W))
            axes[1, j].plot(np.asarray(meas[f"profile_{name}_phi"])[j], y * 1e3, label=side_label(name, W))
        axes[0, j].set_title(f"z = {s:g} m")
        axes[0, j].set_xlabel("streamwise velocity [m/s]")
        axes[1, j].set_xlabel("solid volume fraction [-]")
        for a in axes[:, j]:
            a.grid(alpha=0.3)
    for a in axes[:, 0]:
        a.set_ylabel("height above the floor y [mm]")
    axes[0, 0].legend(fontsize=8)
    return _save(fig, path)


def _find_chute(meas: dict) -> dict:
    """The chute measurement dict: ``/measurements/chute`` or ``/measurements`` itself."""
    if isinstance(meas.get("chute"), dict):
        return meas["chute"]
    return meas


def chute_plots(results_h5_path, out_dir) -> list[tuple[str, Path | None, str]]:
    """The chute's plots (:meth:`cfddem.scenes.chute.ChuteScene.plots`): bed height, surface
    velocity, mean velocity and depth profiles, each ``(file name, path or None, why skipped)``."""
    from cfddem.io.results import read_measurements

    out = Path(out_dir)
    raw = read_measurements(results_h5_path)
    meas = _find_chute(raw)
    is_chute = isinstance(raw.get("chute"), dict) or "sensor_x" in raw
    jobs = [("bed_height.png", plot_bed_height), ("surface_velocity.png", plot_surface_velocity),
            ("mean_velocity.png", plot_mean_velocity), ("depth_profiles.png", plot_depth_profiles)]
    done = []
    for fname, fn in jobs:
        if not is_chute:  # measurements off, or a run that ended before the averaging started
            done.append((fname, None, "no chute measurements in this run"))
            continue
        try:
            done.append((fname, fn(meas, out / fname), ""))
        except KeyError as e:
            reason = e.args[0] if e.args else str(e)
            log.warning("report: skipped %s (%s)", fname, reason)
            done.append((fname, None, reason))
    return done


def write_run_report(results_h5_path, out_dir) -> list[Path]:
    """Write the time series plot and every plot of the run's scene (its ``plots`` hook,
    :mod:`cfddem.scenes`) whose data are in the results file to ``out_dir``, and an index
    ``report.txt`` listing each plot written and each plot skipped with the reason.  The scene
    is the stored configuration's ``geometry.type`` (a file without one: the default scene).

    Returns the written paths (PNG files, then ``report.txt``). Skips of plots whose data a run
    should have are also logged as warnings on the ``cfddem.report`` logger.
    """
    from cfddem.io.results import read_config, read_series
    from cfddem.scenes import DEFAULT_SCENE, scene_class

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    try:
        _, config = read_config(results_h5_path)
        scene = scene_class(config["geometry"]["type"])
    except (KeyError, TypeError, ValueError, OSError):
        scene = scene_class(DEFAULT_SCENE)
    written: list[Path] = [plot_series(read_series(results_h5_path), out / "series.png")]
    lines = [f"report of {results_h5_path}", "written  series.png"]
    for fname, path, reason in scene.plots(results_h5_path, out):
        if path is None:
            lines.append(f"skipped  {fname}: {reason}")
        else:
            written.append(path)
            lines.append(f"written  {fname}")
    idx = out / "report.txt"
    idx.write_text("\n".join(lines) + "\n")
    written.append(idx)
    return written
