"""The gas's momentum budget over the whole domain (cfddem.measure.gas_budget): it is the
solver's own update regrouped, so it closes to round-off on any axis with every term on; a
channel in steady state puts the driving force on the walls; a restart continues it exactly.
(The coupled case, drag reaction against the particles' drag: tests/unit/test_budget.py.)"""

import numpy as np
import pytest

from cfddem.errors import CaseError
from cfddem.gas import (FreeSlip, GasSolver, Inlet, LidCrossWind, NoSlip, Periodic, PressureOutlet,
                        StaggeredGrid)
from cfddem.measure.gas_budget import GasBudget

_LOCS = ("fcc", "cfc", "ccf")
OMEGA, AXIS_POINT = (0.0, 1.2, 0.7), (0.003, 0.0, -0.02)


def _busy_solver(**kw):
    """A small box with every kind of side (no-slip, free slip, lid cross-wind, inlet with a
    tangential part, pressure outlet), rotation, gravity and TVD advection."""
    grid = StaggeredGrid((6, 5, 8), (0.012, 0.01, 0.016), origin=(0.0, 0.0, -0.004), halo=2)
    bcs = {"x-": NoSlip(), "x+": FreeSlip(), "y-": NoSlip(), "y+": LidCrossWind(omega=OMEGA, axis_point=AXIS_POINT),
           "z-": Inlet(speed=0.2, tangential=(0.01, 0.0, 0.0)), "z+": PressureOutlet(p=0.3)}
    s = GasSolver(grid, rho=1.2, mu=1e-3, bcs=bcs, gravity=(1.0, -9.81, 4.9), omega=OMEGA, axis_point=AXIS_POINT,
                  tol=1e-10, **kw)
    s.set_velocity(lambda x, y, z: (0 * x, 0 * x, 0.2 + 0 * x))
    return s


def _busy_steps(s, budgets, n0, n1, dt=2e-4):
    """Steps n0..n1-1 with a porosity changing in space and time, random drag and sources;
    each budget closes an interval every 7 steps."""
    X, Y, Z = s.grid.mesh("ccc")
    for n in range(n0, n1):
        rng = np.random.default_rng(n)
        s.set_porosity(0.75 + 0.2 * np.sin(300 * X + 2 * n) * np.cos(200 * Y) * np.sin(100 * Z + n))
        shapes = [s.grid.interior_shape(loc) for loc in _LOCS]
        K = tuple(rng.uniform(0, 50, sh) for sh in shapes)
        Up = tuple(rng.normal(0, 0.1, sh) for sh in shapes)
        S = tuple(rng.normal(0.5, 1, sh) for sh in shapes)
        assert s.step(dt, source=S, drag_K=K, drag_Up=Up).ok
        if n % 7 == 0:
            for b in budgets:
                b.close_interval()


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_budget_closes_to_round_off_with_every_term(axis):
    """Porosity changing every step, drag, sources, rotation, gravity, all side kinds: the
    terms add up to the storage to 1e-13 of the largest term, along each axis; the side terms
    are where they must be (no flux through walls, no shear on a free-slip side)."""
    s = _busy_solver()
    b = GasBudget(s, axis=axis, start_time=2e-3).attach()
    _busy_steps(s, [b], 0, 40)
    r = b.results()
    assert int(r["n_steps"]) == 30  # the steps from t = 2 ms on
    assert r["t_first"] == pytest.approx(2e-3) and r["duration"] == pytest.approx(6e-3)
    assert r["residual_relative"] < 1e-13
    scale = max(abs(float(r[k])) for k in b.terms)
    for k in ("drag", "pressure_particles", "source", "gravity", "coriolis", "centrifugal", "mass_imbalance"):
        assert abs(float(r[k])) > 1e-6 * scale, k  # every volume term is on
    assert r["storage"] != 0.0
    names = set(b.terms)
    ax = "xyz"[axis]
    assert {f"pressure_{ax}-", f"pressure_{ax}+", f"viscous_{ax}-", f"viscous_{ax}+"} <= names
    for side in ("x-", "x+", "y-"):  # walls: nothing flows through them
        if side[0] != ax:
            assert r[f"flux_{side}"] == 0.0
            assert abs(float(r[f"shear_{side}"])) > 0 or side == "x+"
    if ax != "x":
        assert r["shear_x+"] == 0.0  # free slip: no shear stress


def test_restart_continues_the_budget_exactly():
    """get_state / set_state in the middle of the window, with an open interval: the same
    results as without the interruption (bit for bit)."""
    s1, s2 = _busy_solver(), _busy_solver()
    b1 = GasBudget(s1, axis=2).attach()
    b2 = GasBudget(s2, axis=2).attach()
    _busy_steps(s1, [b1], 0, 20)
    _busy_steps(s2, [b2], 0, 10)
    st_gas, st_b = s2.get_state(), b2.get_state()
    s3 = _busy_solver()
    s3.set_state(st_gas)
    b3 = GasBudget(s3, axis=2).attach()
    b3.set_state(st_b)
    _busy_steps(s3, [b3], 10, 20)
    r1, r3 = b1.results(), b3.results()
    assert set(r1) == set(r3)
    for k in r1:
        assert np.array_equal(np.asarray(r1[k]), np.asarray(r3[k]), equal_nan=True), k


def _poiseuille(nx, steps, window):
    """Plane Poiseuille flow between no-slip walls at x = 0 and L driven by a body force
    rho g along z (y and z periodic), started from the exact profile; the budget over the last
    ``window`` steps."""
    L, rho, mu, g = 0.01, 1.0, 1e-2, 1.0
    grid = StaggeredGrid((nx, 2, 4), (L, 0.0025, 0.005), halo=2)
    bcs = {"x-": NoSlip(), "x+": NoSlip(), "y-": Periodic(), "y+": Periodic(), "z-": Periodic(), "z+": Periodic()}
    s = GasSolver(grid, rho=rho, mu=mu, bcs=bcs, gravity=(0.0, 0.0, g), tol=1e-12)
    s.set_velocity(lambda x, y, z: (0 * x, 0 * x, rho * g / (2 * mu) * x * (L - x)))
    dt = 0.5 * s.max_stable_dt()
    b = GasBudget(s, axis=2, start_time=(steps - window - 0.5) * dt).attach()
    for n in range(steps):
        assert s.step(dt).ok
        if n % 50 == 0:
            b.close_interval()
    x = grid.centres(0)
    exact = rho * g / (2 * mu) * x * (L - x)
    err = float(np.abs(s.w.interior[:, 0, 0] - exact).max() / exact.max())
    return b, b.results(), err, rho * g * float(np.prod(grid.lengths)), rho * g * L / 2 * grid.lengths[1] * grid.lengths[2]


def test_poiseuille_wall_shear_carries_the_body_force():
    """In steady state each wall carries half the body force: shear_x- = shear_x+ =
    -gravity/2 to 1e-9 (the steady state is reached to about that), equal to the analytic
    wall stress rho g L/2 times the wall area (the discrete force balance holds whatever the
    grid); the velocity has the discretisation error of second order (1.6 % at 8 cells, 4x
    more at 4), and nothing else acts."""
    b, r, err8, grav, tau_a = _poiseuille(8, 2200, 400)
    assert int(r["n_steps"]) == 400
    assert r["gravity"] == pytest.approx(grav, rel=1e-12)
    for side in ("x-", "x+"):
        assert r[f"shear_{side}"] == pytest.approx(-0.5 * grav, rel=1e-9)
        assert -r[f"shear_{side}"] == pytest.approx(tau_a, rel=1e-9)
        assert r[f"flux_{side}"] == 0.0
    assert abs(r["storage"]) < 1e-9 * grav
    assert abs(r["mass_imbalance"]) < 1e-12 * grav
    assert r["residual_relative"] < 1e-13
    assert b.terms == ["drag", "pressure_particles", "source", "gravity", "coriolis", "centrifugal", "mass_imbalance",
                       "flux_x-", "shear_x-", "flux_x+", "shear_x+"]  # periodic y and z: no side terms
    _, _, err4, _, _ = _poiseuille(4, 600, 100)
    assert 0.012 < err8 < 0.02
    assert err4 / err8 == pytest.approx(4.0, rel=0.1)


def test_duct_with_inlet_and_outlet_balances_pressure_drop_flux_and_shear():
    """A square duct (no-slip on four sides), uniform inflow at z-, pressure outlet at z+,
    developing flow in steady state: pressure force on inlet and outlet + the momentum flux in
    and out + the wall shear = 0 to 1e-6 of the pressure force, the four walls carry equal
    shear (symmetry, 1e-9), the flux out exceeds the flux in (the profile develops: more
    momentum for the same mass) and the mass imbalance is at the pressure solve's tolerance."""
    n, L, Lz, U = 6, 0.006, 0.024, 0.05
    grid = StaggeredGrid((n, n, 12), (L, L, Lz), halo=2)
    bcs = {"x-": NoSlip(), "x+": NoSlip(), "y-": NoSlip(), "y+": NoSlip(), "z-": Inlet(speed=U),
           "z+": PressureOutlet(p=0.0)}
    s = GasSolver(grid, rho=1.0, mu=2e-3, bcs=bcs, tol=1e-12)
    s.set_velocity(lambda x, y, z: (0 * x, 0 * x, U + 0 * x))
    dt = 0.5 * s.max_stable_dt()
    steps = 3000
    b = GasBudget(s, axis=2, start_time=(steps - 300.5) * dt).attach()
    for k in range(steps):
        assert s.step(dt).ok
    r = b.results()
    dp = float(r["pressure_z-"] + r["pressure_z+"])
    assert dp > 0
    shear = sum(float(r[f"shear_{sd}"]) for sd in ("x-", "x+", "y-", "y+"))
    flux = float(r["flux_z-"] + r["flux_z+"])
    assert flux < 0 < float(r["flux_z-"])
    assert dp + flux + shear + float(r["viscous_z-"] + r["viscous_z+"]) == pytest.approx(0.0, abs=1e-6 * dp)
    for sd in ("x+", "y-", "y+"):
        assert r[f"shear_{sd}"] == pytest.approx(r["shear_x-"], rel=1e-9)
    assert abs(float(r["mass_imbalance"])) < 1e-9 * dp
    assert abs(float(r["storage"])) < 1e-6 * dp
    assert r["residual_relative"] < 1e-13


def test_needs_explicit_viscosity_and_a_whole_end_plane():
    with pytest.raises(CaseError, match="gas.viscosity"):
        GasBudget(_busy_solver(viscosity="implicit"), axis=2)
    with pytest.raises(CaseError, match="gas_budget.axis"):
        GasBudget(_busy_solver(), axis=3)
