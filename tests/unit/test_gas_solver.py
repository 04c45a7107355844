"""GasSolver API: restart, thread independence, input checks, diagnostics, AMG reuse."""

import numba
import numpy as np
import pytest

from cfddem.errors import CaseError
from cfddem.gas import GasSolver, Inlet, LidCrossWind, NoSlip, PressureOutlet, StaggeredGrid


pytestmark = pytest.mark.usefixtures("one_numba_thread")


def chute_section(advection="tvd", viscosity="explicit", pressure_solver="mg", **kw):
    g = StaggeredGrid((6, 5, 16), (0.08, 0.045, 0.24))
    om = (0.0, 1.45, -0.84)
    bcs = {"x-": NoSlip(), "x+": NoSlip(), "y-": NoSlip(), "y+": LidCrossWind(omega=om, axis_point=(0.04, 0, 0.035)),
           "z-": Inlet(speed=lambda x, y, z: 0.5 + 5 * y), "z+": PressureOutlet(p=lambda x, y, z: 1.2 * -8.5 * y)}
    s = GasSolver(g, bcs=bcs, gravity=(0.0, -8.5, 4.9), omega=om, axis_point=(0.04, 0, 0.035), advection=advection,
                  viscosity=viscosity, pressure_solver=pressure_solver, **kw)
    return g, s


def eps_at(g, t):
    X, Y, Z = g.mesh("ccc")
    return 0.7 + 0.2 * np.sin(40 * X + 30 * Y - 20 * Z + 15 * t)


def drive(s, g, n0, n1, dt=1e-3):
    shapes = [g.interior_shape(loc) for loc in ("fcc", "cfc", "ccf")]
    K = tuple(np.full(sh, 20.0) for sh in shapes)
    Up = (np.zeros(shapes[0]), np.zeros(shapes[1]), np.full(shapes[2], 0.7))
    src = (np.zeros(shapes[0]), np.full(shapes[1], -0.3), np.zeros(shapes[2]))
    infos = []
    for n in range(n0, n1):
        s.set_porosity(eps_at(g, (n + 1) * dt))
        infos.append(s.step(dt, source=src, drag_K=K, drag_Up=Up))
        assert infos[-1].ok, infos[-1].message
    return infos


@pytest.mark.parametrize("viscosity", ["explicit", "implicit"])
def test_restart_is_bit_identical(viscosity):
    g, a = chute_section(viscosity=viscosity)
    a.set_porosity(eps_at(g, 0.0))
    drive(a, g, 0, 8)
    state = a.get_state()
    drive(a, g, 8, 16)
    g2, b = chute_section(viscosity=viscosity)
    b.set_state(state)
    drive(b, g2, 8, 16)
    for fa, fb in zip((a.u, a.v, a.w, a.p), (b.u, b.v, b.w, b.p)):
        assert np.array_equal(fa.data, fb.data)
    assert a.time == b.time and a.step_count == b.step_count == 16


def test_thread_count_does_not_change_results():
    res = []
    for nt in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
        numba.set_num_threads(nt)
        g, s = chute_section(threads=None)  # the kernels on every thread the caller has
        s.set_porosity(eps_at(g, 0.0))
        drive(s, g, 0, 5)
        res.append([f.data.copy() for f in (s.u, s.v, s.w, s.p)])
    numba.set_num_threads(1)
    for x, y in zip(*res):
        assert np.array_equal(x, y)


@pytest.mark.parametrize("pressure_solver", ["mg", "amg"])
def test_step_info_and_amg_reuse(pressure_solver):
    g, s = chute_section(pressure_solver=pressure_solver)
    s.set_porosity(eps_at(g, 0.0))
    infos = drive(s, g, 0, 12)
    if pressure_solver == "amg":
        assert infos[0].amg_rebuilt
        assert s.psolver.n_rebuilds < 12  # the hierarchy is reused while eps changes slowly
    else:
        assert not any(i.amg_rebuilt for i in infos) and s.psolver.n_rebuilds == 0
    for i in infos:
        assert 0 < i.pressure_iterations < 60 and i.max_divergence < 1e-9
        if pressure_solver == "amg":
            assert i.pressure_residual <= 1e-8
        else:  # mg stops at the relative tolerance or at the guaranteed mass-balance defect
            assert i.pressure_residual <= 1e-8 or i.max_divergence <= s.defect_tol
        assert 0 < i.cfl < 1
    assert s.max_stable_dt() > 0
    c = s.cell_centred_velocity()
    assert c.shape == (6, 5, 16, 3)
    assert np.allclose(c[..., 2], 0.5 * (s.w.interior[:, :, :-1] + s.w.interior[:, :, 1:]))


def test_nan_is_reported_with_cell_and_quantity():
    g, s = chute_section()
    s.u.data[g.halo + 3, g.halo + 2, g.halo + 7] = np.nan
    info = s.step(1e-3)
    assert not info.ok
    assert "non-finite gas" in info.message and "index" in info.message


def test_bad_inputs_raise():
    g, s = chute_section()
    with pytest.raises(CaseError, match="porosity"):
        s.set_porosity(np.full(g.shape, 1.5))
    with pytest.raises(CaseError, match="porosity"):
        s.set_porosity(np.ones((2, 2, 2)))
    with pytest.raises(CaseError, match="source"):
        s.step(1e-3, source=(np.zeros((1, 1, 1)),) * 3)
    with pytest.raises(CaseError, match="drag_K"):
        s.step(1e-3, drag_K=tuple(-np.ones(g.interior_shape(loc)) for loc in ("fcc", "cfc", "ccf")),
               drag_Up=tuple(np.zeros(g.interior_shape(loc)) for loc in ("fcc", "cfc", "ccf")))
    with pytest.raises(CaseError, match="advection"):
        GasSolver(g, bcs=s.bc.bcs, advection="upwind")
    with pytest.raises(CaseError, match="halo"):
        GasSolver(StaggeredGrid((4, 4, 4), (1, 1, 1), halo=1), bcs=s.bc.bcs)


def test_stable_dt_limits_by_name():
    """Each explicit term's limit, by the formulas of max_stable_dt, which is their minimum;
    inf where a term sets none."""
    from cfddem.gas import Periodic

    g, s = chute_section()
    s.set_porosity(eps_at(g, 0.0))
    lim = s.stable_dt_limits()
    assert set(lim) == {"advective", "viscous", "coriolis"}
    assert s.max_stable_dt() == min(lim.values())
    assert lim["coriolis"] == pytest.approx(0.05 / np.linalg.norm((0.0, 1.45, -0.84)), rel=1e-12)
    e = s.eps.interior
    inv = [1.0 / h**2 for h in g.spacing]
    S = max(sum(inv) + (1.0 + s.lam_ratio) * inv[c] for c in range(3))
    assert lim["viscous"] == pytest.approx(1.0 / (2.0 * s.nu * e.max() / e.min() * S), rel=1e-12)
    s.step(1e-3)
    assert lim["advective"] > s.stable_dt_limits()["advective"] or np.isinf(lim["advective"])
    assert s.stable_dt_limits()["advective"] == pytest.approx(s.cfl_max / s._advective_rate(), rel=1e-12)
    # implicit viscosity, no rotation, gas at rest: no limit at all
    g2 = StaggeredGrid((4, 4, 4), (1.0, 1.0, 1.0))
    s2 = GasSolver(g2, bcs={k: Periodic() for k in ("x-", "x+", "y-", "y+", "z-", "z+")}, viscosity="implicit")
    assert s2.stable_dt_limits() == {"advective": np.inf, "viscous": np.inf, "coriolis": np.inf}
    assert s2.max_stable_dt() == np.inf


@pytest.mark.parametrize("bad", [0.0, -0.1, 1.0 + 1e-9, np.nan, np.inf, -np.inf])
def test_porosity_is_checked_and_kept_on_bad_input(bad):
    """set_porosity (one compiled check-and-copy pass) copies a valid field exactly, names the
    first bad cell of an invalid one (NaN and inf included), and leaves the field as it was."""
    g, s = chute_section()
    e = eps_at(g, 0.0)
    e[-1, -1, -1] = 1.0 + 5e-13  # within the round-off allowance above 1
    s.set_porosity(e)
    assert np.array_equal(s.eps.interior, e)
    before = s.eps.data.copy()
    e2 = eps_at(g, 0.5)
    e2[2, 3, 7] = bad
    e2[4, 1, 9] = bad
    with pytest.raises(CaseError, match=r"porosity.*cell \(2, 3, 7\)"):
        s.set_porosity(e2)
    assert np.array_equal(s.eps.data, before)
    e3 = eps_at(g, 0.7)
    s.set_porosity(np.asfortranarray(e3))  # any memory layout
    assert np.array_equal(s.eps.interior, e3)


def test_implicit_drag_relaxes_to_particle_velocity():
    """Uniform gas in a periodic box with K >> 0: one step with dt K/(eps rho) = 1000 brings
    u within 0.1 % of U_p (implicit: no overshoot, no step limit)."""
    from cfddem.gas import Periodic

    g = StaggeredGrid((4, 4, 4), (1.0, 1.0, 1.0))
    s = GasSolver(g, rho=1.2, mu=1.8e-5, bcs={k: Periodic() for k in ("x-", "x+", "y-", "y+", "z-", "z+")})
    s.set_porosity(np.full(g.shape, 0.5))
    shapes = [g.interior_shape(loc) for loc in ("fcc", "cfc", "ccf")]
    K = tuple(np.full(sh, 600.0) for sh in shapes)
    Up = tuple(np.full(sh, v) for sh, v in zip(shapes, (1.0, -2.0, 0.5)))
    s.step(1.0, drag_K=K, drag_Up=Up)
    # (eps + dt K/rho) u = dt K/rho U_p  ->  u = U_p * 500 / 500.5
    assert np.allclose(s.u.interior, 1.0 * 500 / 500.5, rtol=1e-12)
    assert np.allclose(s.v.interior, -2.0 * 500 / 500.5, rtol=1e-12)


def test_implicit_viscosity_matches_explicit_for_small_steps():
    """With a step far below the viscous limit, semi-implicit and explicit viscosity agree to
    O(dt) (backward vs forward Euler on the same spatial operator)."""
    res = {}
    for visc in ("explicit", "implicit"):
        g, s = chute_section(viscosity=visc)
        s.set_porosity(eps_at(g, 0.0))
        infos = drive(s, g, 0, 10, dt=2e-4)
        res[visc] = s.w.interior.copy()
        if visc == "implicit":
            assert all(i.viscous_iterations > 0 for i in infos)
    scale = np.max(np.abs(res["explicit"]))
    assert np.max(np.abs(res["implicit"] - res["explicit"])) < 1e-3 * scale
    assert np.max(np.abs(res["implicit"] - res["explicit"])) > 0


def test_drag_and_source_reach_the_momentum_balance():
    """Periodic box, eps = 0.4: steady state of eps rho du/dt = S - K (u - U_p) is
    u = U_p + S/K, whatever the time step (implicit drag)."""
    from cfddem.gas import Periodic

    g = StaggeredGrid((4, 3, 5), (0.04, 0.03, 0.05))
    s = GasSolver(g, rho=1.2, mu=1.8e-5, bcs={k: Periodic() for k in ("x-", "x+", "y-", "y+", "z-", "z+")})
    s.set_porosity(np.full(g.shape, 0.4))
    shapes = [g.interior_shape(loc) for loc in ("fcc", "cfc", "ccf")]
    K = tuple(np.full(sh, 100.0) for sh in shapes)
    Up = tuple(np.full(sh, v) for sh, v in zip(shapes, (0.1, -0.2, 0.0)))
    S = tuple(np.full(sh, v) for sh, v in zip(shapes, (5.0, 0.0, -3.0)))
    for _ in range(40):
        assert s.step(0.05, source=S, drag_K=K, drag_Up=Up).ok
    assert np.allclose(s.u.interior, 0.15, rtol=1e-10)
    assert np.allclose(s.v.interior, -0.2, rtol=1e-10)
    assert np.allclose(s.w.interior, -0.03, rtol=1e-10)


def test_plug_flow_through_freeslip_channel_with_outlet():
    """Inlet speed U at z-, pressure outlet at z+, free-slip side walls: the plug flow
    u = (0, 0, U) with uniform pressure is an exact discrete solution and must persist,
    for both advection schemes; the inflow equals the outflow."""
    from cfddem.gas import FreeSlip

    for adv in ("tvd", "central"):
        g = StaggeredGrid((4, 5, 12), (0.04, 0.05, 0.12))
        bcs = {"x-": FreeSlip(), "x+": FreeSlip(), "y-": FreeSlip(), "y+": FreeSlip(),
               "z-": Inlet(speed=0.7), "z+": PressureOutlet(p=0.0)}
        s = GasSolver(g, bcs=bcs, advection=adv)
        s.set_velocity(lambda x, y, z: (0 * x, 0 * x, 0.7 + 0 * x))
        for _ in range(20):
            assert s.step(2e-3).ok
        assert np.allclose(s.w.interior, 0.7, rtol=0, atol=1e-12)
        assert np.max(np.abs(s.u.interior)) < 1e-12 and np.max(np.abs(s.v.interior)) < 1e-12
        assert np.max(np.abs(s.p.interior)) < 1e-9


def test_defect_tol_stops_the_pressure_solve_at_the_guaranteed_mass_balance():
    """The mg solve stops once ||r||_2 <= defect_tol rho/dt^2, which bounds the measured
    defect max|d(eps)/dt + div(eps_f u)| dt by defect_tol; a loose defect_tol saves
    iterations, defect_tol = 0 leaves the relative criterion alone."""
    out = {}
    for dtol in (0.0, 1e-6):
        g, s = chute_section(defect_tol=dtol)
        s.set_porosity(eps_at(g, 0.0))
        out[dtol] = drive(s, g, 0, 8)
    for i in out[0.0]:
        assert i.pressure_residual <= 1e-8
    for i in out[1e-6]:
        assert i.ok and i.max_divergence <= 1e-6
    assert sum(i.pressure_iterations for i in out[1e-6]) < sum(i.pressure_iterations for i in out[0.0])


def test_threads_cap_the_step_and_restore_the_callers_count():
    """threads=1 (the default) runs the step's kernels serially, gives the same numbers as
    the threaded step and hands the caller's thread count back, also after a failed call."""
    nt = min(2, numba.config.NUMBA_NUM_THREADS)
    numba.set_num_threads(nt)
    try:
        res = []
        for threads in (1, None):
            g, s = chute_section(threads=threads)
            assert s.threads == threads
            s.set_porosity(eps_at(g, 0.0))
            drive(s, g, 0, 3)
            assert numba.get_num_threads() == nt
            res.append([f.data.copy() for f in (s.u, s.v, s.w, s.p)])
        for x, y in zip(*res):
            assert np.array_equal(x, y)
        with pytest.raises(CaseError, match="gas.dt"):
            chute_section(threads=1)[1].step(-1.0)
        assert numba.get_num_threads() == nt
        for bad in (0, 1.5, True):
            with pytest.raises(CaseError, match="gas.threads"):
                chute_section(threads=bad)
    finally:
        numba.set_num_threads(1)


def test_initial_guess_options_reach_the_same_flow():
    """The pressure solve's first iterate ("scaled", the default; "previous"; "zero") changes
    the iterations, not the flow: the three runs agree to the solver tolerance; an unknown
    option is a CaseError naming the key."""
    res = {}
    for guess in ("scaled", "previous", "zero"):
        g, s = chute_section(initial_guess=guess)
        assert s.initial_guess == guess
        s.set_porosity(eps_at(g, 0.0))
        infos = drive(s, g, 0, 6)
        assert all(i.ok for i in infos)
        res[guess] = [f.interior.copy() for f in (s.u, s.v, s.w, s.p)]
    for guess in ("previous", "zero"):
        for a, b in zip(res["scaled"], res[guess]):
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-7 * np.abs(b).max())
    with pytest.raises(CaseError, match="gas.initial_guess"):
        chute_section(initial_guess="last")
