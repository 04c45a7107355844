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
