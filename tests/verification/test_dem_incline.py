"""A sphere on an incline: rest, rolling and sliding regimes (physics.md §1.3)."""

import math

import numpy as np
import pytest

from cfddem.particles import LinearContact, ParticleSystem, PlaneWall
from tests.analytic import InclineSphere, LinearCollision

R = 1.5e-3
RHO = 2550.0
M = RHO * 4.0 / 3.0 * math.pi * R**3
G = 9.81
MU, MU_R = 0.3, 0.05


def _incline(theta, mu=MU, mu_r=MU_R, t_end=0.25):
    """Floor y = 0, gravity tilted by theta towards +x.  Returns (times, x velocity, spin z,
    position x) sampled every 1 ms."""
    pw = LinearContact(k_n=1000.0, e_n=0.5, e_t=0.5, mu=mu, mu_r=mu_r)
    inc = InclineSphere(theta, mu, mu_r, G)
    s = ParticleSystem(pp=pw, walls=[PlaneWall(contact=pw, point=(0, 0, 0), normal=(0, 1, 0))],
                       dt=1e-5, gravity=inc.gravity())
    y0 = R - LinearCollision(pw.k_n, pw.e_n, M).static_overlap(inc.normal_load(M))
    s.add_particles([[0.0, y0, 0.0]], 0.0, R, RHO)
    return record_incline(s, t_end)


def record_incline(s, t_end):
    """Step a one-sphere system (dt = 1e-5 s) to ``t_end``; every 1 ms record (time, x velocity,
    spin z, position x)."""
    ts, vs, ws, xs = [], [], [], []
    for _ in range(int(round(t_end / 1e-3))):
        st = s.step(100)
        assert st.ok, st.message
        ts.append(s.time)
        vs.append(s.vel[0, 0])
        ws.append(s.omega[0, 2])
        xs.append(s.pos[0, 0])
    return np.array(ts), np.array(vs), np.array(ws), np.array(xs)


def _accel(t, v, t0=0.05):
    sel = t >= t0
    return np.polyfit(t[sel], v[sel], 1)[0]


def test_at_rest_below_rolling_friction():
    theta = math.atan(0.6 * MU_R)
    assert InclineSphere(theta, MU, MU_R, G).regime() == "rest"
    t, v, w, x = _incline(theta)
    # a free-rolling sphere would have reached 5/7 g sin(theta) t = 0.026 m/s
    print(f"rest: max |v| after 0.05 s = {np.max(np.abs(v[t > 0.05])):.3g} m/s, drift {abs(x[-1] - x[len(x) // 5]):.3g} m")
    assert np.max(np.abs(v[t > 0.05])) < 1e-6
    assert np.max(np.abs(w[t > 0.05])) < 1e-12
    assert abs(x[-1] - x[len(x) // 5]) < 1e-9


@pytest.mark.parametrize("tan_theta", [0.3, 0.8])
def test_rolling_below_sliding_threshold(tan_theta):
    theta = math.atan(tan_theta)
    inc = InclineSphere(theta, MU, MU_R, G)
    assert inc.regime() == "roll"
    t, v, w, x = _incline(theta)
    a = _accel(t, v)
    a_th = inc.acceleration()
    print(f"rolling tan={tan_theta}: a/a_theory = {a / a_th:.5f}")
    assert a == pytest.approx(a_th, rel=1e-2)
    # rolling without slipping: v = -R w_z
    assert np.allclose(v[t > 0.05], -R * w[t > 0.05], rtol=2e-3)


@pytest.mark.parametrize("tan_theta", [1.0, 1.5])
def test_sliding_above_threshold(tan_theta):
    theta = math.atan(tan_theta)
    inc = InclineSphere(theta, MU, MU_R, G)
    assert inc.regime() == "slide"
    t, v, w, x = _incline(theta)
    a = _accel(t, v)
    a_th = inc.acceleration()
    print(f"sliding tan={tan_theta}: a/a_theory = {a / a_th:.5f}")
    assert a == pytest.approx(a_th, rel=1e-2)
    assert np.all(v[t > 0.05] > -R * w[t > 0.05] * 1.01)  # slipping
