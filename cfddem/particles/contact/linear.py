"""Linear spring-dashpot contact law (``contact.model = "linear"``, model id 0; physics.md §1.1).

Cundall & Strack 1979; damping from the restitution coefficient as in LIGGGHTS ``hooke`` and
Silbert et al. 2001.  Inputs (k_n, e_n, e_t, mu, mu_r; optionally k_t_ratio):

    eta_n = -2 ln(e_n) sqrt(m* k_n) / sqrt(pi^2 + ln^2 e_n)
    k_t   = (2/7) k_n (pi^2 + ln^2 e_t) / (pi^2 + ln^2 e_n)   (k_t_ratio = 0, the default)
    k_t   = k_t_ratio k_n                                     (k_t_ratio > 0: a given stiffness ratio,
                                                               as in DEM papers that state k_t/k_n)
    eta_t = -2 ln(e_t) sqrt(m_t k_t) / sqrt(pi^2 + ln^2 e_t),    m_t = (2/7) m*
    t_c   = sqrt(m* (pi^2 + ln^2 e_n) / k_n)

m* = m_a m_b / (m_a + m_b) (m* = m_a against a wall).  Because m* differs per pair with
polydispersity, kernels receive the *coefficients* c_n, c_t and compute per contact

    eta_n = c_n sqrt(m* k_n),  c_n = -2 ln e_n / sqrt(pi^2 + ln^2 e_n)
    eta_t = c_t sqrt(m* k_t),  c_t = -2 ln e_t sqrt(2/7) / sqrt(pi^2 + ln^2 e_t)

Parameter row: [0, k_n, c_n, k_t, c_t, mu, mu_r, 0].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from cfddem._jit import kernel
from cfddem.particles.contact.base import FRICTION_KEYS, INF, ContactLaw, LawKey, coulomb_limit, split_velocity

LINEAR_KEYS = (
    LawKey("k_n", "N/m", "normal spring stiffness of the linear spring-dashpot law", "normal stiffness", 1000.0,
           lo=0.0, lo_open=True, hi=INF, hi_open=True),
    LawKey("e_n", "-", "normal coefficient of restitution", "normal restitution", 0.97, 0.95,
           lo=0.0, lo_open=True, hi=1.0),
    LawKey("e_t", "-", "tangential restitution of a sticking collision", "tangential restitution", 0.33,
           lo=0.0, lo_open=True, hi=1.0),
    LawKey("k_t_ratio", "-", "linear law: tangential stiffness k_t / k_n (0: derived from e_n and e_t, equal normal "
           "and tangential collision times); when set, e_t sets only the tangential damping (the restitution of "
           "one tangential half-oscillation of mass 2/7 m*)", "tangential stiffness ratio", 0.0, lo=0.0),
) + FRICTION_KEYS


@kernel(inline="always")
def linear_force(kn, cn, kt, ct, mu, meff, reff, dn, nx, ny, nz, vx, vy, vz, hx, hy, hz, dt_hist):
    """Linear spring-dashpot pair law with tangential history and Coulomb limit.

    n points from a to its partner b, v = v_ab is the relative velocity of a's contact point with
    respect to b's, h = d_t the tangential spring (already projected into the tangent plane);
    ``reff`` (R*) is not used.

        F_n = -k_n d_n n - eta_n v_n,         eta_n = c_n sqrt(m* k_n)
        d_t <- d_t + v_t dt_hist
        F_t = -k_t d_t - eta_t v_t,           eta_t = c_t sqrt(m* k_t)
        if |F_t| > mu |F_n|:  F_t <- mu |F_n| F_t/|F_t|,
                              d_t <- -(F_t + eta_t v_t) / k_t
    (sliding: d_t is reset so that spring + dashpot give exactly the limited force, as LIGGGHTS'
    ``tangential history``; re-evaluating the law at the same state is then idempotent)

    The normal force is not clipped at zero (so that the contact lasts exactly t_c and restitutes
    e_n, as derived).  Returns (F on a (3), F_t (3), new d_t (3), |F_n|).
    """
    vn, vtx, vty, vtz = split_velocity(vx, vy, vz, nx, ny, nz)
    eta_n = cn * math.sqrt(meff * kn)
    fn = -kn * dn - eta_n * vn
    hx += vtx * dt_hist
    hy += vty * dt_hist
    hz += vtz * dt_hist
    eta_t = ct * math.sqrt(meff * kt)
    fnabs = abs(fn)
    ftx, fty, ftz, sliding = coulomb_limit(-kt * hx - eta_t * vtx, -kt * hy - eta_t * vty, -kt * hz - eta_t * vtz,
                                           fnabs, mu)
    if sliding and kt > 0.0:
        hx = -(ftx + eta_t * vtx) / kt
        hy = -(fty + eta_t * vty) / kt
        hz = -(ftz + eta_t * vtz) / kt
    return (fn * nx + ftx, fn * ny + fty, fn * nz + ftz, ftx, fty, ftz, hx, hy, hz, fnabs)


@kernel(inline="always")
def linear_energy(kn, cn, kt, ct, reff, dn, hx, hy, hz):
    """Elastic energy of one contact: 1/2 k_n d_n^2 + 1/2 k_t |d_t|^2."""
    h2 = hx * hx + hy * hy + hz * hz
    return 0.5 * kn * dn * dn + 0.5 * kt * h2


@dataclass(frozen=True)
class LinearContact(ContactLaw):
    """Linear spring-dashpot contact with tangential history, Coulomb limit and rolling friction.

    Parameters: normal stiffness ``k_n`` [N/m], normal restitution ``e_n``, tangential
    restitution of a sticking collision ``e_t``, Coulomb friction ``mu``, rolling friction
    ``mu_r`` (constant directional torque, physics.md §1.3); ``k_t_ratio`` > 0 sets k_t = k_t_ratio
    k_n instead of deriving it (e_t then sets the tangential damping ratio only).
    """

    name = "linear"
    model_id = 0
    KEYS = LINEAR_KEYS
    force = staticmethod(linear_force)
    energy = staticmethod(linear_energy)
    title = "spring-dashpot"
    check_doc = ("the normal damping\n"
                 "eta_n = -2 ln(e_n) sqrt(m* k_n) / sqrt(pi^2 + ln^2 e_n), "
                 "k_t = (2/7) k_n (pi^2 + ln^2 e_t)/(pi^2 + ln^2 e_n),\n"
                 "eta_t (with m_t = 2/7 m*), the collision time t_c = sqrt(m* (pi^2 + ln^2 e_n)/k_n) (m* = m/2\n"
                 "particle-particle, m particle-wall)")

    k_n: float
    e_n: float
    e_t: float
    mu: float
    mu_r: float = 0.0
    k_t_ratio: float = 0.0

    def __post_init__(self):
        self._check_keys()

    # --- coefficients -------------------------------------------------------------------
    @property
    def k_t(self) -> float:
        """k_t = (2/7) k_n (pi^2 + ln^2 e_t) / (pi^2 + ln^2 e_n), or k_t_ratio k_n when that is set."""
        if self.k_t_ratio > 0.0:
            return self.k_t_ratio * self.k_n
        ln_n, ln_t = math.log(self.e_n), math.log(self.e_t)
        return 2.0 / 7.0 * self.k_n * (math.pi**2 + ln_t**2) / (math.pi**2 + ln_n**2)

    @property
    def c_n(self) -> float:
        """eta_n / sqrt(m* k_n) = -2 ln e_n / sqrt(pi^2 + ln^2 e_n)."""
        ln_n = math.log(self.e_n)
        return -2.0 * ln_n / math.sqrt(math.pi**2 + ln_n**2)

    @property
    def c_t(self) -> float:
        """eta_t / sqrt(m* k_t) = -2 ln e_t sqrt(2/7) / sqrt(pi^2 + ln^2 e_t)."""
        ln_t = math.log(self.e_t)
        return -2.0 * ln_t * math.sqrt(2.0 / 7.0) / math.sqrt(math.pi**2 + ln_t**2)

    def kernel_params(self) -> tuple[float, float, float, float]:
        """(k_n, c_n, k_t, c_t)."""
        return self.k_n, self.c_n, self.k_t, self.c_t

    def collision_time(self, m_eff: float, r_eff: float | None = None, speed: float | None = None) -> float:
        """t_c = sqrt(m* (pi^2 + ln^2 e_n) / k_n), the duration of a normal collision
        (independent of the effective radius and the impact speed, accepted for the common
        signature of :meth:`ContactLaw.collision_time`)."""
        return math.sqrt(m_eff * (math.pi**2 + math.log(self.e_n) ** 2) / self.k_n)

    def derived(self, m_eff: float) -> dict[str, float]:
        """Derived numbers for effective mass ``m_eff``: eta_n, k_t, eta_t, m_t, t_c."""
        k_t = self.k_t
        return dict(
            m_eff=m_eff,
            k_n=self.k_n,
            eta_n=self.c_n * math.sqrt(m_eff * self.k_n),
            k_t=k_t,
            m_t=2.0 / 7.0 * m_eff,
            eta_t=self.c_t * math.sqrt(m_eff * k_t),
            t_c=self.collision_time(m_eff),
            mu=self.mu,
            mu_r=self.mu_r,
        )

    def linearised(self, m_eff: float, r_eff: float, speed: float) -> dict[str, float]:
        dv = self.derived(m_eff)
        return {"k_n": self.k_n, "eta_n": dv["eta_n"], "k_t": dv["k_t"], "eta_t": dv["eta_t"]}

    def describe(self, m_eff: float, r_eff: float, speed: float, radius: float) -> str:
        """k_n, eta_n, k_t, eta_t, t_c at m* (R*, the impact speed and the radius do not enter)."""
        dv = self.derived(m_eff)
        return (f"k_n = {self.k_n:g} N/m, eta_n = {dv['eta_n']:.4g} kg/s, k_t = {dv['k_t']:.4g} N/m, "
                f"eta_t = {dv['eta_t']:.4g} kg/s, t_c = {dv['t_c']:.4g} s (m* = {m_eff:.4g} kg)")
