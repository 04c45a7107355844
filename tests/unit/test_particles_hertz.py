"""Hertz-Mindlin contact (physics.md §1.2): derived numbers, force-overlap law, tangential
stiffness, restitution and duration of head-on collisions, wall contact, energy conservation,
thread independence."""

import math

import numba
import numpy as np
import pytest

from cfddem.errors import CaseError
from cfddem.particles import HertzMindlinContact, ParticleSystem, PlaneWall
from cfddem.particles.contact import MODEL_HERTZ_MINDLIN, NPARAM

R, RHO = 1.5e-3, 2550.0
M = RHO * 4.0 / 3.0 * math.pi * R**3
E, NU = 5e7, 0.3


def test_effective_moduli_and_parameter_row():
    c = HertzMindlinContact(E=E, nu=NU, e=0.5, mu=0.4, mu_r=0.1)
    assert c.E_star == pytest.approx(E / (2 * (1 - NU**2)), rel=1e-14)
    assert c.G_star == pytest.approx(E / (4 * (2 - NU) * (1 + NU)), rel=1e-14)
    le = math.log(0.5)
    assert c.beta == pytest.approx(le / math.sqrt(le**2 + math.pi**2), rel=1e-14)
    p = c.params()
    assert p.shape == (NPARAM,)
    assert p.tolist() == [MODEL_HERTZ_MINDLIN, c.E_star, -2 * math.sqrt(5 / 6) * c.beta, c.G_star,
                          -2 * math.sqrt(5 / 6) * c.beta, 0.4, 0.1, 0.0]
    # against a wall of another material (steel)
    w = HertzMindlinContact(E=E, nu=NU, e=0.5, mu=0.4, E_wall=2e11, nu_wall=0.29)
    assert 1 / w.E_star == pytest.approx((1 - NU**2) / E + (1 - 0.29**2) / 2e11, rel=1e-14)
    assert 1 / w.G_star == pytest.approx(2 * (2 - NU) * (1 + NU) / E + 2 * (2 - 0.29) * (1 + 0.29) / 2e11, rel=1e-14)
    # Hertz time (Johnson) and Rayleigh time
    tc = c.collision_time(M / 2, R / 2, 2.0)
    assert tc == pytest.approx(2.87 * ((M / 2) ** 2 / (R / 2 * c.E_star**2 * 2.0)) ** 0.2, rel=1e-14)
    G = E / (2 * (1 + NU))
    assert c.rayleigh_time(R, RHO) == pytest.approx(math.pi * R * math.sqrt(RHO / G) / (0.1631 * NU + 0.8766), rel=1e-14)
    d = c.derived(M / 2, R / 2, 2.0)
    assert d["S_n"] == pytest.approx(2 * c.E_star * math.sqrt(R / 2 * d["d_max"]), rel=1e-14)
    assert d["S_t"] == pytest.approx(8 * c.G_star * math.sqrt(R / 2 * d["d_max"]), rel=1e-14)
    with pytest.raises(ValueError):
        c.collision_time(M / 2)


@pytest.mark.parametrize("kw,key", [(dict(E=0.0), "E"), (dict(E=float("inf")), "E"), (dict(nu=0.6), "nu"),
                                    (dict(nu=-1.0), "nu"), (dict(e=0.0), "e"), (dict(e=1.1), "e"),
                                    (dict(mu=-0.1), "mu"), (dict(mu_r=-0.1), "mu_r"),
                                    (dict(E_wall=1e9), "E_wall"), (dict(E_wall=-1.0, nu_wall=0.3), "E_wall")])
def test_bad_input_names_the_key(kw, key):
    args = dict(E=E, nu=NU, e=0.5, mu=0.3)
    args.update(kw)
    with pytest.raises(CaseError) as ei:
        HertzMindlinContact(**args)
    assert ei.value.key == key


def test_normal_force_overlap_law_quasi_static():
    """Two very heavy spheres (R_a != R_b) pushed together slowly with e = 1 (no damping): the
    contact force at every evaluated overlap is (4/3) E* sqrt(R*) d^1.5."""
    c = HertzMindlinContact(E=E, nu=NU, e=1.0, mu=0.5)
    ra, rb = R, 0.7 * R
    s = ParticleSystem(pp=c, walls=[], dt=1e-6)
    s.add_particles([[0, 0, 0], [ra + rb + 1e-6, 0, 0]], [[0.005, 0, 0], [-0.005, 0, 0]], [ra, rb], 1e12)
    reff = ra * rb / (ra + rb)
    got, want = [], []
    for _ in range(60):
        s.step(10)
        order = np.argsort(s.ids)
        p = s.pos[order]
        d = ra + rb - np.linalg.norm(p[1] - p[0])
        if d > 0:
            got.append(-s.force[order][0, 0])
            want.append(4 / 3 * c.E_star * math.sqrt(reff) * d**1.5)
    got, want = np.array(got), np.array(want)
    assert len(got) > 40 and want.max() > 300 * want.min()  # a wide range of overlaps
    np.testing.assert_allclose(got, want, rtol=1e-12)
    # elastic energy (8/15) E* sqrt(R*) d^2.5
    assert s.elastic_energy() == pytest.approx(8 / 15 * c.E_star * math.sqrt(reff) * d**2.5, rel=1e-12)


def test_tangential_stiffness_at_fixed_overlap():
    """A heavy sphere pressed into a floor (fixed overlap d) while the floor slides by a small
    distance u: the tangential force is S_t u with S_t = 8 G* sqrt(R d) (sticking, e = 1)."""
    c = HertzMindlinContact(E=E, nu=NU, e=1.0, mu=100.0)
    d = 2e-5
    vw = 1e-3
    s = ParticleSystem(pp=c, walls=[PlaneWall(contact=c, point=(0, 0, 0), normal=(0, 1, 0),
                                              velocity=(vw, 0, 0))], dt=1e-6)
    s.add_particles([[0, R - d, 0]], 0.0, R, 1e12)
    s.step(1000)
    u = vw * s.time
    fw = s.wall_forces()[0]  # force of the particle on the wall: -F_t on the particle
    ov = R - s.pos[0, 1]
    assert ov == pytest.approx(d, rel=1e-6)
    st = 8 * c.G_star * math.sqrt(R * ov)
    assert -fw[0] == pytest.approx(st * u, rel=1e-5)
    assert fw[1] == pytest.approx(-4 / 3 * c.E_star * math.sqrt(R) * ov**1.5, rel=1e-9)


def _head_on(e, v, E_=E, wall=False, e_wall=None):
    """Head-on collision (two equal spheres at +-v/2, or one sphere at v against a floor).
    Returns (measured restitution, contact duration, law)."""
    c = HertzMindlinContact(E=E_, nu=NU, e=e, mu=0.3)
    if wall:
        m_eff, r_eff = M, R
        cw = e_wall or c
        walls = [PlaneWall(contact=cw, point=(0, 0, 0), normal=(0, 1, 0))]
        tc = cw.collision_time(m_eff, r_eff, v)
    else:
        m_eff, r_eff = M / 2, R / 2
        walls = []
        tc = c.collision_time(m_eff, r_eff, v)
    dt = tc / 400
    s = ParticleSystem(pp=c, walls=walls, dt=dt)
    if wall:
        s.add_particles([[0, R + 0.5 * v * dt, 0]], [[0, -v, 0]], R, RHO)
        gap = lambda: s.pos[0, 1] - R  # noqa: E731
        vrel = lambda: -s.vel[0, 1]  # noqa: E731
    else:
        s.add_particles([[0, 0, 0], [2 * R + 0.5 * v * dt, 0, 0]], [[v / 2, 0, 0], [-v / 2, 0, 0]], R, RHO)

        def gap():
            p = s.pos[np.argsort(s.ids)]
            return p[1, 0] - p[0, 0] - 2 * R

        def vrel():
            q = s.vel[np.argsort(s.ids)]
            return q[0, 0] - q[1, 0]
    v0 = vrel()
    g_prev, t_in, t_out = gap(), None, None
    for _ in range(20000):
        s.step(1)
        g = gap()
        if t_in is None and g < 0 <= g_prev:
            t_in = s.time - dt * (-g) / (g_prev - g)
        if t_in is not None and g >= 0 > g_prev:
            t_out = s.time - dt * g / (g - g_prev)
            break
        g_prev = g
    assert t_out is not None
    s.step(3)
    return -vrel() / v0, t_out - t_in, tc


@pytest.mark.parametrize("e", [0.3, 0.7, 0.9])
def test_restitution_equals_input_and_is_speed_independent(e):
    e1, _, _ = _head_on(e, 0.2)
    e2, _, _ = _head_on(e, 2.0)
    print(f"HM pp e={e}: measured {e1:.5f} (0.2 m/s), {e2:.5f} (2 m/s)")
    assert e1 == pytest.approx(e, rel=5e-3)
    assert e2 == pytest.approx(e, rel=5e-3)
    assert e1 == pytest.approx(e2, rel=2e-3)


def test_collision_time_matches_hertz():
    for v in (0.2, 2.0):
        e, t, tc = _head_on(1.0, v)
        print(f"HM elastic v={v}: t/t_c(2.87 formula) = {t / tc:.5f}, e = {e:.6f}")
        assert e == pytest.approx(1.0, abs=1e-4)
        assert t == pytest.approx(tc, rel=5e-3)


@pytest.mark.parametrize("e", [0.5, 0.9])
def test_sphere_dropped_on_a_plane(e):
    em, _, _ = _head_on(e, 1.0, wall=True)
    print(f"HM wall e={e}: measured {em:.5f}")
    assert em == pytest.approx(e, rel=5e-3)
    # a steel floor (E_wall, nu_wall): same restitution, shorter contact
    steel = HertzMindlinContact(E=E, nu=NU, e=e, mu=0.3, E_wall=2e11, nu_wall=0.29)
    em2, t2, tc2 = _head_on(e, 1.0, wall=True, e_wall=steel)
    assert em2 == pytest.approx(e, rel=5e-3)


def _box_run(threads=None, n_steps=1500, mu=0.0, e=1.0):
    c = HertzMindlinContact(E=E, nu=NU, e=e, mu=mu, mu_r=0.05 if mu else 0.0)
    L = 0.0122
    walls = [PlaneWall(contact=c, point=(0, 0, 0), normal=(0, 1, 0)),
             PlaneWall(contact=c, point=(0, L, 0), normal=(0, -1, 0))]
    s = ParticleSystem(pp=c, walls=walls, dt=5e-7, periodic=((0, L), None, (0, L)))
    rng = np.random.default_rng(7)
    g = np.arange(4) * 3.05e-3 + 1.525e-3
    pos = np.array([[x, y, z] for x in g for y in g for z in g])
    pos += rng.uniform(-2e-5, 2e-5, pos.shape)
    s.add_particles(pos, rng.normal(0, 1.0, pos.shape), R * rng.uniform(0.97, 1.0, len(pos)), RHO,
                    omega=rng.normal(0, 300, pos.shape))
    if threads is not None:
        s.serial_below = 0
    e0 = s.kinetic_energy() + s.elastic_energy()
    es = []
    for _ in range(n_steps // 100):
        assert s.step(100).ok
        es.append(s.kinetic_energy() + s.elastic_energy())
    return s, e0, np.array(es)


def test_energy_conservation_elastic_frictionless_box():
    s, e0, es = _box_run(n_steps=3000)
    drift = np.max(np.abs(es - e0)) / e0
    print(f"HM box: {s.n} particles, max |E - E0|/E0 = {drift:.2e} over 3000 steps")
    assert drift < 1e-4


def test_one_and_two_threads_bit_identical():
    old = numba.get_num_threads()
    out = []
    try:
        for nt in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
            numba.set_num_threads(nt)
            s, _, _ = _box_run(threads=nt, n_steps=600, mu=0.4, e=0.6)
            o = np.argsort(s.ids)
            out.append(np.concatenate([s.pos[o].ravel(), s.vel[o].ravel(), s.omega[o].ravel()]))
    finally:
        numba.set_num_threads(old)
    assert np.array_equal(out[0], out[1])


# --- case level: contact.model, HM keys, check numbers, cylinder walls in a case -----------------
def _hm_case(**extra):
    from cfddem.config import build_case

    raw = {"contact": {"model": "hertz_mindlin",
                       "particle_particle": {"E": 5e7, "nu": 0.3, "e": 0.6, "mu": 0.4},
                       "particle_wall": {"E": 1e8, "nu": 0.25, "e": 0.5, "mu": 0.5}},
           "geometry": {"type": "box", "lo": [0, 0, 0], "hi": [0.05, 0.05, 0.05]},
           "particles": {"initial": [{"pos": [0.025, 0.025, 0.025]}]},
           "time": {"dt": 2e-6}}
    for k, v in extra.items():
        if k == "geometry":  # another scene: its own geometry keys only
            raw[k] = dict(v)
        else:
            raw.setdefault(k, {}).update(v)
    return build_case(raw)


def test_case_hertz_mindlin_laws_and_check_numbers():
    from cfddem.simulation import (check_time_step, collision_time, contact_law, describe_case,
                                   engine_wall, rayleigh_time)
    from cfddem.scenes.common import wall_specs

    case = _hm_case()
    pp = contact_law(case.resolved["contact"]["particle_particle"], case.contact.model)
    assert isinstance(pp, HertzMindlinContact) and (pp.E, pp.nu, pp.e, pp.mu) == (5e7, 0.3, 0.6, 0.4)
    walls = [engine_wall(w, case.contact.model) for w in wall_specs(case)]
    assert len(walls) == 6 and all(isinstance(w.contact, HertzMindlinContact) and w.contact.E == 1e8 for w in walls)
    m = RHO * math.pi / 6 * 0.003**3
    v = 1.0  # no speed scale in a box: the 1 m/s floor
    tc_pp = pp.collision_time(m / 2, 0.75e-3, v)
    tc_pw = walls[0].contact.collision_time(m, 1.5e-3, v)
    assert collision_time(case) == pytest.approx(min(tc_pp, tc_pw), rel=1e-14)
    G = 5e7 / (2 * 1.3)
    assert rayleigh_time(case) == pytest.approx(math.pi * 1.5e-3 * math.sqrt(RHO / G) / (0.1631 * 0.3 + 0.8766), rel=1e-14)
    assert check_time_step(case) == pytest.approx(2e-6 / min(tc_pp, tc_pw), rel=1e-14)
    text = "\n".join(describe_case(case))
    assert "Hertz-Mindlin E* = " in text and "Rayleigh time" in text
    # above t_c/5: refused naming time.dt; forced: accepted
    big = 0.3 * min(tc_pp, tc_pw)
    with pytest.raises(CaseError) as ei:
        check_time_step(_hm_case(time={"dt": big}))
    assert ei.value.key == "time.dt"
    assert check_time_step(_hm_case(time={"dt": big, "force": True})) > 0.2


def test_case_hm_key_validation_and_hints():
    with pytest.raises(CaseError) as ei:
        _hm_case(contact={"particle_particle": {"nu": 0.7}})
    assert ei.value.key == "contact.particle_particle.nu"
    with pytest.raises(CaseError) as ei:
        _hm_case(contact={"particle_wall": {"E": -1.0}})
    assert ei.value.key == "contact.particle_wall.E"
    with pytest.raises(CaseError) as ei:
        _hm_case(contact={"model": "hertz"})
    assert ei.value.key == "contact.model" and "hertz_mindlin" in str(ei.value)
    with pytest.raises(CaseError) as ei:
        _hm_case(contact={"particle_particle": {"nuu": 0.3}})
    assert ei.value.key == "contact.particle_particle.nuu" and "did you mean 'nu'" in str(ei.value)


def test_case_cylinder_wall_entry():
    from cfddem.particles import CylinderWall
    from cfddem.scenes.common import wall_specs, walls_bounding_box
    from cfddem.simulation import engine_wall

    cyl = {"type": "cylinder", "name": "ring", "point": [0.0, 0.0, 0.0], "axis": [0, 0, 1], "radius": 0.05,
           "half_height": 0.02, "mu": 0.6, "E": 2e8}
    case = _hm_case(geometry={"type": "none", "walls": [cyl]},
                    particles={"initial": [{"pos": [0.0, 0.0, 0.0]}]})
    specs = wall_specs(case)
    assert [w.kind for w in specs] == ["cylinder"]
    w = engine_wall(specs[0], case.contact.model)
    assert isinstance(w, CylinderWall) and w.radius == 0.05 and w.half_height == 0.02 and w.inside
    assert w.contact.mu == 0.6 and w.contact.E == 2e8 and w.contact.nu == 0.25  # override + table
    lo, hi = walls_bounding_box(specs, case)
    np.testing.assert_allclose(lo, [-0.05, -0.05, -0.02])
    np.testing.assert_allclose(hi, [0.05, 0.05, 0.02])
    assert len(specs[0].quads()) == 32
    for bad, key in [({"radius": 0.0}, "radius"), ({"axis": [0, 0, 0]}, "axis"), ({"half_height": None}, "half_height")]:
        c2 = dict(cyl)
        c2.update(bad)
        if bad.get("half_height", 1) is None:
            del c2["half_height"]
        with pytest.raises(CaseError) as ei:
            _hm_case(geometry={"type": "none", "walls": [c2]})
        assert ei.value.key == f"geometry.walls[0].{key}"
