"""Square-duct Poiseuille flow: flow rate and second-order convergence.

Duct of side L along z (periodic), no-slip side walls, driven by a uniform body force G
(the pressure gradient) passed as the explicit momentum source, eps = 1.  The exact flow
rate (e.g. White, Viscous Fluid Flow, eq. 3-48, a = b = L/2) is

    Q = G L^4 / (12 mu) [1 - (192 / pi^5) sum_{n odd} tanh(n pi / 2) / n^5]
      = G L^4 / (28.454 mu)

(tests.analytic.SquareDuct).
"""

import numpy as np
import pytest

from cfddem.gas import GasSolver, NoSlip, Periodic, StaggeredGrid
from tests.analytic import SquareDuct


pytestmark = pytest.mark.usefixtures("one_numba_thread")


def duct_flow_rate(N, G=2.0, L=0.1, mu=1e-3, rho=1.0, viscosity="explicit", dt=None, T=0.6):
    g = StaggeredGrid((N, N, 1), (L, L, L / N))
    bcs = {"x-": NoSlip(), "x+": NoSlip(), "y-": NoSlip(), "y+": NoSlip(), "z-": Periodic(), "z+": Periodic()}
    s = GasSolver(g, rho=rho, mu=mu, bcs=bcs, advection="tvd", viscosity=viscosity)
    src = (np.zeros(g.interior_shape("fcc")), np.zeros(g.interior_shape("cfc")), np.full(g.interior_shape("ccf"), G))
    dt = dt or 0.9 * s.max_stable_dt()
    nsteps = int(np.ceil(T * L * L * rho / mu / dt))  # T = 0.6: slowest mode decays by exp(-2 pi^2 * 0.6) ~ 7e-6
    for _ in range(nsteps):
        info = s.step(dt, source=src)
        assert info.ok, info.message
    assert s.divergence_residual() < 1e-12
    print(f"N={N} {viscosity}: {nsteps} steps of {dt:.3g} s")
    w = s.w.interior[:, :, 0]
    assert np.all(w > 0)
    return w.sum() * (L / N) ** 2


def test_square_duct_flow_rate_and_order():
    G, L, mu = 2.0, 0.1, 1e-3
    qe = SquareDuct(G, L, mu).flow_rate()
    assert qe == pytest.approx(G * L**4 / (28.454 * mu), rel=1e-4)
    errs = [abs(duct_flow_rate(N, G, L, mu) - qe) / qe for N in (8, 16, 32)]
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    print("relative flow-rate errors", errs, "orders", orders)
    assert errs[-1] < 0.01
    assert np.all(np.abs(orders - 2.0) < 0.15), orders


def test_implicit_viscosity_takes_large_steps():
    """Semi-implicit viscosity: steps 38 x the explicit limit (dt = 0.2 s vs 5.3e-3 s on
    16 x 16) reach the same steady flow rate as the explicit scheme (measured difference
    2e-9 relative) in 60 steps instead of 2276."""
    G, L, mu = 2.0, 0.1, 1e-3
    q_exp = duct_flow_rate(16, G, L, mu, T=1.2)
    # backward Euler damps the slowest mode by 1/(1 + 2 pi^2 nu dt/L^2) = 0.72 per step: 60 steps
    q_imp = duct_flow_rate(16, G, L, mu, viscosity="implicit", dt=0.2, T=1.2)
    print("explicit", q_exp, "implicit", q_imp)
    assert q_imp == pytest.approx(q_exp, rel=1e-7)
