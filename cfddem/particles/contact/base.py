"""What every contact law shares (physics.md §1): the parameter row the kernels receive, the
description of a case key, the friction keys mu and mu_r, the base class, and the compiled
pieces that do not depend on the law (tangential-history projection, normal/tangential split of
the relative velocity, Coulomb limit, rolling-friction torque).

Parameter row (float64, length ``NPARAM``), one per contact table (particle-particle, each wall):

    [model id, p1, p2, p3, p4, mu, mu_r, 0]

``p1..p4`` are the law's own numbers (:meth:`ContactLaw.kernel_params`; the linear law: k_n, c_n,
k_t, c_t).  Friction and rolling friction have fixed slots because the pair and wall loops use
them outside the law (Coulomb limit inside the law, rolling torque after it, physics.md §1.3).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from cfddem._jit import kernel
from cfddem.errors import CaseError

NPARAM = 8
P_MODEL, P_1, P_2, P_3, P_4, P_MU, P_MUR = 0, 1, 2, 3, 4, 5, 6
INF = float("inf")


@dataclass(frozen=True)
class LawKey:
    """One case key of a contact law: ``contact.particle_particle.<name>``,
    ``contact.particle_wall.<name>`` (``doc``, defaults ``default`` and ``default_wall``) and the
    per-wall overrides (``geometry.walls``, the silo and shear-cell wall groups; ``short``).
    The range (lo, hi, open or closed ends) is checked for every one of them."""

    name: str
    unit: str
    doc: str
    short: str
    default: float
    default_wall: float | None = None  # particle_wall default (None: ``default``)
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False

    def default_for(self, wall: bool) -> float:
        """The default in ``contact.particle_wall`` (``wall``) or ``contact.particle_particle``."""
        return self.default_wall if wall and self.default_wall is not None else self.default

    def range_text(self) -> str:
        """'positive', '>= 0', 'in (0, 1]', ... ('and finite' when the upper end is an open inf)."""
        if self.hi is None or (self.hi == INF and self.hi_open):
            fin = "" if self.hi is None else " and finite"
            if self.lo_open:
                return ("positive" if self.lo == 0 else f"> {self.lo:g}") + fin
            return f">= {self.lo:g}" + fin
        return f"in {'(' if self.lo_open else '['}{self.lo:g}, {self.hi:g}{')' if self.hi_open else ']'}"

    def check(self, key: str, v: float) -> None:
        """Raise ``CaseError(key, ...)`` unless v lies in the range (nan never does)."""
        ok = (self.lo is None or (v > self.lo if self.lo_open else v >= self.lo)) and \
             (self.hi is None or (v < self.hi if self.hi_open else v <= self.hi))
        if not ok:
            raise CaseError(key, f"{v:g} must be {self.range_text()}")


MU = LawKey("mu", "-", "Coulomb friction coefficient", "sliding friction", 0.12, 0.22, lo=0.0)
MU_R = LawKey("mu_r", "-", "rolling friction coefficient (constant directional torque)", "rolling friction",
              0.0, lo=0.0)
FRICTION_KEYS = (MU, MU_R)  # every law has them (fixed slots of the parameter row)


class ContactLaw:
    """Base of the contact laws.  A law is a frozen dataclass whose fields are its case keys
    (``KEYS``, ending with :data:`FRICTION_KEYS`), registered in
    :data:`cfddem.particles.contact.CONTACT_LAWS` under ``name``, with

    * ``model_id``: its id in the parameter row (unique among the registered laws);
    * ``force``: the pair law, an inline kernel
      ``force(p1, p2, p3, p4, mu, m*, R*, d_n, n (3), v_ab (3), d_t (3), dt_hist)`` returning
      (F on a (3), F_t (3), new d_t (3), |F_n|), d_t already projected into the tangent plane;
    * ``energy``: ``energy(p1, p2, p3, p4, R*, d_n, d_t (3))``, the elastic energy of one contact;
    * :meth:`kernel_params` (p1..p4), :meth:`collision_time`, :meth:`describe` (the line of
      ``cfddem check``), optionally :meth:`rayleigh_time`;
    * ``title``, ``reference``, ``check_doc``: its words in the ``contact.model`` key and in the
      derived-numbers paragraph of docs/case-format.md.
    """

    name: ClassVar[str]
    model_id: ClassVar[int]
    KEYS: ClassVar[tuple[LawKey, ...]]
    title: ClassVar[str] = ""
    reference: ClassVar[str] = ""
    check_doc: ClassVar[str] = ""
    mu: float
    mu_r: float

    def _check_keys(self) -> None:
        for k in self.KEYS:
            k.check(k.name, getattr(self, k.name))

    @classmethod
    def from_table(cls, params: dict) -> "ContactLaw":
        """The law from a contact table (``contact.particle_wall`` with a wall's overrides, ...);
        a key the table lacks takes the key's particle-particle default (a resolved case holds
        them all; this serves tables written before a key existed, e.g. ``k_t_ratio``)."""
        return cls(**{k.name: params.get(k.name, k.default) for k in cls.KEYS})

    @classmethod
    def model_doc(cls) -> str:
        """Its entry in the meaning of ``contact.model``: 'name' title (keys ...; reference)."""
        keys = ", ".join(k.name for k in cls.KEYS)
        return (f"'{cls.name}'" + (f" {cls.title}" if cls.title else "")
                + f" (keys {keys}" + (f"; {cls.reference}" if cls.reference else "") + ")")

    def kernel_params(self) -> tuple[float, float, float, float]:  # pragma: no cover - per law
        raise NotImplementedError

    def params(self) -> np.ndarray:
        """The float64 parameter row that kernels receive (layout in the module docstring)."""
        p = np.zeros(NPARAM)
        p[P_MODEL] = self.model_id
        p[P_1:P_4 + 1] = self.kernel_params()
        p[P_MU] = self.mu
        p[P_MUR] = self.mu_r
        return p

    def collision_time(self, m_eff: float, r_eff: float | None = None,
                       speed: float | None = None) -> float:  # pragma: no cover - per law
        raise NotImplementedError

    def rayleigh_time(self, radius: float, density: float) -> float:
        """The Rayleigh-wave time step scale of the particle material; inf for laws without
        elastic moduli (no such limit)."""
        return math.inf

    def describe(self, m_eff: float, r_eff: float, speed: float, radius: float) -> str:  # pragma: no cover
        """The derived numbers ``cfddem check`` prints for one contact pair."""
        raise NotImplementedError

    def linearised(self, m_eff: float, r_eff: float, speed: float) -> dict[str, float] | None:
        """The contact as two damped springs for the stable-step prediction of ``cfddem check``
        (:func:`cfddem.stability.contact_step_limit`): ``k_n``, ``eta_n`` (normal mode, mass
        m*) and ``k_t``, ``eta_t`` (sticking tangential mode), a nonlinear law linearised at the
        overlap of a head-on impact at ``speed``.  None: the law gives no prediction."""
        return None


# --- compiled pieces shared by every law ----------------------------------------------------


@kernel(inline="always")
def project_history(hx, hy, hz, nx, ny, nz):
    """Rotate the tangential spring d_t into the plane normal to n, keeping its length.

    d_t' = (d_t - (d_t.n) n) |d_t| / |d_t - (d_t.n) n|   (LIGGGHTS ``tangential history``).
    """
    h2 = hx * hx + hy * hy + hz * hz
    if h2 == 0.0:
        return 0.0, 0.0, 0.0
    hn = hx * nx + hy * ny + hz * nz
    px = hx - hn * nx
    py = hy - hn * ny
    pz = hz - hn * nz
    p2 = px * px + py * py + pz * pz
    if p2 == 0.0:
        return 0.0, 0.0, 0.0
    s = math.sqrt(h2 / p2)
    return px * s, py * s, pz * s


@kernel(inline="always")
def split_velocity(vx, vy, vz, nx, ny, nz):
    """(v_n, v_t (3)): v_n = v.n and the tangential part v_t = v - v_n n."""
    vn = vx * nx + vy * ny + vz * nz
    return vn, vx - vn * nx, vy - vn * ny, vz - vn * nz


@kernel(inline="always")
def coulomb_limit(ftx, fty, ftz, fnabs, mu):
    """Coulomb limit: F_t scaled down to mu |F_n| when longer.  Returns (F_t (3), sliding)."""
    ft2 = ftx * ftx + fty * fty + ftz * ftz
    flim = mu * fnabs
    if ft2 > flim * flim:
        s = flim / math.sqrt(ft2)
        return ftx * s, fty * s, ftz * s, True
    return ftx, fty, ftz, False


@kernel(inline="always")
def rolling_torque_limited(mu_r, rr, fnabs, wx, wy, wz, inv_i_sum, dt):
    """Rolling-friction torque on a for one contact, limited so that it never reverses w_rel.

        T_r = -min(mu_r R_r |F_n|, |w_rel| / (dt (1/I_a + 1/I_b))) w_rel/|w_rel|

    The torque acts over one full step (two half kicks of velocity Verlet) and changes w_rel by
    T_r dt (1/I_a + 1/I_b); the cap makes this change at most what stops w_rel (per contact).
    ``inv_i_sum`` = 1/I_a + 1/I_b.  Returns the torque on a (b receives its negative).
    """
    w = math.sqrt(wx * wx + wy * wy + wz * wz)
    if w == 0.0 or mu_r == 0.0:
        return 0.0, 0.0, 0.0
    t = mu_r * rr * fnabs
    tstop = w / (dt * inv_i_sum)
    if tstop < t:
        t = tstop
    s = -t / w
    return s * wx, s * wy, s * wz
