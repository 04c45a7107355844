"""The particles' momentum budget (cfddem.measure.budget): it closes on cases with a known
answer, and the per-particle force split it reads (ParticleSystem.force_breakdown) adds up to
the engine's force."""

import math

import numpy as np
import pytest

from cfddem.coupling.exchange import column_gas
from cfddem.measure.budget import MomentumBudget, block_error
from cfddem.measure.gas_budget import GasBudget
from cfddem.particles import LinearContact, ParticleSystem, PlaneWall

G = 9.81


def test_block_error_of_independent_samples():
    """Blocks of white noise: the block error is sigma/sqrt(n) within its own scatter."""
    rng = np.random.default_rng(1)
    x = rng.normal(0.0, 2.0, (4000, 3))
    e = block_error(x, 10)
    assert np.all(np.abs(e / (2.0 / math.sqrt(4000)) - 1.0) < 0.6)
    assert np.isnan(block_error(x[:1], 10)).all()


def test_add_gas_bins_against_numpy():
    """add_gas's compiled pass gives numpy's sums: the free particles' drag and pressure per bin
    (particles outside the bins and held ones left out), over every free particle, and the slip
    per porosity class (eps < 0.6, < 0.9, >= 0.9; only binned particles with keff > 0)."""
    rng = np.random.default_rng(3)
    n, edges, dt = 500, np.array([0.0, 0.1, 0.25, 0.3, 0.5]), 2e-4
    pos = rng.uniform(-0.1, 0.6, (n, 3))
    held = rng.random(n) < 0.1
    drag, pres = rng.normal(0, 1e-3, (n, 3)), rng.normal(0, 1e-4, (n, 3))
    keff = np.where(rng.random(n) < 0.2, 0.0, rng.uniform(1e-3, 2e-3, n))
    eps = rng.uniform(0.35, 1.0, n)
    b = MomentumBudget(edges, axis=1)
    b._times.append(0.0)
    b.add_gas(0.0, dt, pos, held, drag, pres, keff, eps)
    z = pos[:, 1]
    binned = ~held & (z >= 0.0) & (z < 0.5)
    idx = np.searchsorted(edges, z, side="right") - 1
    for name, f in (("drag", drag), ("pressure", pres)):
        want = np.array([f[binned & (idx == j), 1].sum() for j in range(4)])
        assert np.allclose(b._acc[name], dt * want, rtol=1e-12, atol=0)
    assert np.allclose(b._acc_all, dt * np.array([drag[~held, 1].sum(), pres[~held, 1].sum()]), rtol=1e-12)
    ok = binned & (keff > 0)
    cls = np.digitize(eps, (0.6, 0.9))
    for j in range(3):
        sel = ok & (cls == j)
        assert sel.sum() > 10
        assert b._slip[j] == pytest.approx(dt * np.array([(drag[sel, 1] / keff[sel]).sum(), sel.sum()]), rel=1e-12)


def test_budget_blocks_do_not_depend_on_threads(monkeypatch):
    """The per-step pass in blocks over the threads: blocks of 64 of 600 particles sliding in a
    rotating, walled box give bit-identical budget terms at 1 and 2 threads, and the same as one
    block (the serial order) to round-off."""
    import numba

    from cfddem import _jit
    from cfddem.measure import budget as bm

    def run(block, threads):
        monkeypatch.setattr(bm, "BUDGET_BLOCK", block)
        law = LinearContact(k_n=500.0, e_n=0.5, e_t=0.5, mu=0.3)
        walls = [PlaneWall(contact=law, point=(0, 0, 0), normal=(0, 1, 0), name="floor"),
                 PlaneWall(contact=law, point=(0, 0, 0), normal=(1, 0, 0), name="side")]
        s = ParticleSystem(pp=law, walls=walls, dt=2e-5, gravity=(-3.0, -G * 0.87, G * 0.5), omega=(0.0, 1.6, 0.0),
                           axis_point=(0.04, 0.0, -0.03), periodic=(None, None, (0.0, 0.06)))
        P = np.array([[0.00149 + 0.0032 * i, 0.00149 + 0.0032 * j, 0.0016 + 0.0032 * k]
                      for j in range(3) for i in range(12) for k in range(18)])[:600]
        s.add_particles(P, [0.0, 0.0, 0.2], 0.0015, 2500.0)
        b = MomentumBudget(np.linspace(0.0, 0.06, 7), axis=2, wall_names=["floor", "side"])
        old = numba.get_num_threads()
        _jit.set_threads(threads)
        try:
            for k in range(600):
                assert s.step(1).ok
                if k >= 100 and k % 50 == 0:
                    b.sample(s.time, s)
        finally:
            numba.set_num_threads(old)
        return b.results()

    one, two, serial = run(64, 1), run(64, min(2, numba.config.NUMBA_NUM_THREADS)), run(1 << 30, 1)
    for k in ("gravity", "walls", "wall_floor", "wall_side", "contacts", "coriolis", "centrifugal", "flux", "residual"):
        assert np.array_equal(one[k], two[k]), k
        scale = np.abs(serial["gravity"]).max()
        assert np.allclose(one[k], serial[k], rtol=1e-9, atol=1e-12 * scale), k
    assert np.abs(one["wall_side"]).max() > 1e-3 * np.abs(one["gravity"]).max()  # the side wall does push


def test_force_breakdown_adds_up():
    """gravity + centrifugal + walls + contacts = the engine's force, and the contacts of a
    closed group sum to zero (Newton's third law), in a rotating frame."""
    law = LinearContact(k_n=500.0, e_n=0.1, e_t=0.5, mu=0.3)
    s = ParticleSystem(pp=law, walls=[PlaneWall(contact=law, point=(0, 0, 0), normal=(0, 1, 0), name="floor")],
                       dt=1e-5, gravity=(0.0, -G, 3.0), omega=(0.0, 1.5, 0.0), axis_point=(0.1, 0.0, -0.2))
    rng = np.random.default_rng(0)
    P = np.array([[i * 0.00302, 0.0015 + j * 0.003, 0.0] for i in range(6) for j in range(4)])
    s.add_particles(P, rng.normal(0, 0.01, P.shape), 0.0015, 2500.0)
    for _ in range(1000):
        assert s.step(1).ok
    fb = s.force_breakdown()
    total = fb["gravity"] + fb["centrifugal"] + fb["contacts"] + sum(fb["walls"].values())
    assert np.allclose(total, s.force, rtol=0, atol=1e-14)
    assert np.abs(fb["walls"]["floor"]).max() > 0  # some touch the floor
    assert np.abs(fb["contacts"]).max() > 1e-4  # some touch each other (weight ~3.5e-4 N)
    assert np.abs(fb["contacts"].sum(axis=0)).max() < 1e-12 * np.abs(fb["contacts"]).max() * len(P)
    assert np.allclose(fb["coriolis"], -2 * s.mass[:, None] * np.cross([0.0, 1.5, 0.0], s.vel))


def test_rolling_at_constant_speed_gravity_balances_the_wall():
    """Spheres rolling down an incline with tan(theta) = mu_r (physics.md §1.3: a = 5/7 g
    (sin - mu_r cos) = 0): the budget's gravity and wall terms cancel to 1e-6 of gravity, and
    nothing else acts."""
    theta = math.atan(0.2)
    law = LinearContact(k_n=1000.0, e_n=0.5, e_t=0.5, mu=0.5, mu_r=0.2)
    L = 0.1
    s = ParticleSystem(pp=law, walls=[PlaneWall(contact=law, point=(0, 0, 0), normal=(0, 1, 0), name="floor")],
                       dt=1e-5, gravity=(0.0, -G * math.cos(theta), G * math.sin(theta)),
                       periodic=(None, None, (0.0, L)))
    R, rho = 0.0015, 2500.0
    m = rho * 4 / 3 * math.pi * R**3
    v0 = 0.3
    P = np.array([[0.005 * i, R - m * G * math.cos(theta) / 1000.0, 0.012 * i + 0.003] for i in range(8)])
    s.add_particles(P, [0.0, 0.0, v0], R, rho, omega=[[v0 / R, 0.0, 0.0]])
    b = MomentumBudget([0.0, 0.05, L], axis=2, wall_names=["floor"])
    for k in range(4000):
        assert s.step(1).ok
        if k >= 2000 and k % 50 == 0:
            b.sample(s.time, s)
    r = b.results()
    grav = r["gravity"].sum()
    assert grav == pytest.approx(8 * m * G * math.sin(theta), rel=1e-12)
    assert abs(grav + r["walls"].sum()) < 1e-6 * grav
    assert r["wall_floor"].sum() == pytest.approx(r["walls"].sum(), rel=1e-12)
    for k in ("contacts", "coriolis", "centrifugal", "drag", "pressure"):
        assert np.abs(r[k]).max() < 1e-12 * grav
    assert abs(s.vel[:, 2].mean() - v0) < 1e-3 * v0  # still at its speed


@pytest.fixture(scope="module")
def fixed_bed():
    """A bed of 300 glass spheres (1 mm) settled on the floor of a periodic column, air blown
    through it at about 0.3 U_mf; the budget (one bin, vertical) over 40 ms."""
    d, h, cells = 1e-3, 3e-3, (8, 12, 2)
    Lx, Ly, Lz = cells[0] * h, cells[1] * h, cells[2] * h
    law = LinearContact(k_n=20.0, e_n=0.5, e_t=0.5, mu=0.3)
    walls = [PlaneWall(contact=law, point=(0, 0, 0), normal=(0, 1, 0), name="floor"),
             PlaneWall(contact=law, point=(0, Ly, 0), normal=(0, -1, 0), name="lid")]
    s = ParticleSystem(pp=law, walls=walls, dt=2.5e-5, gravity=(0.0, -G, 0.0), periodic=((0, Lx), None, (0, Lz)))
    sp = 1.15 * d
    nx, nz = int(Lx / sp), int(Lz / sp)
    pts = [((i + 0.5) * Lx / nx, 0.525e-3 + j * sp, (k + 0.5) * Lz / nz) for j in range(4) for i in range(nx)
           for k in range(nz)][:300]
    s.add_particles(np.array(pts), 0.0, 0.5 * d, 2550.0)
    cg = column_gas(s, lengths=(Lx, Ly, Lz), cells=cells, inlet_velocity=0.0, gravity=(0.0, -G, 0.0),
                    coupling_interval=4)
    assert cg.advance(4000).ok  # settle (0.1 s)
    cg.set_superficial_inlet("y-", 0.15)
    assert cg.advance(2000).ok  # the gas through the bed (50 ms)
    b = MomentumBudget([0.0, Ly], axis=1, wall_names=["floor", "lid"])
    cg.force_sink = b
    gb = GasBudget(cg.gas, axis=1, start_time=s.time).attach()  # the gas's side over the same gas steps
    b.sample(s.time, s, cg)  # the particles' window starts here too
    dps = []
    for _ in range(40):
        assert cg.advance(40).ok
        b.sample(s.time, s, cg)
        gb.close_interval()
        p = cg.gas.p.interior
        pb = float((p[:, 0, :] - 0.5 * (p[:, 1, :] - p[:, 0, :])).mean())
        dps.append(pb - 1.2 * G * Ly)
    return s, cg, b.results(), float(np.mean(dps)) * Lx * Lz, gb.results()


def test_fixed_bed_gas_force_equals_pressure_drop(fixed_bed):
    """The gas's force on a fixed bed (the budget's drag + pressure over all particles) equals
    the pressure drop across it times the area plus the buoyancy rho_g g V_p (the gas's own
    momentum balance), within 3 %; the drag is most of it and points up.  Measured: 2.1 % (the
    distributor pressure is extrapolated from the first two cell rows, and the gas enters the
    bed at U/eps and leaves at U, a momentum flux the balance above leaves out)."""
    s, cg, r, dpA, _ = fixed_bed
    Vp = float(np.sum(4 / 3 * math.pi * s.radius**3))
    f_gas = float(r["drag_all"] + r["pressure_all"])
    assert f_gas == pytest.approx(dpA + 1.2 * G * Vp, rel=0.03)
    assert r["drag_all"] > 0.5 * f_gas > 0
    assert r["drag"].sum() == pytest.approx(r["drag_all"], rel=1e-9)  # every particle is in the bin


def test_fixed_bed_budget_closes(fixed_bed):
    """The bed at rest under the gas: gravity + floor + drag + pressure + contacts ~ 0; the
    residual is below 1 % of gravity and the floor carries the rest of the weight."""
    s, cg, r, dpA, _ = fixed_bed
    grav = float(r["gravity"].sum())
    assert grav == pytest.approx(-float(s.mass.sum()) * G, rel=1e-12)
    assert abs(float(r["residual"].sum())) < 0.01 * abs(grav)
    carried = float(r["drag"].sum() + r["pressure"].sum() + r["wall_floor"].sum())
    assert carried == pytest.approx(-grav, rel=0.01)


def test_fixed_bed_slip_is_the_interstitial_velocity(fixed_bed):
    """The loose lattice bed (porosity about 0.7 at the particles: the "surface" class, 0.6 to
    0.9) sees the gas at about the interstitial velocity U/eps: its slip lies between U/0.9 and
    U/0.6 (measured 0.183 m/s for U = 0.15 m/s), for all 300 particles, none in another class."""
    s, cg, r, dpA, g = fixed_bed
    assert 0.15 / 0.9 < r["slip_surface"] < 0.15 / 0.6
    assert r["slip_surface_count"] == pytest.approx(300.0, rel=1e-9)
    assert r["slip_dilute_count"] == 0.0 and r["slip_bed_count"] == 0.0


def test_fixed_bed_gas_budget_reacts_to_the_particles(fixed_bed):
    """The gas's budget over the same gas steps: its drag reaction is minus the drag on the
    particles (the gas side of the exchange against the particles' budget, 1e-10), its
    pressure reaction minus the particles' pressure force (transpose part, 1e-10); the budget
    closes to round-off, the mass imbalance is small against the drag (the bed barely moves);
    the pressure difference between the inlet and outlet planes and the momentum flux through
    them hold the gas's weight, the particles' reaction and the boundary half-cell source up
    (1e-3: the normal viscous stress, 3e-4, is left out), and more momentum enters than leaves
    (the gas enters the bed's bottom cell at U/eps).  Measured: drag reaction -51.8 uN, flux
    in 5.2 uN, out -3.9 uN, pressure planes 104.6 uN."""
    s, cg, r, dpA, g = fixed_bed
    assert int(g["n_steps"]) == 1600 // 4
    assert g["duration"] == pytest.approx(float(r["gas_time"]), rel=1e-12)
    assert g["drag"] == pytest.approx(-float(r["drag_all"]), rel=1e-10)
    assert g["drag"] == pytest.approx(-float(g["particle_drag"]), rel=1e-10)
    assert g["pressure_particles"] == pytest.approx(-float(g["particle_pressure"]), rel=1e-10)
    assert g["residual_relative"] < 1e-12
    assert abs(float(g["mass_imbalance"])) < 1e-3 * abs(float(g["drag"]))
    ends = float(g["pressure_y-"] + g["pressure_y+"] + g["flux_y-"] + g["flux_y+"])
    assert ends == pytest.approx(-float(g["drag"] + g["pressure_particles"] + g["gravity"] + g["source"]), rel=1e-3)
    assert g["flux_y-"] > -g["flux_y+"] > 0
