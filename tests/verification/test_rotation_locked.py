"""Rotation locked (``particles.rotation = 'locked'``): a sphere that cannot spin slides on an
incline with a = g (sin - mu cos) where a free one rolls at 5/7 g sin, and stays at rest below
tan theta = mu; a locked clump keeps its orientation through collisions; locking mid-run
zeroes the spins; a locked feed particle stays locked at its release; restart bit-identical;
the shear cell pours freely and locks at its scraping (the lid stays free)."""

import math

import numpy as np
import pytest

from cfddem.config import load_case
from cfddem.particles import LinearContact, ParticleSystem, PlaneWall
from cfddem.particles.clumps import pellet
from cfddem.simulation import Simulation
from tests.analytic import InclineSphere, LinearCollision
from tests.verification.test_dem_incline import G, M, R, RHO, record_incline

MU = 0.3


def _incline(theta, locked, t_end=0.2):
    pw = LinearContact(k_n=1000.0, e_n=0.5, e_t=0.5, mu=MU)
    inc = InclineSphere(theta, MU, 0.0, G)
    s = ParticleSystem(pp=pw, walls=[PlaneWall(contact=pw, point=(0, 0, 0), normal=(0, 1, 0))],
                       dt=1e-5, gravity=inc.gravity())
    s.rotation_locked = locked
    y0 = R - LinearCollision(pw.k_n, pw.e_n, M).static_overlap(inc.normal_load(M))
    s.add_particles([[0.0, y0, 0.0]], 0.0, R, RHO)
    return record_incline(s, t_end)


def _accel(t, v, t0=0.05):
    sel = t >= t0
    return np.polyfit(t[sel], v[sel], 1)[0]


@pytest.mark.parametrize("tan_theta", [0.5, 0.8])
def test_locked_sphere_slides_where_a_free_one_rolls(tan_theta):
    theta = math.atan(tan_theta)
    t, v, w, x = _incline(theta, locked=False)
    assert _accel(t, v) == pytest.approx(5.0 / 7.0 * G * math.sin(theta), rel=1e-2)  # rolls
    t, v, w, x = _incline(theta, locked=True)
    slide = G * (math.sin(theta) - MU * math.cos(theta))
    assert _accel(t, v) == pytest.approx(slide, rel=1e-2)
    assert np.all(w == 0.0)


def test_locked_sphere_rests_below_the_friction_angle():
    theta = math.atan(0.8 * MU)  # a free sphere rolls down this slope
    t, v, w, x = _incline(theta, locked=True)
    assert np.max(np.abs(v[t > 0.05])) < 1e-6
    assert np.all(w == 0.0)


def _two_pellets(locked):
    pp = LinearContact(k_n=2000.0, e_n=0.5, e_t=0.5, mu=0.4)
    s = ParticleSystem(pp=pp, walls=[], dt=2e-5)
    s.rotation_locked = locked
    sh = pellet(2, 0.004, 1500.0)
    q = np.array([[1.0, 0.0, 0.0, 0.0], [math.cos(0.4), 0.0, math.sin(0.4), 0.0]])
    s.add_clumps(sh, [[0.0, 0.0, 0.0], [0.0035, 0.0015, 0.0]], quat=q, vel=[[0.3, 0.0, 0.0], [-0.3, 0.0, 0.0]])
    return s, q


def test_locked_clumps_keep_their_orientation_in_a_collision():
    s, q = _two_pellets(locked=True)
    p0 = s.clumps.vel.sum(axis=0) * s.clumps.mass[0]
    s.step(2000)
    assert np.array_equal(s.clumps.quat, q / np.linalg.norm(q, axis=1)[:, None])
    assert np.all(s.clumps.L == 0.0) and np.all(s.omega == 0.0)
    assert np.any(np.abs(s.clumps.vel - [[0.3, 0, 0], [-0.3, 0, 0]]) > 0.01)  # they did collide
    assert np.allclose(s.clumps.vel.sum(axis=0) * s.clumps.mass[0], p0, atol=1e-12)  # momentum kept
    s2, _ = _two_pellets(locked=False)
    s2.step(2000)
    assert np.max(np.abs(s2.clumps.L)) > 0.0  # free clumps spin in the same collision


def test_lock_rotation_mid_run_locks_clumps_and_their_members():
    s, q = _two_pellets(locked=False)
    s.add_particles([[0.02, 0.0, 0.0]], 0.0, R, RHO, omega=[0.0, 0.0, 5.0])
    s.step(2000)  # the pellets collide and spin
    assert np.max(np.abs(s.clumps.L)) > 0.0
    assert s.lock_rotation() == 3  # two clumps and the sphere
    assert np.all(s.clumps.wfix == 1.0) and np.all(s.clumps.L == 0.0)
    assert np.all(s.omega == 0.0) and np.all(s._held[: s.n] == 2)
    quat = s.clumps.quat.copy()
    s.step(500)
    assert np.array_equal(s.clumps.quat, quat)


def test_lock_rotation_mid_run_and_feed_release():
    pp = LinearContact(k_n=1000.0, e_n=0.5, e_t=0.5, mu=0.3)
    s = ParticleSystem(pp=pp, walls=[], dt=1e-5)
    s.add_particles([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0]], 0.0, R, RHO, omega=[0.0, 0.0, 5.0])
    s.add_particles([[0.02, 0.0, 0.0]], [0.1, 0.0, 0.0], R, RHO, omega=[0.0, 0.0, 5.0], held=True)
    assert s.lock_rotation() == 2
    assert np.all(s.omega[:2] == 0.0) and s.omega[2, 2] == 5.0  # the feed particle moves as set
    assert list(s.held) == [False, False, True]
    s.release(s.held)
    assert list(s._held[:3]) == [2, 2, 2] and not s.held.any()
    # added after the lock: locked, spin given or not
    s.add_particles([[0.04, 0.0, 0.0]], 0.0, R, RHO, omega=[1.0, 0.0, 0.0])
    assert s._held[3] == 2 and np.all(s.omega[3] == 0.0)


def _box_case(tmp_path, rotation):
    d = tmp_path / f"box_{rotation}"
    d.mkdir()
    (d / "case.toml").write_text(f"""
[time]
end_time = 0.05
dt = 2e-5
threads = 1
[output]
series_interval = 0.01
vtk = false
plots = false
[particles]
diameter = 0.003
density = 2500.0
rotation = "{rotation}"
[[particles.initial]]
pos = [0.01, 0.005, 0.01]
vel = [0.2, 0.0, 0.0]
omega = [0.0, 0.0, 30.0]
[[particles.initial]]
pos = [0.02, 0.005, 0.01]
[contact.particle_particle]
k_n = 1000.0
mu = 0.5
[contact.particle_wall]
k_n = 1000.0
mu = 0.5
[geometry]
type = "box"
""")
    return d


def test_box_case_locked_from_the_start_and_restart(tmp_path):
    d = _box_case(tmp_path, "locked")
    sim = Simulation(load_case(d), tmp_path / "a", echo=False, progress=False, threads=1)
    assert sim.run().status == "done"
    assert np.all(sim.system.omega == 0.0)
    free = Simulation(load_case(_box_case(tmp_path, "free")), tmp_path / "f", echo=False, progress=False,
                      threads=1)
    free.run()
    assert np.max(np.abs(free.system.omega)) > 1.0
    # stopped half way and resumed: bit-identical to the straight run
    half = Simulation(load_case(d, overrides=["time.max_steps=1250"]), tmp_path / "b", echo=False, progress=False,
                      threads=1)
    assert half.run().status == "stopped"
    rest = Simulation(load_case(d), tmp_path / "b", resume=True, echo=False, progress=False, threads=1)
    rest.run()
    assert np.array_equal(rest.system.pos, sim.system.pos) and np.array_equal(rest.system.vel, sim.system.vel)


def test_shear_cell_pours_free_and_locks_at_the_scraping(tmp_path, one_numba_thread):
    from tests.integration.test_shear_cell import CASE

    d = tmp_path / "shear"
    d.mkdir()
    (d / "case.toml").write_text(CASE.format(clump="none", variant="bulk", n=330))
    case = load_case(d, overrides=['particles.rotation="locked"', "contact.particle_particle.mu=0.1"])
    sim = Simulation(case, tmp_path / "s", echo=False, progress=False, threads=1)
    sim.run()
    s = sim.system
    sample = s.body < 0
    assert np.all(s.omega[sample] == 0.0) and np.all(s._held[: s.n][sample] == 2)
    lid = sim.scene._lid()
    assert s.clumps.wfix[lid, 0] == 0.0 and np.any(s.clumps.L[lid] != 0.0)  # the lid tilts and spins
    # poured with free rotation: the same packing as the free run's (the fills are identical)
    free = Simulation(load_case(d, overrides=["contact.particle_particle.mu=0.1"]), tmp_path / "f", echo=False,
                      progress=False, threads=1)
    free.run()
    assert sim.scene.fill_info == free.scene.fill_info


def test_a_lock_taken_mid_run_survives_a_restart():
    """The silo and shear cell lock after their fill: a run resumed from a checkpoint taken
    after the lock locks the particles added later too (and so does one written before the
    flag was saved, where a locked particle says so)."""
    pp = LinearContact(k_n=1000.0, e_n=0.5, e_t=0.5, mu=0.3)
    s = ParticleSystem(pp=pp, walls=[], dt=1e-5)
    s.add_particles([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0]], 0.0, R, RHO, omega=[0.0, 0.0, 5.0])
    s.lock_rotation()
    s.step(10)
    st = s.get_state()
    assert int(st["rotation_locked"]) == 1
    for state in (st, {k: v for k, v in st.items() if k != "rotation_locked"}):
        r = ParticleSystem(pp=pp, walls=[], dt=1e-5)
        assert not r.rotation_locked
        r.set_state(state)
        assert r.rotation_locked
        r.add_particles([[0.04, 0.0, 0.0]], 0.0, R, RHO, omega=[1.0, 0.0, 0.0])
        assert r._held[2] == 2 and np.all(r.omega[2] == 0.0)
    free = ParticleSystem(pp=pp, walls=[], dt=1e-5)
    free.add_particles([[0.0, 0.0, 0.0]], 0.0, R, RHO)
    r = ParticleSystem(pp=pp, walls=[], dt=1e-5)
    r.set_state(free.get_state())
    assert not r.rotation_locked
