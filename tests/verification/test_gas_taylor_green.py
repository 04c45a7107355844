"""2D Taylor-Green vortex in a periodic box: spatial order of accuracy of the velocity.

u = sin x cos y e^{-2 nu t}, v = -cos x sin y e^{-2 nu t}, p = (rho/4)(cos 2x + cos 2y)
e^{-4 nu t} on [0, 2 pi]^2, eps = 1.  The time step scales with h^2 so that the first-order
temporal error shrinks as fast as the second-order spatial error; the measured order of the
max-norm velocity error over three grids must be 2 +- 0.2 for the central scheme.
"""

import numpy as np
import pytest

from cfddem.gas import GasSolver, Periodic, StaggeredGrid
from tests.analytic import TaylorGreen


pytestmark = pytest.mark.usefixtures("one_numba_thread")


def tg_error(N, advection, nu=0.05, T=0.5):
    L = 2 * np.pi
    g = StaggeredGrid((N, N, 1), (L, L, L / N))
    bcs = {s: Periodic() for s in ("x-", "x+", "y-", "y+", "z-", "z+")}
    s = GasSolver(g, rho=1.0, mu=nu, bcs=bcs, advection=advection, tol=1e-10)
    tg = TaylorGreen(nu)
    s.set_velocity(lambda x, y, z: (*tg.velocity(x, y, 0.0), 0 * x))
    s.set_pressure(lambda x, y, z: tg.pressure(x, y, 0.0))
    h = L / N
    n = int(np.ceil(T / (0.25 * h * h)))
    dt = T / n
    for _ in range(n):
        info = s.step(dt)
        assert info.ok, info.message
    X, Y, Z = g.mesh("fcc")
    ue = tg.velocity(X, Y, T)[0]
    X, Y, Z = g.mesh("cfc")
    ve = tg.velocity(X, Y, T)[1]
    return max(np.max(np.abs(s.u.interior - ue)), np.max(np.abs(s.v.interior - ve)))


def test_taylor_green_second_order_central():
    errs = [tg_error(N, "central") for N in (16, 32, 64)]
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    print("central: errors", errs, "orders", orders)
    assert np.all(np.abs(orders - 2.0) < 0.2), orders
    assert errs[-1] < 2e-3


def test_taylor_green_tvd_converges():
    """van Leer TVD clips the slope at the extrema of the velocity.  On these grids the
    clipping error shrinks faster than h^2 (measured orders 2.4 and 2.7, errors 6.5e-3,
    1.2e-3, 1.9e-4): the TVD scheme is at least second order here, but less accurate than
    central on coarse grids."""
    errs = [tg_error(N, "tvd") for N in (16, 32, 64)]
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    print("tvd: errors", errs, "orders", orders)
    assert np.all(orders > 1.8), orders
    assert errs[-1] < 5e-4
