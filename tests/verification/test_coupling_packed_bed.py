"""Fixed packed bed in a periodic box driven by a mean pressure gradient G (a body force
eps G on the gas, through the gas's gravity term eps_f rho g with g = G/rho): the superficial
velocity U solves U = eps^2 G / beta(eps, Re(U)), Re = rho U d / mu (physics.md section 4,
beta from the closure; tests.analytic.FixedBed, and for the Ergun branch of ergun_gidaspow the
closed form tests.analytic.Ergun)."""

import numpy as np
import pytest

from cfddem.coupling import drag
from cfddem.coupling.exchange import CoupledGas
from cfddem.gas import Periodic, StaggeredGrid
from cfddem.particles.contact import LinearContact
from cfddem.particles.system import ParticleSystem
from tests.analytic import Ergun, FixedBed

RHO, MU = 1.2, 1.8e-5
PERIODIC = {s: Periodic() for s in ("x-", "x+", "y-", "y+", "z-", "z+")}


pytestmark = pytest.mark.usefixtures("one_numba_thread")


def _bed(closure, G, d=0.8e-3, per_cell=4, cells=4, h=4e-3):
    """Simple cubic lattice commensurate with the grid (every cell holds the same particles at
    the same offsets), so the porosity is uniform.  Particles 1e12 kg/m3: held in place."""
    Lb = cells * h
    s = h / per_cell
    g1 = (np.arange(cells * per_cell) + 0.5) * s
    P = np.array(np.meshgrid(g1, g1, g1, indexing="ij")).reshape(3, -1).T
    sys_ = ParticleSystem(pp=LinearContact(k_n=10.0, e_n=0.9, e_t=0.5, mu=0.3), walls=[], dt=1e-4,
                          periodic=((0.0, Lb),) * 3)
    sys_.add_particles(P, 0.0, d / 2, 1e12)
    cg = CoupledGas(sys_, StaggeredGrid((cells,) * 3, (Lb,) * 3), PERIODIC, rho=RHO, mu=MU, closure=closure,
                    coupling_interval=10, gravity=(G / RHO, 0.0, 0.0))
    eps = 1.0 - len(P) * np.pi * d**3 / 6 / Lb**3
    return sys_, cg, eps, d


def _superficial(cg):
    """Flow rate per area through the x-faces: mean of eps_f u over all x-faces."""
    e = cg.gas.eps.interior
    ef = 0.5 * (e + np.roll(e, 1, axis=0))
    return float(np.mean(ef * cg.gas.u.interior[:-1]))


@pytest.mark.parametrize("closure", ["beetstra", "ergun_gidaspow", "koch_hill", "wen_yu", "di_felice"])
def test_packed_bed_superficial_velocity(closure):
    G = 120.0  # Pa/m
    sys_, cg, eps, d = _bed(closure, G)
    for _ in range(60):  # gas time 0.06 s, about 40 gas relaxation times rho eps / beta
        st = cg.advance(10)
        assert st.ok, st.message
    e = cg.gas.eps.interior
    assert np.ptp(e) < 1e-12 and abs(e.mean() - eps) < 1e-12  # uniform porosity as designed

    U_expect = FixedBed(eps, d, MU, RHO, drag.get_closure(closure)).superficial_velocity(G)
    if closure == "ergun_gidaspow":  # eps < 0.8: the Ergun branch, a quadratic in U
        assert eps < 0.8
        assert U_expect == pytest.approx(Ergun(eps, d, MU, RHO).superficial_velocity(G), rel=1e-10)
    U = _superficial(cg)
    Re = RHO * U_expect * d / MU
    assert 1.0 < Re < 20.0  # beyond Stokes: the implicit relation matters
    # required: 1 %; measured 1e-10 (uniform porosity makes the discrete balance exact)
    assert abs(U - U_expect) / U_expect < 1e-6, (U, U_expect)
    assert np.max(np.abs(sys_.vel)) < 1e-9 * U  # held in place
