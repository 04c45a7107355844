"""Lid-driven cavity at Re = 100 against Ghia, Ghia & Shin (1982), J. Comput. Phys. 48, 387,
Tables I and II (Re = 100 columns): u along the vertical centre line, v along the horizontal
centre line.  Unit square, lid speed 1 (the y+ side), nu = 0.01, 64 x 64 cells (2D: one
periodic cell in z), TVD advection, marched to a steady state.  Default tier: semi-implicit
viscosity with a large step; slow tier: the same with explicit viscosity.  Bound: 2 % of the
lid speed at all 17 tabulated points of each profile (both runs are within 0.9 %)."""

import numpy as np
import pytest

from cfddem.gas import GasSolver, NoSlip, Periodic, StaggeredGrid, Velocity


pytestmark = pytest.mark.usefixtures("one_numba_thread")


Y_GHIA = np.array([1.0, 0.9766, 0.9688, 0.9609, 0.9531, 0.8516, 0.7344, 0.6172, 0.5, 0.4531, 0.2813,
                   0.1719, 0.1016, 0.0703, 0.0625, 0.0547, 0.0])
U_GHIA = np.array([1.0, 0.84123, 0.78871, 0.73722, 0.68717, 0.23151, 0.00332, -0.13641, -0.20581, -0.21090,
                   -0.15662, -0.10150, -0.06434, -0.04775, -0.04192, -0.03717, 0.0])
X_GHIA = np.array([1.0, 0.9688, 0.9609, 0.9531, 0.9453, 0.9063, 0.8594, 0.8047, 0.5, 0.2344, 0.2266,
                   0.1563, 0.0938, 0.0781, 0.0703, 0.0625, 0.0])
V_GHIA = np.array([0.0, -0.05906, -0.07391, -0.08864, -0.10313, -0.16914, -0.22445, -0.24533, 0.05454,
                   0.17527, 0.17507, 0.16077, 0.12317, 0.10890, 0.10091, 0.09233, 0.0])


def cavity(N, advection="tvd", viscosity="explicit", cfl=0.5):
    g = StaggeredGrid((N, N, 1), (1.0, 1.0, 1.0 / N))
    bcs = {"x-": NoSlip(), "x+": NoSlip(), "y-": NoSlip(), "y+": Velocity((1.0, 0.0, 0.0)),
           "z-": Periodic(), "z+": Periodic()}
    s = GasSolver(g, rho=1.0, mu=0.01, bcs=bcs, advection=advection, tol=1e-6, viscosity=viscosity, cfl_max=cfl)
    dt = 0.9 * min(s.max_stable_dt(), cfl / N)
    u_old = s.u.interior.copy()
    for i in range(20000):
        info = s.step(dt)
        assert info.ok, info.message
        if i % 100 == 99:
            rate = np.max(np.abs(s.u.interior - u_old)) / (100 * dt)
            u_old = s.u.interior.copy()
            if rate < 1e-4:  # d|u|/dt < 1e-4 lid speeds per unit time: steady
                break
    assert rate < 1e-4
    assert s.divergence_residual() < 1e-10
    yc = np.concatenate([[0.0], g.centres(1), [1.0]])
    ucol = np.concatenate([[0.0], s.u.interior[N // 2, :, 0], [1.0]])  # x = 0.5 is a u-face
    xc = np.concatenate([[0.0], g.centres(0), [1.0]])
    vrow = np.concatenate([[0.0], s.v.interior[:, N // 2, 0], [0.0]])  # y = 0.5 is a v-face
    return np.interp(Y_GHIA, yc, ucol) - U_GHIA, np.interp(X_GHIA, xc, vrow) - V_GHIA


def test_cavity_re100_64_implicit_viscosity():
    """The brief's grid with the semi-implicit viscosity and a step at Courant number 0.9 of
    the lid speed (dt = 0.014, 3x the explicit viscous limit): 1100 steps, about 12 s.
    Measured: max |u - u_Ghia| = 0.0044, max |v - v_Ghia| = 0.0082 (lid speed 1)."""
    du, dv = cavity(64, viscosity="implicit", cfl=0.9)
    print("max |du|", np.max(np.abs(du)), "max |dv|", np.max(np.abs(dv)))
    assert np.max(np.abs(du)) < 0.02
    assert np.max(np.abs(dv)) < 0.02


@pytest.mark.slow
def test_cavity_re100_64_explicit():
    """Explicit viscosity, dt = 0.9 x the viscous limit (4200 steps, about 40 s on an idle
    core).  Measured: max |u - u_Ghia| = 0.0043, max |v - v_Ghia| = 0.0081."""
    du, dv = cavity(64)
    print("max |du|", np.max(np.abs(du)), "max |dv|", np.max(np.abs(dv)))
    assert np.max(np.abs(du)) < 0.02
    assert np.max(np.abs(dv)) < 0.02
