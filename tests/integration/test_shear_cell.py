"""Short Jenike shear-cell runs (a 40 mm cell, ~350 spheres or pellets, soft contacts): the lid
load is held within 1 %, the results contract, restart bit-identical with the lid clump, the
wall-friction variant; bulk friction from a synthetic series; case errors."""

import math

import numpy as np
import pytest

from cfddem.config import load_case
from cfddem.errors import CaseError
from cfddem.io.results import read_measurements, read_series
from cfddem.measure.shear import bulk_friction, inertial_number, lid_disc
from cfddem.simulation import Simulation

CASE = """
[time]
end_time = 1.0
dt = 1e-5
threads = 1
[output]
series_interval = 0.005
snapshot_interval = 0.5
vtk = false
plots = false
[gravity]
g = 9.81
[particles]
diameter = 0.004
density = 1000.0
seed = 5
clump = "{clump}"
[contact.particle_particle]
k_n = 5000.0
e_n = 0.5
e_t = 0.5
mu = 0.5
[contact.particle_wall]
k_n = 5000.0
e_n = 0.5
e_t = 0.5
mu = 0.3
[geometry]
type = "shear_cell"
[shear]
variant = "{variant}"
cell_diameter = 0.04
base_height = 0.008
ring_height = 0.014
ring_offset = 0.002
wall_thickness = 0.003
normal_stress = 2000.0
load_ramp_time = 0.02
shear_speed = 0.05
shear_distance = 0.002
n_particles = {n}
fill_time = 0.08
settle_energy = 2e-8
consolidate_time = 0.04
lid_settle_speed = 0.002
sample_interval = 0.002
check_steps = 20
[shear.plate]
mu = 0.2
"""


def _run(write_case, tmp_path, name, clump="none", variant="bulk", n=330, extra="", **kw):
    d = write_case(CASE.format(clump=clump, variant=variant, n=n) + extra, name=name)
    out = tmp_path / f"{name}_out"
    summary = Simulation(load_case(d), out, echo=False, progress=False, **kw).run()
    return summary, out


def test_short_shear_holds_the_lid_load_and_stores_the_contract(write_case, tmp_path, one_numba_thread):
    summary, out = _run(write_case, tmp_path, "bulk")
    assert summary.status == "done" and "shear complete" in summary.message
    m = read_measurements(out / "results.h5")
    sh = m["shear"]
    # the particles' time-averaged vertical force on the lid equals the target load to 1 %
    assert abs(float(sh["load_error"])) < 0.01
    target = 2000.0 * math.pi * 0.02**2
    assert np.allclose(sh["load_target"], target, rtol=1e-12)
    assert abs(np.mean(sh["normal_force"]) / target - 1.0) < 0.01
    mu = float(m["bulk_friction"])
    assert 0.1 < mu < 1.2
    # bulk friction is the stored series' ratio over the second half of the travel
    r = bulk_friction(sh["displacement"], sh["shear_force"], sh["normal_force"] + sh["weight_above"], 0.002)
    assert r["mu"] == pytest.approx(mu, rel=1e-12)
    assert sh["displacement"][-1] == pytest.approx(0.002, abs=0.05 * 0.002)
    s = read_series(out / "results.h5")
    for k in ("shear_force", "shear_displacement", "normal_force", "lid_height", "lid_tilt_deg"):
        assert k in s and np.all(np.isfinite(s[k]))
    assert np.all(np.diff(s["shear_displacement"]) >= -1e-15)
    assert s["shear_displacement"].max() == pytest.approx(0.002, rel=0.05)
    assert np.max(s["lid_tilt_deg"]) < 10.0


def test_pellets_fill_and_restart_is_bit_identical(write_case, tmp_path, one_numba_thread):
    extra = "\n[checkpoint]\nevery_steps = 9000\n"
    ref, out_ref = _run(write_case, tmp_path, "ref", clump="pellet2", n=150, extra=extra)
    assert ref.status == "done"
    d = write_case(CASE.format(clump="pellet2", variant="bulk", n=150) + extra, name="part")
    part = Simulation(load_case(d, overrides=["time.max_steps=13000"]), tmp_path / "part_out", echo=False,
                      progress=False).run()
    assert part.status == "stopped"
    res = Simulation(load_case(d), tmp_path / "part_out", resume=True, echo=False, progress=False).run()
    assert res.status == "done" and res.steps == ref.steps
    a, b = read_series(out_ref / "results.h5"), read_series(tmp_path / "part_out" / "results.h5")
    for k in ("shear_force", "normal_force", "lid_height", "kinetic_energy"):
        assert np.array_equal(a[k], b[k]), k
    ma, mb = read_measurements(out_ref / "results.h5"), read_measurements(tmp_path / "part_out" / "results.h5")
    assert float(ma["bulk_friction"]) == float(mb["bulk_friction"])


def test_synthetic_series_bulk_friction():
    x = np.linspace(0.0, 0.006, 61)
    N = np.full_like(x, 28.0)
    S = np.where(x < 0.002, 14.0 * x / 0.002, 11.2)  # peak-free ramp then steady 0.4 N
    r = bulk_friction(x, S, N, 0.006)
    assert r["mu"] == pytest.approx(0.4, rel=1e-12)
    assert r["n_samples"] == 31 and r["window"] == (0.003, 0.006)
    r = bulk_friction(x, S, N, 0.006, window=(0.0, 1.0))
    assert r["mu"] == pytest.approx(np.mean(S) / 28.0, rel=1e-12)
    assert math.isnan(bulk_friction([], [], [], 0.006)["mu"])
    with pytest.raises(ValueError):
        bulk_friction(x, S[:-1], N, 0.006)
    assert inertial_number(0.003, 0.004, 4000.0, 1000.0) == pytest.approx(0.003 / 0.04 * 0.004 / 2.0)


def test_lid_disc_fits_and_touches():
    c = lid_disc(0.02, 0.002)
    assert np.max(np.hypot(c[:, 0], c[:, 2])) <= 0.018 + 1e-12
    d = np.linalg.norm(c[:, None] - c[None], axis=2) + np.eye(len(c))
    assert d.min() == pytest.approx(0.004, rel=1e-12)
    assert len(c) >= 0.75 * (0.018 / 0.002) ** 2  # hexagonal packing fills the disc


@pytest.mark.parametrize("key,value", [
    ("shear.cell_diameter", 0.03), ("shear.ring_offset", 0.02), ("shear.steady_window", [0.8, 0.2]),
    ("shear.ring_height", 0.005), ("gravity.inclination_deg", 10.0), ("frame.rpm", 5.0),
    ("particles.diameter_max", 0.005), ("shear.variant", "ring"), ("shear.fill_friction", -0.5),
])
def test_case_errors_name_the_key(write_case, key, value):
    d = write_case(CASE.format(clump="none", variant="bulk", n=300), name="bad")
    with pytest.raises(CaseError) as e:
        load_case(d, overrides=[f"{key}={value!r}".replace("'", '"')])
    assert e.value.key == key


def test_clump_key_outside_the_shear_cell_is_refused(write_case):
    d = write_case("[geometry]\ntype = 'box'\n[particles]\nclump = 'pellet2'\n", name="box")
    with pytest.raises(CaseError) as e:
        load_case(d)
    assert e.value.key == "particles.clump"


def test_wall_friction_variant(write_case, tmp_path, one_numba_thread):
    summary, out = _run(write_case, tmp_path, "wall", variant="wall", n=200)
    assert summary.status == "done"
    m = read_measurements(out / "results.h5")
    mu_w = float(m["wall_friction"])
    # the plate carries the whole sample: the tangential force it takes cannot exceed mu = 0.2 times
    # its normal force (spheres without rolling friction also roll on it: below mu, above zero)
    assert 0.005 < mu_w <= 0.2 * 1.05
    assert abs(float(m["shear"]["load_error"])) < 0.01


def test_fill_rolling_friction_packs_a_high_rolling_friction_fill_denser(write_case, tmp_path, one_numba_thread):
    """``shear.fill_rolling_friction``: with the case's rolling friction mu_r = 0.5 the fill
    stays loose (solid fraction 0.30); filled at mu_r = 0 (same lattice and sliding friction) it
    settles at 0.55; the case's mu_r holds from the scraping on and the fill's value is recorded."""
    from cfddem.particles.contact import P_MUR

    d = write_case(CASE.format(clump="none", variant="bulk", n=330), name="fr")
    phi = {}
    for fr in (-1.0, 0.0):
        out = tmp_path / f"fr{fr}"
        sim = Simulation(load_case(d, overrides=["contact.particle_particle.mu_r=0.5", f"shear.fill_rolling_friction={fr}",
                                                 "shear.shear_distance=0.0005"]), out, echo=False, progress=False)
        assert sim.run().status == "done"
        sh = read_measurements(out / "results.h5")["shear"]
        phi[fr] = float(sh["fill_solid_fraction"])
        assert float(sh["fill_rolling_friction"]) == (0.5 if fr < 0 else 0.0)
        assert float(sh["fill_friction"]) == 0.5
        assert np.all(sim.system._pp_params[:, P_MUR] == 0.5)
    # measured: 0.30 with the case's mu_r = 0.5, 0.55 filled at mu_r = 0
    assert 0.50 < phi[0.0] < 0.64
    assert phi[-1.0] < phi[0.0] - 0.1


def test_fill_friction_packs_denser_and_holds_only_until_the_scraping(write_case, tmp_path, one_numba_thread):
    """``shear.fill_friction``: a frictionless fill of the same lattice settles denser than one
    at the case's mu = 0.5 (measured: solid fraction 0.59 against 0.54-0.55 over seeds 5 and 6);
    the case's friction holds from the scraping on; a run stopped during the fill and resumed is
    bit-identical to the straight run (the fill friction is set again at the resume)."""
    from cfddem.particles.contact import P_MU

    extra = "\n[checkpoint]\nevery_steps = 100000\n"
    d = write_case(CASE.format(clump="none", variant="bulk", n=330) + extra, name="ff")
    phi = {}
    for ff in (-1.0, 0.0):
        sim = Simulation(load_case(d, overrides=[f"shear.fill_friction={ff}"]), tmp_path / f"ff{ff}", echo=False,
                         progress=False)
        assert sim.run().status == "done"
        sh = read_measurements(tmp_path / f"ff{ff}" / "results.h5")["shear"]
        phi[ff] = float(sh["fill_solid_fraction"])
        assert float(sh["fill_friction"]) == (0.5 if ff < 0 else 0.0)
        assert np.all(sim.system._pp_params[:, P_MU] == 0.5)  # the case's friction after the scraping
        assert 0.50 < phi[ff] < 0.64
        assert abs(float(sh["load_error"])) < 0.01
    assert phi[0.0] > phi[-1.0] + 0.025
    ref = read_series(tmp_path / "ff0.0" / "results.h5")
    part = Simulation(load_case(d, overrides=["shear.fill_friction=0.0", "time.max_steps=3000"]), tmp_path / "part",
                      echo=False, progress=False)
    assert part.run().status == "stopped"
    res = Simulation(load_case(d, overrides=["shear.fill_friction=0.0"]), tmp_path / "part", resume=True, echo=False,
                     progress=False)
    assert res.run().status == "done"
    b = read_series(tmp_path / "part" / "results.h5")
    for k in ("shear_force", "normal_force", "kinetic_energy"):
        assert np.array_equal(ref[k], b[k]), k
    assert float(read_measurements(tmp_path / "part" / "results.h5")["shear"]["fill_solid_fraction"]) == phi[0.0]
