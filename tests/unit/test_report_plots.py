"""Plots write real PNGs from synthetic data; the run report reads a ResultsFile."""

import logging

import numpy as np
import pytest

from cfddem.io.results import ResultsFile
from cfddem.measure.chute import ChuteMeasurements
from cfddem.report.plots import (plot_bed_height, plot_depth_profiles, plot_mean_velocity,
                                 plot_series, plot_surface_velocity, write_run_report)

PNG = b"\x89PNG\r\n\x1a\n"
W, R = 0.08, 0.0015


def _meas():
    rng = np.random.default_rng(2)
    n = 6000
    pos = np.column_stack([rng.uniform(R, W - R, n), rng.uniform(R, 0.02, n), rng.uniform(-0.01, 0.65, n)])
    vel = np.column_stack([rng.normal(0, 0.1, n), np.zeros(n), 1.0 + 10 * pos[:, 1]])
    cm = ChuteMeasurements(W, (-0.006, 0.654))
    for t in (0.0, 0.1):
        cm.measure(t, pos, vel, np.full(n, R))
    return cm


def _is_png(p, min_size=5000):
    data = p.read_bytes()
    return data[:8] == PNG and len(data) > min_size


def test_each_plot_writes_png(tmp_path):
    m = _meas().results()
    assert _is_png(plot_bed_height(m, tmp_path / "b.png"))
    assert _is_png(plot_surface_velocity(m, tmp_path / "s.png"))
    assert _is_png(plot_mean_velocity(m, tmp_path / "m.png"))
    m2 = dict(m, mean_vz=m["mean_vz"] * 0.8)
    assert _is_png(plot_mean_velocity([m, m2], tmp_path / "m2.png", labels=["air", "vacuum"]))
    assert _is_png(plot_depth_profiles(m, tmp_path / "d.png"))
    t = np.linspace(0, 1, 50)
    series = {"time": t, "n_particles": 100 * t, "mass_in": 1.6 * t, "mass_out": np.r_[np.zeros(25), t[25:]],
              "kinetic_energy": t ** 2}
    assert _is_png(plot_series(series, tmp_path / "t.png"))
    with pytest.raises(ValueError):
        plot_mean_velocity([m, m2], tmp_path / "x.png", labels=["one"])
    with pytest.raises(KeyError):
        plot_bed_height({}, tmp_path / "x.png")
    with pytest.raises(KeyError):
        plot_series({"time": t}, tmp_path / "x.png")


def test_run_report_from_results_file(tmp_path):
    cm = _meas()
    p = tmp_path / "results.h5"
    with ResultsFile(p) as rf:
        for k in range(20):
            rf.append_series(time=0.01 * k, n_particles=10 * k, mass_in=0.016 * k,
                             kinetic_energy=0.1 * k, max_overlap_ratio=0.01)
        rf.write_measurements(cm.group, cm.results(), cm.attrs())
    out = tmp_path / "report"
    files = write_run_report(p, out)
    names = [f.name for f in files]
    assert names == ["series.png", "bed_height.png", "surface_velocity.png", "mean_velocity.png",
                     "depth_profiles.png", "report.txt"]
    assert all(_is_png(f) for f in files[:-1])
    assert "skipped" not in files[-1].read_text()


class _Collect(logging.Handler):
    def __init__(self):
        super().__init__(logging.WARNING)
        self.text = ""

    def emit(self, record):
        self.text += self.format(record) + "\n"


def test_run_report_says_what_it_skipped(tmp_path):
    p = tmp_path / "results.h5"
    with ResultsFile(p) as rf:
        rf.append_series(time=0.0, n_particles=0)
        rf.append_series(time=0.1, n_particles=5)
    # a handler on the report logger itself: the run logger may stop propagation to root
    h = _Collect()
    lg = logging.getLogger("cfddem.report")
    lg.addHandler(h)
    try:
        files = write_run_report(p, tmp_path / "rep")
    finally:
        lg.removeHandler(h)
    assert [f.name for f in files] == ["series.png", "report.txt"]
    text = files[-1].read_text()
    # a run without chute measurements (silo, shear cell, box): listed, not warned about
    for name in ("bed_height.png", "surface_velocity.png", "mean_velocity.png", "depth_profiles.png"):
        assert f"skipped  {name}: no chute measurements" in text
        assert name not in h.text
    # a chute run whose measurements lack a plot's data: warned about
    with ResultsFile(p, mode="a") as rf:
        rf.write_measurements("chute", {"sensor_x": np.array([0.015, 0.045])}, {})
    lg.addHandler(h)
    try:
        files = write_run_report(p, tmp_path / "rep2")
    finally:
        lg.removeHandler(h)
    assert "bed_height.png" in h.text and "skipped  bed_height.png" in files[-1].read_text()
