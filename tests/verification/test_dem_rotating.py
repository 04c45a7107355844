"""Free particles in the rotating frame (physics.md §3)."""

import math

import numpy as np

from cfddem.particles import LinearContact, ParticleSystem
from tests.analytic import RotatingFrame

R, RHO = 1.5e-3, 2550.0


def test_free_particle_follows_rotated_straight_line():
    """Over one revolution the particle's position in the rotating frame equals the rotated
    image of its straight inertial path, r(t) - a = Rot(-Omega t) (r_in(t) - a)."""
    Om = np.array([0.0, 2.0 * math.pi, 0.0])  # one revolution per second, about y
    a = np.array([0.05, -0.3, 0.1])
    r0 = np.array([0.3, 0.1, -0.2])
    v0 = np.array([0.2, 0.05, -0.1])
    dt = 1e-4  # Omega dt = 6.3e-4; the error is second order, ~0.4 (Omega dt)^2 here
    s = ParticleSystem(pp=LinearContact(1000.0, 0.9, 0.5, 0.3), walls=[], dt=dt, omega=Om,
                       axis_point=a)
    s.add_particles([r0], [v0], R, RHO)
    frame = RotatingFrame(Om, a)
    worst = 0.0
    nsteps = int(round(1.0 / dt))
    for k in range(10):
        assert s.step(nsteps // 10).ok
        t = s.time
        exact = frame.free_position(r0, v0, t)
        worst = max(worst, np.linalg.norm(s.pos[0] - exact) / np.linalg.norm(exact - a))
    assert abs(s.time - 1.0) < 1e-12
    print(f"free particle: max relative deviation over one revolution {worst:.3g}")
    assert worst < 1e-6
    # after a full revolution the frames coincide: the velocity is the inertial one seen from the frame
    v_exact = frame.free_velocity(r0, v0, s.time)
    assert np.linalg.norm(s.vel[0] - v_exact) < 1e-6 * np.linalg.norm(v_exact)


def test_spinning_free_particle_keeps_inertial_angular_momentum():
    Om = np.array([0.3, 1.7, -0.4])
    dt = 1e-4
    s = ParticleSystem(pp=LinearContact(1000.0, 0.9, 0.5, 0.3), walls=[], dt=dt, omega=Om)
    w0 = np.array([50.0, -20.0, 10.0])
    s.add_particles([[0.0, 0.0, 0.0]], 0.0, R, RHO, omega=[w0])
    s.step(20000)
    t = s.time
    # inertial spin w + Omega is a fixed inertial vector: seen from the frame it turns by -Omega t
    w_exact = RotatingFrame(Om).free_spin(w0, t)
    assert np.linalg.norm(s.omega[0] - w_exact) < 1e-10 * np.linalg.norm(w0 + Om)
    assert abs(np.linalg.norm(s.omega[0] + Om) / np.linalg.norm(w0 + Om) - 1) < 1e-12
