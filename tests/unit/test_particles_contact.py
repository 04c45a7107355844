"""Derived contact parameters, rolling friction limiter, status flags."""

import math

import numpy as np
import pytest

from cfddem.errors import CaseError
from cfddem.particles import LinearContact, ParticleSystem, PlaneWall

pytestmark = pytest.mark.nojit  # also run as plain Python (tests/unit/test_nojit_tier.py)

R, RHO = 1.5e-3, 2550.0
M = RHO * 4.0 / 3.0 * math.pi * R**3


def test_derived_numbers_match_formulas():
    c = LinearContact(k_n=1000.0, e_n=0.97, e_t=0.33, mu=0.12)
    m = M / 2
    d = c.derived(m)
    ln_n, ln_t = math.log(0.97), math.log(0.33)
    assert d["eta_n"] == pytest.approx(-2 * ln_n * math.sqrt(m * 1000) / math.sqrt(math.pi**2 + ln_n**2), rel=1e-14)
    assert d["k_t"] == pytest.approx(2 / 7 * 1000 * (math.pi**2 + ln_t**2) / (math.pi**2 + ln_n**2), rel=1e-14)
    assert d["eta_t"] == pytest.approx(-2 * ln_t * math.sqrt(2 / 7 * m * d["k_t"]) / math.sqrt(math.pi**2 + ln_t**2), rel=1e-14)
    assert d["t_c"] == pytest.approx(math.sqrt(m * (math.pi**2 + ln_n**2) / 1000), rel=1e-14)
    assert c.collision_time(m) == d["t_c"]
    # equal damped normal and tangential periods
    wn = math.sqrt(1000 / m - (d["eta_n"] / (2 * m)) ** 2)
    mt = d["m_t"]
    wt = math.sqrt(d["k_t"] / mt - (d["eta_t"] / (2 * mt)) ** 2)
    assert wn == pytest.approx(wt, rel=1e-12)
    # e = 1: no damping, k_t = 2/7 k_n
    c1 = LinearContact(k_n=500.0, e_n=1.0, e_t=1.0, mu=0.0)
    assert c1.c_n == 0.0 and c1.c_t == 0.0 and c1.k_t == pytest.approx(500 * 2 / 7)


@pytest.mark.parametrize("kw", [dict(e_n=0.0), dict(e_n=1.2), dict(e_t=-0.1), dict(mu=-1.0),
                                dict(k_n=0.0), dict(mu_r=-0.1)])
def test_bad_contact_input_raises_case_error(kw):
    args = dict(k_n=1000.0, e_n=0.9, e_t=0.5, mu=0.3)
    args.update(kw)
    with pytest.raises(CaseError):
        LinearContact(**args)


def test_wall_rolling_friction_never_reverses_spin():
    """A sphere resting on a floor and spinning about the normal: only the rolling torque acts.
    The spin decays at mu_r R |F_n| / I, stops, and never changes sign."""
    c = LinearContact(k_n=1000.0, e_n=0.5, e_t=0.5, mu=0.5, mu_r=0.2)
    s = ParticleSystem(pp=c, walls=[PlaneWall(contact=c, point=(0, 0, 0), normal=(0, 1, 0))],
                       dt=1e-5, gravity=(0, -9.81, 0))
    s.add_particles([[0, R - M * 9.81 / 1000, 0]], 0.0, R, RHO, omega=[[0, 3.0, 0]])
    I = 0.4 * M * R**2
    rate = 0.2 * R * M * 9.81 / I  # rad/s^2
    ws = []
    for _ in range(300):
        s.step(10)
        ws.append(s.omega[0, 1])
    ws = np.array(ws)
    # never reversed beyond round-off (the stopping torque leaves residuals ~1e-16 w that decay)
    assert np.all(ws >= -1e-15 * 3.0)
    assert abs(ws[-1]) < 1e-15
    t_stop = 3.0 / rate
    t = 1e-4 * (np.arange(len(ws)) + 1)
    early = t < 0.8 * t_stop
    assert np.allclose(ws[early], 3.0 - rate * t[early], rtol=1e-3, atol=1e-3)


def test_pair_rolling_friction_never_reverses_relative_spin():
    """Two spheres pressed together by external forces, counter-spinning about the line of
    centres: the per-contact limiter stops w_rel without reversing it."""
    c = LinearContact(k_n=1000.0, e_n=0.5, e_t=0.5, mu=0.5, mu_r=0.3)
    s = ParticleSystem(pp=c, walls=[], dt=1e-5)
    F = 0.01
    dn = F / 1000.0
    s.add_particles([[0, 0, 0], [2 * R - dn, 0, 0]], 0.0, R, RHO, omega=[[5.0, 0, 0], [-3.0, 0, 0]])
    o = np.argsort(s.ids)
    s.ext_force[o[0]] = [F, 0, 0]
    s.ext_force[o[1]] = [-F, 0, 0]
    wrel = []
    for _ in range(400):
        s.step(5)
        o = np.argsort(s.ids)
        wrel.append(s.omega[o[0], 0] - s.omega[o[1], 0])
    wrel = np.array(wrel)
    assert np.all(wrel >= -1e-15 * 8.0)
    assert abs(wrel[-1]) < 1e-12
    I = 0.4 * M * R**2
    rate = 0.3 * (R / 2) * F * 2 / I  # d w_rel/dt = -T (1/I_a + 1/I_b)
    t = 5e-5 * (np.arange(len(wrel)) + 1)
    early = t < 0.8 * 8.0 / rate
    assert np.allclose(wrel[early], 8.0 - rate * t[early], rtol=1e-2, atol=2e-2)
    # total angular momentum conserved (internal torque pair)
    assert abs(s.omega[:, 0].sum() - 2.0) < 1e-9


def test_overlap_flag_names_particle_and_cause():
    c = LinearContact(k_n=10.0, e_n=0.9, e_t=0.5, mu=0.3)
    s = ParticleSystem(pp=c, walls=[], dt=1e-4, max_overlap_ratio=0.2)
    ids = s.add_particles([[0, 0, 0], [2 * R + 1e-5, 0, 0]], [[5.0, 0, 0], [-5.0, 0, 0]], R, RHO)
    st = s.step(1000)
    assert not st.ok and st.flag == "overlap"
    assert st.index in ids.tolist()
    assert st.value > 0.2
    # dt = 1e-4 s is t_c/42 here: the overlap comes from contacts too soft for 10 m/s, not the step
    assert "NOT the time step" in st.message and "too soft for the speeds" in st.message
    assert f"particle id {st.index}" in st.message
    assert st.steps_done < 1000


def test_nan_flag():
    c = LinearContact(k_n=1000.0, e_n=0.9, e_t=0.5, mu=0.3)
    s = ParticleSystem(pp=c, walls=[], dt=1e-5)
    ids = s.add_particles([[0, 0, 0], [0.1, 0, 0]], 0.0, R, RHO)
    s.ext_force[1] = [np.nan, 0, 0]
    st = s.step(10)
    assert not st.ok and st.flag == "nan" and st.index == int(s.ids[1]) and st.steps_done == 1
    assert "non-finite" in st.message
