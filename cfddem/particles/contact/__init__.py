"""Contact laws (physics.md §1): one module per law, registered in :data:`CONTACT_LAWS`.

A law module (``linear.py``, ``hertz_mindlin.py``) holds everything about its law: the formulas,
the compiled force and elastic-energy kernels, its case keys (names, units, defaults, ranges,
meanings: docs/case-format.md and the validation of ``contact.*`` and of the per-wall overrides
are generated from them), its parameter row, its collision time (and Rayleigh time) and the
derived numbers ``cfddem check`` prints.  Everything else reads the registry:

* the case schema (``contact.model`` choices, the ``contact.particle_particle`` /
  ``particle_wall`` tables, the per-wall override tables) and the wall-key checks
  (:func:`contact_keys`, :func:`check_contact_values`);
* :func:`contact_law` builds the law object of a contact table;
* the pair and wall loops call :func:`pair_law` (and the energy check :func:`spring_energy`),
  which switch on the model id of the parameter row over the registered laws: a chain of inline
  kernels built from the registry (:func:`_chain`) whose every branch is the law's own inline
  kernel, so the compiled loops are the same as if the switch were written out by hand.

Adding a law: a new module with a :class:`~cfddem.particles.contact.base.ContactLaw` dataclass
and its kernels, and one entry in :data:`CONTACT_LAWS` (docs/particles.md, "Adding a contact law").
"""

from __future__ import annotations

from cfddem._jit import kernel
from cfddem.errors import CaseError
from cfddem.particles.contact.base import (NPARAM, P_1, P_2, P_3, P_4, P_MODEL, P_MU, P_MUR, ContactLaw,
                                           LawKey, project_history, rolling_torque_limited)
from cfddem.particles.contact.hertz_mindlin import HertzMindlinContact
from cfddem.particles.contact.linear import LinearContact

CONTACT_LAWS: dict[str, type[ContactLaw]] = {
    LinearContact.name: LinearContact,
    HertzMindlinContact.name: HertzMindlinContact,
}
DEFAULT_LAW = "linear"  # contact.model when the case does not say

MODEL_LINEAR = LinearContact.model_id
MODEL_HERTZ_MINDLIN = HertzMindlinContact.model_id

__all__ = ["CONTACT_LAWS", "DEFAULT_LAW", "ContactLaw", "HertzMindlinContact", "LawKey", "LinearContact",
           "MODEL_HERTZ_MINDLIN", "MODEL_LINEAR", "NPARAM", "P_1", "P_2", "P_3", "P_4", "P_MODEL", "P_MU", "P_MUR",
           "check_contact_values", "contact_keys", "contact_law", "law_class", "pair_law", "project_history",
           "rolling_torque_limited", "spring_energy", "wall_contact_force"]


def law_class(model: str) -> type[ContactLaw]:
    """The registered law called ``model`` (CaseError naming ``contact.model`` otherwise)."""
    try:
        return CONTACT_LAWS[model]
    except KeyError:
        allowed = ", ".join(repr(m) for m in CONTACT_LAWS)
        raise CaseError("contact.model", f"{model!r} is not allowed: one of {allowed}") from None


def contact_law(params: dict, model: str | None = None) -> ContactLaw:
    """The engine's contact law for a contact table (``contact.particle_particle``,
    ``contact.particle_wall`` with a wall's overrides): the law named ``model`` built from its
    keys.  Without ``model`` the table's own "model" entry decides (default linear)."""
    return law_class(model or params.get("model", DEFAULT_LAW)).from_table(params)


def contact_keys() -> dict[str, LawKey]:
    """Every case key of the registered laws, in registry order, each once (a key shared by
    several laws, such as mu, has one description)."""
    keys: dict[str, LawKey] = {}
    for law in CONTACT_LAWS.values():
        for k in law.KEYS:
            if keys.setdefault(k.name, k) != k:
                raise TypeError(f"contact key {k.name!r} is described differently by two laws")
    return keys


def check_contact_values(prefix: str, values: dict) -> None:
    """Check the contact keys set in ``values`` (a ``geometry.walls`` entry, a silo or shear-cell
    wall group; None = unset, other keys ignored) against the ranges of the laws' keys; errors
    name ``prefix.key``."""
    for name, spec in contact_keys().items():
        v = values.get(name)
        if v is not None:
            spec.check(f"{prefix}.{name}", v)


def check_docs() -> tuple[str, str]:
    """(what ``cfddem check`` derives with the default law, the paragraphs of the other laws),
    for the header of docs/case-format.md."""
    others = "".join(f'With `contact.model = "{name}"`: {law.check_doc}\n'
                     for name, law in CONTACT_LAWS.items() if name != DEFAULT_LAW)
    return CONTACT_LAWS[DEFAULT_LAW].check_doc, others


# --- the switch over the registered laws (compiled) ------------------------------------------
# pair_law and spring_energy call the kernel of the law whose model id is in the parameter row:
# a chain of inline kernels ``if model == id: law kernel else: next link`` built from the
# registry (the last law also takes unknown ids).  Arguments are scalars only: inlined functions
# taking arrays cost refcount traffic in the hot loops.


def _force_link(law, rest):
    force = law.force
    mid = float(law.model_id)
    if rest is None:
        @kernel(inline="always")
        def link(model, p1, p2, p3, p4, mu, meff, reff, dn, nx, ny, nz, vx, vy, vz, hx, hy, hz, dt_hist):
            return force(p1, p2, p3, p4, mu, meff, reff, dn, nx, ny, nz, vx, vy, vz, hx, hy, hz, dt_hist)
        return link

    @kernel(inline="always")
    def link(model, p1, p2, p3, p4, mu, meff, reff, dn, nx, ny, nz, vx, vy, vz, hx, hy, hz, dt_hist):
        if model == mid:
            return force(p1, p2, p3, p4, mu, meff, reff, dn, nx, ny, nz, vx, vy, vz, hx, hy, hz, dt_hist)
        return rest(model, p1, p2, p3, p4, mu, meff, reff, dn, nx, ny, nz, vx, vy, vz, hx, hy, hz, dt_hist)
    return link


def _energy_link(law, rest):
    energy = law.energy
    mid = float(law.model_id)
    if rest is None:
        @kernel(inline="always")
        def link(model, p1, p2, p3, p4, reff, dn, hx, hy, hz):
            return energy(p1, p2, p3, p4, reff, dn, hx, hy, hz)
        return link

    @kernel(inline="always")
    def link(model, p1, p2, p3, p4, reff, dn, hx, hy, hz):
        if model == mid:
            return energy(p1, p2, p3, p4, reff, dn, hx, hy, hz)
        return rest(model, p1, p2, p3, p4, reff, dn, hx, hy, hz)
    return link


def _chain(make):
    laws = list(CONTACT_LAWS.values())
    if len({law.model_id for law in laws}) != len(laws):
        raise TypeError("two registered contact laws share a model id")
    f = None
    for law in reversed(laws):
        f = make(law, f)
    return f


_force = _chain(_force_link)
_energy = _chain(_energy_link)


@kernel(inline="always")
def pair_law(model, p1, p2, p3, p4, mu, meff, reff, dn, nx, ny, nz, vx, vy, vz, hx, hy, hz, dt_hist):
    """The contact force of the law with id ``model`` (row slots p1..p4, mu; ``reff`` = R*):
    projects the tangential spring d_t into the current tangent plane, then calls the law's
    ``force`` kernel.  Returns (F on a (3), F_t (3), new d_t (3), |F_n|)."""
    hx, hy, hz = project_history(hx, hy, hz, nx, ny, nz)
    return _force(model, p1, p2, p3, p4, mu, meff, reff, dn, nx, ny, nz, vx, vy, vz, hx, hy, hz, dt_hist)


@kernel(inline="always")
def spring_energy(model, p1, p2, p3, p4, reff, dn, hx, hy, hz):
    """Elastic energy of one contact of the law with id ``model`` (its ``energy`` kernel)."""
    return _energy(model, p1, p2, p3, p4, reff, dn, hx, hy, hz)


@kernel
def wall_contact_force(model, p1, p2, p3, p4, mu, m, r, ov, nx, ny, nz, qx, qy, qz, vx, vy, vz, wx, wy, wz,
                       wvx, wvy, wvz, hx, hy, hz, refx, refy, refz, dt_hist):
    """One contact of a sphere (mass m, radius r, velocity v, spin w) with a wall (analytic or
    mesh) of the law with id ``model`` (row slots p1..p4, mu): overlap ``ov``, unit normal n from
    the wall towards the centre, contact point q, wall surface velocity wv at q, tangential
    spring h, reference point ref of the torque on the wall.  The wall is the partner b of
    infinite mass (m* = m, R* = r) in :func:`pair_law`.

    Returns (F on the sphere (3), torque on the sphere about its centre (3), new spring (3),
    |F_n|, torque on the wall about ref (3)).  The force on the wall is -F.
    """
    # n_ab from the particle (a) towards the wall (b)
    ax_ = -nx
    ay_ = -ny
    az_ = -nz
    sx = r * wx
    sy = r * wy
    sz = r * wz
    rvx = vx - wvx + sy * az_ - sz * ay_
    rvy = vy - wvy + sz * ax_ - sx * az_
    rvz = vz - wvz + sx * ay_ - sy * ax_
    cfx, cfy, cfz, ctx, cty, ctz, hx, hy, hz, fnabs = pair_law(
        model, p1, p2, p3, p4, mu, m, r, ov, ax_, ay_, az_, rvx, rvy, rvz, hx, hy, hz, dt_hist)
    lx = qx - refx
    ly = qy - refy
    lz = qz - refz
    return (cfx, cfy, cfz, r * (ay_ * ctz - az_ * cty), r * (az_ * ctx - ax_ * ctz), r * (ax_ * cty - ay_ * ctx),
            hx, hy, hz, fnabs, -(ly * cfz - lz * cfy), -(lz * cfx - lx * cfz), -(lx * cfy - ly * cfx))
