"""The flat-bottom silo blender's set-up (cfddem/scenes/blender.py): bad input gets one line naming
the key, the channel walls and the periodic axis, the batch fill colouring, c_in, and the engine's
periodic clump centre of mass that the feeder zone relies on."""

import math

import numpy as np
import pytest

from cfddem.config import build_case
from cfddem.errors import CaseError
from cfddem.scenes.blender import BlenderGeometry, colour_layers, input_concentration
from cfddem.scenes.common import wall_specs

BASE = {
    "time": {"end_time": 0.1, "dt": 4e-5},
    "particles": {"diameter": 0.0038, "density": 950.0},
    "contact": {"particle_particle": {"k_n": 200.0, "e_n": 0.5, "mu": 0.3},
                "particle_wall": {"k_n": 200.0, "e_n": 0.5, "mu": 0.3}},
    "geometry": {"type": "silo_blender"},
    "silo": {"width": 0.035, "depth": 0.0115, "outlet_width": 0.016, "n_particles": 300},
    "blender": {"channel_length": 0.02},
}


def case_with(silo=None, blender=None, particles=None):
    raw = {k: (dict(v) if isinstance(v, dict) else v) for k, v in BASE.items()}
    raw["silo"].update(silo or {})
    raw["blender"].update(blender or {})
    raw["particles"].update(particles or {})
    return build_case(raw)


@pytest.mark.parametrize("silo, blender, particles, key", [
    # a template clump too large for the outlet (bounding length 5 d = 19 mm > 16 mm)
    ({}, {}, {"clump": "template", "clump_spheres": [[x, 0, 0, 0.5] for x in (-2, -1, 0, 1, 2)]},
     "particles.clump_spheres"),
    ({}, {}, {"clump": "template", "clump_spheres": [[0, 0, 0, 0.5], [0.2, 0, 0, -0.1]]}, "particles.clump_spheres[1]"),
    ({}, {}, {"clump": "template", "clump_spheres": [[0, 0, 0, 0.5], [2, 0, 0, 0.5]]}, "particles.clump_spheres[1]"),
    ({}, {"feeder_range": [-0.05, -0.01]}, {}, "blender.feeder_range"),  # below the channel's bottom (-0.02)
    ({}, {"feeder_range": [-0.01, 0.005]}, {}, "blender.feeder_range"),  # above the outlet plane
    ({}, {"feeder_range": [-0.005, -0.01]}, {}, "blender.feeder_range"),
    ({}, {"batch_fraction": 1.2}, {}, "blender.batch_fraction"),
    ({}, {"batch_fraction": 0.0}, {}, "blender.batch_fraction"),
    ({}, {"batch_fraction": 1.0}, {}, "blender.batch_fraction"),
    ({"height": 0.062}, {}, {}, "silo.height"),  # the lattice reaches 0.0607 m: 1.3 mm free < 30 mm
    ({}, {"free_height": 0.004}, {}, "blender.free_height"),  # less than two particles
    ({}, {"channel_length": 0.005}, {}, "blender.channel_length"),
    ({"lip": 0.004}, {}, {}, "silo.lip"),
    ({}, {"input": "sinusoid", "input_mean": 0.8, "input_amplitude": 0.4}, {}, "blender.input_amplitude"),
    ({}, {"sublayers": 0}, {}, "blender.sublayers"),
])
def test_bad_input_names_the_key(silo, blender, particles, key):
    with pytest.raises(CaseError) as e:
        case_with(silo, blender, particles)
    assert e.value.key == key, str(e.value)
    assert "\n" not in str(e.value)


def test_blender_keys_refused_in_a_silo():
    raw = dict(BASE, geometry={"type": "silo"})
    with pytest.raises(CaseError) as e:
        build_case(raw)
    assert e.value.key == "blender.channel_length" and "silo_blender" in e.value.reason


def test_channel_walls_periodic_axis_and_top():
    case = case_with()
    geo = BlenderGeometry(case.resolved)
    walls = {w.name: w for w in wall_specs(case)}
    # the lips run from the channel bottom (the gate) to the outlet plane
    lip = walls["lip_left"]
    assert lip.point[1] == pytest.approx(-0.01) and lip.half_extents[0] == pytest.approx(0.01)
    assert lip.point[0] == pytest.approx(0.0175 - 0.008)
    assert walls["gate"].point[1] == pytest.approx(-0.02)
    # periodic from the channel bottom to the fill's top + free height; the side walls reach the top
    lo, hi = geo.periodic[1]
    assert lo == pytest.approx(-0.02) and hi == pytest.approx(geo.fill_top + 0.03)
    assert geo.periodic[0] is None and geo.periodic[2] is None
    top = walls["left"].point[1] + walls["left"].half_extents[0]
    assert top == pytest.approx(hi)
    # front and back walls cover the channel
    assert walls["front"].point[1] - walls["front"].half_extents[1] < -0.02
    assert geo.feeder == pytest.approx((-0.02, -0.01))


@pytest.mark.parametrize("f, n", [(0.13, 1), (0.25, 3), (0.5, 5), (0.5, 1)])
def test_batch_colouring_fraction_and_layers(f, n):
    rng = np.random.default_rng(3)
    y = rng.uniform(0.0, 0.27, 4000)
    m = rng.uniform(1.0, 1.5, 4000)
    tr = colour_layers(y, m, f, n)
    # the labelled mass fraction is f within n body masses (each layer boundary cuts one body)
    assert abs(m[tr].sum() / m.sum() - f) <= n * m.max() / m.sum()
    # n tracer layers, centred in n equal-mass strata: count the runs of tracer in height order
    s = tr[np.argsort(y)].astype(int)
    assert int(np.sum(np.diff(s) == 1) + s[0]) == n
    # the first layer is centred at the (1/2)/n mass quantile
    q = np.cumsum(m[np.argsort(y)]) / m.sum()
    i0 = int(np.argmax(s))
    i1 = i0 + int(np.argmin(s[i0:]))  # the end of the first run of tracer
    assert 0.5 * (q[i0] + q[i1 - 1]) == pytest.approx(0.5 / n, abs=2e-3)
    assert q[i1 - 1] - q[i0] == pytest.approx(f / n, abs=2e-3)


def test_input_concentration():
    b = {"input": "step", "input_step_time": 0.5, "input_mean": 0.5, "input_amplitude": 0.3, "input_period": 2.0}
    assert input_concentration(b, 0.49) == 0.0 and input_concentration(b, 0.5) == 1.0
    b["input"] = "sinusoid"
    assert input_concentration(b, 0.5) == pytest.approx(0.8) and input_concentration(b, 1.5) == pytest.approx(0.2)
    b["input"] = "batch"
    assert math.isnan(input_concentration(b, 1.0))


def test_clump_centre_of_mass_wraps_and_the_zone_keeps_it(one_numba_thread):
    """A clump falling through a periodic vertical box: its centre of mass stays in the box and
    the velocity zone in the lower part catches it on every pass (the blender's feeder)."""
    from cfddem.particles.clumps import pellet
    from cfddem.particles.contact import contact_law

    from cfddem.particles.system import ParticleSystem

    law = contact_law({"k_n": 200.0, "e_n": 0.5, "e_t": 0.5, "mu": 0.3, "mu_r": 0.0}, "linear")
    sys_ = ParticleSystem(pp=law, walls=[], dt=1e-4, gravity=(0.0, -9.81, 0.0),
                          periodic=(None, (0.0, 0.05), None))
    sys_.add_clumps(pellet(2, 0.004, 950.0), np.array([[0.0, 0.052, 0.0]]))  # given above the box: wrapped
    assert 0.0 <= sys_.clumps.com[0, 1] < 0.05
    sys_.add_velocity_zone((-1.0, 0.0, -1.0), (1.0, 0.01, 1.0), 1, -0.3)
    hits = 0
    for _ in range(400):  # 0.4 s: several passes through the 50 mm box
        assert sys_.step(5).ok
        y = sys_.clumps.com[0, 1]
        assert 0.0 <= y < 0.05
        hits += sys_.zone_count
        if 0.0 <= y < 0.01:
            assert sys_.clumps.vel[0, 1] == pytest.approx(-0.3)
    assert hits > 10
    # the members sit at the wrapped centre of mass plus their offsets (minimum image)
    d = sys_.pos[:, 1] - sys_.clumps.com[0, 1]
    d -= 0.05 * np.round(d / 0.05)
    assert np.all(np.abs(d) <= 0.001 + 1e-12)
