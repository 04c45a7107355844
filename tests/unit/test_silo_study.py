"""The Beverloo study's table, fit and files from sweep rows (synthetic flow rates), and its
input errors."""

import math

import numpy as np
import pytest

from cfddem.errors import CaseError
from cfddem.measure.silo import beverloo_rate
from cfddem.silo_study import beverloo_table, run_beverloo_study, write_beverloo_outputs


def rows_for(widths, C=0.6, k=1.4, rho_b=560.0, L=0.04, d=0.0038, clog=()):
    rows = []
    for b in widths:
        W = float(beverloo_rate(b, C, k, rho_b, L, d))
        rows.append({"values": {"silo.outlet_width": b}, "status": "done",
                     "measurements": {"mass_flow_rate": math.nan if b in clog else W,
                                      "bulk_density": rho_b * (1 + 0.01 * (b - 0.02) / 0.02),
                                      "clogged": 1 if b in clog else 0}})
    return rows


def test_table_fit_and_files(tmp_path):
    widths = [0.03, 0.0076, 0.012, 0.016, 0.02, 0.025]
    rows = rows_for(widths, clog=(0.0076,))
    st = beverloo_table(rows, None, 0.04, 0.0038, 9.81)
    assert [t["outlet_width"] for t in st["table"]] == sorted(widths)
    assert st["n_fitted"] == 5 and st["table"][0]["clogged"] == 1
    rho_mean = np.mean([r["measurements"]["bulk_density"] for r in rows])
    assert st["rho_b"] == pytest.approx(rho_mean)
    # rho_b differs slightly from the generating 560: C absorbs the ratio, k is unchanged
    assert st["fit"]["C"] == pytest.approx(0.6 * 560.0 / rho_mean, rel=1e-4)
    assert st["fit"]["k"] == pytest.approx(1.4, abs=1e-3)
    assert all(abs(t["deviation"]) < 1e-3 for t in st["table"] if not t["clogged"])
    files = write_beverloo_outputs(st, tmp_path)
    names = sorted(p.name for p in files)
    assert names == ["beverloo.csv", "beverloo.md", "beverloo.png"]
    text = (tmp_path / "beverloo.csv").read_text().splitlines()
    assert text[0].startswith("# rho_b = ") and text[1].startswith("# C = ")
    assert text[2] == "outlet_width,mass_flow_rate,bulk_density,clogged,status,beverloo_rate,deviation"
    assert len(text) == 3 + len(widths)
    md = (tmp_path / "beverloo.md").read_text()
    assert "| 7.6 | - |" in md and "| 30 |" in md
    assert (tmp_path / "beverloo.png").stat().st_size > 5000


def test_no_fit_with_a_single_flowing_width(tmp_path):
    st = beverloo_table(rows_for([0.0076, 0.02], clog=(0.0076,)), None, 0.04, 0.0038, 9.81)
    assert st["fit"] is None and st["n_fitted"] == 1
    write_beverloo_outputs(st, tmp_path)
    assert "no fit" in (tmp_path / "beverloo.csv").read_text()


def test_study_input_errors(root):
    with pytest.raises(CaseError) as e:
        run_beverloo_study(root / "cases" / "silo_flat", [0.02])
    assert e.value.key == "--widths"
    with pytest.raises(CaseError) as e:
        run_beverloo_study(root / "cases" / "silo_flat", [0.02, -0.01])
    assert e.value.key == "--widths"
    with pytest.raises(CaseError) as e:
        run_beverloo_study(root / "cases" / "box_small", [0.02, 0.03])
    assert e.value.key == "geometry.type"


def test_silo_plots_from_a_results_file(tmp_path):
    from cfddem.io.results import ResultsFile
    from cfddem.measure.silo import VelocityField, channel_boundary
    from cfddem.silo_study import write_silo_plots

    f = VelocityField(0.0, 0.06, 0.0, 0.04, 0.005)
    rng = np.random.default_rng(2)
    pos = np.column_stack([rng.uniform(0, 0.06, 500), rng.uniform(0, 0.04, 500), np.zeros(500)])
    vel = np.column_stack([np.zeros(500), -np.exp(-((pos[:, 0] - 0.03) / 0.01) ** 2), np.zeros(500)])
    f.sample(pos, vel)
    vx, vy = f.mean()
    ch = channel_boundary(vy, f.x, 0.03)
    t = np.linspace(0, 1, 101)
    with ResultsFile(tmp_path / "results.h5", mode="w") as res:
        res.write_measurements(None, {
            "mass_flow_rate": 0.02, "bulk_density": 550.0, "clogged": 0,
            "silo": {"discharge_time": t, "discharge_mass": 0.02 * t, "fit_window": np.array([0.2, 0.8, 0.004, 0.016]),
                     "field": {"x": f.x, "y": f.y, "vx": vx, "vy": vy, "count": f.count},
                     "channel": {"y": f.y, "x_left": ch["x_left"], "x_right": ch["x_right"], "fraction": 0.1}}})
    files = write_silo_plots(tmp_path / "results.h5", tmp_path / "plots")
    assert [p.name for p in files] == ["silo_discharge.png", "silo_field.png"]
    assert all(p.stat().st_size > 5000 for p in files)
