"""Rotating frame: the lab-frame air at rest, seen from the rotating frame, is steady.

In the frame rotating with Omega about an axis through r_a, air at rest in the lab moves
as u = -Omega x (r - r_a) (rigid rotation at -Omega).  With r_perp the distance vector from
the axis: u.grad u = -|Omega|^2 r_perp, Coriolis -2 Omega x u = -2 |Omega|^2 r_perp,
centrifugal -Omega x (Omega x r) = +|Omega|^2 r_perp, so -u.grad u + Coriolis + centrifugal
= 0 and only gravity remains, balanced by the hydrostatic pressure rho g.r.
Closed box whose six sides prescribe that same velocity; gravity parallel to Omega (the
chute's vertical axis, box tilted by 30 degrees).  The discrete operators are exact for
these linear fields, so the state must stay put to round-off and solver tolerance.
"""

import numpy as np
import pytest

from cfddem.gas import GasSolver, LidCrossWind, StaggeredGrid
from tests.analytic import RotatingFrame


pytestmark = pytest.mark.usefixtures("one_numba_thread")


@pytest.mark.parametrize("advection", ["tvd", "central"])
def test_lab_rest_state_is_steady_in_rotating_frame(advection):
    th = np.radians(30.0)
    up = np.array([0.0, np.cos(th), -np.sin(th)])        # vertical in chute coordinates
    omega = 16 * 2 * np.pi / 60 * up                     # 16 rpm
    gravity = -9.81 * up
    axis = (0.035, 0.0, 0.035)
    g = StaggeredGrid((8, 6, 12), (0.08, 0.045, 0.2), origin=(0.0, 0.0, -0.05))
    bc = LidCrossWind(omega=tuple(omega), axis_point=axis)
    rho = 1.2
    s = GasSolver(g, rho=rho, mu=1.8e-5, bcs={k: bc for k in ("x-", "x+", "y-", "y+", "z-", "z+")},
                  gravity=tuple(gravity), omega=tuple(omega), axis_point=axis, advection=advection, tol=1e-10,
                  defect_tol=0.0)  # the relative criterion alone: steadiness to round-off is tested
    s.set_velocity(RotatingFrame(tuple(omega), axis).lab_rest_velocity)
    s.set_pressure(lambda x, y, z: rho * (gravity[0] * x + gravity[1] * y + gravity[2] * z))
    u0 = [f.interior.copy() for f in s.velocity]
    p0 = s.p.interior.copy()
    umax = max(np.max(np.abs(a)) for a in u0)
    dt = s.max_stable_dt()
    for _ in range(50):
        info = s.step(dt)
        assert info.ok, info.message
    du = max(np.max(np.abs(f.interior - a)) for f, a in zip(s.velocity, u0))
    dp = s.p.interior - p0
    dp -= dp.mean()
    print(advection, "du/umax", du / umax, "dp", np.max(np.abs(dp)))
    assert du < 1e-9 * umax
    assert np.max(np.abs(dp)) < 1e-9 * rho * 9.81 * 0.2
    assert s.divergence_residual() < 1e-14


def test_coriolis_turns_a_uniform_stream():
    """A uniform stream u in a fully periodic box with Omega = Omega_z turns at the rate
    2 Omega (inertial oscillation; no pressure gradient arises): after time t the angle is
    2 Omega t to first order in dt."""
    from cfddem.gas import Periodic

    Om = 0.5
    g = StaggeredGrid((4, 4, 4), (1.0, 1.0, 1.0))
    s = GasSolver(g, rho=1.0, mu=0.0, bcs={k: Periodic() for k in ("x-", "x+", "y-", "y+", "z-", "z+")},
                  omega=(0.0, 0.0, Om), axis_point=(0.5, 0.5, 0.5), advection="central")
    s.set_velocity(lambda x, y, z: (1.0 + 0 * x, 0 * x, 0 * x))
    # the centrifugal force |Omega|^2 r_perp is not periodic: cancel it with the source S
    X = g.mesh("fcc")[0]
    Y = g.mesh("cfc")[1]
    src = (Om**2 * -(X - 0.5), Om**2 * -(Y - 0.5), np.zeros(g.interior_shape("ccf")))
    n, T = 400, 1.0
    for _ in range(n):
        assert s.step(T / n, source=src).ok
    ang = np.arctan2(np.mean(s.v.interior), np.mean(s.u.interior))
    u_exact = RotatingFrame((0.0, 0.0, Om)).coriolis_turned((1.0, 0.0, 0.0), T)
    assert ang == pytest.approx(np.arctan2(u_exact[1], u_exact[0]), rel=5e-3)
    # forward Euler grows the speed by sqrt(1 + (2 Omega dt)^2) per step
    speed = np.hypot(np.mean(s.v.interior), np.mean(s.u.interior))
    assert speed == pytest.approx((1 + (2 * Om * T / n) ** 2) ** (n / 2), rel=1e-9)
