"""Prescribed, time-varying porosity: the discrete porous continuity equation
d(eps)/dt + div(eps_f u) = 0 holds to 1e-10 (times dt) every step."""

import numpy as np
import pytest

from cfddem.gas import GasSolver, Inlet, NoSlip, Periodic, PressureOutlet, StaggeredGrid


pytestmark = pytest.mark.usefixtures("one_numba_thread")


def eps_field(g, t):
    X, Y, Z = g.mesh("ccc")
    return 0.7 + 0.04 * np.sin(2 * np.pi * 5 * t) + 0.2 * np.sin(2 * np.pi * X / 0.08) * np.sin(np.pi * Y / 0.045) * np.cos(2 * np.pi * (Z / 0.2 - 3 * t))


def test_mass_balance_open_chute_section():
    g = StaggeredGrid((8, 6, 20), (0.08, 0.045, 0.2))
    bcs = {"x-": NoSlip(), "x+": NoSlip(), "y-": NoSlip(), "y+": NoSlip(), "z-": Inlet(speed=0.3),
           "z+": PressureOutlet(p=0.0)}
    s = GasSolver(g, rho=1.2, mu=1.8e-5, bcs=bcs, gravity=(0.0, -8.5, 4.9), tol=1e-10)
    s.set_porosity(eps_field(g, 0.0))
    dt = 2e-3
    worst = 0.0
    for n in range(1, 41):
        s.set_porosity(eps_field(g, n * dt))
        info = s.step(dt)
        assert info.ok, info.message
        worst = max(worst, s.divergence_residual())
        assert s.divergence_residual() < 1e-10, (n, s.divergence_residual())
    print("worst dt*|deps/dt + div(eps u)|", worst)
    # the porosity change really drives a flow: the outflow differs from the inflow
    ef = 0.5 * (s.eps.data[g.halo:-g.halo, g.halo:-g.halo, g.halo + 19] + s.eps.data[g.halo:-g.halo, g.halo:-g.halo, g.halo + 20])
    out = np.sum(ef * s.w.interior[:, :, -1])
    ef_in = 0.5 * (s.eps.data[g.halo:-g.halo, g.halo:-g.halo, g.halo - 1] + s.eps.data[g.halo:-g.halo, g.halo:-g.halo, g.halo])
    inflow = np.sum(ef_in * s.w.interior[:, :, 0])
    dedt = np.sum(eps_field(g, 40 * dt) - eps_field(g, 39 * dt)) / dt * g.spacing[2]
    assert abs(out - inflow) > 1e-3 * abs(inflow)
    assert (out - inflow) == pytest.approx(-dedt, rel=1e-8, abs=1e-12)


def test_mass_balance_periodic_box_with_drag():
    """Fully periodic (singular pressure system), a porosity wave travelling with speed c and
    implicit drag towards a particle velocity U_p: mass balance to 1e-10 every step."""
    g = StaggeredGrid((6, 6, 16), (0.06, 0.06, 0.16))
    s = GasSolver(g, rho=1.2, mu=1.8e-5, bcs={k: Periodic() for k in ("x-", "x+", "y-", "y+", "z-", "z+")},
                  tol=1e-10)
    X, Y, Z = g.mesh("ccc")
    ev = lambda t: 0.6 + 0.3 * np.sin(2 * np.pi * (Z / 0.16 - 0.5 * t)) * np.cos(2 * np.pi * X / 0.06)  # noqa: E731
    s.set_porosity(ev(0.0))
    shapes = [g.interior_shape(loc) for loc in ("fcc", "cfc", "ccf")]
    K = tuple(np.full(sh, 50.0) for sh in shapes)
    Up = (np.zeros(shapes[0]), np.zeros(shapes[1]), np.full(shapes[2], 0.08))
    dt = 5e-3
    for n in range(1, 31):
        s.set_porosity(ev(n * dt))
        info = s.step(dt, drag_K=K, drag_Up=Up)
        assert info.ok, info.message
        assert s.divergence_residual() < 1e-10
        assert abs(info.compatibility) < 1e-9
    assert np.max(np.abs(s.w.interior)) > 1e-3
