"""The one boundary model (cfddem.gas.boundaries.BC rules, read by the gas, the mapping and the
exchange) and the face operators written once (cfddem.gas.operators), against the formulas
they replaced."""

from dataclasses import dataclass

import numpy as np
import pytest

from cfddem.coupling import mapping as M
from cfddem.coupling.exchange import CoupledGas
from cfddem.errors import CaseError
from cfddem.gas import (BC, BoundarySet, FreeSlip, GasSolver, Inlet, LidCrossWind, NoSlip, Periodic,
                        PressureOutlet, StaggeredGrid, Velocity)
from cfddem.gas import operators as op
from cfddem.particles.contact import LinearContact
from cfddem.particles.system import ParticleSystem

pytestmark = pytest.mark.usefixtures("one_numba_thread")

SIDES = ("x-", "x+", "y-", "y+", "z-", "z+")
RULE_NAMES = ("normal_rule", "tangential_rule", "pressure_rule", "particle_rule", "half_cell_source")

# what each kind declares (docs/gas.md, "The boundary model")
DECLARED = [
    (NoSlip(), ("prescribed", "prescribed", "neumann", "fold", True)),
    (FreeSlip(), ("prescribed", "slip", "neumann", "fold", True)),
    (Velocity(value=(0.1, 0.0, 0.0)), ("prescribed", "prescribed", "neumann", "fold", True)),
    (Inlet(speed=0.2), ("prescribed", "prescribed", "neumann", "fold", True)),
    (LidCrossWind(omega=(0.0, 0.0, 1.0)), ("prescribed", "prescribed", "neumann", "fold", True)),
    (PressureOutlet(p=0.0), ("solved", "zero_gradient", "dirichlet", "fold", False)),
    (Periodic(), ("periodic", "periodic", "periodic", "wrap", False)),
]


@pytest.mark.parametrize("bc,rules", DECLARED, ids=[type(b).__name__ for b, _ in DECLARED])
def test_each_kind_declares_its_rules(bc, rules):
    assert tuple(getattr(bc, r) for r in RULE_NAMES) == rules
    assert bc.periodic == (rules[0] == "periodic")


def _mixed_box(cells=(4, 5, 3)):
    """Walls on x, inlet y- and outlet y+, periodic z."""
    bcs = {"x-": NoSlip(), "x+": FreeSlip(), "y-": Inlet(speed=0.2), "y+": PressureOutlet(p=1.0),
           "z-": Periodic(), "z+": Periodic()}
    return StaggeredGrid(cells, (0.04, 0.05, 0.03), halo=2), bcs


def test_boundary_set_derives_what_the_consumers_read():
    grid, bcs = _mixed_box()
    bs = BoundarySet(grid, bcs)
    assert bs.periodic == (False, False, True)
    # the momentum equation updates the outlet face (n = 5 along y), not the wall/inlet faces
    assert bs.face_range == [(1, 4), (1, 6), (0, 3)]
    assert bs.pressure_bc == {"x-": "neumann", "x+": "neumann", "y-": "neumann", "y+": "dirichlet",
                              "z-": "periodic", "z+": "periodic"}
    assert bs.particle_rules == ("fold", "fold", "fold", "fold", "wrap", "wrap")
    assert bs.half_cell == ((True, True), (True, False), (False, False))
    assert bs.needs_wide_halo
    a = np.arange(float(np.prod(grid.interior_shape("ccf")))).reshape(grid.interior_shape("ccf"))
    bs.copy_periodic_faces(a, 2, 0)
    assert np.array_equal(a[:, :, 3], a[:, :, 0])
    b = a.copy()
    bs.copy_periodic_faces(b, 0, 0)  # x is not periodic: nothing
    assert np.array_equal(a, b)


def test_exchange_and_mapping_read_the_rules():
    """CoupledGas takes its half-cell sides from the BCs, and its mapping plans take the BCs'
    particle rules: the same weights as the equivalent periodic flags."""
    grid, bcs = _mixed_box()
    sys_ = ParticleSystem(pp=LinearContact(k_n=100.0, e_n=0.9, e_t=0.5, mu=0.3), walls=[], dt=1e-5)
    cg = CoupledGas(sys_, grid, bcs, rho=1.2, mu=1.8e-5)
    assert cg._bside == [(True, True), (True, False), (False, False)]
    assert cg._has_boundary == [True, True, False]
    rng = np.random.default_rng(0)
    pos = rng.uniform(-0.002, 1.0, (200, 3)) * np.array(grid.lengths)  # some beyond the sides
    for loc in M.LOCATIONS:
        i1, w1 = M.trilinear_weights(grid, pos, loc, cg.gas.bc)
        i2, w2 = M.trilinear_weights(grid, pos, loc, (False, False, True))
        i3, w3 = M.trilinear_weights(grid, pos, loc, bcs)
        assert np.array_equal(i1, i2) and np.array_equal(w1, w2)
        assert np.array_equal(i1, i3) and np.array_equal(w1, w3)
    plan = M.MappingPlan(grid, pos, cg.gas.bc)
    assert plan.rules == cg.gas.bc.particle_rules and plan.periodic == (False, False, True)
    with pytest.raises(CaseError, match="both sides"):
        M.MappingPlan(grid, pos, dict(bcs, **{"z+": NoSlip()}))
    with pytest.raises(CaseError, match="particle rule"):
        M.MappingPlan(grid, pos, ("fold",) * 5 + ("reflect",))


@dataclass(frozen=True)
class _Bad(BC):
    kind = "bad"


def test_inconsistent_rules_are_rejected():
    grid, bcs = _mixed_box()
    cases = [
        (dict(particle_rule="wrap"), "all four"),  # periodic in one rule only
        (dict(normal_rule="solved"), "needs pressure_rule 'dirichlet'"),  # solved with Neumann
        (dict(normal_rule="solved", pressure_rule="dirichlet"), "half_cell_source"),  # ... with a half cell
        (dict(tangential_rule="reflect"), "allowed"),  # not a rule value
    ]
    for over, msg in cases:
        bad = type("Bad", (_Bad,), over)()
        with pytest.raises(CaseError, match=r"gas\.bcs\.x-.*" + msg):
            BoundarySet(grid, dict(bcs, **{"x-": bad}))
    BoundarySet(grid, dict(bcs, **{"x-": _Bad()}))  # the base rules are consistent
    with pytest.raises(CaseError, match="both sides"):
        BoundarySet(grid, dict(bcs, **{"z+": NoSlip()}))


@dataclass(frozen=True)
class PorousMovingLid(BC):
    """A kind that exists nowhere in cfddem, added here in one place: the gas leaves through
    the lid at the pressure ``p`` (a solved normal face), the lid drags the gas along x at
    ``speed`` (a prescribed tangential velocity)."""

    speed: float = 0.0
    p: float = 0.0
    kind = "porous_lid"
    normal_rule = "solved"
    tangential_rule = "prescribed"
    pressure_rule = "dirichlet"
    half_cell_source = False

    def velocity(self, side, x, y, z):
        shape = np.broadcast(x, y, z).shape
        return np.full(shape, self.speed), np.zeros(shape), np.zeros(shape)

    def pressure(self, side, x, y, z):
        return self.p


def test_a_new_kind_added_in_one_place():
    """The subclass above works in the halo fill, the gas step, the mapping and the exchange
    without a change anywhere else."""
    cells = (4, 6, 3)
    grid = StaggeredGrid(cells, (0.04, 0.06, 0.03), halo=2)
    bcs = {"x-": Periodic(), "x+": Periodic(), "y-": Inlet(speed=0.1), "y+": PorousMovingLid(speed=0.3, p=2.0),
           "z-": Periodic(), "z+": Periodic()}
    gas = GasSolver(grid, bcs=bcs, rho=1.2, mu=1.8e-5, gravity=(0.0, -9.81, 0.0))
    assert gas.bc.face_range[1] == (1, cells[1] + 1)  # the lid face is an unknown
    assert gas.bc.pressure_bc["y+"] == "dirichlet" and gas.bc.half_cell[1] == (True, False)
    gas.set_velocity(lambda x, y, z: (0.0 * x, 0.1 + 0.0 * x, 0.0 * x))
    for _ in range(5):
        info = gas.step(1e-3)
        assert info.ok, info.message
    h, ny = grid.halo, cells[1]
    u, v, p = gas.u.data, gas.v.data, gas.p.data
    # tangential: the lid speed is the mean of the last interior point and its ghost
    np.testing.assert_allclose(0.5 * (u[:, h + ny - 1] + u[:, h + ny]), 0.3, rtol=0, atol=1e-14)
    # normal: zero-gradient halo beyond the solved lid face; pressure: 2 p_b - interior
    assert np.array_equal(v[:, h + ny + 1], v[:, h + ny])
    np.testing.assert_allclose(0.5 * (p[:, h + ny - 1] + p[:, h + ny]), 2.0, rtol=0, atol=1e-12)
    # continuity: the lid passes what the inlet feeds
    assert info.max_divergence < 1e-10
    flux_out = float(np.sum(v[h:h + cells[0], h + ny, h:h + cells[2]]))
    np.testing.assert_allclose(flux_out, 0.1 * cells[0] * cells[2], rtol=1e-9)
    # coupled: a few particles, the exchange balances its drag
    sys_ = ParticleSystem(pp=LinearContact(k_n=100.0, e_n=0.9, e_t=0.5, mu=0.3), walls=[], dt=1e-5)
    rng = np.random.default_rng(2)
    sys_.add_particles(rng.uniform(0.1, 0.9, (20, 3)) * np.array(grid.lengths), 0.0, 1e-3, 2500.0)
    cg = CoupledGas(sys_, grid, bcs, rho=1.2, mu=1.8e-5, coupling_interval=5)
    cg.gas.set_velocity(lambda x, y, z: (0.0 * x, 0.1 + 0.0 * x, 0.0 * x))
    st = cg.advance(10)
    assert st.ok
    ex = cg.last_exchange
    d = ex["particle_drag_impulse"] + ex["gas_drag_impulse"]
    assert np.all(np.abs(d) <= 1e-12 * np.abs(ex["particle_drag_impulse"]).max())
    assert np.any(ex["particle_drag_impulse"] != 0)


# ---- the operators against the formulas they replaced -----------------------------------
def test_face_gradient_and_interpolation_operators_equal_the_old_formulas():
    """c2f_gradient (c2f_grad_at) is np.diff / h bit for bit (the exchange's and the mapping's
    old formula); interp_to_face (c2f_interp_at) the arithmetic mean; interp_to_centre
    (f2c_interp_at) the old cell_centred_velocity formula."""
    rng = np.random.default_rng(4)
    grid = StaggeredGrid((5, 4, 6), (0.07, 0.05, 0.11), halo=2)
    p = grid.zeros("ccc")
    p.data[...] = rng.normal(size=p.data.shape) * 1e3
    for d in range(3):
        h = grid.spacing[d]
        g = op.c2f_gradient(p.data, d, h)
        sl = [slice(None)] * 3
        sl[d] = slice(1, p.data.shape[d])
        assert np.array_equal(g[tuple(sl)], np.diff(p.data, axis=d) / h)
        f = op.interp_to_face(p, d).data
        lo = [slice(None)] * 3
        hi = [slice(None)] * 3
        lo[d] = slice(0, -1)
        hi[d] = slice(1, None)
        assert np.array_equal(f[tuple(sl)], 0.5 * (p.data[tuple(lo)] + p.data[tuple(hi)]))
    gas = GasSolver(grid, bcs={s: NoSlip() for s in SIDES}, rho=1.2, mu=1.8e-5)
    for f in gas.velocity:
        f.data[...] = rng.normal(size=f.data.shape)
    g = grid.halo
    nx, ny, nz = grid.shape
    u, v, w = gas.u.data, gas.v.data, gas.w.data
    old = np.empty((nx, ny, nz, 3))
    old[..., 0] = 0.5 * (u[g:g + nx, g:g + ny, g:g + nz] + u[g + 1:g + nx + 1, g:g + ny, g:g + nz])
    old[..., 1] = 0.5 * (v[g:g + nx, g:g + ny, g:g + nz] + v[g:g + nx, g + 1:g + ny + 1, g:g + nz])
    old[..., 2] = 0.5 * (w[g:g + nx, g:g + ny, g:g + nz] + w[g:g + nx, g:g + ny, g + 1:g + nz + 1])
    assert np.array_equal(gas.cell_centred_velocity(), old)


def _old_mapping_face_gradient(spec, p, per):
    """cfddem.coupling.mapping.face_gradient before the operators (commit 1b56e68)."""
    grads = []
    for a in range(3):
        h = spec.spacing[a]
        shp = list(spec.shape)
        shp[a] += 1
        g = np.zeros(shp)
        sl = [slice(None)] * 3
        sl[a] = slice(1, spec.shape[a])
        g[tuple(sl)] = np.diff(p, axis=a) / h
        if per[a]:
            first = [slice(None)] * 3
            last = [slice(None)] * 3
            first[a] = slice(0, 1)
            last[a] = slice(spec.shape[a] - 1, spec.shape[a])
            wrap = (p[tuple(first)] - p[tuple(last)]) / h
            s0 = [slice(None)] * 3
            s0[a] = slice(0, 1)
            sn = [slice(None)] * 3
            sn[a] = slice(spec.shape[a], spec.shape[a] + 1)
            g[tuple(s0)] = wrap
            g[tuple(sn)] = wrap
        grads.append(g)
    return grads


@pytest.mark.parametrize("per", [(False, False, False), (True, False, True), (True, True, True)])
def test_mapping_face_gradient_equals_the_old_formula(per):
    spec = M.GridSpec((0.0, -0.1, 0.3), (0.013, 0.017, 0.011), (4, 5, 3))
    p = np.random.default_rng(7).normal(size=spec.shape) * 50.0
    for got, ref in zip(M.face_gradient(spec, p, per), _old_mapping_face_gradient(spec, p, per)):
        assert got.shape == ref.shape and np.array_equal(got, ref)


def _old_boundary_source(cg):
    """CoupledGas._boundary_source before the operators (numpy, commit 1b56e68)."""
    h = cg.grid.halo
    e = cg.gas.eps.data
    p = cg.gas.p.data
    core = [slice(h, h + n) for n in cg.grid.shape]
    out = []
    for c in range(3):
        n = cg.grid.shape[c]
        shp = list(cg.grid.shape)
        shp[c] += 1
        S = np.zeros(shp)
        lo, hi = cg.gas.bc.face_range[c]
        for lower, on in zip((True, False), cg._bside[c]):
            if not on:
                continue
            f = 1 if lower else n - 1
            cell = 0 if lower else n - 1
            sl = list(core)
            sl[c] = slice(h + cell, h + cell + 1)
            eb = e[tuple(sl)]
            a = list(core)
            b = list(core)
            a[c] = slice(h + f, h + f + 1)
            b[c] = slice(h + f - 1, h + f)
            g = (p[tuple(a)] - p[tuple(b)]) / cg.grid.spacing[c] if lo <= f < hi else np.zeros_like(eb)
            blend = np.minimum(1.0, (1.0 - eb) / cg.HALF_CELL_SOLID)
            idx = [slice(None)] * 3
            idx[c] = slice(f, f + 1)
            S[tuple(idx)] += 0.5 * eb * blend * (-g + cg.rho * cg._g[c])
        out.append(S)
    return out


def test_boundary_source_and_face_gradients_equal_the_old_formulas():
    """The exchange's half-cell source (now a kernel on c2f_grad_at) and its face gradients
    (now grad_to_face) bit for bit as the numpy code they replaced; walls, an inlet, an
    outlet and a periodic axis."""
    grid, bcs = _mixed_box((4, 5, 3))
    sys_ = ParticleSystem(pp=LinearContact(k_n=100.0, e_n=0.9, e_t=0.5, mu=0.3), walls=[], dt=1e-5)
    cg = CoupledGas(sys_, grid, bcs, rho=1.2, mu=1.8e-5, gravity=(0.3, -9.81, 0.0))
    rng = np.random.default_rng(3)
    cg.gas.p.interior[...] = rng.normal(size=grid.shape) * 10.0
    cg.gas.fill_halos()
    cg.gas.set_porosity(rng.uniform(0.35, 1.0, grid.shape))
    S = cg._boundary_source()
    for c, (got, ref) in enumerate(zip(S, _old_boundary_source(cg))):
        assert np.array_equal(got, ref), c
    assert np.any(S[0] != 0) and np.any(S[1] != 0) and not np.any(S[2])
    h = grid.halo
    pd = cg.gas.p.data
    for c, got in enumerate(cg._face_gradients()):
        n = grid.shape[c]
        sl = [slice(h, h + grid.shape[e]) for e in range(3)]
        sl[c] = slice(h - 1, h + n + 1)
        ref = np.diff(pd[tuple(sl)], axis=c)
        ref /= grid.spacing[c]
        lo, hi = cg.gas.bc.face_range[c]
        idx = [slice(None)] * 3
        idx[c] = slice(0, lo)
        ref[tuple(idx)] = 0.0
        idx[c] = slice(hi, n + 1)
        ref[tuple(idx)] = 0.0
        assert np.array_equal(got, ref), c
