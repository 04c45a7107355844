"""Silo scene set-up: case errors name the key, the walls (hopper normal and overlap, no leak
through seams and corners), the fill lattice."""

import math

import numpy as np
import pytest

from cfddem.config import build_case
from cfddem.errors import CaseError
from cfddem.scenes.common import wall_specs
from cfddem.scenes.silo import SiloGeometry, fill_lattice

BASE = {
    "time": {"end_time": 0.1, "dt": 2e-5},
    "particles": {"diameter": 0.0038, "density": 950.0},
    "contact": {"particle_particle": {"k_n": 1000.0, "e_n": 0.8, "mu": 0.3},
                "particle_wall": {"k_n": 1000.0, "e_n": 0.8, "mu": 0.3}},
    "geometry": {"type": "silo"},
    "silo": {"width": 0.05, "depth": 0.012, "outlet_width": 0.016, "n_particles": 50},
}


def case_with(**silo):
    raw = {k: (dict(v) if isinstance(v, dict) else v) for k, v in BASE.items()}
    raw["silo"] = dict(BASE["silo"], **silo)
    return build_case(raw)


@pytest.mark.parametrize("silo, key", [
    ({"outlet_width": 0.048}, "silo.outlet_width"),
    ({"lattice_jitter": 0.2, "lattice_gap": 0.1}, "silo.lattice_jitter"),
    ({"fit_range": [0.8, 0.2]}, "silo.fit_range"),
    ({"fit_range": [0.2]}, "silo.fit_range"),
    ({"hopper_angle_deg": 85.0}, "silo.hopper_angle_deg"),
    ({"gate": "later"}, "silo.gate"),
    ({"front_back": {"mu": -0.1}}, "silo.front_back.mu"),
    ({"sides": {"e_n": 1.5}}, "silo.sides.e_n"),
    ({"bottom": {"friction": 0.3}}, "silo.bottom.friction"),
    ({"height": 0.01}, "silo.height"),
    ({"removal_depth": 0.001}, "silo.removal_depth"),
    ({"widht": 0.1}, "silo.widht"),
    ({"n_particles": 0}, "silo.n_particles"),
])
def test_config_errors_name_the_key(silo, key):
    with pytest.raises(CaseError) as e:
        case_with(**silo)
    assert e.value.key == key
    if key == "silo.widht":
        assert "did you mean 'width'" in str(e.value)


def test_silo_needs_vertical_gravity():
    raw = dict(BASE, gravity={"inclination_deg": 30.0})
    with pytest.raises(CaseError) as e:
        build_case(raw)
    assert e.value.key == "gravity.inclination_deg"


def test_per_wall_contact_overrides():
    case = case_with(front_back={"mu": 0.05, "mu_r": 0.01}, gate_wall={"mu": 0.6})
    walls = {w.name: w for w in wall_specs(case)}
    assert set(walls) == {"front", "back", "left", "right", "bottom_left", "bottom_right", "lip_left", "lip_right",
                          "gate"}
    assert walls["front"].params["mu"] == 0.05 and walls["back"].params["mu_r"] == 0.01
    assert walls["gate"].params["mu"] == 0.6
    assert walls["left"].params["mu"] == 0.3 and walls["left"].params["k_n"] == 1000.0  # contact.particle_wall


def test_hopper_walls_geometry_and_contact():
    from cfddem.particles.walls import wall_contact_py
    from cfddem.simulation import engine_wall

    case = case_with(hopper_angle_deg=60.0, width=0.06, outlet_width=0.02)
    g = SiloGeometry(case.resolved["silo"], 0.0038)
    assert g.y_h == pytest.approx(0.02 * math.tan(math.radians(60)))
    walls = {w.name: w for w in wall_specs(case)}
    assert "hopper_left" in walls and "bottom_left" not in walls
    a = math.radians(60)
    wl = engine_wall(walls["hopper_left"]).geometry()
    r = 0.0019
    # a sphere on the left hopper plane, half way up, overlapping by 0.1 r
    s = 0.01  # distance along the plane from the slot edge
    foot = np.array([0.02 - s * math.cos(a), s * math.sin(a), 0.006])
    n = np.array([math.sin(a), math.cos(a), 0.0])
    ov, nx, ny, nz, *_ = wall_contact_py(wl, foot + 0.9 * r * n, r)
    assert ov == pytest.approx(0.1 * r, rel=1e-9)
    np.testing.assert_allclose([nx, ny, nz], n, atol=1e-12)
    # over the slot edge (the lower edge of the plane): an edge contact pointing from the edge
    edge = np.array([0.02, 0.0, 0.006])
    c = edge + 0.8 * r * np.array([math.cos(0.3), -math.sin(0.3), 0.0])
    ov, nx, ny, nz, *_ = wall_contact_py(wl, c, r)
    assert ov == pytest.approx(0.2 * r, rel=1e-9)
    np.testing.assert_allclose([nx, ny, nz], [math.cos(0.3), -math.sin(0.3), 0.0], atol=1e-12)
    # the right plane mirrors the left one
    wr = engine_wall(walls["hopper_right"]).geometry()
    mirror = np.array([0.06 - foot[0], foot[1], foot[2]])
    ov, nx, ny, nz, *_ = wall_contact_py(wr, mirror + 0.9 * r * np.array([-n[0], n[1], 0.0]), r)
    assert ov == pytest.approx(0.1 * r, rel=1e-9) and nx == pytest.approx(-n[0])


@pytest.mark.parametrize("angle", [0.0, 60.0])
def test_no_leak_through_seams_and_corners(angle, one_numba_thread):
    """Spheres fired at 2 m/s into every seam and corner of a closed silo stay inside."""
    from cfddem.particles.system import ParticleSystem
    from cfddem.simulation import contact_law, engine_wall

    case = case_with(hopper_angle_deg=angle, width=0.06, outlet_width=0.02, depth=0.03, height=0.4)
    g = SiloGeometry(case.resolved["silo"], 0.0038)
    specs = wall_specs(case)
    sys_ = ParticleSystem(pp=contact_law(case.resolved["contact"]["particle_particle"]),
                          walls=[engine_wall(w) for w in specs], dt=2e-5, gravity=(0.0, -9.81, 0.0))
    r = 0.0019
    W, L, xc, yh, b = g.W, g.L, g.xc, g.y_h, g.b
    pos, vel = [], []
    v = 2.0
    for zs, vz in ((2 * r, -v), (L - 2 * r, v), (0.5 * L, 0.0)):
        # side wall - bottom (or hopper top) corner, both sides
        pos += [[2.5 * r, yh + 3 * r, zs], [W - 2.5 * r, yh + 3 * r, zs]]
        vel += [[-v, -v, vz], [v, -v, vz]]
        # slot: down into the lip channel onto the gate corner
        pos += [[xc - 0.5 * b + 1.5 * r, 3 * r, zs]]
        vel += [[-v, -v, vz]]
        # along the bottom / hopper plane towards the slot edge and the side
        pos += [[xc + 0.5 * b + 3 * r, 4 * r + (3 * r * math.tan(math.radians(angle)) if angle else 0.0), zs]]
        vel += [[-v, -2 * v, vz]]
        # straight into a front/back wall high up
        pos += [[0.5 * xc, yh + 12 * r, zs]]
        vel += [[0.3 * v, 0.0, vz if vz else v]]
    pos, vel = np.array(pos), np.array(vel)
    assert not sys_.overlaps(pos, r).any()
    sys_.add_particles(pos, vel, r, 950.0)
    lip = g.lip
    for _ in range(20):
        st = sys_.step(250)
        assert st.ok, st.message
        p = sys_.pos
        assert np.all(p[:, 0] > 0.4 * r) and np.all(p[:, 0] < W - 0.4 * r)
        assert np.all(p[:, 2] > 0.4 * r) and np.all(p[:, 2] < L - 0.4 * r)
        assert np.all(p[:, 1] > -lip + 0.4 * r)
        if angle:
            floor = (np.abs(p[:, 0] - xc) - 0.5 * b) * math.tan(math.radians(angle))
            assert np.all(p[:, 1] > floor + 0.4 * r / math.cos(math.radians(angle)) - 1e-12)
        else:
            outside_slot = np.abs(p[:, 0] - xc) > 0.5 * b
            assert np.all(p[outside_slot, 1] > 0.4 * r)
    assert sys_.n == len(pos)


def test_fill_lattice_is_free_of_overlaps_and_inside():
    pos = fill_lattice(0.05, 0.012, 0.01, 0.0038, 200, 0.12, 0.08, seed=4)
    assert pos.shape == (200, 3)
    d = np.linalg.norm(pos[:, None, :] - pos[None, :, :], axis=2)
    np.fill_diagonal(d, 1.0)
    assert d.min() > 0.0038 * 1.03
    r = 0.0019
    assert pos[:, 0].min() > r and pos[:, 0].max() < 0.05 - r
    assert pos[:, 2].min() > r and pos[:, 2].max() < 0.012 - r
    assert pos[:, 1].min() > 0.01 + r
    np.testing.assert_array_equal(pos, fill_lattice(0.05, 0.012, 0.01, 0.0038, 200, 0.12, 0.08, seed=4))


def test_fill_friction_sets_only_the_pair_sliding_friction_during_the_fill():
    from cfddem.particles import LinearContact, ParticleSystem, PlaneWall
    from cfddem.particles.contact import P_MU, P_MUR

    pp = LinearContact(k_n=1000.0, e_n=0.5, e_t=0.5, mu=0.35, mu_r=0.1)
    pw = LinearContact(k_n=1000.0, e_n=0.5, e_t=0.5, mu=0.17, mu_r=0.1)
    s = ParticleSystem(pp=pp, walls=[PlaneWall(contact=pw, point=(0, 0, 0), normal=(0, 1, 0))], dt=1e-5)
    s.set_friction(False, pp_mu=0.15)  # the thesis's fill
    assert s._pp_params[0, P_MU] == 0.15 and s._pp_params[0, P_MUR] == 0.1
    assert s._wpar[0, P_MU] == 0.17 and s._wpar[0, P_MUR] == 0.1
    s.set_friction(False)  # frictionless: everything off
    assert s._pp_params[0, [P_MU, P_MUR]].tolist() == [0.0, 0.0] and s._wpar[0, P_MU] == 0.0
    s.set_friction(True)  # back to the built values
    assert s._pp_params[0, [P_MU, P_MUR]].tolist() == [0.35, 0.1] and s._wpar[0, [P_MU, P_MUR]].tolist() == [0.17, 0.1]
    with pytest.raises(CaseError, match="silo.fill_friction"):
        case_with(fill_friction=0.15, frictionless_fill=True)
    with pytest.raises(CaseError, match="silo.fill_friction"):
        case_with(fill_friction=-0.5)
    assert case_with(fill_friction=0.15).resolved["silo"]["fill_friction"] == 0.15


def test_fill_rolling_friction_sets_only_the_pair_rolling_friction_during_the_fill():
    """``fill_rolling_friction``: the pairs' rolling friction alone, or with the sliding
    friction; the walls keep theirs; the built values come back; bad values name the key."""
    from cfddem.particles import LinearContact, ParticleSystem, PlaneWall
    from cfddem.particles.contact import P_MU, P_MUR
    from cfddem.scenes.common import apply_fill_friction, fill_friction_set

    pp = LinearContact(k_n=1000.0, e_n=0.5, e_t=0.5, mu=0.35, mu_r=0.5)
    pw = LinearContact(k_n=1000.0, e_n=0.5, e_t=0.5, mu=0.17, mu_r=0.2)
    s = ParticleSystem(pp=pp, walls=[PlaneWall(contact=pw, point=(0, 0, 0), normal=(0, 1, 0))], dt=1e-5)
    apply_fill_friction(s, {"fill_friction": -1.0, "fill_rolling_friction": 0.0})
    assert s._pp_params[0, [P_MU, P_MUR]].tolist() == [0.35, 0.0]
    assert s._wpar[0, [P_MU, P_MUR]].tolist() == [0.17, 0.2]
    apply_fill_friction(s, {"fill_friction": 0.15, "fill_rolling_friction": 0.05})
    assert s._pp_params[0, [P_MU, P_MUR]].tolist() == [0.15, 0.05]
    s.set_friction(True)
    assert s._pp_params[0, [P_MU, P_MUR]].tolist() == [0.35, 0.5] and s._wpar[0, [P_MU, P_MUR]].tolist() == [0.17, 0.2]
    apply_fill_friction(s, {"fill_friction": -1.0, "fill_rolling_friction": -1.0})  # neither: unchanged
    assert s._pp_params[0, [P_MU, P_MUR]].tolist() == [0.35, 0.5]
    assert not fill_friction_set({"fill_friction": -1.0, "fill_rolling_friction": -1.0})
    assert fill_friction_set({"fill_friction": -1.0, "fill_rolling_friction": 0.0})
    with pytest.raises(CaseError, match="silo.fill_rolling_friction"):
        case_with(fill_rolling_friction=0.0, frictionless_fill=True)
    with pytest.raises(CaseError, match="silo.fill_rolling_friction"):
        case_with(fill_rolling_friction=-0.2)
    assert case_with(fill_rolling_friction=0.0).resolved["silo"]["fill_rolling_friction"] == 0.0



def test_fill_friction_is_kept_in_the_system_state():
    """A checkpoint taken during a fill holds the fill's friction and the built values: the
    resumed system has both, and setting the same friction again (the scene's resume) does not
    force an extra force evaluation (which would break a bit-identical restart)."""
    from cfddem.particles import LinearContact, ParticleSystem, PlaneWall
    from cfddem.particles.contact import P_MU, P_MUR

    def build():
        pp = LinearContact(k_n=1000.0, e_n=0.5, e_t=0.5, mu=0.35, mu_r=0.1)
        pw = LinearContact(k_n=1000.0, e_n=0.5, e_t=0.5, mu=0.17, mu_r=0.1)
        s = ParticleSystem(pp=pp, walls=[PlaneWall(contact=pw, point=(0, 0, 0), normal=(0, 1, 0))], dt=1e-5)
        return s

    s = build()
    s.add_particles([[0.0, 0.002, 0.0]], 0.0, 0.002, 1000.0)
    s.set_friction(False, pp_mu=0.15)
    s.step(5)
    r = build()
    r.set_state(s.get_state())
    assert r._pp_params[0, [P_MU, P_MUR]].tolist() == [0.15, 0.1] and r._wpar[0, P_MU] == 0.17
    stale = r._forces_stale
    r.set_friction(False, pp_mu=0.15)
    assert r._forces_stale == stale
    r.set_friction(True)
    assert r._pp_params[0, [P_MU, P_MUR]].tolist() == [0.35, 0.1] and r._forces_stale
