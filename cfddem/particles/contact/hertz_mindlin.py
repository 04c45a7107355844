"""Hertz-Mindlin no-slip contact law with viscous damping (``contact.model = "hertz_mindlin"``,
model id 1; physics.md §1.2).

The EDEM "Hertz-Mindlin (no slip)" model and LIGGGHTS ``gran model hertz tangential history``
with ``hertz/stiffness``-style inputs; Tsuji et al. 1992 damping.  Inputs (E, nu, e, mu, mu_r):

    1/E* = (1 - nu1^2)/E1 + (1 - nu2^2)/E2,   1/G* = 2(2 - nu1)(1 + nu1)/E1 + 2(2 - nu2)(1 + nu2)/E2
    R* = R_a R_b/(R_a + R_b) (R against a wall),  m* = m_a m_b/(m_a + m_b) (m against a wall)
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

Parameter row: [1, E*, 2 sqrt(5/6) beta', G*, 2 sqrt(5/6) beta', mu, mu_r, 0].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from cfddem._jit import kernel
from cfddem.errors import CaseError
from cfddem.particles.contact.base import FRICTION_KEYS, INF, ContactLaw, LawKey, coulomb_limit, split_velocity

_E = LawKey("E", "Pa", "hertz_mindlin: Young's modulus (DEM practice: a reduced value, glass is 6.3e10)",
            "Young's modulus (hertz_mindlin)", 5e7, lo=0.0, lo_open=True, hi=INF, hi_open=True)
_NU = LawKey("nu", "-", "hertz_mindlin: Poisson ratio", "Poisson ratio (hertz_mindlin)", 0.25,
             lo=-1.0, lo_open=True, hi=0.5)
HERTZ_MINDLIN_KEYS = (
    _E,
    _NU,
    LawKey("e", "-", "hertz_mindlin: coefficient of restitution", "restitution (hertz_mindlin)", 0.97, 0.95,
           lo=0.0, lo_open=True, hi=1.0),
) + FRICTION_KEYS


@kernel(inline="always")
def hertz_mindlin_force(estar, cd, gstar, cd_t, mu, meff, reff, dn, nx, ny, nz, vx, vy, vz, hx, hy, hz, dt_hist):
    """Hertz-Mindlin pair law (module docstring), same conventions and return as
    :func:`cfddem.particles.contact.linear.linear_force`; ``cd`` damps both directions
    (``cd_t``, its copy in the row, is not used):

        q = sqrt(R* d_n),  S_n = 2 E* q,  S_t = 8 G* q
        F_n = -(4/3) E* q d_n - c sqrt(S_n m*) v_n          (c = 2 sqrt(5/6) beta')
        d_t <- d_t + v_t dt_hist;   F_s = -S_t d_t
        |F_s| > mu |F_n|:  F_t = mu |F_n| F_s/|F_s|,  d_t <- -F_t / S_t   (sliding, no damping)
        else:              F_t = F_s - c sqrt(S_t m*) v_t
    """
    vn, vtx, vty, vtz = split_velocity(vx, vy, vz, nx, ny, nz)
    q = math.sqrt(reff * dn)
    sn = 2.0 * estar * q
    fn = -(4.0 / 3.0) * estar * q * dn - cd * math.sqrt(sn * meff) * vn
    st = 8.0 * gstar * q
    hx += vtx * dt_hist
    hy += vty * dt_hist
    hz += vtz * dt_hist
    fnabs = abs(fn)
    ftx, fty, ftz, sliding = coulomb_limit(-st * hx, -st * hy, -st * hz, fnabs, mu)
    if sliding:
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
def hertz_mindlin_energy(estar, cd, gstar, cd_t, reff, dn, hx, hy, hz):
    """Elastic energy of one contact: (8/15) E* sqrt(R*) d_n^(5/2) + 1/2 S_t |d_t|^2,
    S_t = 8 G* sqrt(R* d_n)."""
    h2 = hx * hx + hy * hy + hz * hz
    q = math.sqrt(reff * dn)
    return 8.0 / 15.0 * estar * q * dn * dn + 0.5 * 8.0 * gstar * q * h2


@dataclass(frozen=True)
class HertzMindlinContact(ContactLaw):
    """Hertz-Mindlin no-slip contact with viscous damping (physics.md §1.2; module docstring).

    Parameters: Young's modulus ``E`` [Pa] and Poisson ratio ``nu`` of the particle material,
    restitution coefficient ``e``, Coulomb friction ``mu``, rolling friction ``mu_r``.  Against a
    wall of another material give ``E_wall``, ``nu_wall``; by default the partner is of the same
    material (E, nu).
    """

    name = "hertz_mindlin"
    model_id = 1
    KEYS = HERTZ_MINDLIN_KEYS
    force = staticmethod(hertz_mindlin_force)
    energy = staticmethod(hertz_mindlin_energy)
    reference = "physics.md §1.2"
    check_doc = ("E* = E/(2(1 - nu^2)), G* = E/(4(2 - nu)(1 + nu)), beta, and\n"
                 "at the expected impact speed v (the case's speed scale, at least 1 m/s) the Hertz collision time\n"
                 "t_c = 2.87 (m*^2/(R* E*^2 v))^(1/5) and the Rayleigh time T_R = pi R sqrt(rho/G)/(0.1631 nu + 0.8766);\n"
                 "warning above dt = t_c/20 or 0.2 T_R, refused above t_c/5 unless forced.")

    E: float
    nu: float
    e: float
    mu: float
    mu_r: float = 0.0
    E_wall: float | None = None
    nu_wall: float | None = None

    def __post_init__(self):
        self._check_keys()
        if (self.E_wall is None) != (self.nu_wall is None):
            raise CaseError("E_wall", "give both E_wall and nu_wall (the partner material) or neither")
        if self.E_wall is not None:
            _E.check("E_wall", self.E_wall)
            _NU.check("nu_wall", self.nu_wall)

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

    def kernel_params(self) -> tuple[float, float, float, float]:
        """(E*, c, G*, c) with c = 2 sqrt(5/6) beta'."""
        return self.E_star, self.c_damp, self.G_star, self.c_damp

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

    def linearised(self, m_eff: float, r_eff: float, speed: float) -> dict[str, float]:
        dv = self.derived(m_eff, r_eff, speed)
        return {"k_n": dv["S_n"], "eta_n": dv["eta_n"], "k_t": dv["S_t"], "eta_t": dv["eta_t"]}

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

    def describe(self, m_eff: float, r_eff: float, speed: float, radius: float) -> str:
        """E*, G*, beta and, at impact speed ``speed``, the maximum overlap (in particle radii),
        S_n, eta_n, S_t and the Hertz time."""
        dv = self.derived(m_eff, r_eff, speed)
        return (f"Hertz-Mindlin E* = {dv['E_star']:.4g} Pa, G* = {dv['G_star']:.4g} Pa, "
                f"beta = {dv['beta']:.4g}; at v = {speed:.3g} m/s: max overlap {dv['d_max'] / radius:.3g} R, "
                f"S_n = {dv['S_n']:.4g} N/m, eta_n = {dv['eta_n']:.4g} kg/s, S_t = {dv['S_t']:.4g} N/m, "
                f"t_c = {dv['t_c']:.4g} s (m* = {m_eff:.4g} kg, R* = {r_eff:.4g} m)")
