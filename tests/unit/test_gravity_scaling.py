"""The gravity-scaling reader (cfddem/gravity_scaling.py) on synthetic silo run folders whose
answers are known: a discharge that scales exactly with sqrt(g), a plug-flow field, a fill
lattice with a known overlap and bulk density."""

import csv
import math

import numpy as np
import pytest

from cfddem.errors import CaseError
from cfddem.gravity_scaling import main, run_quantities
from cfddem.io.results import ResultsFile

D = 0.004
S = 0.99 * D  # lattice spacing: every neighbour pair overlaps by 0.01 d = 0.02 R
B = 2 * D + 10 * S  # the bulk-density box |x - xc| <= b/2 - d is then 10 lattice columns wide
WIDTH, DEPTH = 0.15, 5 * S
H = 6 * D + 8 * S  # the box y in [3 d, H - 3 d] is 8 rows high
RHO_P = 950.0
C_W = 0.1  # W = C_W sqrt(g)
C_T = 0.2  # T = C_T / sqrt(g)
A_V = 0.5  # vy = -A_V sqrt(g d)
DT = 3e-6


def _lattice():
    xc = 0.5 * WIDTH
    xs = xc - 5 * S + (np.arange(-2, 12) + 0.5) * S
    ys = 3 * D + (np.arange(-3, 10) + 0.5) * S
    zs = (np.arange(5) + 0.5) * S
    X, Y, Z = np.meshgrid(xs, ys, zs, indexing="ij")
    return np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)


def _write_run(folder, g, seed=1):
    folder.mkdir(parents=True)
    t_gate = 0.3 / math.sqrt(g / 9.81)
    W, T = C_W * math.sqrt(g), C_T / math.sqrt(g)
    t = t_gate + T * np.linspace(0.0, 1.5, 31)  # T falls on record 20
    m = np.minimum(W * (t - t_gate), W * T)
    x = (np.arange(30) + 0.5) * WIDTH / 30
    y = (np.arange(20) + 0.5) * H / 20
    vy = np.full((20, 30), -A_V * math.sqrt(g * D))
    resolved = {"gravity": {"g": g}, "particles": {"diameter": D, "density": RHO_P, "seed": seed},
                "time": {"dt": DT}, "silo": {"width": WIDTH, "outlet_width": B, "depth": DEPTH},
                "contact": {"model": "hertz_mindlin",
                            "particle_particle": {"E": 1e8, "nu": 0.4, "e": 1e-4, "mu": 0.3}}}
    pos = _lattice()
    with ResultsFile(folder / "results.h5", mode="w") as res:
        res.write_config("", resolved)
        res.write_snapshot(0.0, 0, pos=pos, radius=np.full(len(pos), 0.5 * D))
        res.write_snapshot(t_gate, 100, pos=pos, radius=np.full(len(pos), 0.5 * D))
        res.write_snapshot(t_gate + 0.5 * T, 200, pos=pos, radius=np.full(len(pos), 0.1 * D))  # after the gate
        for ti, ov in ((0.0, 0.5), (t_gate, 0.01), (t_gate + T, 0.03)):
            res.append_series(ti, max_overlap_ratio=ov)
        res.write_measurements(None, {
            "mass_flow_rate": W, "bulk_density": math.nan, "clogged": 0,
            "silo": {"discharge_time": t, "discharge_mass": m, "gate_open_time": t_gate, "fill_height": H,
                     "field": {"x": x, "y": y, "vx": np.zeros_like(vy), "vy": vy, "count": np.ones_like(vy)}}})


@pytest.fixture
def sweep(tmp_path):
    for g, seed in ((9.81, 1), (9.81, 2), (490.5, 1)):
        _write_run(tmp_path / "sweep" / f"g{g}_s{seed}", g, seed)
    return tmp_path / "sweep"


def test_one_run_gives_the_known_numbers(sweep):
    q = run_quantities(sweep / "g490.5_s1")
    g = 490.5
    assert q["W"] == pytest.approx(C_W * math.sqrt(g), rel=1e-12)
    assert q["W_sqrt_g"] == pytest.approx(C_W, rel=1e-12)
    assert q["T"] == pytest.approx(C_T / math.sqrt(g), rel=1e-9)
    assert q["T_sqrt_g"] == pytest.approx(C_T, rel=1e-9)
    assert q["steps_discharge"] == pytest.approx(C_T / math.sqrt(g) / DT, rel=1e-9)
    # the fill snapshot is the one at the gate (not the later one with other radii)
    assert q["mean_overlap"] == pytest.approx(0.02, rel=1e-6)
    assert q["max_overlap"] == pytest.approx(0.02, rel=1e-6)
    assert q["fill_n_in_box"] == 400
    assert q["bulk_density"] == pytest.approx(RHO_P * math.pi / 6 * (D / S) ** 3, rel=1e-9)
    assert q["max_overlap_discharge"] == pytest.approx(0.03)  # the series after the gate only
    for p in q["profiles"].values():
        np.testing.assert_allclose(p, -A_V, rtol=1e-12)
    assert q["pattern"] == "mass"
    # plug flow from 0.8 H at A_V sqrt(g d): one residence time 0.8 H / v, no spread
    assert q["t_mean"] == pytest.approx(0.8 * H / (A_V * math.sqrt(g * D)), rel=0.01)
    assert q["theta_var"] < 1e-4
    assert q["tracers"] == "200/200"


def test_collision_time_ratio_grows_as_g_to_the_two_fifths(sweep):
    lo, hi = run_quantities(sweep / "g9.81_s1"), run_quantities(sweep / "g490.5_s1")
    # Hertz t_c ~ v^(-1/5) with v = sqrt(g d); flow time sqrt(d / g)
    assert hi["t_c_over_t_flow"] / lo["t_c_over_t_flow"] == pytest.approx(50.0 ** 0.4, rel=1e-9)
    assert lo["t_mean_sqrt_g"] == pytest.approx(hi["t_mean_sqrt_g"], rel=0.02)


def test_command_writes_the_table_and_chart(sweep, tmp_path, capsys):
    assert main([str(sweep), "--out", str(tmp_path / "out")]) == 0
    rows = list(csv.DictReader((tmp_path / "out" / "gravity_scaling.csv").open()))
    assert [(float(r["g"]), int(r["seed"])) for r in rows] == [(9.81, 1), (9.81, 2), (490.5, 1)]
    assert all(float(r["W_sqrt_g"]) == pytest.approx(C_W) for r in rows)
    md = (tmp_path / "out" / "gravity_scaling.md").read_text()
    assert "| 9.81 | 1 | 2 (1,2) | mass |" in md and "| 490.5 | 50 | 1 (1) | mass |" in md
    assert (tmp_path / "out" / "gravity_scaling.png").stat().st_size > 20000
    assert "gravity_scaling.md" in capsys.readouterr().out


def test_a_folder_without_runs_is_one_line(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert main([str(tmp_path / "empty")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("cfddem: error: SWEEP_DIR:") and "\n" not in err
    with pytest.raises(CaseError):
        run_quantities(tmp_path / "empty")
