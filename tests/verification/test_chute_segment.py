"""The streamwise-periodic chute segment (cfddem/scenes/chute_segment.py): it keeps its beads,
accelerates them at g sin(theta) without friction, gas or rotation, the drag of air at rest
slows moving beads at the rate a single-bead estimate gives, and bad keys are one-line
CaseErrors."""

import math

import numpy as np
import pytest

from cfddem.config import load_case
from cfddem.errors import CaseError
from cfddem.scenes.chute_segment import ChuteSegmentScene
from cfddem.simulation import Simulation

pytestmark = pytest.mark.usefixtures("one_numba_thread")

SMALL = ["segment.length=0.012", "segment.bed_depth=0.005", "output.vtk=false", "output.plots=false",
         "output.snapshot_interval=1", "measurements.enabled=false", "checkpoint.wall_interval=0",
         "output.series_interval=0.002"]


def _run(root, tmp_path, name, extra):
    case = load_case(root / "cases" / "chute_segment", overrides=SMALL + extra)
    sim = Simulation(case, tmp_path / name, echo=False, progress=False, threads=1)
    s = sim.run()
    assert s.status == "done", s.message
    from cfddem.io.results import read_series

    return sim, read_series(tmp_path / name / "results.h5")


def test_frictionless_segment_accelerates_at_g_sin_theta(root, tmp_path):
    """Frictionless walls, no gas, no rotation: only gravity acts along z on the whole bed (the
    contacts cancel, the walls push along x and y), so the mean velocity grows at g sin(30 deg)
    = 4.905 m/s^2 whatever the bed does; and the periodic segment keeps every bead."""
    sim, s = _run(root, tmp_path, "fric0", ["gas.enabled=false", "frame.rpm=0", "contact.particle_wall.mu=0",
                                            "time.end_time=0.03", "segment.velocity=0.5"])
    n0 = ChuteSegmentScene.expected_particles(sim.case)
    assert n0 > 100 and np.all(s["n_particles"] == n0) and sim.system.n == n0
    t, v = s["time"], s["mean_velocity_z"]
    a = np.polyfit(t, v, 1)[0]
    assert a == pytest.approx(9.81 * math.sin(math.radians(30)), rel=0.01)
    assert v[0] == pytest.approx(0.5, abs=1e-12)


def test_drag_of_air_at_rest_against_a_single_bead(root, tmp_path):
    """A dilute layer of beads at 1 m/s in air at rest (0 rpm): over 10 ms the air has not yet
    been dragged along (its mass is 1/30 of the beads' but the drag needs about 0.1 s to move
    it), so the beads lose speed against the gas-free run at about the rate of one bead in still
    air, a = (3/4) C_D (rho_g / rho_p) v^2 / d with the Schiller-Naumann C_D at Re = 200:
    0.095 m/s^2.  In a layer of solid fraction 0.15 the Beetstra drag is 1.5-3 times the
    isolated bead's; the air carried along lowers it.  Asserted: the sign, and the rate within
    a factor 0.5-4 of the single bead (order of magnitude)."""
    ov = ["frame.rpm=0", "segment.bed_depth=0.006", "segment.solid_fraction=0.15", "segment.velocity=1.0",
          "segment.gas_velocity=0", "time.end_time=0.01"]
    _, sg = _run(root, tmp_path, "gas", ov + ["gas.enabled=true"])
    _, sn = _run(root, tmp_path, "nogas", ov + ["gas.enabled=false"])
    dv = sn["mean_velocity_z"][-1] - sg["mean_velocity_z"][-1]
    t = sg["time"][-1]
    rho_g, rho_p, d, mu, v = 1.2, 2550.0, 0.003, 1.8e-5, 1.0
    re = rho_g * v * d / mu
    cd = 24 / re * (1 + 0.15 * re ** 0.687)
    a1 = 0.75 * cd * rho_g / rho_p * v * v / d
    assert a1 == pytest.approx(0.095, rel=0.02)
    assert dv > 0
    assert 0.5 < (dv / t) / a1 < 4.0, (dv / t, a1)
    # the gas's impulse on the beads (gas_impulse_z) per unit bead mass is the velocity they lost
    m = sg["particle_momentum_z"][0] / sg["mean_velocity_z"][0]
    assert -sg["gas_impulse_z"][-1] / m == pytest.approx(dv, rel=0.1)
    # the drag pushed the air along: its mean velocity rose from rest
    assert sg["gas_mean_velocity_z"][0] == 0.0 and sg["gas_mean_velocity_z"][-1] > 1e-3


@pytest.mark.parametrize("override,key,words", [
    ("segment.length=0.01", "segment.length", "shorter than 4 particle diameters"),
    ("segment.bed_depth=0.002", "segment.bed_depth", "less than one particle diameter"),
    ("segment.bed_depth=0.05", "segment.bed_depth", "above the side walls"),
    ("particles.diameter_max=0.004", "particles.diameter_max", "one diameter"),
    ("geometry.length=0.5", "geometry.length", "needs geometry.type = 'chute'"),
    ("segment.solid_fraction=0.9", "segment.solid_fraction", ""),
])
def test_bad_keys_are_one_line_case_errors(root, override, key, words):
    with pytest.raises(CaseError) as e:
        load_case(root / "cases" / "chute_segment", overrides=[override])
    assert e.value.key == key and words in e.value.reason and "\n" not in str(e.value)


def test_scaled_overrides_keep_steps_per_collision(root):
    """The map's scaling: k ~ d^2, dt ~ sqrt(d), so dt / t_c stays the case's; the gas step stays."""
    from cfddem.gas_map import scaled_overrides

    case = load_case(root / "cases" / "chute_segment")
    ov = scaled_overrides(case, 0.001, 8.0)
    assert ov["contact.particle_particle.k_n"] == pytest.approx(1000 / 9)
    assert ov["time.dt"] == pytest.approx(4e-5 / math.sqrt(3))
    m = lambda dd: 2550 * math.pi * dd ** 3 / 6  # noqa: E731
    assert ov["time.dt"] / math.sqrt(m(0.001) / ov["contact.particle_particle.k_n"]) == pytest.approx(
        4e-5 / math.sqrt(m(0.003) / 1000))
    assert ov["gas.coupling_interval"] * ov["time.dt"] == pytest.approx(3.2e-4, rel=0.05)
    assert ov["segment.length"] == pytest.approx(0.008) and ov["gas.cells"] == [16, 8, 2]
