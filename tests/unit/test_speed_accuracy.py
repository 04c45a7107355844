"""Speed-against-accuracy post-processing of a sweep folder."""

import csv
import json
import subprocess
import sys
from functools import lru_cache
from itertools import combinations

import numpy as np
import pytest

from cfddem.io.results import ResultsFile
from cfddem.measure.chute import ChuteMeasurements

from .test_compare import fake_run


def test_deviations_and_chart(tmp_path):
    sweep = tmp_path / "sweep"
    sweep.mkdir()
    # dt 1e-5 is the reference (speed 2.0); 2e-5 deviates by 1 %; 4e-5 by 5 %; 8e-5 blew up
    fake_run(sweep / "time.dt=1e-05", 2.0, False, 400.0)
    fake_run(sweep / "time.dt=2e-05", 2.02, False, 200.0)
    fake_run(sweep / "time.dt=4e-05", 2.10, False, 100.0)
    with (sweep / "summary.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["name", "time.dt", "status", "wall_time", "error"])
        w.writerow(["time.dt=1e-05", "1e-05", "done", "400", ""])
        w.writerow(["time.dt=2e-05", "2e-05", "done", "200", ""])
        w.writerow(["time.dt=4e-05", "4e-05", "done", "100", ""])
        w.writerow(["time.dt=8e-05", "8e-05", "failed", "5", "overlap"])
    p = subprocess.run([sys.executable, "-m", "cfddem.cli", "accuracy", str(sweep)], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    res = json.loads((sweep / "speed_accuracy.json").read_text())
    assert res["reference"] == "time.dt=1e-05"
    rows = {r["name"]: r for r in res["rows"]}
    assert rows["time.dt=1e-05"]["surface_velocity_rel_rms"] == pytest.approx(0.0)
    assert rows["time.dt=2e-05"]["surface_velocity_rel_rms"] == pytest.approx(0.01, rel=1e-6)
    assert rows["time.dt=4e-05"]["surface_velocity_rel_rms"] == pytest.approx(0.05, rel=1e-6)
    assert rows["time.dt=2e-05"]["within_bands"] is True
    # mean streamwise velocity over the last 0.1 m, and its difference from the reference's
    assert rows["time.dt=4e-05"]["velocity_end"] == pytest.approx(2.10)
    assert rows["time.dt=4e-05"]["velocity_end_rel"] == pytest.approx(0.05)
    assert rows["time.dt=4e-05"]["within_bands"] is False
    assert rows["time.dt=8e-05"]["status"] == "failed"
    assert (sweep / "speed_accuracy.png").stat().st_size > 10000


def _gas_field(cells, lengths, fn):
    x, y, z = [(np.arange(n) + 0.5) * L / n for n, L in zip(cells, lengths)]
    X, Y, Z = np.meshgrid(x, y, z, indexing="ij")
    mv = np.zeros(tuple(cells) + (3,))
    mv[..., 2] = fn(X, Y, Z)
    return {"mean_velocity": mv, "x": x, "y": y, "z": z}


def test_gas_deviation_same_grid_and_across_grids():
    from cfddem.report.speed_accuracy import gas_deviation

    L = (0.08, 0.045, 0.9)
    ref = _gas_field((16, 15, 150), L, lambda x, y, z: 1.0 + 0.0 * x)
    run = _gas_field((16, 15, 150), L, lambda x, y, z: 1.01 + 0.0 * x)
    assert gas_deviation(ref, run) == pytest.approx(0.01, rel=1e-12)
    assert gas_deviation(ref, ref) == 0.0
    # a linear field on a coarser grid is interpolated exactly between the coarse centres and
    # clamped to the nearest centre outside them
    fn = lambda x, y, z: 2.0 + 5.0 * x - 4.0 * y + 3.0 * z  # noqa: E731
    ref = _gas_field((16, 15, 150), L, fn)
    run = _gas_field((8, 5, 75), L, fn)
    cx, cy, cz = [np.clip(ref[k], run[k][0], run[k][-1]) for k in "xyz"]
    X, Y, Z = np.meshgrid(cx, cy, cz, indexing="ij")
    wr = ref["mean_velocity"][..., 2]
    expected = np.sqrt(np.mean((fn(X, Y, Z) - wr) ** 2)) / np.sqrt(np.mean(wr**2))
    assert expected > 1e-3
    assert gas_deviation(ref, run) == pytest.approx(expected, rel=1e-10)
    # one cell across an axis (a pseudo-2-D grid): its only value is used
    run1 = _gas_field((1, 15, 150), L, lambda x, y, z: 1.0 + 0.0 * x)
    ref1 = _gas_field((16, 15, 150), L, lambda x, y, z: 1.0 + 0.0 * x)
    assert gas_deviation(ref1, run1) == pytest.approx(0.0, abs=1e-14)


# ------------------------------------------------------------------ replicas, floor, verdict
@lru_cache(maxsize=1)
def _base():
    """Chute measurements of a bed of 4000 beads moving at 2 m/s (bed height and surface velocity
    on the sensors' and cells' grids)."""
    rng = np.random.default_rng(0)
    n = 4000
    pos = np.c_[rng.uniform(0.002, 0.078, n), rng.uniform(0.0015, 0.012, n), rng.uniform(-0.1, 0.8, n)]
    vel = np.zeros((n, 3))
    vel[:, 2] = 2.0
    m = ChuteMeasurements(width=0.08, z_range=(-0.1, 0.8), start_time=0.0)
    for t in (0.0, 0.01):
        m.measure(t, pos, vel, np.full(n, 0.0015))
    return m.group, m.results(), m.attrs()


def synth_run(folder, wall, bed_mm=0.0, vel_rel=0.0, bed_noise=None, vel_noise=None):
    """A run folder whose bed is ``bed_mm`` (+ ``bed_noise`` (3, 150), mm) higher than the base's
    and whose surface velocity is ``1 + vel_rel`` (+ ``vel_noise`` (16, 150)) times the base's."""
    group, res, attrs = _base()
    res = dict(res)
    res["bed_height_sensor"] = res["bed_height_sensor"] + 1e-3 * (bed_mm + (0.0 if bed_noise is None else bed_noise))
    res["surface_vz"] = res["surface_vz"] * (1.0 + vel_rel + (0.0 if vel_noise is None else vel_noise))
    res["mean_vz"] = res["mean_vz"] * (1.0 + vel_rel)
    folder.mkdir(parents=True)
    with ResultsFile(folder / "results.h5") as h:
        h.write_config("", {"frame": {"rpm": 16.0}, "exit": {"z": 0.8}})
        h.append_series(time=0.0, n_particles=4000)
        h.write_measurements(group, res, attrs)
        h.write_metadata(wall_time=wall)
    return folder


def write_summary(sweep, cols, rows):
    """``rows``: the values of ``cols``, status, wall time, error; the names as the sweep's."""
    names = []
    with (sweep / "summary.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["name", *cols, "status", "wall_time", "error"])
        for r in rows:
            names.append("__".join(f"{c}={v}" for c, v in zip(cols, r) if v != ""))
            w.writerow([names[-1], *r])
    return names


COLS = ["time.dt", "checkpoint.perturb_seed"]


def dt_sweep(tmp_path, offset_2e5=0.05, replicas=(0.2, -0.2, 0.0)):
    """dt = 1e-5 (the reference) with one replica per bed offset (mm; surface velocity offset
    1 % of it per mm), 2e-5 off by ``offset_2e5`` mm, 4e-5 by 1.4 mm, 8e-5 blew up."""
    sweep = tmp_path / "sweep"
    sweep.mkdir()
    rows = []
    for seed, a in enumerate(replicas, start=1):
        rows.append(["1e-05", seed, "done", 400 + 5 * seed, ""])
    rows += [["2e-05", "", "done", 200, ""], ["4e-05", "", "done", 100, ""],
             ["8e-05", "", "failed", 5, "step 120: overlap/radius 0.62 > 0.5: time step too large"]]
    names = write_summary(sweep, COLS, rows)
    for name, r, a in zip(names, rows, list(replicas) + [offset_2e5, 1.4]):
        synth_run(sweep / name, r[3], bed_mm=a, vel_rel=0.01 * a)
    return sweep


def test_replicas_are_one_setting_and_give_the_floor(tmp_path):
    from cfddem.report.speed_accuracy import group_settings, speed_accuracy

    sweep = dt_sweep(tmp_path)
    rows = list(csv.DictReader((sweep / "summary.csv").open()))
    groups = group_settings(rows, COLS)
    assert [len(g["names"]) for g in groups] == [3, 1, 1, 1]
    assert groups[0]["values"] == {"time.dt": "1e-05"}
    res = speed_accuracy(sweep)
    assert len(res["settings"]) == 4 and res["reference_runs"] == groups[0]["names"]
    # bed offsets (+a, -a, 0): each replica against the mean of the other two is off by
    # 1.5a, 1.5a, 0, so the floor is a sqrt(1.5); the surface velocity (1 + 0.01 a) likewise,
    # relative to the others' mean speed
    a = 0.2
    fl = res["noise_floor"]
    assert fl["n_replicas"] == 3
    assert fl["bed_height_rms_mm"] == pytest.approx(a * np.sqrt(1.5), rel=1e-9)
    e = 0.01 * a
    expect = np.sqrt(np.mean([(1.5 * e / (1 - e / 2)) ** 2, (1.5 * e / (1 + e / 2)) ** 2, 0.0]))
    assert fl["surface_velocity_rel_rms"] == pytest.approx(expect, rel=1e-9)
    rows = {r["name"]: r for r in res["rows"]}
    assert rows["time.dt=1e-05__checkpoint.perturb_seed=1"]["bed_height_rms_mm"] == pytest.approx(1.5 * a, rel=1e-9)
    assert rows["time.dt=1e-05__checkpoint.perturb_seed=3"]["bed_height_rms_mm"] == pytest.approx(0.0, abs=1e-12)
    # the others against the replicas' mean (the base): their own offsets; u = s sqrt(1 + 1/3),
    # s^2 = floor^2 (k-1)/k = a^2
    s = {x["label"]: x for x in res["settings"]}
    s2 = next(x for x in res["settings"] if x["values"]["time.dt"] == "2e-05")
    assert s2["bed_height_rms_mm"] == pytest.approx(0.05, rel=1e-9)
    assert s2["bed_height_rms_mm_unc"] == pytest.approx(a * np.sqrt(4 / 3), rel=1e-9)
    assert len(s) == 4


def test_floor_of_random_scatter(tmp_path):
    """Replicas with independent random scatter of RMS s per point: the floor (each replica
    against the mean of the k - 1 others) is s sqrt(1 + 1/(k-1)), here within the sampling error
    of 4 x 450 bed points and 4 x 2400 velocity cells."""
    from cfddem.report.speed_accuracy import speed_accuracy

    sweep = tmp_path / "sweep"
    sweep.mkdir()
    rng = np.random.default_rng(5)
    k, s_bed, s_vel = 4, 0.3, 0.004
    names = write_summary(sweep, COLS, [["1e-05", j, "done", 100.0, ""] for j in range(k)])
    for n in names:
        synth_run(sweep / n, 100.0, bed_noise=rng.normal(0, s_bed, (3, 150)), vel_noise=rng.normal(0, s_vel, (16, 150)))
    fl = speed_accuracy(sweep)["noise_floor"]
    assert fl["bed_height_rms_mm"] == pytest.approx(s_bed * np.sqrt(1 + 1 / (k - 1)), rel=0.05)
    assert fl["surface_velocity_rel_rms"] == pytest.approx(s_vel * np.sqrt(1 + 1 / (k - 1)), rel=0.03)


@pytest.mark.parametrize("offset, distinct", [(0.05, False), (0.6, True)])
def test_verdict_picks_the_cheapest_setting_inside_the_bands(tmp_path, offset, distinct):
    from cfddem.report.speed_accuracy import speed_accuracy

    res = speed_accuracy(dt_sweep(tmp_path, offset_2e5=offset))
    by_dt = {x["values"]["time.dt"]: x for x in res["settings"]}
    # 4e-5 deviates by 1.4 mm (< 1.5 mm) but its upper bound 1.4 + 0.23 mm is outside
    assert by_dt["4e-05"]["bed_height_rms_mm"] == pytest.approx(1.4, rel=1e-9)
    assert by_dt["4e-05"]["within_bands"] is False
    assert by_dt["2e-05"]["within_bands"] is True and by_dt["1e-05"]["within_bands"] is True
    # 0.6 mm > 2 x 0.23 mm: told apart from the scatter; 0.05 mm is not
    assert by_dt["2e-05"]["distinguishable"] is distinct
    assert res["verdict_setting"] == by_dt["2e-05"]["setting"]
    v = res["verdict"]
    assert v.startswith("cheapest inside the experimental bands") and "(200 s, 2.05x faster than the reference)" in v  # 410 s / 200 s
    assert ("not distinguishable" not in v) is distinct
    assert by_dt["2e-05"]["label"] in v
    # the verdict in every output
    sweep = tmp_path / "sweep"
    assert json.loads((sweep / "speed_accuracy.json").read_text())["verdict"] == v
    assert f"**Verdict:** {v}" in (sweep / "speed_accuracy.md").read_text()
    srows = list(csv.DictReader((sweep / "speed_accuracy_settings.csv").open()))
    assert [r["verdict"] for r in srows if r["verdict"]] == [v]


def test_unstable_settings_are_marked(tmp_path):
    from cfddem.report.speed_accuracy import draw_chart, speed_accuracy

    res = speed_accuracy(dt_sweep(tmp_path))
    bad = [x for x in res["settings"] if x["status"] == "failed"]
    assert len(bad) == 1 and bad[0]["reason"] == "unstable: overlap" and bad[0]["wall_time"] == 5
    fig, labels = draw_chart(res)
    texts = [t.get_text() for t in labels]
    assert any("unstable: overlap" in t for t in texts)
    # a red cross at its wall time in every panel
    import matplotlib.pyplot as plt

    panels = [ax for ax in fig.axes if ax.get_xscale() == "log"]
    assert len(panels) == 2
    for ax in panels:
        xs = [ln.get_xdata()[0] for ln in ax.lines if ln.get_marker() == "x" and ln.get_color() == "tab:red"]
        assert xs == [5]
    plt.close(fig)


def test_labels_do_not_overlap(tmp_path):
    """Nine settings crowded at nearly the same wall time and deviation, plus a failed one: the
    numbers beside the points and the table cells do not overlap (the boxes the renderer draws)."""
    from cfddem.report.speed_accuracy import FONT, draw_chart, speed_accuracy, text_box

    sweep = tmp_path / "sweep"
    sweep.mkdir()
    rows = [["1e-05", j, "done", 400.0 + j, ""] for j in (1, 2)]
    rows += [[f"{1e-5 * (1 + 0.1 * i):.3g}", "", "done", 200.0 + 4 * i, ""] for i in range(1, 10)]
    rows += [["9e-05", "", "failed", 201.0, "refused: time.dt above t_c/5 (use time.force)"]]
    names = write_summary(sweep, COLS, rows)
    for i, (n, r) in enumerate(zip(names, rows)):
        if r[2] == "done":
            synth_run(sweep / n, r[3], bed_mm=0.1 * (i % 2) + 0.01 * i, vel_rel=0.0005 * i)
    res = speed_accuracy(sweep)
    fig, labels = draw_chart(res)
    r = fig.canvas.get_renderer()
    boxes = [text_box(t, r) for t in labels]  # an annotation's text, without its leader line
    numbers = [t for t in labels if t.get_text() in {"R"} | {str(i) for i in range(1, 12)}]
    assert len(numbers) >= 2 * 11  # R and ten numbered settings in each panel, and the table's column
    for (i, a), (j, b) in combinations(enumerate(boxes), 2):
        assert not a.overlaps(b), (labels[i].get_text(), labels[j].get_text())
    assert min(t.get_fontsize() for t in labels) >= FONT >= 9
    assert any("failed: refused" in t.get_text() for t in labels)
    import matplotlib.pyplot as plt

    plt.close(fig)


def test_floor_from_the_replicas_of_another_setting(tmp_path):
    """The reference (1e-5) run once, the cheaper 2e-5 three times with bed offsets +a, -a, 0
    around 0.3 mm: ``floor_from`` takes the floor from the 2e-5 replicas (a sqrt(1.5)), their
    setting's deviation is their mean's (0.3 mm) with u = s sqrt(1/3 + 1/1), s = a, and the
    chart and tables say whose scatter it is; a setting with one run is refused as the source."""
    from cfddem.errors import CaseError
    from cfddem.report.speed_accuracy import speed_accuracy

    sweep = tmp_path / "sweep"
    sweep.mkdir()
    a = 0.2
    rows = [["1e-05", "", "done", 800, ""]] + [["2e-05", j, "done", 200, ""] for j in (1, 2, 3)] \
        + [["4e-05", "", "done", 100, ""]]
    names = write_summary(sweep, COLS, rows)
    for n, r, off in zip(names, rows, [0.0, 0.3 + a, 0.3 - a, 0.3, 1.0]):
        synth_run(sweep / n, r[3], bed_mm=off)
    res = speed_accuracy(sweep, floor_from=names[1], out=tmp_path / "out")
    fl = res["noise_floor"]
    assert fl["n_replicas"] == 3 and not fl["of_reference"] and fl["setting"].startswith("dt")
    assert fl["bed_height_rms_mm"] == pytest.approx(a * np.sqrt(1.5), rel=1e-9)
    s2 = next(x for x in res["settings"] if x["values"]["time.dt"] == "2e-05")
    assert s2["bed_height_rms_mm"] == pytest.approx(0.3, rel=1e-9)
    assert s2["bed_height_rms_mm_unc"] == pytest.approx(a * np.sqrt(1 / 3 + 1), rel=1e-9)
    s4 = next(x for x in res["settings"] if x["values"]["time.dt"] == "4e-05")
    assert s4["bed_height_rms_mm_unc"] == pytest.approx(a * np.sqrt(2.0), rel=1e-9)
    assert "replicas of" in res["verdict"]
    assert "replicas of" in (tmp_path / "out" / "speed_accuracy.md").read_text()
    with pytest.raises(CaseError, match="--floor-from"):
        speed_accuracy(sweep, floor_from=names[0], out=tmp_path / "out2")


@pytest.mark.parametrize("xlim", [(9.0, 7400.0), (60.0, 800.0), (150.0, 400.0)])
def test_wall_time_tick_labels_do_not_overlap(xlim):
    """On a 3.7 in panel the wall-time tick labels (plain numbers) never touch, from a range of
    under one decade (at least three ticks) to nearly three decades (a failed run at 15 s beside
    a reference at 4,600 s put 500 and 1000 into each other with 1-2-5 ticks)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from cfddem.report.speed_accuracy import _wall_ticks

    fig, ax = plt.subplots(figsize=(3.7, 3.0), dpi=100)
    ax.set_xscale("log")
    ax.set_xlim(*xlim)
    _wall_ticks(ax, xlim)
    ax.tick_params(labelsize=9)
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    boxes = [t.get_window_extent(r) for t in ax.get_xticklabels() if t.get_text() and t.get_visible()]
    assert len(boxes) >= 3
    boxes.sort(key=lambda b: b.x0)
    assert all(b1.x0 - b0.x1 > 2.0 for b0, b1 in zip(boxes, boxes[1:]))
    plt.close(fig)
