"""The shared analytic references (tests/analytic.py) checked against independent facts:
limits, the governing equations by finite differences, quadratures, and alternative
derivations.  None of this uses cfddem."""

import math

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.integrate import quad
from scipy.sparse.linalg import spsolve

from tests.analytic import (Ergun, FixedBed, HertzNormal, InclineSphere, LinearCollision, PublishedDrag,
                            RotatingFrame, SpherePair, SquareDuct, StokesRelaxation, TaylorGreen)


def _ddt(f, t, h):
    """Central difference of f at t (f may return arrays)."""
    return (np.asarray(f(t + h)) - np.asarray(f(t - h))) / (2 * h)


# ----- linear collision -----------------------------------------------------------------------


def test_collision_time_reduces_to_half_period_when_elastic():
    c = LinearCollision(k_n=1000.0, e_n=1.0, m_eff=3.6e-5)
    assert c.eta_n == 0.0
    assert c.t_c == pytest.approx(math.pi * math.sqrt(3.6e-5 / 1000.0), rel=1e-15)
    assert c.rebound_velocity(0.3) == pytest.approx(-0.3, rel=1e-12)


@pytest.mark.parametrize("e_n", [0.1, 0.5, 0.9])
def test_collision_oscillator_solves_the_ode_and_returns_e_n(e_n):
    k, m, v = 1000.0, 3.6e-5, 0.25
    c = LinearCollision(k_n=k, e_n=e_n, m_eff=m)
    tc = c.t_c
    ts = np.linspace(0.05, 0.95, 7) * tc
    h = 1e-5 * tc
    d = c.overlap(ts, v)
    d1 = _ddt(lambda t: c.overlap(t, v), ts, h)
    d2 = (c.overlap(ts + h, v) - 2 * d + c.overlap(ts - h, v)) / h**2
    scale = k * v * tc  # force scale
    assert np.max(np.abs(m * d2 + c.eta_n * d1 + k * d)) < 1e-5 * scale
    assert np.allclose(d1, c.overlap_rate(ts, v), rtol=1e-7, atol=0)
    # starts at zero with the approach speed, positive during contact, zero again at t_c, and
    # the contact opens there at the speed e_n v
    assert c.overlap(0.0, v) == 0.0 and c.overlap_rate(0.0, v) == pytest.approx(v, rel=1e-15)
    assert np.all(c.overlap(np.linspace(1e-3, 1 - 1e-3, 99) * tc, v) > 0)
    assert abs(c.overlap(tc, v)) < 1e-13 * v * tc
    assert c.overlap(1.001 * tc, v) < 0
    assert c.rebound_velocity(v) == pytest.approx(-e_n * v, rel=1e-12)


@pytest.mark.parametrize("e_n,e_t", [(0.3, 0.8), (0.9, 0.2), (0.6, 0.6)])
def test_tangential_oscillation_has_the_normal_period(e_n, e_t):
    """physics.md §1.1 derives k_t = (2/7) k_n (pi^2 + ln^2 e_t)/(pi^2 + ln^2 e_n) and
    m_t = (2/7) m* so that a sticking contact oscillates tangentially with the normal t_c:
    the same collision-time formula with (k_t, e_t, m_t) must give the same t_c."""
    k, m = 1000.0, 3.6e-5
    k_t = 2.0 / 7.0 * k * (math.pi**2 + math.log(e_t) ** 2) / (math.pi**2 + math.log(e_n) ** 2)
    normal = LinearCollision(k_n=k, e_n=e_n, m_eff=m, e_t=e_t)
    tangential = LinearCollision(k_n=k_t, e_n=e_t, m_eff=2.0 / 7.0 * m)
    assert tangential.t_c == pytest.approx(normal.t_c, rel=1e-14)
    # and that oscillation returns the tangential velocity with factor e_t
    assert tangential.rebound_velocity(0.1) == pytest.approx(normal.tangential_rebound(0.1), rel=1e-12)


def test_static_overlaps_carry_the_load():
    F = 2.7e-3
    lin = LinearCollision(k_n=1000.0, e_n=0.5, m_eff=1.0)
    assert lin.k_n * lin.static_overlap(F) == pytest.approx(F, rel=1e-15)
    hz = HertzNormal(E_star=5.5e6, r_eff=1.5e-3)
    d0 = hz.static_overlap(F)
    assert hz.force(d0) == pytest.approx(F, rel=1e-14)
    assert hz.force(2 * d0) / hz.force(d0) == pytest.approx(2**1.5, rel=1e-14)


# ----- incline ------------------------------------------------------------------------------


MU, MU_R, G = 0.3, 0.05, 9.81


def _at(tan_theta):
    return InclineSphere(math.atan(tan_theta), MU, MU_R, G)


def test_incline_regimes_switch_at_the_documented_thresholds():
    """physics.md §1.3: rest for tan(theta) < mu_r, rolling up to (7 mu - 5 mu_r)/2, then
    rolling and sliding."""
    slide = (7 * MU - 5 * MU_R) / 2
    assert _at(MU_R).rest_threshold == MU_R and _at(MU_R).slide_threshold == pytest.approx(slide, rel=1e-15)
    assert _at(MU_R * (1 - 1e-9)).regime() == "rest"
    assert _at(MU_R * (1 + 1e-9)).regime() == "roll"
    assert _at(slide * (1 - 1e-9)).regime() == "roll"
    assert _at(slide * (1 + 1e-9)).regime() == "slide"
    # the acceleration is continuous at both switches
    assert _at(MU_R * (1 + 1e-9)).acceleration() == pytest.approx(0.0, abs=1e-9)
    assert _at(slide * (1 - 1e-9)).acceleration() == pytest.approx(_at(slide * (1 + 1e-9)).acceleration(), rel=1e-8)
    # the friction needed for rolling reaches mu exactly at the sliding threshold
    assert _at(slide).friction_ratio() == pytest.approx(MU, rel=1e-14)
    with pytest.raises(ValueError):
        InclineSphere(0.1, mu=0.1, mu_r=0.2)


@pytest.mark.parametrize("tan_theta", [0.0, 0.03, 0.3, 0.8, 1.0, 1.5, 5.0])
def test_incline_obeys_newton_for_the_sphere(tan_theta):
    """Along the slope m a = m g sin - f; about the centre (2/5) m R^2 dw/dt = f R - mu_r R N
    (no rolling torque at rest); f <= mu N; the contact point does not slip unless f = mu N."""
    inc = _at(tan_theta)
    th = inc.theta
    c = math.cos(th)
    f = inc.friction_ratio() * G * c  # friction force per unit mass
    a, rim = inc.acceleration(), inc.rim_acceleration()
    assert a == pytest.approx(G * math.sin(th) - f, abs=1e-12)
    torque = 0.0 if inc.regime() == "rest" else f - MU_R * G * c
    assert 0.4 * rim == pytest.approx(torque, abs=1e-12)
    assert inc.friction_ratio() <= MU * (1 + 1e-12)
    if inc.regime() == "slide":
        assert a - rim > 0  # slipping
    else:
        assert a - rim == 0.0
    g = np.array(inc.gravity())
    assert np.linalg.norm(g) == pytest.approx(G, rel=1e-15) and math.atan2(g[0], -g[1]) == pytest.approx(th)
    assert inc.normal_load(2.0) == pytest.approx(-2.0 * g[1], rel=1e-15)


# ----- rotating frame -----------------------------------------------------------------------


OM = np.array([0.3, 1.7, -0.4])
AXIS = np.array([0.05, -0.3, 0.1])
R0, V0 = np.array([0.3, 0.1, -0.2]), np.array([0.2, 0.05, -0.1])


@pytest.mark.parametrize("t", [0.0, 0.37, 2.1])
def test_free_particle_solves_the_rotating_frame_equation_of_motion(t):
    """physics.md §3: dv/dt = -2 Omega x v - Omega x (Omega x (r - a)) for a force-free particle."""
    fr = RotatingFrame(tuple(OM), tuple(AXIS))
    h = 1e-4
    r = fr.free_position(R0, V0, t)
    v = fr.free_velocity(R0, V0, t)
    assert np.allclose(_ddt(lambda s: fr.free_position(R0, V0, s), t, h), v, rtol=0, atol=1e-8)
    acc = _ddt(lambda s: fr.free_velocity(R0, V0, s), t, h)
    expected = -2 * np.cross(OM, v) - np.cross(OM, np.cross(OM, r - AXIS))
    assert np.allclose(acc, expected, rtol=0, atol=1e-7)
    if t == 0.0:
        assert np.allclose(r, R0, atol=1e-15) and np.allclose(v, V0, atol=1e-15)


def test_free_particle_after_one_revolution_is_on_its_inertial_line():
    fr = RotatingFrame(tuple(OM), tuple(AXIS))
    T = 2 * math.pi / np.linalg.norm(OM)
    v_in = V0 + np.cross(OM, R0 - AXIS)
    assert np.allclose(fr.free_position(R0, V0, T), R0 + v_in * T, rtol=0, atol=1e-14)


def test_free_spin_and_lab_rest_state():
    fr = RotatingFrame(tuple(OM), tuple(AXIS))
    w0 = np.array([50.0, -20.0, 10.0])
    # T = -I Omega x w (physics.md §3): dw/dt = -Omega x w
    for t in (0.0, 0.8):
        w = fr.free_spin(w0, t)
        assert np.allclose(_ddt(lambda s: fr.free_spin(w0, s), t, 1e-5), -np.cross(OM, w), rtol=0, atol=1e-6)
    # a point at rest in the lab: the free particle starting with the lab-rest velocity stays
    # on it, and the field u = -Omega x (r - a) is divergence-free with zero total acceleration
    # u.grad u + 2 Omega x u + Omega x (Omega x (r - a)) = 0
    u0 = np.array(fr.lab_rest_velocity(*R0))
    for t in (0.3, 1.1):
        r = fr.free_position(R0, u0, t)
        assert np.allclose(fr.free_velocity(R0, u0, t), np.array(fr.lab_rest_velocity(*r)), rtol=0, atol=1e-14)
    h = 1e-6
    grad = np.array([(np.array(fr.lab_rest_velocity(*(R0 + h * e))) - np.array(fr.lab_rest_velocity(*(R0 - h * e))))
                     / (2 * h) for e in np.eye(3)])  # grad[j, i] = d u_i / d x_j
    assert abs(np.trace(grad)) < 1e-9
    accel = u0 @ grad + 2 * np.cross(OM, u0) + np.cross(OM, np.cross(OM, R0 - AXIS))
    assert np.allclose(accel, 0.0, atol=1e-9)
    # Coriolis alone turns a uniform stream: du/dt = -2 Omega x u, speed kept
    u = fr.coriolis_turned([1.0, 0.2, -0.3], 0.7)
    du = _ddt(lambda s: fr.coriolis_turned([1.0, 0.2, -0.3], s), 0.7, 1e-5)
    assert np.allclose(du, -2 * np.cross(OM, u), rtol=0, atol=1e-8)
    assert np.linalg.norm(u) == pytest.approx(np.linalg.norm([1.0, 0.2, -0.3]), rel=1e-14)


# ----- sphere pairs -------------------------------------------------------------------------


@pytest.mark.parametrize("r1,r2,d", [(2.0, 2.0, 1.5), (2.0, 1.3, 2.5), (1.0, 0.4, 0.7), (1.0, 0.5, 1.45)])
def test_lens_volume_against_quadrature(r1, r2, d):
    """The intersection's cross-section at x along the line of centres has radius^2
    min(r1^2 - x^2, r2^2 - (x - d)^2) where positive."""

    def area(x):
        return math.pi * max(0.0, min(r1 * r1 - x * x, r2 * r2 - (x - d) ** 2))

    x_plane = (d * d + r1 * r1 - r2 * r2) / (2 * d)  # where the two spheres' surfaces meet
    ref = quad(area, -r1, r1, points=[x_plane], epsabs=0, epsrel=1e-13)[0]
    pair = SpherePair(r1, r2, d)
    assert pair.lens_volume == pytest.approx(ref, rel=1e-10)
    assert pair.volume == pytest.approx(4 / 3 * math.pi * (r1**3 + r2**3) - ref, rel=1e-12)


def test_lens_volume_limits_and_equal_radii():
    r = 2.0
    for d in (0.3, 1.0, 3.9):
        assert SpherePair(r, r, d).lens_volume == pytest.approx(math.pi * (4 * r + d) * (2 * r - d) ** 2 / 12,
                                                                rel=1e-14)
    assert SpherePair(1.0, 0.5, 1.5 * (1 - 1e-12)).lens_volume == pytest.approx(0.0, abs=1e-10)
    small = 4 / 3 * math.pi * 0.5**3
    assert SpherePair(1.0, 0.5, 0.5 * (1 + 1e-12)).lens_volume == pytest.approx(small, rel=1e-9)
    assert SpherePair(1.0, 0.5, 0.2).lens_volume == small and SpherePair(1.0, 0.5, 2.0).lens_volume == 0.0


def test_separated_inertia_by_the_parallel_axis_theorem():
    r1, r2, d, rho = 0.001, 0.0007, 0.004, 2000.0
    m = [rho * 4 / 3 * math.pi * r**3 for r in (r1, r2)]
    x = np.array([0.0, d])
    com = np.dot(m, x) / sum(m)
    own = sum(0.4 * mi * ri**2 for mi, ri in zip(m, (r1, r2)))
    I_perp = own + sum(mi * (xi - com) ** 2 for mi, xi in zip(m, x))
    assert np.allclose(SpherePair(r1, r2, d).separated_inertia(rho), [own, I_perp, I_perp], rtol=1e-13, atol=0)
    with pytest.raises(ValueError):
        SpherePair(r1, r2, 0.3 * d).separated_inertia(rho)


# ----- Taylor-Green ---------------------------------------------------------------------------


@pytest.mark.parametrize("k", [1.0, 3.0])
def test_taylor_green_solves_navier_stokes(k):
    """Divergence-free, decays at exp(-2 nu k^2 t), and the momentum equation
    u_t + (u.grad) u = -grad p / rho + nu lap u holds, all by central differences."""
    nu, rho = 0.05, 1.3
    tg = TaylorGreen(nu, k=k, rho=rho)
    rng = np.random.default_rng(0)
    x, y = rng.uniform(0, 2 * np.pi / k, (2, 20))
    t, h, ht = 0.4, 1e-4, 1e-4
    U = lambda x, y, t: np.array(tg.velocity(x, y, t))  # noqa: E731
    ux = (U(x + h, y, t) - U(x - h, y, t)) / (2 * h)
    uy = (U(x, y + h, t) - U(x, y - h, t)) / (2 * h)
    lap = (U(x + h, y, t) + U(x - h, y, t) + U(x, y + h, t) + U(x, y - h, t) - 4 * U(x, y, t)) / h**2
    ut = (U(x, y, t + ht) - U(x, y, t - ht)) / (2 * ht)
    u = U(x, y, t)
    assert np.max(np.abs(ux[0] + uy[1])) < 1e-7 * k
    assert np.allclose(ut, -2 * nu * k * k * u, rtol=0, atol=1e-7)
    px = (tg.pressure(x + h, y, t) - tg.pressure(x - h, y, t)) / (2 * h)
    py = (tg.pressure(x, y + h, t) - tg.pressure(x, y - h, t)) / (2 * h)
    res = ut + u[0] * ux + u[1] * uy + np.array([px, py]) / rho - nu * lap
    assert np.max(np.abs(res)) < 1e-5 * k * k
    # periodic with the box side 2 pi / k
    assert np.allclose(U(x + 2 * np.pi / k, y, t), u, atol=1e-12)


# ----- square duct -----------------------------------------------------------------------------


def test_square_duct_against_whites_constant_and_a_fine_difference_solution():
    G, L, mu = 2.0, 0.1, 1e-3
    duct = SquareDuct(G, L, mu)
    assert duct.flow_rate() == pytest.approx(G * L**4 / (28.454 * mu), rel=1e-4)
    # no slip on the walls
    s = np.linspace(0, L, 9)
    for x, y in ((s, 0 * s), (s, L + 0 * s), (0 * s, s), (L + 0 * s, s)):
        assert np.max(np.abs(duct.velocity(x, y))) < 1e-12 * G * L**2 / mu
    # mu lap w = -G on n x n interior nodes, 5-point Laplacian (O(h^2), independent of the series)
    n = 159
    h = L / (n + 1)
    lap1 = sp.diags([1.0, -2.0, 1.0], [-1, 0, 1], shape=(n, n)) / h**2
    A = sp.kronsum(lap1, lap1, format="csc")
    w = spsolve(mu * A, np.full(n * n, -G)).reshape(n, n)
    xs = (np.arange(n) + 1) * h
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    ws = duct.velocity(X, Y)
    w_max = ws.max()
    assert np.max(np.abs(w - ws)) < 1e-4 * w_max
    assert ws[n // 2, n // 2] == pytest.approx(w_max)  # maximum on the axis
    # flow rate: the series' Q against the trapezoidal integral of its own velocity (zero on the walls)
    assert np.sum(ws) * h * h == pytest.approx(duct.flow_rate(), rel=1e-4)


# ----- fixed beds -------------------------------------------------------------------------------


def test_ergun_low_re_is_blake_kozeny_and_solves_its_quadratic():
    eps, d, mu, rho = 0.4, 1e-3, 1.8e-5, 1.2
    e = Ergun(eps, d, mu, rho)
    for U in (1e-7, 1e-5):
        bk = 150.0 * (1 - eps) ** 2 * mu * U / (eps**3 * d**2)  # Kozeny-Carman with Ergun's 150
        assert float(e.viscous_gradient(U)) == pytest.approx(bk, rel=1e-14)
        re = rho * U * d / mu
        # the inertial correction is 1.75 Re / (150 (1 - eps)): below 2e-6 here
        assert float(e.pressure_gradient(U)) / bk - 1 == pytest.approx(1.75 * re / (150 * (1 - eps)), rel=1e-6)
    for G in (1.0, 1e3, 1e6):
        U = e.superficial_velocity(G)
        assert U > 0 and float(e.pressure_gradient(U)) == pytest.approx(G, rel=1e-13)


def test_ergun_minimum_fluidisation_is_the_wen_yu_quadratic():
    """1.75 Re^2/eps^3 + 150 (1 - eps) Re/eps^3 = Ar, Ar = rho (rho_p - rho) g d^3 / mu^2."""
    eps, d, mu, rho, rho_p = 0.42, 0.5e-3, 1.8e-5, 1.2, 2550.0
    umf = Ergun(eps, d, mu, rho).minimum_fluidisation_velocity(rho_p, g=9.81)
    re = rho * umf * d / mu
    ar = rho * (rho_p - rho) * 9.81 * d**3 / mu**2
    assert 1.75 * re**2 / eps**3 + 150 * (1 - eps) * re / eps**3 == pytest.approx(ar, rel=1e-12)


def test_fixed_bed_balance_reproduces_ergun_through_the_normalised_drag():
    """The physics.md §4 normalisation beta = 18 mu phi eps F / d^2 with F from Ergun's
    pressure drop gives back Ergun's pressure gradient and flow."""
    eps, d, mu, rho = 0.6, 0.8e-3, 1.8e-5, 1.2
    e = Ergun(eps, d, mu, rho)
    bed = FixedBed(eps, d, mu, rho, lambda eps_, re: e.normalised_drag(re))
    for U in (1e-4, 0.05, 0.7):
        assert bed.pressure_gradient(U) == pytest.approx(float(e.pressure_gradient(U)), rel=1e-13)
    assert bed.superficial_velocity(120.0) == pytest.approx(e.superficial_velocity(120.0), rel=1e-10)
    # a constant F is Darcy's law: U = G d^2 eps / (18 mu phi F)
    darcy = FixedBed(eps, d, mu, rho, lambda eps_, re: 7.0)
    assert darcy.superficial_velocity(50.0) == pytest.approx(50.0 * d * d * eps / (18 * mu * (1 - eps) * 7.0),
                                                             rel=1e-10)


# ----- single particle ------------------------------------------------------------------------


def test_stokes_relaxation():
    rho_p, d, mu = 2500.0, 50e-6, 1.8e-5
    tau = StokesRelaxation.stokes_time(rho_p, d, mu)
    # m / (3 pi mu d): Stokes drag 3 pi mu d (u - v) on the sphere's mass
    assert tau == pytest.approx(rho_p * math.pi * d**3 / 6 / (3 * math.pi * mu * d), rel=1e-14)
    r = StokesRelaxation(tau, U=0.02)
    for t in (0.0, 0.3 * tau, 2 * tau):
        dv = _ddt(r.velocity, t, 1e-6 * tau)
        assert dv == pytest.approx((r.U - r.velocity(t)) / tau, rel=1e-8)
    assert r.velocity(0.0) == 0.0 and r.velocity(50 * tau) == pytest.approx(r.U, rel=1e-15)


@pytest.mark.parametrize("x", [1e-3, 0.022, 0.5, 3.0])
def test_interval_slip_ratio_from_the_exact_impulse(x):
    """K_eff dt (U - v0) equals the exact impulse m (v(dt) - v0) of a relaxation with the gas
    held fixed; the terminal slip is then K / K_eff times the true one."""
    tau, U, m = 0.01, 0.3, 2.0
    dt = x * tau
    r = StokesRelaxation(tau, U)
    K = m / tau
    K_eff = m * float(r.velocity(dt)) / (dt * U)  # from v0 = 0
    assert r.interval_slip_ratio(dt) == pytest.approx(K / K_eff, rel=1e-12)
    if x < 0.1:
        assert r.interval_slip_ratio(dt) == pytest.approx(1 + x / 2, abs=x * x)


# ----- published drag references -----------------------------------------------------------------


def test_published_drag_limits():
    pub = PublishedDrag(mu=1.8e-5, rho=1.2, d=3e-3)
    for eps in (0.5, 0.9, 0.99):
        for re in (0.1, 10.0, 500.0):
            # Wen-Yu: F = (1 + 0.15 Re^0.687) eps^-3.65
            assert pub.wen_yu(eps, re) == pytest.approx((1 + 0.15 * re**0.687) * eps**-3.65, rel=1e-12)
    for eps in (0.4, 0.6, 0.79):
        for re in (0.1, 10.0, 500.0):
            # Gidaspow's dense branch is Ergun, F = (150 phi + 1.75 Re) / (18 eps^2)
            assert pub.ergun_gidaspow(eps, re) == pytest.approx((150 * (1 - eps) + 1.75 * re) / (18 * eps**2),
                                                                rel=1e-12)
    # Stokes-flow limits: Beetstra -> 10 phi/eps^2 + eps^2 (1 + 1.5 sqrt(phi)) (van der Hoef et
    # al. 2005), Koch-Hill dense -> Carman-Kozeny 10 phi/eps^2, Di Felice isolated -> 23.04/24
    eps = 0.55
    phi = 1 - eps
    assert pub.beetstra(eps, 1e-10) == pytest.approx(10 * phi / eps**2 + eps**2 * (1 + 1.5 * math.sqrt(phi)),
                                                     rel=1e-6)
    assert pub.koch_hill(eps, 1e-10) == pytest.approx(10 * phi / eps**2, rel=1e-10)
    assert pub.di_felice(1.0, 1e-12) == pytest.approx(0.96, rel=1e-6)
    assert sorted(PublishedDrag.CLOSURES) == list(PublishedDrag.CLOSURES)
    with pytest.raises(KeyError):
        pub.closure("stokes")
