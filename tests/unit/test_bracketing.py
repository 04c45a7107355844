"""The bracketing modes of the coupling (#20): ``gas.drag_factor`` scales every drag
coefficient; ``gas.coupling = "one_way_rest"`` holds the air at rest (not solved): the
particles feel its drag and buoyancy, the air nothing."""

import math

import numpy as np
import pytest

from cfddem.coupling.exchange import column_gas
from cfddem.particles import LinearContact, ParticleSystem

G, RHO_G, MU = 9.81, 1.2, 1.8e-5
D, RHO_P = 1e-3, 2550.0


def _one_particle(v, **kw):
    """One sphere moving at v through a periodic column of air at rest (no gravity on the
    particle, so that only the gas acts); the gas's force on it after one coupling step."""
    law = LinearContact(k_n=100.0, e_n=0.5, e_t=0.5, mu=0.3)
    s = ParticleSystem(pp=law, walls=[], dt=1e-5, periodic=((0, 6e-3), None, (0, 6e-3)))
    s.add_particles([[3e-3, 6e-3, 3e-3]], [v], 0.5 * D, RHO_P)
    cg = column_gas(s, lengths=(6e-3, 12e-3, 6e-3), cells=(2, 4, 2), inlet_velocity=0.0, gravity=(0.0, -G, 0.0),
                    coupling_interval=1, **kw)
    assert cg.advance(1).ok
    return s, cg


@pytest.mark.parametrize("factor", [0.0, 2.0, 10.0])
def test_drag_factor_scales_the_drag(factor):
    """Air held at rest: with explicit drag the force on a moving sphere is exactly factor
    times the closure's (1e-9); implicit: the bounded form -m expm1(-dt K/m)/dt of factor K."""
    v = np.array([0.0, 0.0, 1.0])
    s1, _ = _one_particle(v, drag_treatment="explicit", frozen=True)
    sf, _ = _one_particle(v, drag_treatment="explicit", drag_factor=factor, frozen=True)
    f1 = s1.ext_force[0]  # the column's air has p = 0: drag only
    ff = sf.ext_force[0]
    assert f1[2] < 0
    assert ff[2] == pytest.approx(factor * f1[2], rel=1e-9, abs=1e-15)
    si, cgi = _one_particle(v, drag_treatment="implicit", drag_factor=factor, frozen=True)
    K = -f1[2] / 1.0  # the explicit K at slip 1 m/s
    m = RHO_P * math.pi / 6 * D**3
    dtg = cgi.dt_gas
    keff = -m * math.expm1(-dtg * factor * K / m) / dtg if factor else 0.0
    assert -si.ext_force[0][2] == pytest.approx(keff, rel=1e-6, abs=1e-15)


def test_frozen_air_stays_at_rest_and_feels_nothing():
    """one_way_rest: after 50 coupling steps of a sphere falling through it the air's velocity
    is still exactly 0 and its pressure untouched (a two-way run's air moves at the first step),
    while the sphere feels the drag of its own slip against air at rest and the buoyancy."""
    v = np.array([0.0, -0.5, 0.3])
    s, cg = _one_particle(v, frozen=True, drag_treatment="explicit")
    p0 = cg.gas.p.data.copy()
    f_first = s.ext_force[0].copy()
    s2, cg2 = _one_particle(v, drag_treatment="explicit")
    assert np.abs(cg2.gas.w.data).max() > 1e-6  # two-way: the air is dragged along at once
    for _ in range(50):
        assert cg.advance(1).ok
    assert np.abs(cg.gas.u.data).max() == 0.0 and np.abs(cg.gas.v.data).max() == 0.0
    assert np.abs(cg.gas.w.data).max() == 0.0
    assert np.array_equal(cg.gas.p.data, p0)
    # the force opposes the particle's own velocity (the slip against air at rest; the column's
    # air has p = 0, no buoyancy) and has slowed it
    f, vn = s.ext_force[0], s.vel[0]
    assert np.linalg.norm(np.cross(f, vn)) < 1e-9 * np.linalg.norm(f) * np.linalg.norm(vn)
    assert f @ vn < 0 and np.linalg.norm(vn) < np.linalg.norm(v)
    assert f_first @ v < 0


def test_case_keys_reach_the_exchange():
    """gas.coupling and gas.drag_factor in a case build the frozen, scaled exchange."""
    from cfddem.config import load_case
    from cfddem.simulation import Simulation

    case = load_case("cases/gas_chute_16rpm", overrides=['gas.coupling="one_way_rest"', "gas.drag_factor=3.0"])
    sim = Simulation(case, out_dir=None)
    sim.build()
    assert sim.gas.frozen and sim.gas.drag_factor == 3.0
    assert sim.gas.advance(3 * case.gas.coupling_interval).ok
    for f in (sim.gas.gas.u, sim.gas.gas.v, sim.gas.gas.w):  # boundary faces included
        assert np.abs(f.data).max() == 0.0


def test_frozen_branch_from_moving_air_holds_it_at_rest(tmp_path):
    """A one_way_rest run branched from a checkpoint whose air moves holds the air at rest
    with the scene's hydrostatic pressure, not the checkpoint's flow."""
    from cfddem.config import load_case
    from cfddem.simulation import Simulation

    ov = ["time.end_time=0.004", "study.compare_without_gas=false", "output.vtk=false", "output.plots=false",
          "measurements.start_time=0.003", "checkpoint.every_steps=20"]
    a = Simulation(load_case("cases/gas_chute_16rpm", overrides=ov), out_dir=tmp_path / "a")
    assert a.run().status == "done"
    assert np.abs(a.gas.gas.w.data).max() > 0.1  # the air moves (inlet co-flow, lid cross-wind)
    b = Simulation(load_case("cases/gas_chute_16rpm", overrides=ov + [
        f'checkpoint.start_from="{tmp_path / "a"}"', "time.end_time=0.006", 'gas.coupling="one_way_rest"']),
        out_dir=tmp_path / "b")
    assert b.run().status == "done"
    ref = Simulation(load_case("cases/gas_chute_16rpm", overrides=['gas.coupling="one_way_rest"']), out_dir=None)
    ref.build()
    for f in (b.gas.gas.u, b.gas.gas.v, b.gas.gas.w):
        assert np.abs(f.data).max() == 0.0
    assert np.array_equal(b.gas.gas.p.data, ref.gas.gas.p.data)
