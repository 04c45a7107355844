"""The blending-study report reads every variant of a sweep folder and writes one report."""

import json
import math

import numpy as np
import pytest

from cfddem.errors import CaseError
from cfddem.io.results import ResultsFile
from cfddem.report.blending import blending_report


def _variant(folder, name, vrr, t_mean, wall, sim, pattern):
    d = folder / name
    d.mkdir(parents=True)
    t = np.arange(1, 201) * 0.005
    c = 0.25 + 0.5 * np.exp(-t / t_mean) * np.cos(2 * np.pi * t / t_mean)
    x, y = np.linspace(0.005, 0.145, 15), np.linspace(0.005, 0.295, 30)
    vy = -np.outer(np.ones(30), np.exp(-((x - 0.075) / 0.03) ** 2))
    with ResultsFile(d / "results.h5") as r:
        r.write_measurements(None, {
            "blending": {"time": t, "concentration_out": c, "vrr": vrr, "t_mean": t_mean, "tracer_fraction_inventory": 0.25,
                         "vrr_recirculations": np.array([1.0, 2.0, 3.0]),
                         "vrr_by_recirculation": np.array([2.0, 5.0, 11.0]) * vrr / 11.0},
            "rtd": {"theta": np.linspace(0, 3, 61), "E": np.exp(-np.linspace(0, 3, 61)),
                    "F": 1 - np.exp(-np.linspace(0, 3, 61)), "first_appearance": 0.1, "peak": 0.0},
            "flow_pattern": pattern,
            "silo": {"field": {"x": x, "y": y, "vx": 0 * vy, "vy": vy, "count": np.ones_like(vy)},
                     "channel": {"y": y, "x_left": np.full(30, 0.05), "x_right": np.full(30, 0.10)}},
        })
    (d / "run.json").write_text(json.dumps({"status": "done", "time": sim, "wall_time": wall, "n_particles": 5000}))


def test_report_reads_each_variant_and_writes_plots_and_the_cost(tmp_path):
    sw = tmp_path / "sweep"
    _variant(sw, "internal", 7.5, 0.4, 3600.0, 2.0, "internal")
    _variant(sw, "semimass", 40.0, 0.3, 1800.0, 1.5, "semi-mass")
    (sw / "failed_one").mkdir()
    (sw / "summary.csv").write_text("name,blender.pattern,status,wall_time\ninternal,a,done,1\n"
                                    "semimass,b,done,1\nfailed_one,c,failed,0\n")
    res = blending_report(sw)
    rows = {r["name"]: r for r in res["rows"]}
    assert rows["internal"]["vrr"] == pytest.approx(7.5)
    assert rows["semimass"]["flow_pattern"] == "semi-mass"
    assert rows["internal"]["hours_per_simulated_s"] == pytest.approx(0.5)  # 3600 s of wall for 2 s simulated
    assert rows["semimass"]["recirculations"] == pytest.approx(1.0 / 0.3)
    assert rows["failed_one"]["status"] == "failed" and "vrr" not in rows["failed_one"]
    names = {f.name for f in res["files"]}
    assert {"blending_report.md", "blending_concentration.png", "blending_vrr.png", "blending_rtd.png",
            "blending_fields.png"} <= names
    md = (sw / "blending_report" / "blending_report.md").read_text()
    assert "| internal | done | internal | 7.5 | 1.36 | 3.41 | 7.5 | 0.4 |" in md
    summ = json.loads((sw / "blending_report" / "blending_summary.json").read_text())
    assert math.isclose(summ[1]["wall_per_simulated_s"], 1200.0)


def test_report_without_a_sweep_is_one_line(tmp_path):
    with pytest.raises(CaseError, match="summary.csv"):
        blending_report(tmp_path)


def test_report_of_two_sweeps_names_variants_by_folder(tmp_path):
    for pattern, vrr in (("semi", 3.0), ("internal", 9.0)):
        sw = tmp_path / pattern
        _variant(sw, "b25", vrr, 0.5, 100.0, 1.0, "internal" if pattern == "internal" else "semi-mass")
        (sw / "summary.csv").write_text("name,status\nb25,done\n")
    res = blending_report([tmp_path / "semi", tmp_path / "internal"], out=tmp_path / "rep")
    assert [(r["name"], r["vrr"]) for r in res["rows"]] == [("semi/b25", 3.0), ("internal/b25", 9.0)]
    assert (tmp_path / "rep" / "blending_vrr.png").exists()


def test_a_silo_run_without_an_rtd_gets_one_from_virtual_tracers(tmp_path):
    """Plug flow at 0.2 m/s in a 0.3 m fill: tracers released at 0.9 of the fill height arrive
    after 0.27 / 0.2 = 1.35 s; t_mean = 2 kg / 1 kg/s = 2 s: theta 0.675, no spread."""
    d = tmp_path / "silo_run"
    d.mkdir()
    x, y = np.linspace(0.005, 0.145, 15), np.linspace(0.005, 0.295, 30)
    vy = np.full((30, 15), -0.2)
    with ResultsFile(d / "results.h5") as r:
        r.write_measurements(None, {"mass_flow_rate": 1.0, "silo": {
            "fill_height": 0.3, "gate_open_time": 0.5,
            "field": {"x": x, "y": y, "vx": 0 * vy, "vy": vy, "count": np.ones_like(vy), "n_samples": 10}}})
        for t, m in ((0.0, 2.0), (0.5, 2.0), (1.0, 1.5)):
            r.append_series(t, mass_present=m)
    (d / "run.json").write_text(json.dumps({"status": "done", "time": 1.0, "wall_time": 10.0, "n_particles": 10}))
    res = blending_report([d], out=tmp_path / "rep")
    row = res["rows"][0]
    assert row["t_mean_s"] == pytest.approx(2.0)
    assert row["rtd_peak_theta"] == pytest.approx(0.675, abs=0.05)  # the RTD's bin width, 0.05
    assert row["rtd_variance"] < 1e-3
    assert row["flow_pattern"] == "mass"
    assert "virtual tracers" in row["rtd_note"]
