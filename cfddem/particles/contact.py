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

Hertz-Mindlin no-slip law with viscous damping (model 1, physics.md §1.2; the EDEM
"Hertz-Mindlin (no slip)" model and LIGGGHTS ``gran model hertz tangential history`` with
``hertz/stiffness``-style inputs; Tsuji et al. 1992 damping), inputs (E, nu, e, mu, mu_r):

    1/E* = (1 - nu1^2)/E1 + (1 - nu2^2)/E2,   1/G* = 2(2 - nu1)(1 + nu1)/E1 + 2(2 - nu2)(1 + nu2)/E2
    R* = R_a R_b/(R_a + R_b) (R against a wall),  m* as above
    S_n = 2 E* sqrt(R* d_n),  S_t = 8 G* sqrt(R* d_n)
    F_n = -(4/3) E* sqrt(R*) d_n^(3/2) n - eta_n v_n,     eta_n = 2 sqrt(5/6) beta' sqrt(S_n m*)
    F_t = -S_t d_t - eta_t v_t (sticking),               eta_t = 2 sqrt(5/6) beta' sqrt(S_t m*)
    beta' = -ln e / sqrt(ln^2 e + pi^2)                  (= -beta of physics.md, >= 0)

d_t is the same incremental tangential spring (history) as in the linear law.  Coulomb limit as
in LIGGGHTS ``tangential_model_history``: the *spring* force S_t |d_t| is compared with
mu |F_n|; when it exceeds it the contact slides, F_t = -mu |F_n| d_t/|d_t| with no tangential
damping, and d_t is rescaled to d_t = -F_t / S_t.  Identical materials: E* = E / (2 (1 - nu^2)),
G* = E / (4 (2 - nu)(1 + nu)).  The restitution of a head-on collision equals e at every impact
speed (the damping scales like the Hertz stiffness; Antypov & Elliott 2011); the duration is the
Hertz time t_c = 2.87 (m*^2 / (R* E*^2 v))^(1/5) (Johnson 1985, §11.4) for e -> 1.

Contact parameters travel to kernels as a float64 row of length ``NPARAM``; ``params[P_MODEL]``
selects the law (``MODEL_LINEAR`` = 0, ``MODEL_HERTZ_MINDLIN`` = 1).  Linear row:
[0, k_n, c_n, k_t, c_t, mu, mu_r, 0].  Hertz-Mindlin row (same slots, other meaning):
[1, E*, 2 sqrt(5/6) beta', G*, 2 sqrt(5/6) beta', mu, mu_r, 0] (``P_ESTAR`` = ``P_KN``,
``P_BETA`` = ``P_CN``, ``P_GSTAR`` = ``P_KT``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cfddem._jit import kernel
from cfddem.errors import CaseError

MODEL_LINEAR = 0
MODEL_HERTZ_MINDLIN = 1
NPARAM = 8
P_MODEL, P_KN, P_CN, P_KT, P_CT, P_MU, P_MUR = 0, 1, 2, 3, 4, 5, 6
P_ESTAR, P_BETA, P_GSTAR = P_KN, P_CN, P_KT  # Hertz-Mindlin meaning of the same slots


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

    def collision_time(self, m_eff: float, r_eff: float | None = None, speed: float | None = None) -> float:
        """t_c = sqrt(m* (pi^2 + ln^2 e_n) / k_n), the duration of a normal collision
        (independent of the effective radius and the impact speed, accepted for a common
        signature with :meth:`HertzMindlinContact.collision_time`)."""
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


def _check_material(key_e: str, key_nu: str, E: float, nu: float) -> None:
    if not (E > 0 and math.isfinite(E)):
        raise CaseError(key_e, f"Young's modulus must be positive and finite (Pa), got {E}")
    if not (-1.0 < nu <= 0.5):
        raise CaseError(key_nu, f"Poisson ratio must be in (-1, 0.5], got {nu}")


@dataclass(frozen=True)
class HertzMindlinContact:
    """Hertz-Mindlin no-slip contact with viscous damping (physics.md §1.2; module docstring).

    Parameters: Young's modulus ``E`` [Pa] and Poisson ratio ``nu`` of the particle material,
    restitution coefficient ``e``, Coulomb friction ``mu``, rolling friction ``mu_r``.  Against a
    wall of another material give ``E_wall``, ``nu_wall``; by default the partner is of the same
    material (E, nu).
    """

    E: float
    nu: float
    e: float
    mu: float
    mu_r: float = 0.0
    E_wall: float | None = None
    nu_wall: float | None = None

    def __post_init__(self):
        _check_material("E", "nu", self.E, self.nu)
        if (self.E_wall is None) != (self.nu_wall is None):
            raise CaseError("E_wall", "give both E_wall and nu_wall (the partner material) or neither")
        if self.E_wall is not None:
            _check_material("E_wall", "nu_wall", self.E_wall, self.nu_wall)
        _check_e("e", self.e)
        if not self.mu >= 0:
            raise CaseError("mu", f"friction coefficient must be >= 0, got {self.mu}")
        if not self.mu_r >= 0:
            raise CaseError("mu_r", f"rolling friction coefficient must be >= 0, got {self.mu_r}")

    def _partner(self):
        if self.E_wall is None:
            return self.E, self.nu
        return self.E_wall, self.nu_wall

    @property
    def E_star(self) -> float:
        """1/E* = (1 - nu1^2)/E1 + (1 - nu2^2)/E2 (same material: E / (2 (1 - nu^2)))."""
        E2, nu2 = self._partner()
        return 1.0 / ((1.0 - self.nu**2) / self.E + (1.0 - nu2**2) / E2)

    @property
    def G_star(self) -> float:
        """1/G* = 2(2 - nu1)(1 + nu1)/E1 + 2(2 - nu2)(1 + nu2)/E2 (same: E / (4 (2 - nu)(1 + nu)))."""
        E2, nu2 = self._partner()
        return 1.0 / (2.0 * (2.0 - self.nu) * (1.0 + self.nu) / self.E + 2.0 * (2.0 - nu2) * (1.0 + nu2) / E2)

    @property
    def G(self) -> float:
        """Shear modulus of the particle material G = E / (2 (1 + nu))."""
        return self.E / (2.0 * (1.0 + self.nu))

    @property
    def beta(self) -> float:
        """beta = ln e / sqrt(ln^2 e + pi^2) (<= 0; physics.md §1.2)."""
        le = math.log(self.e)
        return le / math.sqrt(le * le + math.pi**2)

    @property
    def c_damp(self) -> float:
        """eta / sqrt(S m*) = -2 sqrt(5/6) beta (>= 0), for both the normal and tangential dashpot."""
        return -2.0 * math.sqrt(5.0 / 6.0) * self.beta

    def normal_force(self, r_eff: float, dn: float) -> float:
        """Elastic normal force magnitude (4/3) E* sqrt(R*) d_n^(3/2)."""
        return 4.0 / 3.0 * self.E_star * math.sqrt(r_eff) * dn**1.5

    def stiffness(self, r_eff: float, dn: float) -> tuple[float, float]:
        """(S_n, S_t) = (2 E* sqrt(R* d_n), 8 G* sqrt(R* d_n))."""
        q = math.sqrt(r_eff * dn)
        return 2.0 * self.E_star * q, 8.0 * self.G_star * q

    def collision_time(self, m_eff: float, r_eff: float | None = None, speed: float | None = None) -> float:
        """Hertz collision time t_c = 2.87 (m*^2 / (R* E*^2 v))^(1/5) at impact speed ``speed``
        (Johnson 1985, eq. 11.24; undamped, the damped contact lasts a few per cent longer).
        ``r_eff`` = R* is required; ``speed`` defaults to 1 m/s."""
        if r_eff is None or not r_eff > 0:
            raise ValueError("HertzMindlinContact.collision_time needs the effective radius r_eff > 0")
        v = 1.0 if speed is None else max(float(speed), 1e-12)
        return 2.87 * (m_eff**2 / (r_eff * self.E_star**2 * v)) ** 0.2

    def rayleigh_time(self, radius: float, density: float) -> float:
        """Rayleigh wave time T_R = pi R sqrt(rho / G) / (0.1631 nu + 0.8766) (the usual HM
        time-step scale; G = E / (2 (1 + nu)), particle material)."""
        return math.pi * radius * math.sqrt(density / self.G) / (0.1631 * self.nu + 0.8766)

    def derived(self, m_eff: float, r_eff: float | None = None, speed: float | None = None,
                overlap: float | None = None) -> dict[str, float]:
        """Derived numbers for m*, R*, impact speed v: E*, G*, beta, t_c, and the stiffness and
        damping S_n, eta_n, S_t, eta_t at ``overlap`` (default: the maximum overlap of a head-on
        elastic impact at v, d_max = (15 m* v^2 / (16 E* sqrt(R*)))^(2/5))."""
        v = 1.0 if speed is None else float(speed)
        out = dict(m_eff=m_eff, E_star=self.E_star, G_star=self.G_star, beta=self.beta, mu=self.mu,
                   mu_r=self.mu_r)
        if r_eff is not None:
            d = overlap if overlap is not None else (15.0 * m_eff * v * v / (16.0 * self.E_star * math.sqrt(r_eff))) ** 0.4
            sn, st = self.stiffness(r_eff, d)
            out.update(r_eff=r_eff, speed=v, d_max=d, S_n=sn, S_t=st,
                       eta_n=self.c_damp * math.sqrt(sn * m_eff), eta_t=self.c_damp * math.sqrt(st * m_eff),
                       t_c=self.collision_time(m_eff, r_eff, v))
        return out

    def params(self) -> np.ndarray:
        """The float64 parameter row that kernels receive (layout in the module docstring)."""
        p = np.zeros(NPARAM)
        p[P_MODEL] = MODEL_HERTZ_MINDLIN
        p[P_ESTAR] = self.E_star
        p[P_BETA] = self.c_damp
        p[P_GSTAR] = self.G_star
        p[P_CT] = self.c_damp
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
def hertz_law(estar, cd, gstar, mu, meff, reff, dn, nx, ny, nz, vx, vy, vz, hx, hy, hz, dt_hist):
    """Hertz-Mindlin pair law (model 1; module docstring), same conventions and return as
    :func:`linear_law`:

        q = sqrt(R* d_n),  S_n = 2 E* q,  S_t = 8 G* q
        F_n = -(4/3) E* q d_n - c sqrt(S_n m*) v_n          (c = 2 sqrt(5/6) beta')
        d_t <- d_t + v_t dt_hist;   F_s = -S_t d_t
        |F_s| > mu |F_n|:  F_t = mu |F_n| F_s/|F_s|,  d_t <- -F_t / S_t   (sliding, no damping)
        else:              F_t = F_s - c sqrt(S_t m*) v_t
    """
    vn = vx * nx + vy * ny + vz * nz
    vtx = vx - vn * nx
    vty = vy - vn * ny
    vtz = vz - vn * nz
    q = math.sqrt(reff * dn)
    sn = 2.0 * estar * q
    fn = -(4.0 / 3.0) * estar * q * dn - cd * math.sqrt(sn * meff) * vn
    st = 8.0 * gstar * q
    hx += vtx * dt_hist
    hy += vty * dt_hist
    hz += vtz * dt_hist
    ftx = -st * hx
    fty = -st * hy
    ftz = -st * hz
    ft2 = ftx * ftx + fty * fty + ftz * ftz
    fnabs = abs(fn)
    flim = mu * fnabs
    if ft2 > flim * flim:
        s = flim / math.sqrt(ft2)
        ftx *= s
        fty *= s
        ftz *= s
        hx = -ftx / st
        hy = -fty / st
        hz = -ftz / st
    else:
        eta_t = cd * math.sqrt(st * meff)
        ftx -= eta_t * vtx
        fty -= eta_t * vty
        ftz -= eta_t * vtz
    return (fn * nx + ftx, fn * ny + fty, fn * nz + ftz, ftx, fty, ftz, hx, hy, hz, fnabs)


@kernel(inline="always")
def pair_law(model, kn, cn, kt, ct, mu, meff, reff, dn, nx, ny, nz, vx, vy, vz, hx, hy, hz, dt_hist):
    """Dispatch on the model id: 0 linear spring-dashpot (k_n, c_n, k_t, c_t, mu from the
    parameter row), 1 Hertz-Mindlin (the same slots hold E*, c, G*, c, mu; ``reff`` = R*, unused
    by the linear law).  Scalars only: inlined functions taking arrays cost refcount traffic in
    the hot loops.  Same return as :func:`linear_law`."""
    hx, hy, hz = project_history(hx, hy, hz, nx, ny, nz)
    if model == 1.0:
        return hertz_law(kn, cn, kt, mu, meff, reff, dn, nx, ny, nz, vx, vy, vz, hx, hy, hz, dt_hist)
    return linear_law(kn, cn, kt, ct, mu, meff, dn, nx, ny, nz, vx, vy, vz, hx, hy, hz, dt_hist)


@kernel
def wall_contact_force(model, kn, cn, kt, ct, mu, m, r, ov, nx, ny, nz, qx, qy, qz, vx, vy, vz, wx, wy, wz,
                       wvx, wvy, wvz, hx, hy, hz, refx, refy, refz, dt_hist):
    """One contact of a sphere (mass m, radius r, velocity v, spin w) with a wall (analytic or
    mesh): overlap ``ov``, unit normal n from the wall towards the centre, contact point q, wall
    surface velocity wv at q, tangential spring h, reference point ref of the torque on the wall.
    The wall is the partner b of infinite mass (m* = m, R* = r) in :func:`pair_law`.

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
        model, kn, cn, kt, ct, mu, m, r, ov, ax_, ay_, az_, rvx, rvy, rvz, hx, hy, hz, dt_hist)
    lx = qx - refx
    ly = qy - refy
    lz = qz - refz
    return (cfx, cfy, cfz, r * (ay_ * ctz - az_ * cty), r * (az_ * ctx - ax_ * ctz), r * (ax_ * cty - ay_ * ctx),
            hx, hy, hz, fnabs, -(ly * cfz - lz * cfy), -(lz * cfx - lx * cfz), -(lx * cfy - ly * cfx))


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
