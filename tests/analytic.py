"""Analytic (closed-form or published) reference solutions, shared by the verification tests.

One small frozen dataclass per problem: its parameters, and its solution as methods.  The
verification tests compare the solvers against these objects; tests/unit/test_analytic.py
checks the objects themselves against independent facts (limits, finite-difference residuals
of the governing equations, quadratures).  Nothing here imports cfddem: a reference must not
share code with what it checks.

Formulas cite /work/shared/physics.md (§ numbers) or the textbook or paper they come from.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq
from scipy.spatial.transform import Rotation


def _positive_root(a: float, b: float, c: float) -> float:
    """The positive root of a x^2 + b x - c = 0 (a >= 0, b > 0, c > 0), without cancellation."""
    return 2.0 * c / (b + math.sqrt(b * b + 4.0 * a * c))


# ----- particles (physics.md §1) -----------------------------------------------------------


@dataclass(frozen=True)
class LinearCollision:
    """Normal collision of the linear spring-dashpot contact (physics.md §1.1): a damped
    harmonic oscillator of the overlap d,

        m* d'' + eta_n d' + k_n d = 0,   d(0) = 0,   d'(0) = v_in (approach speed),
        eta_n = -2 ln(e_n) sqrt(m* k_n) / sqrt(pi^2 + ln^2 e_n),

    whose solution is d(t) = v_in / w_d exp(-zeta w_0 t) sin(w_d t), w_0 = sqrt(k_n/m*),
    zeta = eta_n / (2 sqrt(m* k_n)), w_d = w_0 sqrt(1 - zeta^2).  The contact ends when the
    overlap returns to zero, at t_c = pi / w_d = sqrt(m* (pi^2 + ln^2 e_n) / k_n); the
    rebound speed is then e_n v_in.  A sticking tangential contact oscillates with the same
    period and reverses the tangential contact velocity with factor e_t.
    ``m_eff`` is m* = m_a m_b / (m_a + m_b) (m_a against a wall).
    """

    k_n: float
    e_n: float
    m_eff: float
    e_t: float = 1.0

    @property
    def eta_n(self) -> float:
        ln = math.log(self.e_n)
        return -2.0 * ln * math.sqrt(self.m_eff * self.k_n) / math.sqrt(math.pi**2 + ln**2)

    @property
    def t_c(self) -> float:
        """Normal collision time sqrt(m* (pi^2 + ln^2 e_n) / k_n)."""
        return math.sqrt(self.m_eff * (math.pi**2 + math.log(self.e_n) ** 2) / self.k_n)

    def _rates(self) -> tuple[float, float]:
        """(zeta w_0, w_d) of the oscillator."""
        w0 = math.sqrt(self.k_n / self.m_eff)
        zeta = self.eta_n / (2.0 * math.sqrt(self.m_eff * self.k_n))
        return zeta * w0, w0 * math.sqrt(1.0 - zeta * zeta)

    def overlap(self, t, v_in: float):
        """Overlap d(t) [m] for the approach speed ``v_in`` (valid for 0 <= t <= t_c)."""
        s, wd = self._rates()
        t = np.asarray(t, dtype=float)
        return v_in / wd * np.exp(-s * t) * np.sin(wd * t)

    def overlap_rate(self, t, v_in: float):
        """d'(t): the relative normal (closing) speed during contact."""
        s, wd = self._rates()
        t = np.asarray(t, dtype=float)
        return v_in * np.exp(-s * t) * (np.cos(wd * t) - s / wd * np.sin(wd * t))

    def rebound_velocity(self, v_in: float) -> float:
        """Closing speed at the end of contact, d'(t_c) = -e_n v_in."""
        return float(self.overlap_rate(self.t_c, v_in))

    def tangential_rebound(self, u_t):
        """Tangential contact-point velocity after a sticking collision: -e_t u_t."""
        return -self.e_t * np.asarray(u_t, dtype=float)

    def static_overlap(self, load: float) -> float:
        """Overlap carrying a steady normal load: load / k_n."""
        return load / self.k_n


@dataclass(frozen=True)
class HertzNormal:
    """Hertz normal force (physics.md §1.2; Johnson, Contact Mechanics, 1985, §4.2):
    F = (4/3) E* sqrt(R*) d^(3/2)."""

    E_star: float
    r_eff: float

    def force(self, overlap):
        return 4.0 / 3.0 * self.E_star * math.sqrt(self.r_eff) * np.asarray(overlap, dtype=float) ** 1.5

    def static_overlap(self, load: float) -> float:
        """Overlap carrying a steady normal load: (3 F / (4 E* sqrt(R*)))^(2/3)."""
        return (3.0 * load / (4.0 * self.E_star * math.sqrt(self.r_eff))) ** (2.0 / 3.0)


@dataclass(frozen=True)
class InclineSphere:
    """A solid sphere (I = 2/5 m R^2) on a plane inclined at ``theta``, with Coulomb friction
    ``mu`` and rolling friction ``mu_r`` (constant torque mu_r R N against the spin,
    physics.md §1.3).  With N = m g cos(theta) and f the friction force up the slope:

    * rest for tan(theta) < mu_r (the rolling torque holds the sphere);
    * rolling without slip, m a = m g sin - f, I a/R = f R - mu_r R N, so
      a = (5/7) g (sin(theta) - mu_r cos(theta)) and f/N = (2 tan(theta) + 5 mu_r)/7, valid
      while f <= mu N, i.e. tan(theta) <= (7 mu - 5 mu_r)/2;
    * rolling and sliding above that: a = g (sin(theta) - mu cos(theta)), the spin grows at
      R dw/dt = (5/2) (mu - mu_r) g cos(theta), slower than a: the contact point slips.

    Requires mu_r < mu (otherwise there is no pure-rolling range).  Accelerations are along
    the slope, downhill positive.
    """

    theta: float
    mu: float
    mu_r: float
    g: float = 9.81

    def __post_init__(self):
        if not 0.0 <= self.mu_r < self.mu:
            raise ValueError("InclineSphere needs 0 <= mu_r < mu")

    @property
    def rest_threshold(self) -> float:
        """tan(theta) below which the sphere stays at rest: mu_r."""
        return self.mu_r

    @property
    def slide_threshold(self) -> float:
        """tan(theta) above which the rolling sphere also slides: (7 mu - 5 mu_r)/2."""
        return (7.0 * self.mu - 5.0 * self.mu_r) / 2.0

    def regime(self) -> str:
        """'rest', 'roll' or 'slide'."""
        t = math.tan(self.theta)
        if t < self.rest_threshold:
            return "rest"
        return "roll" if t <= self.slide_threshold else "slide"

    def acceleration(self) -> float:
        """Acceleration of the centre along the slope."""
        s, c = math.sin(self.theta), math.cos(self.theta)
        return {"rest": 0.0,
                "roll": 5.0 / 7.0 * self.g * (s - self.mu_r * c),
                "slide": self.g * (s - self.mu * c)}[self.regime()]

    def rim_acceleration(self) -> float:
        """R dw/dt, the spin-up of the rim speed (equal to the acceleration while rolling)."""
        if self.regime() == "slide":
            return 2.5 * (self.mu - self.mu_r) * self.g * math.cos(self.theta)
        return self.acceleration()

    def friction_ratio(self) -> float:
        """|f| / N, the friction force the contact has to carry (mu while sliding)."""
        t = math.tan(self.theta)
        return {"rest": t, "roll": (2.0 * t + 5.0 * self.mu_r) / 7.0, "slide": self.mu}[self.regime()]

    def gravity(self) -> tuple[float, float, float]:
        """Gravity in the frame of a floor y = 0 tilted by theta towards +x."""
        return (self.g * math.sin(self.theta), -self.g * math.cos(self.theta), 0.0)

    def normal_load(self, mass: float) -> float:
        return mass * self.g * math.cos(self.theta)


@dataclass(frozen=True)
class RotatingFrame:
    """The frame rotating at constant ``omega`` about an axis through ``axis_point``
    (physics.md §3).  Seen from it an inertial vector turns by -Omega t, so

    * a free particle (no forces in the lab) with r(0) = r0, v(0) = v0 moves on
      r(t) - a = Rot(-Omega t) (r0 - a + v_in t), v_in = v0 + Omega x (r0 - a), and
      v(t) = Rot(-Omega t) v_in - Omega x (r(t) - a);
    * a free spin keeps its inertial value w + Omega, so w(t) = Rot(-Omega t)(w0 + Omega) - Omega;
    * the lab-frame gas at rest is the steady field u = -Omega x (r - a);
    * a uniform stream, with the centrifugal force cancelled, turns under Coriolis alone,
      du/dt = -2 Omega x u: u(t) = Rot(-2 Omega t) u0 (inertial oscillation).
    """

    omega: tuple
    axis_point: tuple = (0.0, 0.0, 0.0)

    def rotation(self, t: float, rate: float = 1.0) -> np.ndarray:
        """Matrix of the rotation by -rate Omega t."""
        return Rotation.from_rotvec(-rate * t * np.asarray(self.omega, dtype=float)).as_matrix()

    def _v_in(self, r0, v0):
        a = np.asarray(self.axis_point, dtype=float)
        return np.asarray(v0, dtype=float) + np.cross(self.omega, np.asarray(r0, dtype=float) - a)

    def free_position(self, r0, v0, t: float) -> np.ndarray:
        a = np.asarray(self.axis_point, dtype=float)
        return a + self.rotation(t) @ (np.asarray(r0, dtype=float) - a + self._v_in(r0, v0) * t)

    def free_velocity(self, r0, v0, t: float) -> np.ndarray:
        a = np.asarray(self.axis_point, dtype=float)
        return self.rotation(t) @ self._v_in(r0, v0) - np.cross(self.omega, self.free_position(r0, v0, t) - a)

    def free_spin(self, w0, t: float) -> np.ndarray:
        om = np.asarray(self.omega, dtype=float)
        return self.rotation(t) @ (np.asarray(w0, dtype=float) + om) - om

    def lab_rest_velocity(self, x, y, z):
        """u = -Omega x (r - a) at the points (x, y, z) (arrays broadcast), as three arrays."""
        shape = np.broadcast(x, y, z).shape
        r = np.stack([np.broadcast_to(np.asarray(c, dtype=float), shape) - a
                      for c, a in zip((x, y, z), self.axis_point)], axis=-1)
        u = -np.cross(np.asarray(self.omega, dtype=float), r)
        return u[..., 0], u[..., 1], u[..., 2]

    def coriolis_turned(self, u0, t: float) -> np.ndarray:
        """A uniform stream u0 after time t under the Coriolis force alone."""
        return self.rotation(t, rate=2.0) @ np.asarray(u0, dtype=float)


@dataclass(frozen=True)
class SpherePair:
    """Two spheres of radii r1, r2 whose centres are ``d`` apart, placed along x
    (centre 1 at the origin).  Lens (intersection) volume, e.g. Weisstein, MathWorld
    "Sphere-Sphere Intersection":

        V_lens = pi (r1 + r2 - d)^2 (d^2 + 2 d (r1 + r2) - 3 (r1 - r2)^2) / (12 d)

    for |r1 - r2| <= d <= r1 + r2 (equal radii: pi (4 r + d)(2 r - d)^2 / 12).
    """

    r1: float
    r2: float
    d: float

    @property
    def lens_volume(self) -> float:
        r1, r2, d = self.r1, self.r2, self.d
        if d >= r1 + r2:
            return 0.0
        if d <= abs(r1 - r2):
            return 4.0 / 3.0 * math.pi * min(r1, r2) ** 3
        return math.pi * (r1 + r2 - d) ** 2 * (d * d + 2 * d * (r1 + r2) - 3 * (r1 - r2) ** 2) / (12 * d)

    @property
    def volume(self) -> float:
        """Volume of the union."""
        return 4.0 / 3.0 * math.pi * (self.r1**3 + self.r2**3) - self.lens_volume

    def separated_inertia(self, rho: float) -> np.ndarray:
        """Principal moments (about x, y, z through the centre of mass) of two separate
        spheres of density rho: 2/5 m r^2 each plus the parallel-axis term
        m1 m2 / (m1 + m2) d^2 about y and z."""
        if self.d < self.r1 + self.r2:
            raise ValueError("separated_inertia needs d >= r1 + r2")
        m1, m2 = (rho * 4.0 / 3.0 * math.pi * r**3 for r in (self.r1, self.r2))
        own = 0.4 * (m1 * self.r1**2 + m2 * self.r2**2)
        arm = m1 * m2 / (m1 + m2) * self.d**2
        return np.array([own, own + arm, own + arm])


# ----- gas (physics.md §2) -------------------------------------------------------------------


@dataclass(frozen=True)
class TaylorGreen:
    """2D Taylor-Green vortex, an exact solution of the incompressible Navier-Stokes
    equations in a periodic box of side 2 pi / k (e.g. Pope, Turbulent Flows, ex. 6.x;
    Taylor & Green 1937):

        u = sin(kx) cos(ky) F(t),  v = -cos(kx) sin(ky) F(t),   F = exp(-2 nu k^2 t),
        p = (rho/4) (cos 2kx + cos 2ky) F(t)^2.
    """

    nu: float
    k: float = 1.0
    rho: float = 1.0

    def velocity(self, x, y, t: float):
        f = math.exp(-2.0 * self.nu * self.k**2 * t)
        kx, ky = self.k * np.asarray(x, dtype=float), self.k * np.asarray(y, dtype=float)
        return np.sin(kx) * np.cos(ky) * f, -np.cos(kx) * np.sin(ky) * f

    def pressure(self, x, y, t: float):
        f = math.exp(-4.0 * self.nu * self.k**2 * t)
        kx, ky = self.k * np.asarray(x, dtype=float), self.k * np.asarray(y, dtype=float)
        return 0.25 * self.rho * (np.cos(2 * kx) + np.cos(2 * ky)) * f


@dataclass(frozen=True)
class SquareDuct:
    """Fully developed flow in a square duct [0, L]^2 driven by a pressure gradient G
    (White, Viscous Fluid Flow, 3rd ed., eq. 3-47/3-48 with a = b = L/2):
    mu (w_xx + w_yy) = -G, w = 0 on the walls,

        w = (4 G L^2 / (mu pi^3)) sum_{n odd} n^-3 [1 - cosh(n pi (y - L/2)/L) / cosh(n pi/2)] sin(n pi x/L),
        Q = G L^4 / (12 mu) [1 - (192 / pi^5) sum_{n odd} tanh(n pi/2) / n^5]  (= G L^4 / (28.454 mu)).
    """

    G: float
    L: float
    mu: float
    terms: int = 100  # odd n up to 2 terms - 1; the series converge like n^-3 (w) and n^-5 (Q)

    def _n(self):
        return np.arange(1, 2 * self.terms, 2, dtype=float)

    def velocity(self, x, y):
        x = np.asarray(x, dtype=float)[..., None]
        y = np.asarray(y, dtype=float)[..., None]
        n, L = self._n(), self.L
        # cosh(a)/cosh(b) for |a| <= b written with exponentials that cannot overflow
        a, b = n * np.pi * (y - L / 2) / L, n * np.pi / 2
        ratio = np.exp(np.abs(a) - b) * (1 + np.exp(-2 * np.abs(a))) / (1 + np.exp(-2 * b))
        s = np.sum((1.0 - ratio) * np.sin(n * np.pi * x / L) / n**3, axis=-1)
        return 4.0 * self.G * L**2 / (self.mu * np.pi**3) * s

    def flow_rate(self) -> float:
        n = self._n()
        return self.G * self.L**4 / (12 * self.mu) * (1 - 192 / np.pi**5 * np.sum(np.tanh(n * np.pi / 2) / n**5))


# ----- coupling (physics.md §4) --------------------------------------------------------------


@dataclass(frozen=True)
class Ergun:
    """Ergun (1952) pressure gradient through a fixed bed of spheres (diameter d, porosity
    eps) at superficial velocity U:

        -dp/dx = 150 mu (1 - eps)^2 U / (eps^3 d^2) + 1.75 rho (1 - eps) U^2 / (eps^3 d).

    Its viscous term alone is the Blake-Kozeny (Kozeny-Carman) law with Ergun's constant 150
    (Carman's is 180).  In the normalisation of physics.md §4 (beta = eps^2 (-dp/dx) / U,
    F = beta d^2 / (18 mu (1 - eps) eps)) it is F = (150 (1 - eps) + 1.75 Re) / (18 eps^2),
    Re = rho U d / mu.
    """

    eps: float
    d: float
    mu: float
    rho: float

    def _coeffs(self) -> tuple[float, float]:
        """(a, b) of -dp/dx = a U + b U^2."""
        e, d = self.eps, self.d
        return 150.0 * self.mu * (1 - e) ** 2 / (e**3 * d * d), 1.75 * self.rho * (1 - e) / (e**3 * d)

    def pressure_gradient(self, U):
        a, b = self._coeffs()
        U = np.asarray(U, dtype=float)
        return a * U + b * U * U

    def viscous_gradient(self, U):
        """Blake-Kozeny: 150 mu (1 - eps)^2 U / (eps^3 d^2), the Re -> 0 limit."""
        return self._coeffs()[0] * np.asarray(U, dtype=float)

    def normalised_drag(self, re):
        """F(eps, Re) = (150 (1 - eps) + 1.75 Re) / (18 eps^2)."""
        return (150.0 * (1 - self.eps) + 1.75 * np.asarray(re, dtype=float)) / (18.0 * self.eps**2)

    def superficial_velocity(self, G: float) -> float:
        """U at which the bed carries the pressure gradient G (positive root of the quadratic)."""
        a, b = self._coeffs()
        return _positive_root(b, a, G)

    def minimum_fluidisation_velocity(self, rho_p: float, g: float = 9.81) -> float:
        """U_mf: the pressure gradient carries the buoyant bed weight (1 - eps)(rho_p - rho) g
        (Wen & Yu 1966: 1.75 Re^2/eps^3 + 150 (1 - eps) Re/eps^3 = Ar)."""
        return self.superficial_velocity((1 - self.eps) * (rho_p - self.rho) * g)


@dataclass(frozen=True)
class FixedBed:
    """Gas through a fixed, uniform bed with a drag closure F(eps, Re) in the normalisation of
    physics.md §4: the gas momentum balance eps (-dp/dx) = beta u with interstitial velocity
    u = U/eps gives

        -dp/dx = beta U / eps^2,   beta = 18 mu (1 - eps) eps F(eps, Re) / d^2,   Re = rho U d / mu.

    ``F`` is any callable F(eps, Re) (a closure under test, or :meth:`Ergun.normalised_drag`).
    """

    eps: float
    d: float
    mu: float
    rho: float
    F: Callable

    def beta(self, U: float) -> float:
        re = self.rho * U * self.d / self.mu
        return 18.0 * self.mu * (1 - self.eps) * self.eps * float(self.F(self.eps, re)) / self.d**2

    def pressure_gradient(self, U: float) -> float:
        return self.beta(U) * U / self.eps**2

    def superficial_velocity(self, G: float, U_max: float = 10.0) -> float:
        """U solving pressure_gradient(U) = G (brentq on (1e-9, U_max))."""
        return brentq(lambda U: self.pressure_gradient(U) - G, 1e-9, U_max, xtol=1e-14)


@dataclass(frozen=True)
class StokesRelaxation:
    """A particle relaxing towards a uniform gas velocity U with a linear drag,
    m dv/dt = (m / tau)(U - v), v(0) = 0:  v(t) = U (1 - exp(-t/tau)).  For Stokes drag on
    an isolated sphere tau = rho_p d^2 / (18 mu) (:meth:`stokes_time`)."""

    tau: float
    U: float = 1.0

    @staticmethod
    def stokes_time(rho_p: float, d: float, mu: float) -> float:
        return rho_p * d * d / (18.0 * mu)

    def velocity(self, t):
        return self.U * -np.expm1(-np.asarray(t, dtype=float) / self.tau)

    def interval_slip_ratio(self, dt: float) -> float:
        """Terminal slip with the interval-averaged implicit drag over the true one.  Holding
        the gas fixed over an interval dt, the exact relaxation transfers the impulse
        m (U - v0)(1 - e^-x), x = dt/tau, i.e. the coefficient K_eff = K (1 - e^-x)/x; a
        balance K_eff w' = K w against the same weight gives w'/w = x / (1 - e^-x)
        (docs/coupling.md)."""
        x = dt / self.tau
        return x / -math.expm1(-x)


@dataclass(frozen=True)
class PublishedDrag:
    """Drag closures written independently in the dimensional form of each paper (a
    momentum-exchange coefficient beta or a force on one particle, from the slip velocity,
    rho, mu and d), then mapped to F = F_d / (3 pi mu d eps |u - v|) at
    Re = eps rho |u - v| d / mu (physics.md §4).  Methods take (eps, Re) scalars."""

    mu: float
    rho: float
    d: float

    def slip_from_re(self, eps, re):
        """|u - v| such that Re = eps rho |u - v| d / mu."""
        return re * self.mu / (eps * self.rho * self.d)

    def f_from_beta(self, beta, eps):
        return beta * self.d * self.d / (18.0 * self.mu * (1.0 - eps) * eps)

    def f_from_force(self, force, eps, slip):
        return force / (3.0 * math.pi * self.mu * self.d * eps * slip)

    def beetstra(self, eps, re):
        """physics.md A/B form: beta = (mu/d^2)[A phi^2/eps + B phi Re/eps], B prefactor 18*0.413/24."""
        phi = 1.0 - eps
        a = 180.0 + 18.0 * eps**4 / phi * (1.0 + 1.5 * math.sqrt(phi))
        b = (18.0 * 0.413 / 24.0) * (1.0 / eps + 3.0 * eps * phi + 8.4 * re**-0.343) / (
            1.0 + 10.0 ** (3.0 * phi) * re ** (-(1.0 + 4.0 * phi) / 2.0)
        )
        beta = self.mu / self.d**2 * (a * phi**2 / eps + b * phi * re / eps)
        return self.f_from_beta(beta, eps)

    def wen_yu_beta(self, eps, slip):
        """Wen & Yu (1966) with the Schiller-Naumann drag coefficient, Gidaspow's form."""
        rep = eps * self.rho * slip * self.d / self.mu
        cd = 24.0 / rep * (1.0 + 0.15 * rep**0.687) if rep < 1000.0 else 0.44
        return 0.75 * cd * eps * (1.0 - eps) * self.rho * slip / self.d * eps**-2.65

    def wen_yu(self, eps, re):
        return self.f_from_beta(self.wen_yu_beta(eps, self.slip_from_re(eps, re)), eps)

    def ergun_gidaspow(self, eps, re):
        """Gidaspow (1994): Wen-Yu for eps >= 0.8, else the Ergun pressure drop with
        beta |u - v| = eps dp/L (U = eps |u - v|)."""
        slip = self.slip_from_re(eps, re)
        if eps >= 0.8:
            return self.f_from_beta(self.wen_yu_beta(eps, slip), eps)
        dpdl = float(Ergun(eps, self.d, self.mu, self.rho).pressure_gradient(eps * slip))
        return self.f_from_beta(eps * dpdl / slip, eps)

    def di_felice(self, eps, re):
        """Di Felice (1994): F_d = 0.5 C_D0 rho (pi d^2/4) U^2 eps^-chi with U = eps |u - v|."""
        slip = self.slip_from_re(eps, re)
        u_sup = eps * slip
        rep = self.rho * u_sup * self.d / self.mu
        cd0 = (0.63 + 4.8 / math.sqrt(rep)) ** 2
        chi = 3.7 - 0.65 * math.exp(-((1.5 - math.log10(rep)) ** 2) / 2.0)
        force = 0.5 * cd0 * self.rho * math.pi * self.d**2 / 4.0 * u_sup**2 * eps ** (-chi)
        return self.f_from_force(force, eps, slip)

    def koch_hill(self, eps, re):
        """Transcription of MFIX DRAG_KOCH_HILL (Benyahia et al. 2006): lDgA = F * 18 mu eps^2/d^2,
        beta = lDgA * phis, RE = 0.5 d |u - v| (eps rho) / mu."""
        D = self.d
        phis = 1.0 - eps
        slip = self.slip_from_re(eps, re)
        RE = 0.5 * D * slip * (eps * self.rho) / self.mu
        f_stokes = 18.0 * self.mu * eps * eps / D**2
        w = math.exp(-10.0 * (0.4 - phis) / phis)
        F_0 = F_1 = None
        if 0.01 < phis < 0.4:
            F_0 = (1 - w) * (1 + 3 * math.sqrt(phis / 2) + 135 / 64 * phis * math.log(phis) + 17.14 * phis) / (
                1 + 0.681 * phis - 8.48 * phis**2 + 8.16 * phis**3
            ) + w * 10 * phis / (1 - phis) ** 3
        elif phis >= 0.4:
            F_0 = 10 * phis / (1 - phis) ** 3
        if 0.01 < phis <= 0.1:
            F_1 = math.sqrt(2 / phis) / 40
        elif phis > 0.1:
            F_1 = 0.11 + 5.1e-4 * math.exp(11.6 * phis)
        if phis < 0.4:
            F_2 = (1 - w) * (1 + 3 * math.sqrt(phis / 2) + 135 / 64 * phis * math.log(phis) + 17.89 * phis) / (
                1 + 0.681 * phis - 11.03 * phis**2 + 15.41 * phis**3
            ) + w * 10 * phis / (1 - phis) ** 3
        else:
            F_2 = 10 * phis / (1 - phis) ** 3
        F_3 = 0.9351 * phis + 0.03667 if phis < 0.0953 else 0.0673 + 0.212 * phis + 0.0232 / (1 - phis) ** 5
        if phis <= 0.01:
            re_t1 = (F_2 - 1) / (3 / 8 - F_3)
            F = 1 + 3 / 8 * RE if RE <= re_t1 else F_2 + F_3 * RE
        else:
            re_t2 = (F_3 + math.sqrt(F_3 * F_3 - 4 * F_1 * (F_0 - F_2))) / (2 * F_1)
            F = F_0 + F_1 * RE * RE if RE <= re_t2 else F_2 + F_3 * RE
        beta = F * f_stokes * phis
        return self.f_from_beta(beta, eps)

    CLOSURES = ("beetstra", "di_felice", "ergun_gidaspow", "koch_hill", "wen_yu")

    def closure(self, name: str) -> Callable:
        """The reference for closure ``name`` as a function (eps, Re) -> F."""
        if name not in self.CLOSURES:
            raise KeyError(name)
        return getattr(self, name)
