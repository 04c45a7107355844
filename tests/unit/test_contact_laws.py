"""The contact-law registry (cfddem/particles/contact/): every registered law brings its case
keys, derived numbers and kernels, and the schema, the wall-key checks and the compiled switch
are built from the registry, so a new law needs only its module and its registry entry (shown
with a toy law registered here)."""

import math
from dataclasses import dataclass

import numpy as np
import pytest

from cfddem import config
from cfddem._jit import kernel
from cfddem.errors import CaseError
from cfddem.particles import contact as pc
from cfddem.schema import wall_override
from cfddem.particles.contact.base import FRICTION_KEYS, NPARAM, P_1, P_4, P_MODEL, P_MU, P_MUR, ContactLaw, LawKey

LAWS = list(pc.CONTACT_LAWS.values())
M, R = 3.0e-5, 1.5e-3  # a 3 mm glass bead


def _defaults(law, wall=False):
    return {k.name: k.default_for(wall) for k in law.KEYS}


@pytest.mark.parametrize("law", LAWS, ids=lambda c: c.name)
def test_every_law_registers_keys_numbers_and_kernels(law):
    assert pc.CONTACT_LAWS[law.name] is law and issubclass(law, ContactLaw)
    # keys: unit, meanings, defaults inside their own range, friction keys last (fixed row slots)
    assert law.KEYS[-len(FRICTION_KEYS):] == FRICTION_KEYS
    for k in law.KEYS:
        assert k.unit and k.doc and k.short
        for wall in (False, True):
            k.check(k.name, _defaults(law, wall)[k.name])
    # the law from a contact table: parameter row with its id and the friction slots
    c = law.from_table(dict(_defaults(law), mu=0.3, mu_r=0.05))
    p = c.params()
    assert p.shape == (NPARAM,) and p[P_MODEL] == law.model_id
    assert (p[P_MU], p[P_MUR]) == (0.3, 0.05)
    assert p[P_1:P_4 + 1].tolist() == list(c.kernel_params()) and np.all(np.isfinite(p))
    # derived numbers for cfddem check: a collision time and the line naming it
    tc = c.collision_time(M / 2, R / 2, 1.0)
    assert 0 < tc < 1e-2
    line = c.describe(M / 2, R / 2, 1.0, R)
    assert f"t_c = {tc:.4g} s" in line
    assert c.rayleigh_time(R, 2500.0) > 0
    # the compiled switch reaches the law's own kernels, bit for bit
    n = np.array([0.0, 1.0, 0.0])
    h = np.array([2e-6, 0.0, -1e-6])  # in the tangent plane: the projection keeps it
    args = (*p[P_1:P_4 + 1], p[P_MU], M / 2, R / 2, 1e-5, *n, 0.01, 0.2, 0.03, *h, 1e-5)
    got = pc.pair_law(float(law.model_id), *args)
    assert got == law.force(*args)
    assert got[1] < 0 and got[-1] > 0  # approaching and overlapping: a is pushed away from b (along -n)
    e = pc.spring_energy(float(law.model_id), *p[P_1:P_4 + 1], R / 2, 1e-5, *h)
    assert e == law.energy(*p[P_1:P_4 + 1], R / 2, 1e-5, *h) and e > 0


def test_model_ids_unique_and_keys_shared_alike():
    assert len({law.model_id for law in LAWS}) == len(LAWS)
    keys = pc.contact_keys()
    for law in LAWS:
        for k in law.KEYS:
            assert keys[k.name] == k


def test_schema_and_wall_keys_come_from_the_registry():
    sec = config.SCHEMA["contact"]
    assert sec["model"].choices == tuple(pc.CONTACT_LAWS) and sec["model"].default == pc.DEFAULT_LAW
    for law in LAWS:
        assert law.model_doc() in sec["model"].doc
    keys = pc.contact_keys()
    for table, wall in (("particle_particle", False), ("particle_wall", True)):
        assert list(sec[table]) == list(keys)
        for name, k in keys.items():
            spec = sec[table][name]
            assert (spec.unit, spec.doc, spec.lo, spec.hi) == (k.unit, k.doc, k.lo, k.hi)
            assert spec.default == k.default_for(wall)
    for grp in ("front_back", "sides", "bottom", "gate_wall"):
        assert list(config.SCHEMA["silo"][grp]) == list(keys)
    for grp in ("rings", "plate"):
        assert list(config.SCHEMA["shear"][grp]) == list(keys)
    assert set(keys) <= config._WALL_KEYS
    doc = config.case_format_markdown()
    for law in LAWS:
        assert law.check_doc in doc


@pytest.mark.parametrize("key,value,text", [("mu", -0.1, "-0.1 must be >= 0"), ("e_n", 1.5, "1.5 must be in (0, 1]"),
                                            ("k_n", 0.0, "0 must be positive"), ("nu", 0.7, "0.7 must be in (-1, 0.5]"),
                                            ("E", math.inf, "inf must be positive and finite"),
                                            ("e", math.nan, "nan must be in (0, 1]")])
def test_wall_contact_values_are_checked_against_the_law_ranges(key, value, text):
    with pytest.raises(CaseError) as ei:
        pc.check_contact_values("silo.sides", {key: value})
    assert ei.value.key == f"silo.sides.{key}" and text in str(ei.value)
    pc.check_contact_values("silo.sides", {key: None, "other": -5.0})  # unset and unknown keys: not checked


@pytest.mark.parametrize("where,raw", [
    ("geometry.walls[0]", {"geometry": {"type": "box", "walls": [
        {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "nu": 0.7}]}}),
    ("silo.sides", {"geometry": {"type": "silo"}, "silo": {"sides": {"nu": 0.7}}}),
    ("shear.rings", {"geometry": {"type": "shear_cell"}, "shear": {"rings": {"nu": 0.7}}}),
])
def test_every_wall_override_is_checked_when_the_case_loads(where, raw):
    with pytest.raises(CaseError) as ei:
        config.build_case(raw)
    assert ei.value.key == f"{where}.nu"


def test_unknown_model_names_the_key():
    with pytest.raises(CaseError) as ei:
        pc.contact_law(_defaults(pc.LinearContact), "hertz")
    assert ei.value.key == "contact.model" and "'hertz_mindlin'" in str(ei.value)


# --- a toy law: what a newcomer writes (its module) and its registry entry ------------------


@kernel(inline="always")
def _spring_force(k, p2, p3, p4, mu, meff, reff, dn, nx, ny, nz, vx, vy, vz, hx, hy, hz, dt_hist):
    fn = -k * dn
    return (fn * nx, fn * ny, fn * nz, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, abs(fn))


@kernel(inline="always")
def _spring_energy(k, p2, p3, p4, reff, dn, hx, hy, hz):
    return 0.5 * k * dn * dn


@dataclass(frozen=True)
class FrictionlessSpring(ContactLaw):
    """Undamped, frictionless normal spring (a test law)."""

    name = "spring"
    model_id = 7
    KEYS = (LawKey("k", "N/m", "spring: stiffness", "stiffness (spring)", 500.0, lo=0.0, lo_open=True),) + FRICTION_KEYS
    force = staticmethod(_spring_force)
    energy = staticmethod(_spring_energy)
    check_doc = "the period of the spring"

    k: float
    mu: float
    mu_r: float = 0.0

    def __post_init__(self):
        self._check_keys()

    def kernel_params(self):
        return self.k, 0.0, 0.0, 0.0

    def collision_time(self, m_eff, r_eff=None, speed=None):
        return math.pi * math.sqrt(m_eff / self.k)

    def describe(self, m_eff, r_eff, speed, radius):
        return f"k = {self.k:g} N/m, t_c = {self.collision_time(m_eff):.4g} s"


def test_a_new_law_is_one_module_and_one_registry_entry(monkeypatch):
    monkeypatch.setitem(pc.CONTACT_LAWS, "spring", FrictionlessSpring)
    # case keys and the model choice
    sec = config._contact_section()
    assert sec["model"].choices[-1] == "spring" and "'spring' (keys k, mu, mu_r)" in sec["model"].doc
    assert sec["particle_wall"]["k"].default == 500.0 and "k" in wall_override("gate")
    law = pc.contact_law({"k": 800.0, "mu": 0.2, "mu_r": 0.0}, "spring")
    assert isinstance(law, FrictionlessSpring) and law.params()[P_MODEL] == 7
    with pytest.raises(CaseError) as ei:
        pc.check_contact_values("geometry.walls[0]", {"k": -1.0})
    assert ei.value.key == "geometry.walls[0].k"
    # the compiled switch built from the registry reaches the new kernel and keeps the others
    force = pc._chain(pc._force_link)
    energy = pc._chain(pc._energy_link)
    args = (800.0, 0.0, 0.0, 0.0, 0.2, M / 2, R / 2, 1e-5, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1e-5)
    assert force(7.0, *args) == (0.0, -800.0 * 1e-5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 800.0 * 1e-5)
    assert energy(7.0, 800.0, 0.0, 0.0, 0.0, R / 2, 1e-5, 0.0, 0.0, 0.0) == 0.5 * 800.0 * 1e-10
    lin = pc.LinearContact(k_n=1000.0, e_n=0.9, e_t=0.5, mu=0.3)
    largs = (*lin.kernel_params(), *args[4:])
    assert force(float(pc.MODEL_LINEAR), *largs) == pc.LinearContact.force(*largs)
    # a case with the new law loads, and cfddem check prints its numbers
    from cfddem.simulation import collision_time, describe_case

    monkeypatch.setitem(config.SCHEMA, "contact", sec)
    case = config.build_case({"contact": {"model": "spring", "particle_particle": {"k": 800.0}},
                              "geometry": {"type": "box"}, "particles": {"initial": [{"pos": [0.05, 0.05, 0.05]}]}})
    m = case.particles.density * math.pi / 6 * case.particles.diameter ** 3
    tc_pp, tc_pw = math.pi * math.sqrt(m / 2 / 800.0), math.pi * math.sqrt(m / 500.0)
    assert collision_time(case) == pytest.approx(min(tc_pp, tc_pw), rel=1e-14)
    text = "\n".join(describe_case(case))
    assert f"particle-particle: k = 800 N/m, t_c = {tc_pp:.4g} s" in text
    assert f"particle-wall (x-): k = 500 N/m, t_c = {tc_pw:.4g} s" in text
    assert "Rayleigh" not in text
