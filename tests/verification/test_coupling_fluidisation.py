"""Fluidisation of a CFD-DEM column (benchmarks/fluidisation.py builds it): glass spheres
d = 2 mm on a floor, gas fed uniformly from below at a prescribed superficial velocity U.
Below U_mf the pressure drop follows the closure; above it the pressure drop levels off at
the buoyant bed weight per area; U_mf matches drag.minimum_fluidisation_velocity."""

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

from cfddem.coupling import drag
from cfddem.coupling.mapping import MappingPlan

_spec = importlib.util.spec_from_file_location(
    "fluidisation_bench", Path(__file__).resolve().parents[2] / "benchmarks" / "fluidisation.py")
FB = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(FB)


@pytest.fixture(autouse=True)
def _one_thread():
    import numba

    n = numba.get_num_threads()
    numba.set_num_threads(1)
    yield
    numba.set_num_threads(n)


def closure_pressure_drop(sys_, cg, U, closure="beetstra"):
    """Fixed-bed pressure drop from the closure at each particle's own porosity: the gas
    balance ``eps grad p = drag density`` gives dp = sum_a K(eps_a, Re) (U/eps_a) / (eps_a A),
    Re = rho U d / mu (the superficial Reynolds number of the closures)."""
    plan = MappingPlan(cg.grid, np.ascontiguousarray(sys_.pos), cg.periodic)
    eps_a = plan.interpolate(cg.gas.eps.interior, "ccc")
    d = 2.0 * sys_.radius
    re = FB.RHO_G * U * d / FB.MU
    K = drag.drag_force_factor(eps_a, re, FB.MU, d, closure)
    A = cg.grid.lengths[0] * cg.grid.lengths[2]
    return float(np.sum(K * U / eps_a**2)) / A


def _weight(sys_, cg):
    A = cg.grid.lengths[0] * cg.grid.lengths[2]
    rho_p = float(sys_.mass[0] / (4.0 / 3.0 * math.pi * sys_.radius[0] ** 3))
    return float(np.sum(sys_.mass)) * FB.G * (1.0 - FB.RHO_G / rho_p) / A


def _average(sys_, cg, t, samples):
    dps = []
    for _ in range(samples):
        FB.run(sys_, cg, t / samples)
        dps.append(FB.pressure_drop(cg))
    return float(np.mean(dps))


def test_fluidisation_small_column():
    """500 particles, 2 x 12 x 2 cells of 6 mm: fixed bed at 0.5 U_mf within 6 % of the
    closure; fluidised at 1.6 U_mf: pressure drop within 3 % of the bed weight."""
    sys_, cg = FB.build_column(500, cells=(2, 12, 2))
    FB.run(sys_, cg, 0.2)  # pour and settle, gas at rest
    assert abs(FB.pressure_drop(cg)) < 0.01 * _weight(sys_, cg)
    eps_mf = FB.bed_porosity_seen(sys_, cg)
    assert 0.38 < eps_mf < 0.48
    umf = drag.minimum_fluidisation_velocity(eps_mf, 2550.0, FB.RHO_G, 2e-3, FB.MU)
    U1 = 0.5 * umf
    cg.set_superficial_inlet("y-", U1)
    FB.run(sys_, cg, 0.05)
    dp1 = _average(sys_, cg, 0.05, 5)
    pred = closure_pressure_drop(sys_, cg, U1)
    assert abs(dp1 / pred - 1.0) < 0.06, (dp1, pred)
    assert dp1 < 0.7 * _weight(sys_, cg)
    cg.set_superficial_inlet("y-", 1.6 * umf)
    FB.run(sys_, cg, 0.1)
    dp2 = _average(sys_, cg, 0.3, 30)
    W = _weight(sys_, cg)
    assert abs(dp2 / W - 1.0) < 0.03, (dp2, W)
    assert np.percentile(sys_.pos[:, 1], 5) > 1.2 * sys_.radius[0]  # the bottom layer is lifted


@pytest.mark.slow
def test_fluidisation_curve_1000_particles():
    """1000 particles, 3 x 16 x 3 cells: the full stepped curve; fixed-bed points within 8 %
    of the closure, plateau within 3 % of the bed weight, U_mf (fit of the fixed-bed points
    meeting the weight line) within 10 % of drag.minimum_fluidisation_velocity at the
    porosity the particles see."""
    sys_, cg = FB.build_column(1000, cells=(3, 16, 3))
    u_ref = drag.minimum_fluidisation_velocity(0.42, 2550.0, FB.RHO_G, 2e-3, FB.MU)
    vels = u_ref * np.array([0.2, 0.4, 0.6, 0.75, 0.85, 1.3, 1.5, 1.7])
    FB.run(sys_, cg, 0.25)
    eps_mf = FB.bed_porosity_seen(sys_, cg)
    W = _weight(sys_, cg)
    rows = []
    for U in vels:
        cg.set_superficial_inlet("y-", U)
        pred = closure_pressure_drop(sys_, cg, U)
        FB.run(sys_, cg, 0.1)
        dp = _average(sys_, cg, 0.25, 25)
        rows.append(dict(U=U, dp=dp, pred=pred))
    umf_closure = drag.minimum_fluidisation_velocity(eps_mf, 2550.0, FB.RHO_G, 2e-3, FB.MU)
    fixed = [r for r in rows if r["U"] < 0.9 * umf_closure]
    assert len(fixed) >= 4
    for r in fixed:
        assert abs(r["dp"] / r["pred"] - 1.0) < 0.08, r
    plateau = [r for r in rows if r["U"] > 1.25 * umf_closure]
    assert len(plateau) >= 2
    for r in plateau:
        assert abs(r["dp"] / W - 1.0) < 0.03, (r, W)
    umf, _ = FB.umf_from_curve(rows, W)
    assert abs(umf / umf_closure - 1.0) < 0.10, (umf, umf_closure)
