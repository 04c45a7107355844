"""Drag closures: limits, compiled twins, lookup errors, derived quantities."""

import math

import numpy as np
import pytest
from scipy.optimize import bisect

from cfddem.coupling import drag
from cfddem.errors import CaseError
from tests.analytic import Ergun

pytestmark = pytest.mark.nojit  # also run as plain Python (tests/unit/test_nojit_tier.py)

NAMES = sorted(drag.CLOSURES)
MU, RHO_G, RHO_P, D = 1.8e-5, 1.2, 2550.0, 3.0e-3


def test_beetstra_isolated_stokes_limit():
    # eps -> 1, Re -> 0: F -> 1 (Stokes drag)
    assert drag.beetstra(1.0, 0.0) == 1.0
    hs = (1e-4, 1e-6, 1e-8, 1e-12)
    errs = [abs(drag.beetstra(1.0 - h, h) - 1.0) for h in hs]
    # leading correction is 1.5 sqrt(phi) (van der Hoef et al. 2005): F - 1 ~ 1.5 sqrt(1 - eps)
    for h, e in zip(hs, errs):
        assert e == pytest.approx(1.5 * math.sqrt(h), rel=0.1)
    assert errs[-1] < 2e-6


@pytest.mark.parametrize("name", ["beetstra", "wen_yu", "ergun_gidaspow", "koch_hill"])
def test_isolated_sphere_limit_is_one(name):
    assert drag.CLOSURES[name](1.0, 0.0) == pytest.approx(1.0, abs=1e-14)
    assert drag.CLOSURES[name](1.0, 1e-6) == pytest.approx(1.0, abs=2e-5)  # Wen-Yu: 0.15 Re^0.687 = 1.1e-5


def test_di_felice_isolated_limit_is_dallavalle():
    # C_D0 = (0.63 + 4.8/sqrt(Re))^2 -> 23.04/Re, so F -> 23.04/24 = 0.96
    assert drag.di_felice(1.0, 0.0) == pytest.approx(0.96, rel=1e-14)


@pytest.mark.parametrize("eps", [0.36, 0.4, 0.45])
def test_dense_low_re_carman_kozeny(eps):
    ck = 10.0 * (1.0 - eps) / eps**2
    # Koch-Hill: exactly Carman-Kozeny for phi >= 0.4 at Re -> 0 (F1 Re'^2 ~ 1e-17)
    if 1.0 - eps >= 0.4:
        assert drag.koch_hill(eps, 1e-8) == pytest.approx(ck, rel=1e-12)
    # Beetstra: CK plus the eps^2 (1 + 1.5 sqrt(phi)) correction, < 2 % of CK when dense
    b = drag.beetstra(eps, 1e-8)
    assert b == pytest.approx(ck + eps**2 * (1 + 1.5 * math.sqrt(1 - eps)), rel=1e-6)
    assert 1.0 < b / ck < 1.02
    # Ergun's viscous term: 150/180 of Carman-Kozeny
    assert drag.ergun_gidaspow(eps, 1e-12) / ck == pytest.approx(150.0 / 180.0, rel=1e-10)


@pytest.mark.parametrize("name", NAMES)
def test_zero_re_finite_and_monotone_in_re(name):
    fn = drag.CLOSURES[name]
    for eps in (0.4, 0.6, 0.9, 0.99):
        f0 = fn(eps, 0.0)
        assert np.isfinite(f0) and f0 > 0
        res = np.logspace(-3, 4, 60)
        f = fn(np.full_like(res, eps), res)
        # drag force F*Re grows with slip
        assert np.all(np.diff(f * res) > 0)


@pytest.mark.parametrize("name", NAMES)
def test_scalar_twins_equal_vectorised(name):
    eps = np.repeat(np.linspace(0.35, 1.0, 27), 33)
    re = np.tile(np.concatenate([[0.0], np.logspace(-3, 4, 32)]), 27)
    ref = drag.CLOSURES[name](eps, re)
    out = np.empty_like(eps)
    drag.drag_scalar_array(drag.closure_id(name), eps, re, out)
    np.testing.assert_allclose(out, ref, rtol=2e-15, atol=0)
    # the twin itself (called through its dispatcher)
    twin = drag.SCALAR_TWINS[name]
    for i in range(0, eps.size, 97):
        assert twin(eps[i], re[i]) == pytest.approx(ref[i], rel=2e-15, abs=0)


def test_unknown_id_gives_nan():
    out = np.empty(1)
    drag.drag_scalar_array(17, np.array([0.5]), np.array([1.0]), out)
    assert np.isnan(out[0])


def test_unknown_closure_caseerror_with_suggestion():
    with pytest.raises(CaseError) as ei:
        drag.get_closure("betstra")
    assert ei.value.key == "coupling.drag"
    assert str(ei.value) == "coupling.drag: unknown drag closure 'betstra'; did you mean 'beetstra'?"
    with pytest.raises(CaseError, match="did you mean 'koch_hill'"):
        drag.get_closure("koch_hil")
    with pytest.raises(CaseError, match="did you mean 'di_felice'"):
        drag.closure_id("difelice")
    with pytest.raises(CaseError, match="known closures"):
        drag.get_closure("zzzzzzzz")
    assert drag.get_closure("Koch-Hill") is drag.koch_hill
    assert [drag.closure_id(n) for n in drag.CLOSURES] == [0, 1, 2, 3, 4]


def test_relaxation_time():
    # isolated Stokes particle: tau = rho_p d^2/(18 mu)
    assert drag.relaxation_time(1.0, 0.0, RHO_P, D, MU, "wen_yu") == pytest.approx(RHO_P * D**2 / (18 * MU), rel=1e-14)
    # general: tau = rho_p (1 - eps)/beta (from m dv/dt = V beta/(1-eps) (u - v))
    for name in NAMES:
        for eps, re in ((0.45, 3.0), (0.8, 300.0)):
            tau = drag.relaxation_time(eps, re, RHO_P, D, MU, name)
            assert tau == pytest.approx(RHO_P * (1 - eps) / drag.beta(eps, re, MU, D, name), rel=1e-13)


def test_terminal_velocity_wen_yu_single_sphere_archimedes():
    """eps = 1, Wen-Yu = Schiller-Naumann: (3/4) C_D Re^2 = Ar, solved independently."""
    d = 0.5e-3  # Re ~ 60: Schiller-Naumann branch, 18 Re (1 + 0.15 Re^0.687) = Ar
    ar = RHO_G * (RHO_P - RHO_G) * 9.81 * d**3 / MU**2
    re = bisect(lambda r: 18.0 * r * (1.0 + 0.15 * r**0.687) - ar, 1e-6, 1e3, xtol=1e-14, rtol=1e-15)
    wt = drag.terminal_velocity(RHO_P, RHO_G, d, MU, closure="wen_yu")
    assert 10 < re < 1000
    assert wt == pytest.approx(re * MU / (RHO_G * d), rel=1e-10)
    # 3 mm glass bead in air: Newton regime C_D = 0.44, Re = sqrt(4 Ar/(3 * 0.44)) ~ 2750
    ar = RHO_G * (RHO_P - RHO_G) * 9.81 * D**3 / MU**2
    re = math.sqrt(4.0 * ar / (3.0 * 0.44))
    wt = drag.terminal_velocity(RHO_P, RHO_G, D, MU, closure="wen_yu")
    assert wt == pytest.approx(re * MU / (RHO_G * D), rel=1e-10)
    assert 13.0 < wt < 14.5


def test_terminal_velocity_stokes_limit():
    d = 2e-6  # Re ~ 4e-5
    stokes = (RHO_P - RHO_G) * 9.81 * d**2 / (18 * MU)
    assert drag.terminal_velocity(RHO_P, RHO_G, d, MU) == pytest.approx(stokes, rel=1e-3)
    assert drag.terminal_velocity(RHO_P, RHO_G, d, MU, closure="di_felice") == pytest.approx(stokes / 0.96, rel=3e-3)  # + 0.26 sqrt(Re)


def test_umf_ergun_closed_form():
    """Ergun closure: 1.75 Re^2/eps^3 + 150 (1-eps) Re/eps^3 = Ar (Wen & Yu 1966 quadratic,
    tests.analytic.Ergun)."""
    eps = 0.4
    umf = drag.minimum_fluidisation_velocity(eps, RHO_P, RHO_G, D, MU, "ergun_gidaspow")
    assert umf == pytest.approx(Ergun(eps, D, MU, RHO_G).minimum_fluidisation_velocity(RHO_P, g=9.81), rel=1e-10)
    assert 1.2 < umf < 1.6


@pytest.mark.parametrize("name", NAMES)
def test_umf_is_eps_times_suspension_settling_speed(name):
    for eps in (0.4, 0.45):
        umf = drag.minimum_fluidisation_velocity(eps, RHO_P, RHO_G, D, MU, name)
        w = drag.terminal_velocity(RHO_P, RHO_G, D, MU, eps=eps, closure=name)
        assert umf == pytest.approx(eps * w, rel=1e-10)
        # the force balance holds: drag on the bed per volume = bed weight less buoyancy
        slip = umf / eps
        re = RHO_G * umf * D / MU
        assert drag.beta(eps, re, MU, D, name) * slip == pytest.approx(eps * (1 - eps) * (RHO_P - RHO_G) * 9.81, rel=1e-10)


def test_bad_inputs():
    with pytest.raises(CaseError):
        drag.terminal_velocity(1.0, 1.2, D, MU)
    with pytest.raises(CaseError):
        drag.minimum_fluidisation_velocity(1.0, RHO_P, RHO_G, D, MU)


@pytest.mark.parametrize("name", NAMES)
def test_drag_values_parallel_pass_equals_vectorised(name):
    """The coupling's path (drag_values: the twin in a parallel pass) against the numpy form,
    and the out array reused."""
    eps = np.repeat(np.linspace(0.35, 1.0, 27), 33)
    re = np.tile(np.concatenate([[0.0], np.logspace(-3, 4, 32)]), 27)
    ref = drag.CLOSURES[name](eps, re)
    out = np.full_like(eps, np.nan)
    got = drag.drag_values(drag.closure_id(name), eps, re, out)
    assert got is out
    np.testing.assert_allclose(out, ref, rtol=2e-15, atol=0)
