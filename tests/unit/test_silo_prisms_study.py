"""cfddem.silo_prisms without running a silo: the tangential damping -> e_t conversion, the Wilson
interval, and the tables and charts written from sweep rows."""

import csv
import math

import pytest

from cfddem.particles.contact import LinearContact
from cfddem.silo_prisms import clogging_study, e_t_for_damping, silos_study, summarise, wilson

M = 450.0 * math.pi / 6 * 0.02 ** 3


@pytest.mark.parametrize("gamma", [0.0, 3.0, 30.0, 100.0])
@pytest.mark.parametrize("m_eff", [0.5 * M, M])
def test_e_t_gives_the_tangential_damping_per_unit_mass(gamma, m_eff):
    e_t = e_t_for_damping(gamma, m_eff, 6.5e5)
    law = LinearContact(k_n=1e7, e_n=0.5, e_t=e_t, mu=0.38, k_t_ratio=0.065)
    assert law.derived(m_eff)["eta_t"] == pytest.approx(gamma * m_eff, rel=1e-9, abs=1e-15)
    assert (e_t == 1.0) == (gamma == 0.0)


def test_wilson_interval():
    assert wilson(0, 5) == pytest.approx((0.0, 0.4345), abs=1e-4)  # 0 of n: upper z^2/(n + z^2), z = 1.96
    assert wilson(5, 5) == pytest.approx((0.5655, 1.0), abs=1e-4)
    lo, hi = wilson(2, 4)
    assert lo == pytest.approx(1 - hi, abs=1e-12) and 0.15 < lo < 0.2


def row(angle, b, seed, duration, clogged, left=0):
    return {"values": {"silo.hopper_angle_deg": angle, "silo.outlet_width": b, "particles.seed": seed},
            "status": "done", "wall_time": 10.0, "n_particles": left,
            "measurements": {"silo/discharge_duration": duration, "clogged": clogged, "bulk_density": 500.0,
                             "mass_flow_rate": 10.0 * (b - 0.02) ** 1.5}}  # Beverloo with k = 1


def test_tables_and_charts_from_sweep_rows(tmp_path):
    rows = [row(60.0, 0.15, 1, 1.0, 0), row(60.0, 0.15, 2, 1.2, 0),
            row(60.0, 0.04, 1, 0.3, 1, 250), row(60.0, 0.04, 2, 2.5, 0),
            row(0.0, 0.04, 1, 0.1, 1, 290), row(0.0, 0.04, 2, math.nan, 1, 300)]  # clogged before any left
    s = summarise([{"duration": 1.0, "clogged": 0, "ok": True, "wall": 1.0, "left": 0, "rate": 0.5, "rho_b": 1.0},
                   {"duration": 1.2, "clogged": 0, "ok": True, "wall": 1.0, "left": 0, "rate": 0.7, "rho_b": 1.0}])
    assert s["rate"] == pytest.approx(0.6) and s["t_mean"] == pytest.approx(1.1) and s["t_std"] == pytest.approx(0.1414, rel=1e-3)
    files = silos_study(rows, tmp_path, 0.02)
    assert [f.name for f in files] == ["silos.csv", "silos.md", "silos.png"]
    assert all(f.stat().st_size > 0 for f in files)
    table = list(csv.DictReader(open(tmp_path / "silos.csv")))
    t = {(float(r["angle"]), float(r["b_mm"])): r for r in table}
    assert float(t[(60.0, 150.0)]["t_mean"]) == pytest.approx(1.1)
    assert float(t[(60.0, 40.0)]["t_mean"]) == pytest.approx(2.5)  # the clogged run is not a discharge time
    assert int(t[(60.0, 40.0)]["clogged"]) == 1 and t[(0.0, 40.0)]["t_mean"] == "nan"
    assert int(t[(0.0, 40.0)]["clogged"]) == 2  # a clog before any particle left counts
    assert "hopper 60 deg: Beverloo fit to 2 outlets: C = " in (tmp_path / "silos.md").read_text()
    assert ", k = 1 (" in (tmp_path / "silos.md").read_text()
    clogging_study(rows, tmp_path, 0.02)
    c = {(float(r["angle"]), float(r["b_mm"])): r for r in csv.DictReader(open(tmp_path / "clogging.csv"))}
    assert float(c[(60.0, 40.0)]["clog_freq"]) == 0.5 and float(c[(0.0, 40.0)]["clog_freq"]) == 1.0
    assert float(c[(0.0, 40.0)]["wilson_lo"]) == pytest.approx(0.3424, abs=1e-4)  # 2 of 2
    assert (tmp_path / "clogging.png").stat().st_size > 0
