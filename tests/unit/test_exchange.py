"""Unit tests of cfddem.coupling.exchange: exact momentum exchange, phase counter, restart."""

import logging

import numpy as np
import pytest

from cfddem.coupling.exchange import CoupledGas, CouplingStatus
from cfddem.coupling.mapping import porosity
from cfddem.gas import NoSlip, Periodic, StaggeredGrid
from cfddem.particles.contact import LinearContact
from cfddem.particles.system import ParticleSystem

pytestmark = pytest.mark.usefixtures("one_numba_thread")


L = 0.02
PERIODIC = {s: Periodic() for s in ("x-", "x+", "y-", "y+", "z-", "z+")}


def _box(density, seed=1, N=10, treatment="implicit", n_side=5, closure="beetstra"):
    sys_ = ParticleSystem(pp=LinearContact(k_n=100.0, e_n=0.9, e_t=0.5, mu=0.3), walls=[], dt=1e-5,
                          periodic=((0.0, L),) * 3)
    rng = np.random.default_rng(seed)
    g1 = (np.arange(n_side) + 0.5) * L / n_side
    P = np.array(np.meshgrid(g1, g1, g1, indexing="ij")).reshape(3, -1).T
    P = P + rng.uniform(-1e-3, 1e-3, P.shape)
    sys_.add_particles(P, 0.0, 0.5e-3, density)
    grid = StaggeredGrid((4, 4, 4), (L, L, L))
    cg = CoupledGas(sys_, grid, PERIODIC, rho=1.2, mu=1.8e-5, coupling_interval=N, drag_treatment=treatment,
                    closure=closure, tol=1e-12)
    cg.gas.set_velocity(lambda x, y, z: (1.0 + 0 * x, 0.3 * np.sin(2 * np.pi * x / L), 0.2 * np.cos(2 * np.pi * y / L)))
    return sys_, cg


def _total(sys_, cg):
    return cg.gas_momentum() + sys_.momentum()


def test_exchange_is_exact_and_total_momentum_conserved_heavy_particles():
    """Closed periodic box, no gravity, gas moving, particles at rest.  The drag and the
    pressure exchange are exact to round-off (both sides recorded by the coupler).  With
    particles so dense that they barely move (the porosity is then constant in time) the
    total momentum is constant to 1e-12 relative."""
    sys_, cg = _box(2.5e9)
    assert cg.advance(10).ok  # first step projects the initial (not eps-divergence-free) field
    P0 = _total(sys_, cg)
    for _ in range(15):
        st = cg.advance(10)
        assert st.ok, st.message
        e = cg.last_exchange
        scale = np.abs(e["particle_drag_impulse"]).max()
        assert scale > 0
        np.testing.assert_allclose(e["particle_drag_impulse"], -e["gas_drag_impulse"], rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(e["particle_pressure_impulse"], -e["gas_solid_pressure_impulse"], rtol=0,
                                   atol=1e-12 * scale)
    P1 = _total(sys_, cg)
    assert np.max(np.abs(P1 - P0)) <= 1e-12 * np.linalg.norm(P0)
    # the particles did receive momentum (the test is not trivially satisfied)
    assert np.linalg.norm(sys_.momentum()) > 1e-4 * np.linalg.norm(P0) * 1e-3


def test_total_momentum_glass_particles():
    """Glass particles accelerate and move: the exchange stays exact; the total momentum
    drifts only by the gas's advection-form term (second time difference of the porosity),
    measured about 4e-9 relative here; assert 1e-7."""
    sys_, cg = _box(2500.0)
    assert cg.advance(10).ok
    P0 = _total(sys_, cg)
    pp0 = sys_.momentum().copy()
    for _ in range(15):
        assert cg.advance(10).ok
        e = cg.last_exchange
        scale = np.abs(e["particle_drag_impulse"]).max()
        np.testing.assert_allclose(e["particle_drag_impulse"], -e["gas_drag_impulse"], rtol=0, atol=1e-12 * scale)
    P1 = _total(sys_, cg)
    gained = np.linalg.norm(sys_.momentum() - pp0)
    assert gained > 1e-2 * np.linalg.norm(P0)  # the particles took a few per cent of the momentum
    assert np.max(np.abs(P1 - P0)) <= 1e-7 * np.linalg.norm(P0)


def test_phase_counter_and_split_calls_bit_identical():
    s1, c1 = _box(2500.0, n_side=3)
    s2, c2 = _box(2500.0, n_side=3)
    assert c1.advance(28).ok
    for n in (7, 7, 3, 11):
        assert c2.advance(n).ok
    assert c1.gas.step_count == c2.gas.step_count == 3  # couplings at steps 0, 10, 20
    assert c1.phase == c2.phase == 8
    assert np.array_equal(c1.gas.u.data, c2.gas.u.data)
    assert np.array_equal(s1.pos, s2.pos) and np.array_equal(s1.vel, s2.vel)


def test_restart_bit_identical():
    s1, c1 = _box(2500.0, n_side=3)
    assert c1.advance(25).ok  # mid-interval: pending forces must survive the restart
    st_sys, st_gas = s1.get_state(), c1.get_state()
    assert c1.advance(30).ok
    s2, c2 = _box(2500.0, seed=7, n_side=3)  # different start, overwritten by the state
    s2.set_state(st_sys)
    c2.set_state(st_gas)
    assert c2.advance(30).ok
    for a, b in ((c1.gas.u.data, c2.gas.u.data), (c1.gas.p.data, c2.gas.p.data), (s1.pos, s2.pos),
                 (s1.vel, s2.vel), (c1.mean_velocity(), c2.mean_velocity())):
        assert np.array_equal(a, b)
    assert c1.series_row() == c2.series_row()


def test_series_row_vtk_fields_and_diagnostics():
    sys_, cg = _box(2500.0, n_side=3)
    assert cg.advance(20).ok
    row = cg.series_row()
    for k in ("gas_pressure_iterations", "gas_cfl", "min_porosity", "gas_max_divergence", "drag_power",
              "gas_momentum_x", "particle_momentum_z"):
        assert k in row and np.isfinite(row[k])
    assert 0.9 < row["min_porosity"] < 1.0
    assert row["drag_power"] > 0
    # no cell below eps_min: the end-of-run line says nothing about the porosity
    st = cg.run_stats()
    assert st["gas_steps"] == 2 and st["gas_low_porosity_steps"] == 0 and np.isnan(st["gas_low_porosity_min"])
    assert "porosity" not in cg.run_summary()
    v = cg.vtk_fields()
    assert v["shape"] == (4, 4, 4)
    assert v["cell_data"]["velocity"].shape == (4, 4, 4, 3)
    assert v["cell_data"]["pressure"].shape == (4, 4, 4)
    assert np.all(np.isfinite(v["cell_data"]["velocity"]))
    lines = cg.diagnostics()
    assert any("cell volume / particle volume" in s for s in lines)
    assert any("relaxation time" in s for s in lines)


def test_pressure_gradient_transpose_exact_for_linear_pressure():
    """G from the face gradients equals the exact gradient for a linear pressure in the
    interior of a periodic-in-y box (walls elsewhere: the wall cells see half the gradient)."""
    sys_ = ParticleSystem(pp=LinearContact(k_n=100.0, e_n=0.9, e_t=0.5, mu=0.3), walls=[], dt=1e-5)
    bcs = {"x-": NoSlip(), "x+": NoSlip(), "y-": Periodic(), "y+": Periodic(), "z-": NoSlip(), "z+": NoSlip()}
    grid = StaggeredGrid((5, 4, 6), (0.05, 0.04, 0.06))
    cg = CoupledGas(sys_, grid, bcs, rho=1.2, mu=1.8e-5)
    cg.gas.set_pressure(lambda x, y, z: 3.0 * x - 2.0 * z)
    G = cg.centre_pressure_gradient()
    np.testing.assert_allclose(G[0][1:-1], 3.0, rtol=1e-12)
    np.testing.assert_allclose(G[0][0], 1.5, rtol=1e-12)
    np.testing.assert_allclose(G[2][:, :, 1:-1], -2.0, rtol=1e-12)
    np.testing.assert_allclose(G[1], 0.0, atol=1e-12)


def test_negative_porosity_is_reported_not_clipped():
    sys_ = ParticleSystem(pp=LinearContact(k_n=100.0, e_n=0.9, e_t=0.5, mu=0.3), walls=[], dt=1e-5,
                          periodic=((0.0, L),) * 3)
    sys_.add_particles([[0.00375, 0.00375, 0.00375]], 0.0, 2e-3, 2500.0)  # 2.1 times the volume of a 2.5 mm cell
    grid = StaggeredGrid((8, 8, 8), (L, L, L))
    cg = CoupledGas(sys_, grid, PERIODIC, rho=1.2, mu=1.8e-5)
    st = cg.advance(5)
    assert isinstance(st, CouplingStatus) and not st.ok
    assert "gas cell (1, 1, 1)" in st.message and "porosity" in st.message
    # with a floor the run goes on; the cells below eps_min (0.3) are counted silently and
    # reported once, in the end-of-run summary line
    records = []
    log = logging.getLogger("test_exchange.low_porosity")
    log.addHandler(_Collect(records))
    cg2 = CoupledGas(sys_, grid, PERIODIC, rho=1.2, mu=1.8e-5, eps_floor=0.2, log=log)
    assert cg2.advance(50).ok  # 5 gas steps, the particle at rest in gas at rest
    assert cg2.series_row()["n_clipped_cells"] >= 1
    assert records == []
    ref = porosity(grid, sys_.pos, sys_.radius, boundaries=(True, True, True))
    assert ref.n_low == 1 and ref.eps_min_found < 0.0  # the particle centred in cell (1, 1, 1)
    st = cg2.run_stats()
    assert (st["gas_steps"], st["gas_low_porosity_steps"], st["gas_low_porosity_cells_max"]) == (5, 5, ref.n_low)
    assert st["gas_low_porosity_min"] == pytest.approx(ref.eps_min_found, rel=1e-12)
    assert cg2.run_summary().endswith(
        "; porosity below 0.3 in 5 of the gas steps (at most 1 cell at once, lowest "
        f"{ref.eps_min_found:.3g} in cell (1, 1, 1) at t = 0 s; expected where particles pack densely in single "
        "cells, as at a feed lattice or a pile against a wall; the gas used max(eps, 0.2))")


class _Collect(logging.Handler):
    def __init__(self, out):
        super().__init__(logging.DEBUG)
        self.out = out

    def emit(self, record):
        self.out.append(record)


def test_bad_arguments():
    sys_ = ParticleSystem(pp=LinearContact(k_n=100.0, e_n=0.9, e_t=0.5, mu=0.3), walls=[], dt=1e-5)
    grid = StaggeredGrid((2, 2, 2), (L, L, L))
    from cfddem.errors import CaseError

    with pytest.raises(CaseError):
        CoupledGas(sys_, grid, PERIODIC, rho=1.2, mu=1.8e-5, drag_treatment="semi")
    with pytest.raises(CaseError):
        CoupledGas(sys_, grid, PERIODIC, rho=1.2, mu=1.8e-5, periodic=(True, False, True))
    with pytest.raises(CaseError):
        CoupledGas(sys_, grid, PERIODIC, rho=1.2, mu=1.8e-5, closure="stokes")


def test_particle_free_box_is_the_plain_gas_solver():
    """Without particles the coupler adds nothing: walls, an inlet and an outlet, gravity;
    the fields equal those of a GasSolver stepped alone, bit for bit (the boundary half-cell
    source of step 5b is blended out in particle-free cells)."""
    from cfddem.gas import GasSolver, Inlet, PressureOutlet

    bcs = {"x-": NoSlip(), "x+": NoSlip(), "y-": Inlet(speed=0.3), "y+": PressureOutlet(p=0.0),
           "z-": NoSlip(), "z+": NoSlip()}
    grid = StaggeredGrid((3, 5, 4), (0.03, 0.05, 0.04))
    sys_ = ParticleSystem(pp=LinearContact(k_n=100.0, e_n=0.9, e_t=0.5, mu=0.3), walls=[], dt=1e-4)
    cg = CoupledGas(sys_, grid, bcs, rho=1.2, mu=1.8e-5, coupling_interval=5, gravity=(0.0, -9.81, 0.0))
    ref = GasSolver(grid, rho=1.2, mu=1.8e-5, bcs=bcs, gravity=(0.0, -9.81, 0.0))
    for s in (cg.gas, ref):
        s.set_velocity(lambda x, y, z: (0 * x, 0.3 + 0 * x, 0.01 * np.sin(100 * x)))
    ref.set_porosity(np.ones(grid.shape))
    assert cg.advance(25).ok
    for _ in range(5):
        assert ref.step(5e-4).ok
    for a, b in ((cg.gas.u.data, ref.u.data), (cg.gas.v.data, ref.v.data), (cg.gas.w.data, ref.w.data),
                 (cg.gas.p.data, ref.p.data)):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("kind", ["walls_inlet_outlet", "mixed_periodic", "one_cell_wall_axis"])
def test_compiled_pressure_fields_equal_numpy_reference(kind):
    """_pressure_fields (one compiled pass) gives the same G and Gb, bit for bit, as the numpy
    face gradients and _centre_from_faces, and the solid part sum_f (1 - eps_f) g_f of the gas's
    pressure exchange (eps_f the gas's face porosity) to round-off; for walls + inlet + outlet (boundary half-cells on
    two axes), a mixed periodic box, and a one-cell wall axis."""
    from cfddem.gas import Inlet, PressureOutlet

    sys_ = ParticleSystem(pp=LinearContact(k_n=100.0, e_n=0.9, e_t=0.5, mu=0.3), walls=[], dt=1e-5)
    if kind == "walls_inlet_outlet":
        bcs = {"x-": NoSlip(), "x+": NoSlip(), "y-": NoSlip(), "y+": NoSlip(), "z-": Inlet(speed=0.3),
               "z+": PressureOutlet(p=0.0)}
        cells = (5, 4, 7)
    elif kind == "mixed_periodic":
        bcs = {"x-": Periodic(), "x+": Periodic(), "y-": Inlet(speed=0.2), "y+": PressureOutlet(p=0.0),
               "z-": Periodic(), "z+": Periodic()}
        cells = (4, 6, 3)
    else:
        bcs = {"x-": NoSlip(), "x+": NoSlip(), "y-": NoSlip(), "y+": NoSlip(), "z-": Periodic(), "z+": Periodic()}
        cells = (1, 5, 4)
    grid = StaggeredGrid(cells, (0.05, 0.04, 0.06))
    cg = CoupledGas(sys_, grid, bcs, rho=1.2, mu=1.8e-5)
    rng = np.random.default_rng(5)
    pr = rng.normal(size=cells)
    cg.gas.p.interior[...] = pr
    cg.gas.fill_halos()
    cg.gas.set_porosity(rng.uniform(0.4, 1.0, cells))
    grads = cg._face_gradients()
    G_ref = cg._centre_from_faces(grads)
    Gb_ref = cg._centre_from_faces(grads, boundary=True)
    solid_ref = np.array([float(np.sum((1.0 - ef) * g)) for ef, g in zip(cg._face_porosity(), grads)])
    G, Gb, solid = cg._pressure_fields()
    assert any(np.any(g != 0) for g in G)
    assert G.shape == Gb.shape == cells + (3,)
    for c in range(3):
        assert np.array_equal(G[..., c], G_ref[c])
        assert np.array_equal(Gb[..., c], Gb_ref[c])
        if not cg._has_boundary[c]:
            assert not np.any(Gb_ref[c])
    assert any(cg._has_boundary)
    scale = max(float(np.sum(np.abs(g))) for g in grads)
    np.testing.assert_allclose(solid, solid_ref, rtol=0, atol=1e-13 * scale)
    assert np.any(np.abs(solid_ref) > 1e-3 * scale)


def test_coupling_step_identical_for_one_and_two_threads():
    """A whole coupling step (porosity, drag, gas step, forces, exchange sums) on a box with
    walls, an inlet and an outlet: bit-identical ext_force, gas fields and exchange records
    for 1 and 2 numba threads."""
    import numba

    from cfddem.gas import Inlet, PressureOutlet

    def run(nt):
        sys_ = ParticleSystem(pp=LinearContact(k_n=100.0, e_n=0.9, e_t=0.5, mu=0.3), walls=[], dt=1e-5)
        rng = np.random.default_rng(3)
        sys_.add_particles(rng.uniform(0.001, 0.019, (400, 3)), rng.normal(0, 0.1, (400, 3)), 0.4e-3, 2500.0)
        bcs = {"x-": NoSlip(), "x+": NoSlip(), "y-": NoSlip(), "y+": NoSlip(), "z-": Inlet(speed=0.3),
               "z+": PressureOutlet(p=0.0)}
        cg = CoupledGas(sys_, StaggeredGrid((4, 4, 5), (L, L, L)), bcs, rho=1.2, mu=1.8e-5, coupling_interval=5,
                        gravity=(0.0, -9.81, 0.0))
        prev = numba.get_num_threads()
        numba.set_num_threads(nt)
        avg = np.zeros(cg.grid.shape + (3,))
        try:
            for _ in range(2):
                assert cg.couple() is None
                avg += cg.gas.cell_centred_velocity() * cg.dt_gas
        finally:
            numba.set_num_threads(prev)
        assert np.array_equal(cg._avg_sum, avg)  # the compiled time average = the gas's centre velocity
        return (np.array(sys_.ext_force), np.array(cg.gas.u.data), np.array(cg.gas.p.data),
                {k: np.array(v) for k, v in cg.last_exchange.items()}, dict(cg._last))

    a = run(1)
    b = run(min(2, __import__("numba").config.NUMBA_NUM_THREADS))
    assert np.any(a[0] != 0.0)
    for x, y in zip(a[:3], b[:3]):
        assert np.array_equal(x, y)
    for k in a[3]:
        assert np.array_equal(a[3][k], b[3][k])
    assert a[4] == b[4]
    # exchange records: drag and pressure (5a) balance to round-off
    ex = a[3]
    imp = np.abs(ex["particle_drag_impulse"]).max()
    np.testing.assert_allclose(ex["particle_drag_impulse"], -ex["gas_drag_impulse"], rtol=0, atol=1e-12 * imp)


@pytest.mark.parametrize("name", ["beetstra", "wen_yu", "ergun_gidaspow", "di_felice", "koch_hill"])
def test_named_closure_compiled_path_equals_its_numpy_form(name):
    """A named closure runs by its compiled twin in the coupling (drag.drag_values); a user's
    callable runs as given.  Wrapping the closure's numpy form in a lambda takes the callable
    path: the two runs' forces on the particles agree to the twins' round-off (2e-15 in F)."""
    from cfddem.coupling import drag

    def run(closure):
        sys_, cg = _box(2500.0, seed=3, N=5, closure=closure)
        for _ in range(4):
            assert cg.advance(5).ok
        return cg, sys_.ext_force.copy()

    cg_named, f_named = run(name)
    cg_fn, f_fn = run(lambda e, r: drag.CLOSURES[name](e, r))
    assert cg_named._cid == drag.closure_id(name) and cg_fn._cid is None
    scale = np.abs(f_fn).max()
    assert scale > 1e-9  # the gas drags the particles
    np.testing.assert_allclose(f_named, f_fn, rtol=0, atol=1e-12 * scale)
