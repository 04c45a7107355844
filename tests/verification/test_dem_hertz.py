"""A sphere on an incline with the Hertz-Mindlin law and rolling friction: rest, rolling and
sliding regimes (physics.md §1.2, §1.3; same structure as test_dem_incline.py)."""

import math

import numpy as np
import pytest

from cfddem.particles import HertzMindlinContact, ParticleSystem, PlaneWall

from tests.analytic import HertzNormal, InclineSphere

from .test_dem_incline import record_incline

R = 1.5e-3
RHO = 2550.0
M = RHO * 4.0 / 3.0 * math.pi * R**3
G = 9.81
MU, MU_R = 0.3, 0.05


def _incline(theta, t_end=0.15):
    """Floor y = 0, gravity tilted by theta towards +x; HM with E = 1e7 Pa (static normal
    stiffness S_n ~ 600 N/m).  Returns (times, x velocity, spin z, position x) every 1 ms."""
    c = HertzMindlinContact(E=1e7, nu=0.3, e=0.5, mu=MU, mu_r=MU_R)
    inc = InclineSphere(theta, MU, MU_R, G)
    s = ParticleSystem(pp=c, walls=[PlaneWall(contact=c, point=(0, 0, 0), normal=(0, 1, 0))],
                       dt=1e-5, gravity=inc.gravity())
    d0 = HertzNormal(c.E_star, R).static_overlap(inc.normal_load(M))  # R* = R against a wall
    s.add_particles([[0.0, R - d0, 0.0]], 0.0, R, RHO)
    return record_incline(s, t_end)


def _accel(t, v, t0=0.03):
    sel = t >= t0
    return np.polyfit(t[sel], v[sel], 1)[0]


def test_hm_at_rest_below_rolling_friction():
    theta = math.atan(0.6 * MU_R)
    assert InclineSphere(theta, MU, MU_R, G).regime() == "rest"
    t, v, w, x = _incline(theta)
    print(f"HM rest: max |v| after 0.03 s = {np.max(np.abs(v[t > 0.03])):.3g} m/s")
    assert np.max(np.abs(v[t > 0.03])) < 1e-6
    assert np.max(np.abs(w[t > 0.03])) < 1e-12
    assert abs(x[-1] - x[len(x) // 5]) < 1e-9


def test_hm_rolling_below_sliding_threshold():
    tan_theta = 0.4
    theta = math.atan(tan_theta)
    inc = InclineSphere(theta, MU, MU_R, G)
    assert inc.regime() == "roll"
    t, v, w, x = _incline(theta)
    a = _accel(t, v)
    a_th = inc.acceleration()
    print(f"HM rolling tan={tan_theta}: a/a_theory = {a / a_th:.5f}")
    assert a == pytest.approx(a_th, rel=1e-2)
    assert np.allclose(v[t > 0.03], -R * w[t > 0.03], rtol=2e-3)  # no slip


def test_hm_sliding_above_threshold():
    tan_theta = 1.2
    theta = math.atan(tan_theta)
    inc = InclineSphere(theta, MU, MU_R, G)
    assert inc.regime() == "slide"
    t, v, w, x = _incline(theta)
    a = _accel(t, v)
    a_th = inc.acceleration()
    print(f"HM sliding tan={tan_theta}: a/a_theory = {a / a_th:.5f}")
    assert a == pytest.approx(a_th, rel=1e-2)
    assert np.all(v[t > 0.03] > -R * w[t > 0.03] * 1.01)  # slipping
