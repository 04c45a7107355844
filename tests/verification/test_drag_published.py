"""Each drag closure against an independent implementation of its published formula.

The reference versions (tests.analytic.PublishedDrag) are written in the dimensional form of
each paper (a momentum-exchange coefficient beta or a force on one particle, built from a slip
velocity, density, viscosity and diameter) and only then mapped to F = F_d/(3 pi mu d eps |u - v|),
so they share no algebra with cfddem.coupling.drag.  Agreement to 1e-10 relative on
eps in [0.4, 0.99] x Re in [0.01, 1000].
"""

import math

import numpy as np
import pytest

from cfddem.coupling import drag
from tests.analytic import PublishedDrag

MU, RHO, D = 1.8e-5, 1.2, 3.0e-3
EPS = np.linspace(0.4, 0.99, 25)
RE = np.logspace(-2, 3, 31)
GRID = [(float(e), float(r)) for e in EPS for r in RE]


# independent references (tests.analytic.PublishedDrag), one function (eps, Re) -> F per closure
PUB = PublishedDrag(mu=MU, rho=RHO, d=D)
REFS = {name: PUB.closure(name) for name in PublishedDrag.CLOSURES}


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
        slip = PUB.slip_from_re(e, r)
        k = drag.drag_force_factor(e, r, MU, D, name)
        assert abs(k * slip / (math.pi * D**3 / 6.0 * b / (1.0 - e) * slip) - 1.0) < 1e-12


def test_koch_hill_dilute_branch():
    """phi <= 0.01: the Oseen branch 1 + 3/8 Re' and the F2 + F3 Re' branch (MFIX)."""
    pts = [(e, r) for e in (0.991, 0.995, 0.999) for r in np.logspace(-2, 3, 31)]
    got = drag.koch_hill(np.array([p[0] for p in pts]), np.array([p[1] for p in pts]))
    ref = np.array([PUB.koch_hill(*p) for p in pts])
    assert np.max(np.abs(got / ref - 1.0)) < 1e-10
    # both branches really occur on this grid
    osc = np.isclose(got, np.array([e * (1 + 3 / 16 * r) for e, r in pts]), rtol=1e-12)
    assert 0 < osc.sum() < len(pts)


def test_ergun_branch_switch_is_at_eps_0p8():
    """Gidaspow: Ergun strictly below 0.8, Wen-Yu at and above."""
    assert drag.ergun_gidaspow(0.7999999, 10.0) == pytest.approx(drag._ergun(0.7999999, 10.0), rel=1e-14)
    assert drag.ergun_gidaspow(0.8, 10.0) == pytest.approx(drag.wen_yu(0.8, 10.0), rel=1e-14)
