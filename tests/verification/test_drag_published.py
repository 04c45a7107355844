"""Each drag closure against an independent implementation of its published formula.

The reference versions below are written in the dimensional form of each paper (a
momentum-exchange coefficient beta or a force on one particle, built from a slip velocity,
density, viscosity and diameter) and only then mapped to F = F_d/(3 pi mu d eps |u - v|),
so they share no algebra with cfddem.coupling.drag.  Agreement to 1e-10 relative on
eps in [0.4, 0.99] x Re in [0.01, 1000].
"""

import math

import numpy as np
import pytest

from cfddem.coupling import drag

MU, RHO, D = 1.8e-5, 1.2, 3.0e-3
EPS = np.linspace(0.4, 0.99, 25)
RE = np.logspace(-2, 3, 31)
GRID = [(float(e), float(r)) for e in EPS for r in RE]


def slip_from_re(eps, re):
    """|u - v| such that Re = eps rho |u - v| d / mu."""
    return re * MU / (eps * RHO * D)


def f_from_beta(beta, eps):
    return beta * D * D / (18.0 * MU * (1.0 - eps) * eps)


def f_from_force(force, eps, slip):
    return force / (3.0 * math.pi * MU * D * eps * slip)


# ----- independent references ------------------------------------------------------------


def ref_beetstra(eps, re):
    """physics.md A/B form: beta = (mu/d^2)[A phi^2/eps + B phi Re/eps], B prefactor 18*0.413/24."""
    phi = 1.0 - eps
    a = 180.0 + 18.0 * eps**4 / phi * (1.0 + 1.5 * math.sqrt(phi))
    b = (18.0 * 0.413 / 24.0) * (1.0 / eps + 3.0 * eps * phi + 8.4 * re**-0.343) / (
        1.0 + 10.0 ** (3.0 * phi) * re ** (-(1.0 + 4.0 * phi) / 2.0)
    )
    beta = MU / D**2 * (a * phi**2 / eps + b * phi * re / eps)
    return f_from_beta(beta, eps)


def ref_wen_yu_beta(eps, slip):
    rep = eps * RHO * slip * D / MU
    cd = 24.0 / rep * (1.0 + 0.15 * rep**0.687) if rep < 1000.0 else 0.44
    return 0.75 * cd * eps * (1.0 - eps) * RHO * slip / D * eps**-2.65


def ref_wen_yu(eps, re):
    slip = slip_from_re(eps, re)
    return f_from_beta(ref_wen_yu_beta(eps, slip), eps)


def ref_ergun_gidaspow(eps, re):
    """Classic Ergun pressure drop, then beta |u - v| = eps dp/L (U = eps |u - v|)."""
    slip = slip_from_re(eps, re)
    if eps >= 0.8:
        return f_from_beta(ref_wen_yu_beta(eps, slip), eps)
    u_sup = eps * slip
    dpdl = 150.0 * MU * (1 - eps) ** 2 * u_sup / (eps**3 * D**2) + 1.75 * RHO * (1 - eps) * u_sup**2 / (eps**3 * D)
    beta = eps * dpdl / slip
    return f_from_beta(beta, eps)


def ref_di_felice(eps, re):
    """F_d = 0.5 C_D0 rho (pi d^2/4) U^2 eps^-chi with U = eps |u - v|."""
    slip = slip_from_re(eps, re)
    u_sup = eps * slip
    rep = RHO * u_sup * D / MU
    cd0 = (0.63 + 4.8 / math.sqrt(rep)) ** 2
    chi = 3.7 - 0.65 * math.exp(-((1.5 - math.log10(rep)) ** 2) / 2.0)
    force = 0.5 * cd0 * RHO * math.pi * D**2 / 4.0 * u_sup**2 * eps ** (-chi)
    return f_from_force(force, eps, slip)


def ref_koch_hill(eps, re):
    """Transcription of MFIX DRAG_KOCH_HILL (Benyahia et al. 2006): lDgA = F * 18 mu eps^2/d^2,
    beta = lDgA * phis, RE = 0.5 d |u - v| (eps rho) / mu."""
    phis = 1.0 - eps
    slip = slip_from_re(eps, re)
    RE = 0.5 * D * slip * (eps * RHO) / MU
    f_stokes = 18.0 * MU * eps * eps / D**2
    w = math.exp(-10.0 * (0.4 - phis) / phis)
    F_0 = F_1 = None
    if 0.01 < phis < 0.4:
        F_0 = (1 - w) * (1 + 3 * math.sqrt(phis / 2) + 135 / 64 * phis * math.log(phis) + 17.14 * phis) / (
            1 + 0.681 * phis - 8.48 * phis**2 + 8.16 * phis**3
        ) + w * 10 * phis / (1 - phis) ** 3
    elif phis >= 0.4:
        F_0 = 10 * phis / (1 - phis) ** 3
    if 0.01 < phis <= 0.1:
        F_1 = math.sqrt(2 / phis) / 40
    elif phis > 0.1:
        F_1 = 0.11 + 5.1e-4 * math.exp(11.6 * phis)
    if phis < 0.4:
        F_2 = (1 - w) * (1 + 3 * math.sqrt(phis / 2) + 135 / 64 * phis * math.log(phis) + 17.89 * phis) / (
            1 + 0.681 * phis - 11.03 * phis**2 + 15.41 * phis**3
        ) + w * 10 * phis / (1 - phis) ** 3
    else:
        F_2 = 10 * phis / (1 - phis) ** 3
    F_3 = 0.9351 * phis + 0.03667 if phis < 0.0953 else 0.0673 + 0.212 * phis + 0.0232 / (1 - phis) ** 5
    if phis <= 0.01:
        re_t1 = (F_2 - 1) / (3 / 8 - F_3)
        F = 1 + 3 / 8 * RE if RE <= re_t1 else F_2 + F_3 * RE
    else:
        re_t2 = (F_3 + math.sqrt(F_3 * F_3 - 4 * F_1 * (F_0 - F_2))) / (2 * F_1)
        F = F_0 + F_1 * RE * RE if RE <= re_t2 else F_2 + F_3 * RE
    beta = F * f_stokes * phis
    return f_from_beta(beta, eps)


REFS = {
    "beetstra": ref_beetstra,
    "wen_yu": ref_wen_yu,
    "ergun_gidaspow": ref_ergun_gidaspow,
    "di_felice": ref_di_felice,
    "koch_hill": ref_koch_hill,
}


@pytest.mark.parametrize("name", sorted(REFS))
def test_closure_matches_published_formula(name):
    e = np.array([g[0] for g in GRID])
    r = np.array([g[1] for g in GRID])
    got = drag.CLOSURES[name](e, r)
    ref = np.array([REFS[name](a, b) for a, b in GRID])
    assert got.shape == ref.shape == (len(GRID),)
    assert np.all(np.isfinite(got)) and np.all(got > 0)
    rel = np.abs(got / ref - 1.0)
    assert rel.max() < 1e-10, (name, rel.max(), GRID[int(rel.argmax())])


@pytest.mark.parametrize("name", sorted(REFS))
def test_beta_matches_published_coefficient(name):
    """beta(eps, Re, mu, d) = 18 mu phi eps F / d^2, checked against the dimensional reference."""
    for e, r in GRID[::7]:
        b = drag.beta(e, r, MU, D, name)
        ref = REFS[name](e, r) * 18.0 * MU * (1.0 - e) * e / D**2
        assert abs(b / ref - 1.0) < 1e-10
        # force on one particle, V beta/(1-eps) |u - v| = 3 pi mu d eps F |u - v|
        slip = slip_from_re(e, r)
        k = drag.drag_force_factor(e, r, MU, D, name)
        assert abs(k * slip / (math.pi * D**3 / 6.0 * b / (1.0 - e) * slip) - 1.0) < 1e-12


def test_koch_hill_dilute_branch():
    """phi <= 0.01: the Oseen branch 1 + 3/8 Re' and the F2 + F3 Re' branch (MFIX)."""
    pts = [(e, r) for e in (0.991, 0.995, 0.999) for r in np.logspace(-2, 3, 31)]
    got = drag.koch_hill(np.array([p[0] for p in pts]), np.array([p[1] for p in pts]))
    ref = np.array([ref_koch_hill(*p) for p in pts])
    assert np.max(np.abs(got / ref - 1.0)) < 1e-10
    # both branches really occur on this grid
    osc = np.isclose(got, np.array([e * (1 + 3 / 16 * r) for e, r in pts]), rtol=1e-12)
    assert 0 < osc.sum() < len(pts)


def test_ergun_branch_switch_is_at_eps_0p8():
    """Gidaspow: Ergun strictly below 0.8, Wen-Yu at and above."""
    assert drag.ergun_gidaspow(0.7999999, 10.0) == pytest.approx(drag._ergun(0.7999999, 10.0), rel=1e-14)
    assert drag.ergun_gidaspow(0.8, 10.0) == pytest.approx(drag.wen_yu(0.8, 10.0), rel=1e-14)
