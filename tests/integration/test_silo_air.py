"""The silo with air (cases/silo_air, issue #17): a tiny run builds the gas on the silo's
domain (patched bottom: plates and a slot outlet), runs gas steps with a bounded mass-balance
defect and writes the gas measurements; `cfddem check` passes; a hopper is refused."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cfddem.config import load_case
from cfddem.errors import CaseError
from cfddem.gas import Patched
from cfddem.io.results import read_measurements, read_series
from cfddem.simulation import Simulation

ROOT = Path(__file__).resolve().parents[2]
CASE = ROOT / "cases" / "silo_air"

pytestmark = pytest.mark.usefixtures("one_numba_thread")


def test_silo_air_short_run(tmp_path):
    ov = ["silo.n_particles=200", "time.end_time=0.08", 'silo.gate="time"', "silo.gate_time=0.03",
          "output.vtk=false", "output.plots=false", "time.threads=1", "study.compare_without_gas=false",
          "checkpoint.wall_interval=0", "output.series_interval=0.002", "silo.field_start=0.005"]
    case = load_case(CASE, overrides=ov)
    sim = Simulation(case, tmp_path / "run", overwrite=True, echo=False, progress=False, threads=1)
    s = sim.run()
    assert s.status == "done", s.message
    bc = sim.gas.gas.bc
    assert isinstance(bc.bcs["y-"], Patched) and bc.particle_rules[2] == "leave"
    # the slot is the two middle cells across (x 9...15 mm), over the whole depth
    solved = bc.cell_mask("y-", "normal_rule", "solved")
    assert np.array_equal(np.flatnonzero(solved[:, 0]), [3, 4]) and solved.all(axis=1)[[3, 4]].all()
    ser = read_series(tmp_path / "run" / "results.h5")
    assert ser["gas_pressure_iterations"].max() >= 1
    assert np.nanmax(ser["gas_max_divergence"]) < 1e-9
    assert ser["discharged_mass"][-1] > 0  # beads left through the slot after the gate opened at 0.03 s
    gas = sim.gas.gas
    assert sim.gas.n_couplings == pytest.approx(0.08 / (10 * 1.8e-5), abs=2)
    # no flow through the plates; the slot's boundary pressure is the hydrostatic value at y = 0
    v = gas.v.interior
    assert np.all(v[[0, 1, 2, 5, 6, 7], 0, :] == 0.0)
    g = gas.grid.halo
    pb = 0.5 * (gas.p.data[g + 3:g + 5, g - 1, g:-g] + gas.p.data[g + 3:g + 5, g, g:-g])
    assert np.allclose(pb, 1.2 * 9.81 * 0.030, rtol=1e-12)
    meas = read_measurements(tmp_path / "run" / "results.h5")
    assert meas["gas"]["mean_velocity"].shape == (8, 10, 2, 3)
    assert "mass_flow_rate" in meas and "silo" in meas
    # the outlet budget (blocks every field_interval from the gate opening): the air's volume
    # flows obey the porous continuity equation, q_slot - q_top = d(air volume)/dt, to the
    # pressure solve's tolerance; the air volume grows by the beads' volume leaving the gas
    o = meas["silo"]["outlet"]
    b = o["blocks"]
    assert len(b["t_end"]) >= 5 and b["t_start"][0] == pytest.approx(meas["silo"]["gate_open_time"])
    v_bead = np.pi / 6 * 0.001 ** 3
    dv = np.diff(b["air_volume"])
    assert np.allclose(dv, ((b["q_slot"] - b["q_top"]) * b["duration"])[1:], rtol=0, atol=1e-6 * v_bead)
    assert b["air_volume"][-1] - b["air_volume"][0] > 0.5 * v_bead
    # the weight in each half-disc is its sampled bead count times m g; the largest (2 b = 12 mm)
    # holds more beads than the smallest; the air's forces are finite
    m_bead = 2500.0 * v_bead
    assert np.allclose(b["weight"], b["count"] * m_bead * 9.81, rtol=1e-12)
    assert np.all(b["count"][:, 2] >= b["count"][:, 0]) and b["count"][:, 2].max() > 0
    assert np.all(np.isfinite(b["drag"])) and np.all(np.isfinite(b["pressure"]))


def test_silo_air_check_and_hopper_refused():
    p = subprocess.run([sys.executable, "-m", "cfddem.cli", "check", str(CASE)], capture_output=True, text=True,
                       cwd=ROOT)
    assert p.returncode == 0, p.stderr
    assert "slot outlet p = 0.353 Pa over 2 cells across" in p.stdout
    with pytest.raises(CaseError, match="gas.enabled.*flat-bottom"):
        load_case(CASE, overrides=["silo.hopper_angle_deg=60", "silo.height=0"])


def test_check_uses_the_silo_gas_grid():
    """cfddem check's gas numbers come from the silo's own gas domain (3 mm cells), not from the
    chute's geometry keys: the cell Reynolds number of the Courant line and the recommended
    coupling interval."""
    import re

    from cfddem.scenes import scene_of
    from cfddem.simulation import describe_case, expected_max_speed, recommended_coupling_interval

    case = load_case(CASE)
    dom = scene_of(case).gas_domain(case)
    h = min(dom.grid.spacing)
    assert h == pytest.approx(0.003, rel=1e-12)
    re_h = case.gas.density * expected_max_speed(case) * h / case.gas.viscosity
    line = next(x for x in describe_case(case) if "cell Reynolds number" in x)
    assert float(re.search(r"cell Reynolds number ([0-9.e+]+)", line).group(1)) == pytest.approx(re_h, rel=5e-3)
    assert recommended_coupling_interval(case, domain=dom) == recommended_coupling_interval(case)
