"""The chapter-5 silo measurements on synthetic data (cfddem.measure.silo): the kinematic
model's B fit, the profile and centreline extraction, Janssen's formula; the periodic-depth and
profile keys' one-line errors."""

import math

import numpy as np
import pytest

from cfddem.config import build_case
from cfddem.errors import CaseError
from cfddem.measure.coarse import janssen, lateral_pressure_ratio
from tests.unit.test_silo_scene import BASE
from cfddem.measure.silo import (VelocityField, centreline_velocity, fit_kinematic_B, kinematic_profile,
                                 profile_measurements, rows_at_heights)


@pytest.fixture
def saved_figures(monkeypatch):
    """The figures the code under test saves, in order (savefig still writes the file)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    made, orig = [], plt.Figure.savefig

    def keep(fig, *a, **k):
        made.append(fig)
        return orig(fig, *a, **k)

    monkeypatch.setattr(plt.Figure, "savefig", keep)
    return made


def test_B_fit_recovers_B_of_a_gaussian_profile():
    xc, z, B, v0 = 0.04, 0.03, 0.004, 0.12
    x = np.linspace(0.002, 0.078, 21)
    v = kinematic_profile(x - xc, v0, B, z)
    f = fit_kinematic_B(x, v, z, xc)
    assert f["reason"] == ""
    assert f["B"] == pytest.approx(B, rel=1e-6)
    assert f["v0"] == pytest.approx(v0, rel=1e-6)
    # with 3 % noise: B within a few errors, the error of the order of the scatter
    rng = np.random.default_rng(1)
    f = fit_kinematic_B(x, v * (1 + 0.03 * rng.standard_normal(len(x))), z, xc)
    assert abs(f["B"] - B) < 4 * f["B_err"] and 0 < f["B_err"] < 0.1 * B


def test_B_is_nan_where_the_fit_is_not_meaningful():
    x = np.linspace(0.0, 0.08, 21)
    flat = np.full_like(x, 0.05)  # plug flow across the silo: no width to fit
    f = fit_kinematic_B(x, flat, 0.05, 0.04)
    assert math.isnan(f["B"]) and "too flat" in f["reason"]
    f = fit_kinematic_B(x, -np.abs(flat), 0.05, 0.04)  # no downward flow
    assert math.isnan(f["B"]) and "no downward flow" in f["reason"]
    f = fit_kinematic_B(x[:3], flat[:3], 0.05, 0.04)
    assert math.isnan(f["B"]) and "fewer than 4" in f["reason"]
    assert math.isnan(fit_kinematic_B(x, flat, 0.0, 0.04)["B"])


def test_rows_at_heights_interpolates_between_row_centres():
    y = np.array([0.0, 0.01, 0.02])
    v = np.array([[1.0, 2.0], [3.0, np.nan], [5.0, 6.0]])
    r = rows_at_heights(y, v, [0.005, 0.02, 0.03])
    assert r[0, 0] == pytest.approx(2.0) and math.isnan(r[0, 1])
    assert r[1].tolist() == [5.0, 6.0]
    assert np.isnan(r[2]).all()


def synthetic_fields(B=0.003, v0=0.2, W=0.08, L=0.04, cell=0.004):
    """Two window fields sampled from particles on a lattice moving with the kinematic profile
    (downward), the front layer twice as fast as the depth average's other layers."""
    xc = 0.5 * W
    fa, ff = VelocityField(0.0, W, 0.0, 0.1, cell), VelocityField(0.0, W, 0.0, 0.1, cell)
    xs = np.arange(cell / 2, W, cell)
    ys = np.arange(cell / 2, 0.1, cell)
    zs = np.array([0.001, 0.02, 0.03])
    X, Y, Z = np.meshgrid(xs, ys, zs, indexing="ij")
    pos = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    vel = np.zeros_like(pos)
    vel[:, 1] = -kinematic_profile(pos[:, 0] - xc, v0, B, pos[:, 1])
    for _ in range(3):
        fa.sample(pos, vel)
        front = pos[:, 2] < 0.0038
        ff.sample(pos[front], 2 * vel[front])
    return fa, ff, xc, pos, vel


def test_profile_and_centreline_extraction_on_a_synthetic_field():
    B, v0 = 0.003, 0.2
    fa, ff, xc, pos, vel = synthetic_fields(B, v0)
    hs = [0.012, 0.02, 0.05]
    pm = profile_measurements(fa, ff, xc, hs, fraction=0.1)
    # 0.05 m is a row centre (0.002 + 12 x 0.004): that row; 0.012 lies halfway between 0.010 and 0.014
    exp = -kinematic_profile(fa.x - xc, v0, B, 0.05)
    assert np.allclose(pm["depth"]["vy"][2], exp)
    exp = -0.5 * (kinematic_profile(fa.x - xc, v0, B, 0.010) + kinematic_profile(fa.x - xc, v0, B, 0.014))
    assert np.allclose(pm["depth"]["vy"][0], exp)
    assert np.allclose(pm["front"]["vy"], 2 * pm["depth"]["vy"])
    # B fitted to the extracted rows: within 3 % (the rows are interpolated between heights)
    assert np.allclose(pm["depth"]["B"], B, rtol=0.03)
    assert np.allclose(pm["front"]["B"], B, rtol=0.03)
    # channel: where the speed falls to 10 % of the centreline's, x^2 = 4 B z ln 10 (to a cell)
    half = np.sqrt(4 * B * np.asarray(hs) * math.log(10))
    assert np.allclose(pm["channel"]["width"], 2 * half, atol=0.004)
    assert pm["flow_pattern"] in ("mass", "semi-mass", "internal")
    # the centreline series: mean v_y of the particles within d of the centre line and height
    c = centreline_velocity(pos, vel, xc, [0.014, 0.5], 0.0038, 0.0038)
    sel = (np.abs(pos[:, 0] - xc) < 0.0038) & (np.abs(pos[:, 1] - 0.014) < 0.0038)
    assert c[0] == pytest.approx(vel[sel, 1].mean()) and c[0] < 0
    assert math.isnan(c[1])


def test_janssen_values():
    # W = 0.08, T = 0.04, mu_side 0.17, mu_front 0.2, tan phi = 0.37
    K = lateral_pressure_ratio(0.37)
    s = math.sin(math.atan(0.37))
    assert K == pytest.approx((1 - s) / (1 + s)) and K == pytest.approx(0.4848, abs=1e-4)
    zc = 0.08 * 0.04 / (2 * K * (0.17 * 0.04 + 0.2 * 0.08))
    assert zc == pytest.approx(0.14477, rel=1e-4)
    gamma, H = 550 * 9.81, 0.145
    v = janssen([0.0, 0.1, H, 0.2], H, gamma, 0.08, 0.04, K, 0.17, 0.2)
    assert v[0] == pytest.approx(gamma * zc * (1 - math.exp(-H / zc)))
    assert v[0] == pytest.approx(494.2, abs=0.1)
    assert v[1] == pytest.approx(gamma * zc * (1 - math.exp(-0.045 / zc)))
    assert v[2] == 0.0 and v[3] == 0.0
    # deep silo: the asymptote gamma z_c; no wall friction on the front: z_c = T W / (2 K mu_side T)
    assert janssen([0.0], 100.0, gamma, 0.08, 0.04, K, 0.17, 0.2)[0] == pytest.approx(gamma * zc)
    assert janssen([0.0], 100.0, gamma, 0.08, 0.04, K, 0.17, 0.0)[0] == pytest.approx(gamma * 0.08 / (2 * K * 0.17))


@pytest.mark.parametrize("silo, extra, key, words", [
    ({"depth_boundary": "periodical"}, {}, "silo.depth_boundary", "one of"),
    ({"depth_boundary": "periodic", "depth": 0.009}, {}, "silo.depth", "too shallow"),
    ({"depth_boundary": "periodic"}, {"gas": {"enabled": True, "cells": [4, 4, 2]}}, "silo.depth_boundary", "gas"),
    ({"profile_heights": [0.02, 0.01]}, {}, "silo.profile_heights", "increasing"),
    ({"profile_heights": [0.0, 0.01]}, {}, "silo.profile_heights[0]", ""),
    ({"profile_window": [0.7, 0.5]}, {}, "silo.profile_window", "start < end"),
    ({"stress_grid": [0.006, 0.004]}, {}, "silo.stress_grid", "3"),
    ({"bulk_friction": 0.0}, {}, "silo.bulk_friction", ""),
])
def test_bad_keys_give_a_one_line_error_naming_them(silo, extra, key, words):
    raw = {k: (dict(v) if isinstance(v, dict) else v) for k, v in BASE.items()}
    raw["silo"] = dict(BASE["silo"], **silo)
    raw.update(extra)
    with pytest.raises(CaseError) as e:
        build_case(raw)
    assert e.value.key == key
    assert words in str(e.value) and "\n" not in str(e.value)


def test_periodic_depth_is_refused_in_the_blender_and_with_mesh_walls():
    raw = {k: (dict(v) if isinstance(v, dict) else v) for k, v in BASE.items()}
    raw["geometry"] = {"type": "silo_blender"}
    raw["silo"] = dict(BASE["silo"], depth_boundary="periodic")
    with pytest.raises(CaseError) as e:
        build_case(raw)
    assert e.value.key == "silo.depth_boundary" and "blender" in str(e.value)
    raw["geometry"] = {"type": "silo"}
    raw["silo"] = dict(BASE["silo"], depth_boundary="periodic", walls="mesh")
    with pytest.raises(CaseError) as e:
        build_case(raw)
    assert e.value.key in ("silo.walls", "silo.depth_boundary")


def test_bed_top_leaves_out_the_rows_the_surface_left():
    from cfddem.measure.silo import bed_top

    f = VelocityField(0.0, 0.04, 0.0, 0.04, 0.01)  # 4 x 4 cells
    f.count[:3] = 10.0
    f.count[0, 0] = 5.0  # a wall cell with half the count still counts
    f.count[3, 1:] = 10.0  # the top row: one cell empty (the surface left it)
    assert bed_top(f) == pytest.approx(0.03)
    f.count[0, 1:] = 0.0  # the row through the slot below the floor: partly empty, the bed above counts
    assert bed_top(f) == pytest.approx(0.03)
    f.count[2, 2] = 2.0  # under a quarter of the median: the row is not part of the bed
    assert bed_top(f) == pytest.approx(0.02)
    assert math.isnan(bed_top(VelocityField(0.0, 0.04, 0.0, 0.04, 0.01)))


def test_a_reused_run_reads_done_in_the_study_table(tmp_path):
    """The sweep marks a finished run that it found and reused "skipped"; the study's table
    says "done (reused)" (a reader must not take it for a run left out), and keeps the others."""
    from cfddem.silo_thesis import read_variant

    v = {"label": "front/back mu 1", "group": "walls", "x": 1.0}
    rows = [read_variant({"status": st, "wall_time": 12.0, "out_dir": str(tmp_path)}, v)
            for st in ("skipped", "done", "failed")]
    assert [r["status"] for r in rows] == ["done (reused)", "done", "failed"]
    assert rows[0]["wall_time"] == 12.0 and math.isnan(rows[0]["flow_rate"])  # no results.h5 there


def test_mobilised_friction_is_the_walls_vertical_over_horizontal_force():
    from cfddem.silo_thesis import mobilised_friction

    labels = ["front", "back", "left", "right", "gate"]
    # gravity along -y: a wall holding the bed up is pushed down (F_y < 0, load = -F_y > 0)
    force = np.array([[0.0, -0.3, 2.0], [0.0, -0.1, -2.0], [1.0, -0.1, 0.0], [-3.0, 0.1, 0.0], [0.0, -5.0, 0.0]])
    load = -force[:, 1]
    m = mobilised_friction(labels, force, load)
    assert m["mobilised_front_back"] == pytest.approx(0.4 / 4.0, rel=1e-12)
    assert m["mobilised_sides"] == pytest.approx(0.0, abs=1e-15)  # one holds up, one pulls down as much
    # tilted gravity: the horizontal part is what is left of |F| beside the load
    m = mobilised_friction(["left"], np.array([[0.6, -0.8, 0.0]]), np.array([0.8]))
    assert m["mobilised_sides"] == pytest.approx(0.8 / 0.6, rel=1e-12)
    assert math.isnan(m["mobilised_front_back"])  # no front/back walls (a periodic depth)


def test_janssen_with_the_measured_ratios_reduces_to_janssens_curve():
    from cfddem.silo_thesis import janssen_measured_k

    H, W, T, gamma, mu_s, mu_f = 0.145, 0.08, 0.04, 5400.0, 0.17, 0.2
    y = np.linspace(0.002, 0.14, 35)
    K = lateral_pressure_ratio(0.37)
    st = {"y": y, "H": H, "W": W, "T": T, "mu_side": mu_s, "mu_front": mu_f,
          "hydrostatic": gamma * (H - y)}
    band = (y > 0.1 * H) & (y < 0.2 * H)
    assert band.sum() >= 3
    want = float(np.mean(janssen(y[band], H, gamma, W, T, K, mu_s, mu_f)))
    assert janssen_measured_k(st, band, K, K) == pytest.approx(want, rel=1e-12)
    # a larger K against the front/back walls only: more weight on the walls, less stress
    assert janssen_measured_k(st, band, K, 2 * K) < want
    assert math.isnan(janssen_measured_k(st, band, math.nan, K))


def test_floor_drop_study_variants_set_the_depth_and_the_settled_gate():
    from cfddem.silo_thesis import DEFAULTS, X_LABEL, study_variants

    v = study_variants("floor-drop", [0.0, 0.0005, 0.0019])
    assert [x["overrides"] for x in v] == [{"silo.floor_drop": d, "silo.gate": "settled"} for d in (0.0, 0.0005, 0.0019)]
    assert [x["x"] for x in v] == pytest.approx([0.0, 0.5, 1.9], rel=1e-12)  # the chart's axis in mm
    assert [x["label"] for x in v] == ["floor drop 0 mm", "floor drop 0.5 mm", "floor drop 1.9 mm"]
    assert len(study_variants("floor-drop")) == len(DEFAULTS["floor-drop"]) == 5
    assert "mm" in X_LABEL["floor-drop"]


def test_floor_speed_study_variants_set_the_speed_at_one_depth():
    from cfddem.silo_thesis import DEFAULTS, DROP_DEPTH, X_LABEL, study_variants

    v = study_variants("floor-speed", [0.001, 0.025], depth=0.0005)
    assert [x["overrides"] for x in v] == [{"silo.floor_drop": 0.0005, "silo.floor_drop_speed": s,
                                            "silo.gate": "settled"} for s in (0.001, 0.025)]
    assert [x["x"] for x in v] == pytest.approx([1.0, 25.0], rel=1e-12)  # the chart's axis in mm/s
    assert [x["label"] for x in v] == ["drop at 1 mm/s", "drop at 25 mm/s"]
    assert {x["group"] for x in v} == {"floor drop 0.5 mm"}
    d = study_variants("floor-speed")
    assert [x["overrides"]["silo.floor_drop_speed"] for x in d] == DEFAULTS["floor-speed"]
    assert {x["overrides"]["silo.floor_drop"] for x in d} == {DROP_DEPTH} and DROP_DEPTH == 0.001
    assert "mm/s" in X_LABEL["floor-speed"]


@pytest.mark.parametrize("argv, key", [(["floor-drop", "--depth", "0.001"], "--depth"),
                                       (["floor-speed", "--depth", "0"], "--depth"),
                                       (["floor-speed", "--depth", "0.001,0.002"], "--depth")])
def test_floor_speed_depth_is_checked_in_one_line(argv, key, tmp_path, capsys):
    from cfddem.silo_thesis import main

    assert main([*argv, "--out", str(tmp_path / "s")]) != 0
    err = capsys.readouterr().err
    assert key in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "s").exists()


def test_mobilised_chart_draws_each_wall_group_against_the_depth(tmp_path, saved_figures):
    """plot_mobilised: one line per wall group, its points the table's shares at the swept depths
    (in order of the depth, whatever the table's order)."""
    from cfddem.silo_thesis import plot_mobilised

    table = [{"x": 1.0, "share_front_back": 36.0, "share_sides": 14.0, "share_floor": 50.0,
              "mobilised_front_back": 0.17, "mobilised_sides": 0.14, "stress_low": 344.0, "hydrostatic_low": 650.0,
              "janssen_low": 439.0, "janssen_low_K": 323.0},
             {"x": 0.0, "share_front_back": 5.0, "share_sides": 3.0, "share_floor": 92.0,
              "mobilised_front_back": 0.02, "mobilised_sides": 0.02, "stress_low": 605.0, "hydrostatic_low": 655.0,
              "janssen_low": 440.0, "janssen_low_K": math.nan}]
    path = plot_mobilised("floor-drop", table, tmp_path)
    assert path.name == "floor-drop_mobilised.png" and path.stat().st_size > 1000
    ax = saved_figures[0].axes
    lines = {ln.get_label(): ln for ln in ax[0].get_lines()}
    np.testing.assert_array_equal(lines["front/back walls"].get_xdata(), [0.0, 1.0])
    np.testing.assert_array_equal(lines["front/back walls"].get_ydata(), [5.0, 36.0])
    np.testing.assert_array_equal(lines["floor, lips, gate"].get_ydata(), [92.0, 50.0])
    stress = {ln.get_label(): ln for ln in ax[2].get_lines()}
    np.testing.assert_array_equal(stress["coarse-grained"].get_ydata(), [605.0, 344.0])
    assert set(stress) == {"coarse-grained", "hydrostatic", "Janssen, K from the bulk friction", "Janssen, measured K"}


def test_replicas_are_the_variants_again_with_the_next_seeds():
    """--replicas: each variant N times in a row, replica k with particles.seed = seed0 + k; the
    first replica has no seed override, so it is the unreplicated study's run (reused)."""
    from cfddem.silo_thesis import replicate, study_variants

    v = replicate(study_variants("front-back", [0.2, 1.0], periodic=False), 3, 6)
    assert [x["label"] for x in v] == ["front/back mu 0.2"] * 3 + ["front/back mu 1"] * 3
    assert [x["seed"] for x in v] == [6, 7, 8, 6, 7, 8]
    assert v[0]["overrides"] == {"silo.front_back.mu": 0.2}
    assert v[2]["overrides"] == {"silo.front_back.mu": 0.2, "particles.seed": 8}
    assert replicate(v[:1], 1, 6) == [dict(v[0], replica=0, seed=6)]
    with pytest.raises(CaseError, match="--replicas"):
        replicate(v, 0, 6)


def _run_row(label, x, flow, pattern, status="done", B=math.nan, m=None):
    return {"label": label, "group": "walls", "x": x, "status": status, "wall_time": 100.0, "m": m,
            "flow_rate": flow, "bulk_density": 550.0, "flow_pattern": pattern, "B_10": B, "clogged": 0}


def test_replicas_combine_into_mean_and_standard_deviation():
    from cfddem.silo_thesis import combine_replicas

    runs = [_run_row("a", 0.2, 0.10, "semi-mass", B=3.0), _run_row("a", 0.2, 0.11, "semi-mass", B=math.nan),
            _run_row("a", 0.2, 0.12, "semi-mass", B=5.0),
            _run_row("b", 1.0, 0.09, "semi-mass"), _run_row("b", 1.0, math.nan, "", status="failed"),
            _run_row("b", 1.0, 0.10, "mass")]
    a, b = combine_replicas(runs, 3)
    assert (a["label"], a["x"], a["replicas"]) == ("a", 0.2, 3)
    assert a["flow_rate"] == pytest.approx(0.11, rel=1e-12)
    assert a["flow_rate_sd"] == pytest.approx(0.01, rel=1e-9)  # ddof 1
    assert a["B_10"] == pytest.approx(4.0) and a["B_10_sd"] == pytest.approx(math.sqrt(2.0))  # NaN left out
    assert a["B_10_n"] == 2 and a["flow_rate_n"] == 3
    assert a["status"] == "3 of 3 done" and a["wall_time"] == 300.0 and a["n_measured"] == 3
    assert a["flow_pattern"] == "semi-mass" and a["bulk_density_sd"] == 0.0
    assert b["status"] == "2 of 3 done" and b["n_measured"] == 2
    assert b["flow_rate"] == pytest.approx(0.095) and b["flow_pattern"] == "semi-mass 1, mass 1"
    assert combine_replicas(runs, 1) is runs


def test_replicas_measurements_average_for_the_charts():
    """mean_measurements: same-shaped arrays averaged; B's error bars the s.d. over the fills;
    arrays that differ in shape (and text) the first fill's."""
    from cfddem.silo_thesis import mean_measurements

    def m(v, B, t):
        return {"profiles": {"depth": {"vy": np.array([v, 2 * v]), "B": np.array([B, math.nan]),
                                       "B_err": np.array([0.1, 0.1])}, "front": {"B": np.array([B, B])}},
                "centreline_series": {"time": np.arange(t)}, "flow_pattern": "semi-mass"}

    out = mean_measurements([m(1.0, 2.0, 3), m(3.0, 4.0, 3), m(5.0, 6.0, 4)])
    np.testing.assert_allclose(out["profiles"]["depth"]["vy"], [3.0, 6.0], rtol=1e-12)
    np.testing.assert_allclose(out["profiles"]["depth"]["B"][0], 4.0, rtol=1e-12)
    assert math.isnan(out["profiles"]["depth"]["B"][1])
    np.testing.assert_allclose(out["profiles"]["depth"]["B_err"][0], 2.0, rtol=1e-12)  # s.d. of 2, 4, 6
    np.testing.assert_allclose(out["profiles"]["front"]["B_err"], [2.0, 2.0], rtol=1e-12)
    np.testing.assert_array_equal(out["centreline_series"]["time"], np.arange(3))  # shapes differ: the first's
    assert out["flow_pattern"] == "semi-mass"
    one = m(1.0, 2.0, 3)
    assert mean_measurements([one]) is one and mean_measurements([]) is None


def test_replicated_study_tables_read_mean_plus_minus_sd(tmp_path):
    import csv

    from cfddem.silo_thesis import combine_replicas, write_study

    runs = [_run_row("front/back mu 0.2", 0.2, f, "semi-mass") for f in (0.10, 0.11, 0.12)]
    for t, s in zip(runs, (6, 7, 8)):
        t["seed"] = s
    table = combine_replicas(runs, 3)
    files = write_study("front-back", table, tmp_path, ["note"], runs)
    assert {f.name for f in files} >= {"front-back.csv", "front-back_runs.csv", "front-back.md"}
    md = (tmp_path / "front-back.md").read_text()
    assert "| front/back mu 0.2 | 0.110 ± 0.010 | 550 ± 0 | semi-mass |" in md
    from cfddem.silo_thesis import _pm

    assert _pm({"v": 0.11327, "v_sd": 0.001955}, "v", "{:.4g}") == "0.1133 ± 0.0020"
    assert _pm({"v": 586.7, "v_sd": 30.06}, "v", "{:.4g}") == "587 ± 30"
    assert _pm({"v": 76.2, "v_sd": 1.4e-14}, "v", "{:.3g}") == "76.2 ± 0"
    assert _pm({"v": 15.5, "v_sd": math.nan}, "v", "{:.3g}") == "15.5 (one fill)"
    assert _pm({"v": 0.12492615, "v_sd": 1.3e-7}, "v", "{:.2f}") == "0.12 ± 0"
    assert _pm({"v": 0.172, "v_sd": 0.017}, "v", "{:.2f}") == "0.172 ± 0.017"
    assert _pm({"v": 20.4, "v_sd": 2.2, "v_n": 2, "replicas": 3}, "v", "{:.3g}") == "20.4 ± 2.2 (2 fills)"
    assert _pm({"v": 20.4, "v_sd": 2.2, "v_n": 3, "replicas": 3}, "v", "{:.3g}") == "20.4 ± 2.2"
    assert "| 3 of 3 done | 300 |" in md  # the wall time summed over the fills
    row, = csv.DictReader(open(tmp_path / "front-back.csv"))
    assert float(row["flow_rate"]) == pytest.approx(0.11) and float(row["flow_rate_sd"]) == pytest.approx(0.01)
    assert row["replicas"] == "3" and row["n_measured"] == "3"
    each = list(csv.DictReader(open(tmp_path / "front-back_runs.csv")))
    assert [r["seed"] for r in each] == ["6", "7", "8"]
    assert [float(r["flow_rate"]) for r in each] == [0.10, 0.11, 0.12]


def test_swept_chart_draws_the_replicas_error_bars(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from cfddem.silo_thesis import swept_panel

    fig, a = plt.subplots()
    ts = [{"label": "a", "x": 0.2, "flow_rate": 0.11, "flow_rate_sd": 0.01},
          {"label": "b", "x": 1.0, "flow_rate": 0.10, "flow_rate_sd": 0.002}]
    per = [{"label": "p", "x": math.nan, "flow_rate": 0.12, "flow_rate_sd": 0.003}]
    swept_panel(a, "front-back", {"walls": ts, "periodic": per}, {"a": "C0", "b": "C1", "p": "C2"}, "flow_rate",
                1e3, "g/s", "flow", "t")
    bars, = a.containers
    seg = bars.lines[2][0].get_segments()
    np.testing.assert_allclose([s[:, 1] for s in seg], [[100.0, 120.0], [98.0, 102.0]], rtol=1e-12)
    lo, hi = a.get_ylim()
    assert lo <= 98.0 and hi >= 123.0  # the bars and the periodic band fit on the axis
    assert any("120 ± 3" in t.get_text() for t in a.get_legend().get_texts())
    plt.close(fig)


def test_mean_sd_of_replicas_leaves_out_what_is_not_a_finite_number():
    from cfddem.measure.stats import mean_sd

    m, sd, n = mean_sd([1.0, np.float64(3.0), math.nan, None, "semi-mass", np.int64(5)])
    assert (m, n) == (3.0, 3) and sd == pytest.approx(2.0, rel=1e-12)
    assert mean_sd([4.0])[0] == 4.0 and math.isnan(mean_sd([4.0])[1])
    assert mean_sd([math.nan])[2] == 0 and math.isnan(mean_sd([])[0])


def test_floor_speed_charts_put_the_swept_speeds_on_a_log_axis(tmp_path, saved_figures):
    """The floor-speed study's mobilised chart: log x axis, ticks at the speeds as plain numbers."""
    from cfddem.silo_thesis import plot_mobilised

    row = {"share_front_back": 56.0, "share_sides": 10.0, "share_floor": 34.0, "mobilised_front_back": 0.32,
           "mobilised_sides": 0.13, "stress_low": 230.0, "hydrostatic_low": 650.0, "janssen_low": 193.0,
           "janssen_low_K": 95.0}
    table = [dict(row, x=v) for v in (25.0, 1.0, 5.0)]
    path = plot_mobilised("floor-speed", table, tmp_path)
    assert path.name == "floor-speed_mobilised.png" and path.stat().st_size > 1000
    for a in saved_figures[0].axes:
        assert a.get_xscale() == "log"
        np.testing.assert_array_equal(a.get_xticks(), [1.0, 5.0, 25.0])
        assert [t.get_text() for t in a.get_xticklabels()] == ["1", "5", "25"]
        assert "mm/s" in a.get_xlabel()
