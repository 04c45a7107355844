"""Contact laws: derived parameters and the scalar pair law (physics.md §1.1, §1.3).

Linear spring-dashpot (Cundall & Strack 1979; damping from the restitution coefficient as in
LIGGGHTS ``hooke`` and Silbert et al. 2001), inputs (k_n, e_n, e_t, mu, mu_r):

    eta_n = -2 ln(e_n) sqrt(m* k_n) / sqrt(pi^2 + ln^2 e_n)
    k_t   = (2/7) k_n (pi^2 + ln^2 e_t) / (pi^2 + ln^2 e_n)
    eta_t = -2 ln(e_t) sqrt(m_t k_t) / sqrt(pi^2 + ln^2 e_t),    m_t = (2/7) m*
    t_c   = sqrt(m* (pi^2 + ln^2 e_n) / k_n)

m* = m_a m_b / (m_a + m_b) (m* = m_a against a wall).  Because m* differs per pair with
polydispersity, kernels receive the *coefficients* c_n, c_t and compute per contact

    eta_n = c_n sqrt(m* k_n),  c_n = -2 ln e_n / sqrt(pi^2 + ln^2 e_n)
    eta_t = c_t sqrt(m* k_t),  c_t = -2 ln e_t sqrt(2/7) / sqrt(pi^2 + ln^2 e_t)

Contact parameters travel to kernels as a float64 row of length ``NPARAM``
(``params[P_MODEL]`` selects the law; ``MODEL_LINEAR`` = 0 is the only one so far; a
Hertz-Mindlin law (§1.2) is meant to be added as model 1 using the same row layout with its own
slots and the ``reff`` argument that :func:`pair_law` already receives).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cfddem._jit import kernel
from cfddem.errors import CaseError

MODEL_LINEAR = 0
NPARAM = 8
P_MODEL, P_KN, P_CN, P_KT, P_CT, P_MU, P_MUR = 0, 1, 2, 3, 4, 5, 6


def _check_e(key: str, e: float) -> None:
    if not (0.0 < e <= 1.0):
        raise CaseError(key, f"restitution coefficient must be in (0, 1], got {e}")


@dataclass(frozen=True)
class LinearContact:
    """Linear spring-dashpot contact with tangential history, Coulomb limit and rolling friction.

    Parameters: normal stiffness ``k_n`` [N/m], normal restitution ``e_n``, tangential
    restitution of a sticking collision ``e_t``, Coulomb friction ``mu``, rolling friction
    ``mu_r`` (constant directional torque, physics.md §1.3).
    """

    k_n: float
    e_n: float
    e_t: float
    mu: float
    mu_r: float = 0.0

    def __post_init__(self):
        if not (self.k_n > 0 and math.isfinite(self.k_n)):
            raise CaseError("k_n", f"normal stiffness must be positive, got {self.k_n}")
        _check_e("e_n", self.e_n)
        _check_e("e_t", self.e_t)
        if not self.mu >= 0:
            raise CaseError("mu", f"friction coefficient must be >= 0, got {self.mu}")
        if not self.mu_r >= 0:
            raise CaseError("mu_r", f"rolling friction coefficient must be >= 0, got {self.mu_r}")

    # --- coefficients -------------------------------------------------------------------
    @property
    def k_t(self) -> float:
        """k_t = (2/7) k_n (pi^2 + ln^2 e_t) / (pi^2 + ln^2 e_n)."""
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

    def collision_time(self, m_eff: float) -> float:
        """t_c = sqrt(m* (pi^2 + ln^2 e_n) / k_n), the duration of a normal collision."""
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

    def params(self) -> np.ndarray:
        """The float64 parameter row that kernels receive (layout in the module docstring)."""
        p = np.zeros(NPARAM)
        p[P_MODEL] = MODEL_LINEAR
        p[P_KN] = self.k_n
        p[P_CN] = self.c_n
        p[P_KT] = self.k_t
        p[P_CT] = self.c_t
        p[P_MU] = self.mu
        p[P_MUR] = self.mu_r
        return p


# --- compiled scalar pieces --------------------------------------------------------------


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
def linear_law(kn, cn, kt, ct, mu, meff, dn, nx, ny, nz, vx, vy, vz, hx, hy, hz, dt_hist):
    """Linear spring-dashpot pair law with tangential history and Coulomb limit.

    n points from a to its partner b, v = v_ab is the relative velocity of a's contact point with
    respect to b's, h = d_t the tangential spring (already projected into the tangent plane).

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
    vn = vx * nx + vy * ny + vz * nz
    vtx = vx - vn * nx
    vty = vy - vn * ny
    vtz = vz - vn * nz
    eta_n = cn * math.sqrt(meff * kn)
    fn = -kn * dn - eta_n * vn
    hx += vtx * dt_hist
    hy += vty * dt_hist
    hz += vtz * dt_hist
    eta_t = ct * math.sqrt(meff * kt)
    ftx = -kt * hx - eta_t * vtx
    fty = -kt * hy - eta_t * vty
    ftz = -kt * hz - eta_t * vtz
    ft2 = ftx * ftx + fty * fty + ftz * ftz
    fnabs = abs(fn)
    flim = mu * fnabs
    if ft2 > flim * flim:
        s = flim / math.sqrt(ft2)
        ftx *= s
        fty *= s
        ftz *= s
        if kt > 0.0:
            hx = -(ftx + eta_t * vtx) / kt
            hy = -(fty + eta_t * vty) / kt
            hz = -(ftz + eta_t * vtz) / kt
    return (fn * nx + ftx, fn * ny + fty, fn * nz + ftz, ftx, fty, ftz, hx, hy, hz, fnabs)


@kernel(inline="always")
def pair_law(model, kn, cn, kt, ct, mu, meff, reff, dn, nx, ny, nz, vx, vy, vz, hx, hy, hz, dt_hist):
    """Dispatch on the model id (0: linear spring-dashpot, parameters k_n, c_n, k_t, c_t, mu from
    the parameter row).  ``reff`` = R* is unused by the linear law and is there for Hertz-Mindlin.
    Scalars only: inlined functions taking arrays cost refcount traffic in the hot loops.
    Same return as :func:`linear_law`."""
    hx, hy, hz = project_history(hx, hy, hz, nx, ny, nz)
    # model 0 (only model so far)
    return linear_law(kn, cn, kt, ct, mu, meff, dn, nx, ny, nz, vx, vy, vz, hx, hy, hz, dt_hist)


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
