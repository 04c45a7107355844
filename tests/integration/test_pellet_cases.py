"""Pellets (``particles.clump``) in the silo: a short lattice-fill discharge (linear contact) and a
pour fill with Hertz-Mindlin contacts.  Counted in spheres and in bodies: present + discharged =
inserted at every series row, pellets leave whole (2 spheres per discharged body), mass
conserved to round-off, the discharged mass non-decreasing."""

import numpy as np
import pytest

from cfddem.config import load_case
from cfddem.errors import CaseError
from cfddem.io.results import read_series
from cfddem.particles.clumps import pellet
from cfddem.scenes.silo import SiloGeometry
from cfddem.simulation import Simulation

CASE = """
[time]
end_time = {end}
dt = 4e-5
threads = 1
[output]
series_interval = 0.01
snapshot_interval = 0.1
vtk = false
plots = false
[particles]
diameter = 0.0038
density = 950.0
seed = 3
clump = "pellet2"
[contact]
model = "{model}"
[contact.particle_particle]
k_n = 200.0
e_n = 0.7
mu = 0.3
mu_r = 0.02
E = 5e6
nu = 0.3
e = 0.7
[contact.particle_wall]
k_n = 200.0
e_n = 0.7
mu = 0.3
mu_r = 0.02
E = 5e6
nu = 0.3
e = 0.7
[geometry]
type = "silo"
[silo]
fill = "{fill}"
width = 0.04
depth = 0.012
outlet_width = 0.018
n_particles = 150
pour_rate = 0.5
gate = "time"
gate_time = 0.2
clog_time = 0.2
settle_check_interval = 0.01
field_start = 0.05
[silo.front_back]
mu = 0.1
"""

M = pellet(2, 0.0038, 950.0).mass


def run(write_case, tmp_path, name, fill, model, end):
    d = write_case(CASE.format(fill=fill, model=model, end=end), name=name)
    case = load_case(d)
    out = tmp_path / f"{name}_out"
    sim = Simulation(case, out, echo=False, progress=False)
    summary = sim.run()
    return sim, summary, read_series(out / "results.h5")


def check_bookkeeping(s):
    np.testing.assert_array_equal(s["mass_lost"], 0.0)
    # spheres: present + discharged = inserted; bodies: 2 spheres each, removed whole
    np.testing.assert_array_equal(s["n_particles"] + s["discharged_count"], s["inserted_count"])
    np.testing.assert_array_equal(s["inserted_count"], 2 * s["inserted_bodies"])
    np.testing.assert_array_equal(s["discharged_count"], 2 * s["discharged_bodies"])
    np.testing.assert_allclose(s["discharged_mass"], s["discharged_bodies"] * M, rtol=1e-12)
    np.testing.assert_allclose(s["mass_present"] + s["discharged_mass"], s["inserted_bodies"] * M, rtol=1e-12)
    assert np.all(np.diff(s["discharged_mass"]) >= 0.0)


def test_silo_lattice_fill_of_pellets_discharges_whole_pellets(write_case, tmp_path, one_numba_thread):
    sim, summary, s = run(write_case, tmp_path, "lattice", "lattice", "linear", 0.45)
    assert summary.status == "done"
    check_bookkeeping(s)
    assert np.all(s["inserted_bodies"] == 150)
    closed = s["time"] < 0.2 - 1e-9
    assert np.all(s["discharged_mass"][closed] == 0.0)
    # measured: 99 of 150 pellets out by 0.45 s (slot 4.7 d); require a real discharge
    assert s["discharged_bodies"][-1] >= 60
    # soft contacts (k_n = 200 N/m): measured max 0.16 at the end of the drop onto the bottom
    assert np.max(s["max_overlap_ratio"]) < 0.25
    c = sim.system.clumps
    assert sim.system.n == 2 * c.nb and c.nb == 150 - s["discharged_bodies"][-1]


def test_silo_pour_of_pellets_with_hertz_mindlin(write_case, tmp_path, one_numba_thread):
    sim, summary, s = run(write_case, tmp_path, "pour", "pour", "hertz_mindlin", 0.4)
    assert summary.status == "done"
    check_bookkeeping(s)
    assert np.all(np.diff(s["inserted_bodies"]) >= 0) and s["inserted_bodies"][-1] >= 40
    assert s["discharged_bodies"][-1] >= 10
    assert np.max(s["max_overlap_ratio"]) < 0.25


def test_silo_pellet_lattice_is_spaced_for_the_bounding_sphere_and_seeded():
    silo = dict(width=0.04, depth=0.012, outlet_width=0.018, hopper_angle_deg=0.0, lip=0.0, removal_depth=0.0,
                n_particles=60, lattice_gap=0.05, lattice_jitter=0.02, height=0.0, fill="lattice", pour_height=0.0)
    g = SiloGeometry(silo, 0.0038, 3, "pellet2", 950.0)
    assert g.d_site == pytest.approx(1.5 * 0.0038, rel=1e-6)
    p = g.lattice
    dd = np.linalg.norm(p[:, None] - p[None], axis=2) + np.eye(len(p))
    assert dd.min() >= g.d_site * (1 + 0.05 - 0.02) * (1 - 1e-12)  # spacing minus the jitter
    q1, q2 = g.orientations(-1, 60), SiloGeometry(silo, 0.0038, 3, "pellet2", 950.0).orientations(-1, 60)
    np.testing.assert_array_equal(q1, q2)
    assert not np.allclose(q1, g.orientations(0, 60))
    assert not np.allclose(q1, SiloGeometry(silo, 0.0038, 4, "pellet2", 950.0).orientations(-1, 60))


def test_clump_refused_where_nothing_inserts_pellets(write_case):
    text = """
[time]
end_time = 0.01
dt = 1e-5
[particles]
clump = "pellet2"
[[particles.initial]]
pos = [0.0, 0.01, 0.0]
radius = 0.0015
"""
    with pytest.raises(CaseError) as e:
        load_case(write_case(text, name="refused"))
    assert "particles.clump" in str(e.value)


CHUTE = """
[time]
end_time = 0.12
dt = 2e-5
threads = 1
[output]
series_interval = 0.01
snapshot_interval = 0.1
vtk = false
plots = false
[gravity]
g = 9.81
inclination_deg = 30.0
[particles]
diameter = 0.003
density = 2550.0
clump = "pellet4"
[contact.particle_particle]
k_n = 1000.0
e_n = 0.9
e_t = 0.33
mu = 0.12
[contact.particle_wall]
k_n = 1000.0
e_n = 0.9
e_t = 0.33
mu = 0.22
[geometry]
type = "chute"
width = 0.02
depth = 0.012
length = 0.12
z_start = -0.02
[inlet]
type = "sluice"
mass_rate = 0.05
height = 0.012
[measurements]
enabled = false
"""


def test_chute_exit_resume_is_bit_identical(write_case, tmp_path, one_numba_thread):
    """Pellets leave through the chute's exit (the engine's sink plane, at neighbour rebuilds)
    before and after a checkpoint: the resumed run ends with the same particles, the same
    counters and the same series as the run without a stop."""
    text = CHUTE.replace("end_time = 0.12", "end_time = 0.3") + "[checkpoint]\ninterval = 0.2\nwall_interval = 0.0\n"
    case = write_case(text, name="chute_exit")
    ref = Simulation(load_case(case), tmp_path / "ref", echo=False, progress=False)
    assert ref.run().status == "done"
    part = Simulation(load_case(case, overrides=["time.max_steps=12500"]), tmp_path / "part", echo=False,
                      progress=False)
    assert part.run().status == "stopped"
    res = Simulation(load_case(case), tmp_path / "part", resume=True, echo=False, progress=False)
    assert res.run().status == "done"
    sa, sb = read_series(tmp_path / "ref" / "results.h5"), read_series(tmp_path / "part" / "results.h5")
    at_ckpt = sa["mass_out"][np.argmin(np.abs(sa["time"] - 0.2))]
    assert 0.0 < at_ckpt < sa["mass_out"][-1]  # pellets left before the checkpoint and after it
    for k in ("time", "mass_out", "mass_in", "n_particles", "kinetic_energy"):
        assert np.array_equal(sa[k], sb[k]), k
    assert ref.counters == res.counters
    for k in ("pos", "vel", "omega", "ids"):
        assert np.array_equal(getattr(ref.system, k), getattr(res.system, k)), k
    # whole pellets only, and nothing waits past the exit longer than ~2 ms (~4 mm at 2 m/s)
    assert ref.counters["count_out"] % 4 == 0 and ref.system.n == 4 * ref.system.clumps.nb
    assert np.all(ref.system.pos[:, 2] < ref.case.exit.z + 0.004)


def test_chute_fed_with_held_pellets(write_case, tmp_path, one_numba_thread):
    case = load_case(write_case(CHUTE, name="chute"))
    sim = Simulation(case, tmp_path / "chute_out", echo=False, progress=False)
    assert sim.run().status == "done"
    s = read_series(tmp_path / "chute_out" / "results.h5")
    inl = sim.inlet
    m4 = pellet(4, 0.003, 2550.0).mass
    assert inl.shape is not None and inl.particle_mass == pytest.approx(m4, rel=1e-14)
    # whole pellets: 4 spheres per pellet present; present + out = fed (spheres and mass)
    c = sim.system.clumps
    assert sim.system.n == 4 * c.nb
    np.testing.assert_array_equal(s["mass_lost"], 0.0)
    assert sim.counters["count_out"] % 4 == 0
    assert c.nb + sim.counters["count_out"] // 4 == inl.count_inserted
    np.testing.assert_allclose(s["mass_present"] + s["mass_out"], s["mass_in"], rtol=1e-12)
    # the rate is met: fed mass = mdot T to within one layer, nothing dropped
    assert inl.mass_dropped == 0.0
    assert abs(inl.mass_inserted - 0.05 * 0.12) <= m4 * len(inl.lattice.corner)
    # held pellets (centre of mass in the hold zone) move at the feed velocity; the rest are free
    held = c.vfix[:, 2] != 0
    assert np.all(c.com[held, 2] <= inl.z_insert + inl.hold_length + inl.velocity * 1e-3)
    np.testing.assert_allclose(c.vel[held, 2], inl.velocity, rtol=1e-14)
    assert np.max(s["max_overlap_ratio"]) < 0.25


def test_pellet_pour_resume_is_bit_identical(write_case, tmp_path, one_numba_thread):
    # stopped at 0.2 s, mid-pour, gate opening: the pellet bodies, orientations and the sphere
    # and body counters survive the checkpoint
    text = CASE.format(fill="pour", model="hertz_mindlin", end=0.3) + "\n[checkpoint]\ninterval = 0.1\n"
    d = write_case(text, name="resume")
    ref = Simulation(load_case(d), tmp_path / "ref", echo=False, progress=False).run()
    part = Simulation(load_case(d, overrides=["time.max_steps=5000"]), tmp_path / "part", echo=False,
                      progress=False).run()
    assert part.status == "stopped" and part.steps == 5000
    res = Simulation(load_case(d), tmp_path / "part", resume=True, echo=False, progress=False).run()
    assert res.status == "done" and res.steps == ref.steps
    sa, sb = read_series(tmp_path / "ref" / "results.h5"), read_series(tmp_path / "part" / "results.h5")
    assert sa["discharged_bodies"][-1] > 0
    for k in ("time", "discharged_mass", "kinetic_energy", "inserted_count", "inserted_bodies",
              "discharged_bodies", "n_particles"):
        assert np.array_equal(sa[k], sb[k]), k
