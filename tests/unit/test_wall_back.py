"""A sphere that reaches a one-sided wall from its back (issue #22: the Jenike cell with the
thesis's parameters).  The shear cell's ``ring_ledge`` is an annulus facing down at the shear
plane; a particle that had spilled over the shear ring fell onto the base ring's top face, i.e.
onto the back of that annulus.  The contact used to switch on at an overlap of about 2 R and
threw the particle out at tens of m/s (the run stopped with "overlap/radius = 1.94", blaming
the time step).  Now a contact that would begin behind the face is no contact, and is counted."""

import math

import numpy as np
import pytest

from cfddem.particles import HertzMindlinContact, ParticleSystem
from cfddem.particles.walls import AnnulusWall, PlaneWall, RectangleWall
from cfddem.stability import contact_step_limit

R, RHO = 1.9e-3, 950.0  # the thesis's spheres (blending.md §1)
M = RHO * 4.0 / 3.0 * math.pi * R**3
LAW = HertzMindlinContact(E=1e8, nu=0.4, e=0.01, mu=0.6)
DT = 2e-6


def _ledges(extra=()):
    """The shear cell's ledge geometry at y = 0: the base ring's top facing up (R1..R2 about x = 0)
    and the shear ring's bottom facing down (same radii about x = -3 mm)."""
    return [AnnulusWall(contact=LAW, name="base_ledge", point=(0.0, 0.0, 0.0), normal=(0.0, 1.0, 0.0),
                        r_in=0.0475, r_out=0.0505),
            AnnulusWall(contact=LAW, name="ring_ledge", point=(-0.003, 0.0, 0.0), normal=(0.0, -1.0, 0.0),
                        r_in=0.0475, r_out=0.0505), *extra]


def _drop(walls, x0, steps):
    s = ParticleSystem(pp=LAW, walls=walls, dt=DT, gravity=(0.0, -9.81, 0.0))
    s.add_particles(np.array([x0]), np.zeros(3), R, RHO)
    vmax = 0.0
    for _ in range(steps // 200):
        st = s.step(200)
        assert st.ok, st.message
        vmax = max(vmax, float(np.linalg.norm(s.vel[0])))
    return s, vmax


def test_sphere_falling_onto_the_back_of_the_ring_ledge_lands_on_the_base_ledge():
    """Where both annuli lie (49 mm from either ring axis), a sphere
    dropped from 5 mm above the plane lands on the base ledge and comes to rest there: speed
    never above the free-fall speed sqrt(2 g h) = 0.31 m/s (it was thrown at tens of m/s), rest
    overlap the Hertz static overlap (m g / ((4/3) E* sqrt(R)))^(2/3) within 2 %, and one
    back-of-wall event named on ring_ledge."""
    x0 = (0.0, 0.005, 0.049)  # 49 mm from the base ring's axis, 49.1 mm from the shear ring's
    s, vmax = _drop(_ledges(), x0, 40000)  # 0.08 s: falls (32 ms) and settles
    v_fall = math.sqrt(2 * 9.81 * (0.005 - R))
    assert vmax < 1.05 * v_fall
    d_static = (M * 9.81 / (4.0 / 3.0 * LAW.E_star * math.sqrt(R))) ** (2.0 / 3.0)
    assert R - s.pos[0, 1] == pytest.approx(d_static, rel=0.02)
    assert float(np.linalg.norm(s.vel[0])) < 1e-3
    assert s.wall_back_count == 1  # counted once, while it rests behind ring_ledge
    assert s.wall_back_events[0][1:] == (0, "ring_ledge", 1)
    f = s.wall_forces()
    assert f[1] == pytest.approx([0.0, 0.0, 0.0], abs=0.0)  # ring_ledge takes nothing
    assert f[0][1] == pytest.approx(-M * 9.81, rel=1e-3)  # the base ledge carries the weight


@pytest.mark.parametrize("wall", ["rectangle", "annulus"])
def test_sphere_passes_the_back_of_a_bounded_wall_and_meets_the_next(wall):
    """A sphere falling onto the back of a downward-facing rectangle or annulus passes it (no
    contact, one event) and lands on the floor 20 mm below with its free-fall speed intact."""
    if wall == "rectangle":
        back = RectangleWall(contact=LAW, name="lid", point=(0.0, 0.02, 0.0), normal=(0.0, -1.0, 0.0),
                             axis1=(1.0, 0.0, 0.0), half1=0.01, half2=0.01)
    else:
        back = AnnulusWall(contact=LAW, name="lid", point=(0.0, 0.02, 0.0), normal=(0.0, -1.0, 0.0),
                           r_in=0.0, r_out=0.01)
    floor = PlaneWall(contact=LAW, name="floor", point=(0.0, 0.0, 0.0), normal=(0.0, 1.0, 0.0))
    s = ParticleSystem(pp=LAW, walls=[back, floor], dt=DT, gravity=(0.0, -9.81, 0.0))
    s.add_particles(np.array([[0.0, 0.03, 0.0]]), np.zeros(3), R, RHO)
    vmin = 0.0
    while s.pos[0, 1] > R + 1e-4:
        assert s.step(50).ok
        vmin = min(vmin, float(s.vel[0, 1]))
    v_free = math.sqrt(2 * 9.81 * (0.03 - s.pos[0, 1]))
    assert -vmin == pytest.approx(v_free, rel=0.01)
    assert s.wall_back_count == 1
    assert s.wall_back_events[0][2] == "lid"


def test_contact_pushed_past_the_face_from_the_front_is_kept():
    """The rule concerns contacts that would begin behind the face only: a sphere thrown at 3 m/s
    against a very soft plane (E = 3e4 Pa, e = 0.9) is pushed in beyond its radius (its centre
    passes the face) and still bounces back out, with no back-of-wall event."""
    soft = HertzMindlinContact(E=3e4, nu=0.4, e=0.9, mu=0.6)
    floor = PlaneWall(contact=soft, name="floor", point=(0.0, 0.0, 0.0), normal=(0.0, 1.0, 0.0))
    s = ParticleSystem(pp=LAW, walls=[floor], dt=DT, gravity=(0.0, 0.0, 0.0), max_overlap_ratio=3.0)
    s.add_particles(np.array([[0.0, R, 0.0]]), np.array([[0.0, -3.0, 0.0]]), R, RHO)
    ymin = R
    while s.vel[0, 1] < 0.0 or s.pos[0, 1] < R:
        assert s.step(20).ok
        ymin = min(ymin, float(s.pos[0, 1]))
    assert ymin < -0.1 * R  # the centre went past the face, in contact
    assert s.vel[0, 1] == pytest.approx(0.9 * 3.0, rel=0.05)  # out again at e v
    assert s.wall_back_count == 0


def test_overlap_stop_at_a_small_step_does_not_blame_the_time_step():
    """The overlap stop's diagnosis blamed the time step whatever it was (the issue's run: "time
    step too large", at 0.2 of the stable step).  Two spheres placed 60 % of a radius into each
    other at dt = 2e-6 s (0.2 of the one-contact stable step): the message says it is not the time
    step and names the stable step.  Two spheres meeting at 60 m/s with dt = 2e-5 s (5 times the
    stable step at that speed) overlap 0.6 R in one step: the time step stays the cause."""
    for dt, blames in ((2e-6, False), (2e-5, True)):
        s = ParticleSystem(pp=LAW, walls=[], dt=dt)
        if blames:
            s.add_particles(np.array([[0.0, 0.0, 0.0], [2 * R, 0.0, 0.0]]),
                            np.array([[30.0, 0.0, 0.0], [-30.0, 0.0, 0.0]]), R, RHO)
        else:
            s.add_particles(np.array([[0.0, 0.0, 0.0], [1.4 * R, 0.0, 0.0]]), np.zeros(3), R, RHO)
        st = s.step(1)
        assert not st.ok and st.flag == "overlap"
        assert ("NOT the time step" not in st.message) == blames, st.message
        if not blames:
            # the tangential mode of the pair, linearised at the speed the spheres now have
            v = float(np.max(np.linalg.norm(s.vel, axis=1)))
            dts = float(st.message.split("stable step of one contact (")[1].split(" s")[0])
            assert dts == pytest.approx(contact_step_limit(LAW, M / 2, R / 2, v)["tangential"], rel=2e-3)
            assert contact_step_limit(LAW, M / 2, R / 2, 1.0)["tangential"] == pytest.approx(9.89e-6, rel=1e-3)


def test_back_of_wall_events_are_thread_independent():
    """40 spheres dropped around the ledges, 22 of them onto the back of ring_ledge: the parallel
    kernels on 2 threads give the same positions, velocities, count and events as the serial
    twins."""
    import numba

    def run(parallel):
        s = ParticleSystem(pp=LAW, walls=_ledges(), dt=DT, gravity=(0.0, -9.81, 0.0))
        if parallel:
            s.serial_below = 0
        rng = np.random.default_rng(1)
        th = np.linspace(0.0, 2 * np.pi, 41)[:-1]
        rr = rng.uniform(0.0478, 0.0502, 40)
        s.add_particles(np.c_[rr * np.cos(th), 0.004 + 0.004 * rng.uniform(size=40), rr * np.sin(th)],
                        np.zeros(3), R, RHO)
        assert s.step(30000).ok
        return s

    n0 = numba.get_num_threads()
    numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
    try:
        a, b = run(True), run(False)
    finally:
        numba.set_num_threads(n0)
    assert a.wall_back_count == b.wall_back_count == 22
    assert np.array_equal(a.pos, b.pos) and np.array_equal(a.vel, b.vel)
    assert a.wall_back_events == b.wall_back_events
