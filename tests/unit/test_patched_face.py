"""A side with patches (cfddem.gas.boundaries.Patched): one side carrying different rules on
different face cells, read by the halo fill, the momentum update, both pressure solvers and
the exchange.  The silo's bottom is the use: no-slip plates with a pressure outlet over the slot."""

import math

import numpy as np
import pytest

from cfddem.coupling.exchange import CoupledGas
from cfddem.errors import CaseError
from cfddem.gas import BoundarySet, GasSolver, NoSlip, Patched, Periodic, PressureOutlet, StaggeredGrid
from cfddem.particles.contact import LinearContact
from cfddem.particles.system import ParticleSystem

pytestmark = pytest.mark.usefixtures("one_numba_thread")

INF = math.inf
W, H, L = 0.08, 0.06, 0.02
CELLS = (8, 6, 2)
P_TOP = 0.05  # Pa above the slot's 0


def _slot(p=0.0, x0=0.03, x1=0.05, **kw):
    return Patched(default=NoSlip(), patches=[(((x0, -INF, -INF), (x1, INF, INF)), PressureOutlet(p=p))], **kw)


def _bcs(bottom, top=None):
    return {"x-": NoSlip(), "x+": NoSlip(), "z-": NoSlip(), "z+": NoSlip(),
            "y+": top if top is not None else PressureOutlet(p=P_TOP), "y-": bottom}


def _grid():
    return StaggeredGrid(CELLS, (W, H, L), halo=2)


def test_patched_side_rules_per_face_cell():
    bs = BoundarySet(_grid(), _bcs(_slot()))
    # the slot covers x cells 3 and 4 (centres 0.035, 0.045) over the whole depth
    solved = bs.cell_mask("y-", "normal_rule", "solved")
    assert solved.shape == (8, 2)
    assert np.array_equal(np.flatnonzero(solved[:, 0]), [3, 4]) and np.array_equal(solved[:, 0], solved[:, 1])
    assert np.array_equal(bs.cell_mask("y-", "half_cell_source", True), ~solved)
    assert bs.face_range[1] == (0, 7)  # the y- boundary face is in the momentum update (its slot part)
    assert bs.pressure_bc["y-"] == "dirichlet"
    assert bs.half_cell[1] == (True, False)
    assert bs.patched_sides == ["y-"]
    # a tangential point on the edge between plate and slot takes the default (the plate):
    # the u faces of the y- side at x = 0.03 and 0.05 (array indices 2 + 3 and 2 + 5) are no-slip
    u = np.ones(_grid().array_shape("fcc"))
    bs.fill_component(u, 0)
    g = 2
    ghost, first = u[:, g - 1, g], u[:, g, g]
    assert np.allclose(ghost[[g + 3, g + 5]], -first[[g + 3, g + 5]])  # 2 * 0 - a
    assert np.allclose(ghost[g + 4], first[g + 4])  # inside the slot: zero gradient


def test_patched_fill_compiled_equals_numpy():
    grid = _grid()
    bs = BoundarySet(grid, _bcs(_slot(p=0.3)))
    rng = np.random.default_rng(3)
    for loc, fill in (("fcc", lambda a, cp: bs.fill_component(a, 0, cp)), ("cfc", lambda a, cp: bs.fill_component(a, 1, cp)),
                      ("ccf", lambda a, cp: bs.fill_component(a, 2, cp)), ("ccc", lambda a, cp: bs.fill_pressure(a, compiled=cp))):
        a = rng.standard_normal(grid.array_shape(loc))
        b = a.copy()
        fill(a, True)
        fill(b, False)
        assert np.array_equal(a, b), loc


def _run(bottom, steps, ps="mg", top=None):
    gs = GasSolver(_grid(), bcs=_bcs(bottom, top), pressure_solver=ps, tol=1e-12, defect_tol=0.0)
    for _ in range(steps):
        info = gs.step(2e-3)
        assert info.ok, info.message
    return gs, info


@pytest.mark.parametrize("ps", ["mg", "amg"])
def test_flow_through_a_slot_in_a_closed_bottom(ps):
    """Pressure P_TOP on the open top, 0 on the slot: the air flows down and out through the
    slot only.  Steady state: inflow at the top equals outflow through the slot to the solver's
    tolerance, zero normal velocity on the plates, the Dirichlet value on the slot."""
    gs, info = _run(_slot(), 300, ps)
    v = gs.v.interior
    inflow, outflow = -v[:, -1, :].sum(), -v[:, 0, :].sum()
    assert inflow > 0.5  # m/s summed over the 16 top faces: a real flow
    assert abs(inflow - outflow) < 1e-12 * inflow
    assert info.max_divergence < 1e-14
    plate = np.ones(8, bool)
    plate[[3, 4]] = False
    assert np.all(v[plate, 0, :] == 0.0)
    assert np.all(v[~plate, 0, :] < -0.1)  # through the slot
    g = gs.grid.halo
    pb = 0.5 * (gs.p.data[g:g + 8, g - 1, g:g + 2] + gs.p.data[g:g + 8, g, g:g + 2])
    assert np.allclose(pb[~plate], 0.0, atol=1e-15)
    assert np.all(pb[plate] > 0.8 * P_TOP)  # the plates carry (nearly) the top pressure
    # zero gradient across the plate faces (Neumann): the ghost equals the first cell
    assert np.array_equal(gs.p.data[g:g + 8, g - 1, g:g + 2][plate], gs.p.data[g:g + 8, g, g:g + 2][plate])


def test_the_two_pressure_solvers_agree_on_the_slot():
    a, _ = _run(_slot(), 50, "mg")
    b, _ = _run(_slot(), 50, "amg")
    assert np.allclose(a.v.interior, b.v.interior, rtol=0, atol=1e-9)
    assert np.allclose(a.p.interior, b.p.interior, rtol=0, atol=1e-9)


@pytest.mark.parametrize("ps", ["mg", "amg"])
def test_whole_face_patch_is_the_plain_side_bit_for_bit(ps):
    """A patch over the whole face is the plain PressureOutlet side; a patch over no cell is the
    plain NoSlip side: the same fields bit for bit."""
    whole = _slot(p=0.01, x0=-INF, x1=INF)
    none_ = _slot(p=0.01, x0=1.0, x1=2.0)
    top = PressureOutlet(p=P_TOP)
    for patched, plain in ((whole, PressureOutlet(p=0.01)), (none_, NoSlip())):
        a, _ = _run(patched, 20, ps, top)
        b, _ = _run(plain, 20, ps, top)
        for f in ("u", "v", "w", "p"):
            assert np.array_equal(getattr(a, f).data, getattr(b, f).data), f


def test_patched_side_is_refused_when_malformed():
    with pytest.raises(CaseError, match="gas.bcs.y-"):
        BoundarySet(_grid(), _bcs(Patched(default=NoSlip(), patches=[(((0, 0, 0), (1, 1, 1)), Periodic())])))
    with pytest.raises(CaseError, match="particle_rule"):
        BoundarySet(_grid(), _bcs(_slot(particle_rule="wrap")))
    with pytest.raises(CaseError, match="3-vectors"):
        BoundarySet(_grid(), _bcs(Patched(default=NoSlip(), patches=[(((0, 0), (1, 1)), NoSlip())])))
    with pytest.raises(CaseError, match="gas.viscosity"):
        GasSolver(_grid(), bcs=_bcs(_slot()), viscosity="implicit")


def test_exchange_half_cell_and_leave_rule_on_the_patched_side():
    """The boundary half-cell (exchange step 5b) acts on the plates, not over the slot; a
    particle whose centre lies below a side with particle_rule "leave" takes no part in the
    exchange (no volume, no drag, no force), one inside does."""
    grid = _grid()
    sys_ = ParticleSystem(pp=LinearContact(k_n=100.0, e_n=0.9, e_t=0.5, mu=0.3), walls=[], dt=1e-5)
    pos = np.array([[0.005, 0.004, 0.01], [0.04, 0.004, 0.01], [0.04, -0.004, 0.01]])
    sys_.add_particles(pos, np.array([0.0, -0.5, 0.0]), 0.001, 2500.0)
    cg = CoupledGas(sys_, grid, _bcs(_slot(particle_rule="leave")), rho=1.2, mu=1.8e-5,
                    gravity=(0.0, -9.81, 0.0), coupling_interval=1)
    assert cg._bside[1] == (True, False)
    cg.gas.set_pressure(lambda x, y, z: 1.2 * 9.81 * (H - y))
    assert cg.couple() is None
    # porosity: the two particles inside, not the one below the slot
    solid = (1.0 - cg.gas.eps.interior).sum() * grid.cell_volume
    vp = 4.0 / 3.0 * math.pi * 0.001**3
    assert solid == pytest.approx(2 * vp, rel=1e-12)
    f = sys_.ext_force
    assert np.all(f[2] == 0.0)
    assert abs(f[0, 1]) > 0 and abs(f[1, 1]) > 0  # drag on the falling particles inside
    # the half-cell field: on the plate cells, not over the slot
    G, Gb, _ = cg._pressure_fields()
    assert np.all(Gb[[3, 4], 0, :, 1] == 0.0)
    assert np.all(Gb[[0, 1, 2, 5, 6, 7], 0, :, 1] != 0.0)
    ref = cg._centre_from_faces(cg._face_gradients(), boundary=True)[1]
    assert np.allclose(ref, Gb[..., 1], rtol=1e-12, atol=0.0)
    S = cg._boundary_source()
    assert np.all(S[1][[3, 4], 1, :] == 0.0)
