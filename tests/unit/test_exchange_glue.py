"""The compiled glue of the coupling step against the numpy expressions it replaced: K_eff
(implicit and explicit) and the Beetstra closure (powers by numpy, arithmetic compiled,
10^(3 phi) as exp(3 ln10 phi))."""

import numpy as np
import pytest

from cfddem.coupling import drag
from cfddem.coupling import exchange as X


def test_keff_kernel_equals_numpy_expressions():
    rng = np.random.default_rng(5)
    n = 5000
    F = rng.uniform(1.0, 80.0, n)
    eps_a = rng.uniform(0.3, 1.0, n)
    d = rng.uniform(1e-4, 4e-3, n)
    mass = 2500.0 * np.pi * d**3 / 6.0
    mu, dtg = 1.8e-5, 3.2e-4
    K = 3.0 * np.pi * mu * d * eps_a * F  # the expression of CoupledGas.couple before round 3
    out = np.empty(n)
    X._keff_kernel(F, eps_a, d, mass, 3.0 * np.pi * mu, dtg, 0, out)
    assert np.array_equal(out, K)
    X._keff_kernel(F, eps_a, d, mass, 3.0 * np.pi * mu, dtg, 1, out)
    ref = -mass * np.expm1(-dtg * K / mass) / dtg
    np.testing.assert_allclose(out, ref, rtol=4e-16, atol=0)
    # the implicit coefficient is below K and tends to it for dt_g K/m -> 0
    x = dtg * K / mass
    assert np.all(out <= K) and np.all(np.abs(out / K + np.expm1(-x) / x) < 1e-14)
    assert np.all(np.abs(out / K - (1.0 - x / 2.0)) < x * x)  # (1 - e^-x)/x = 1 - x/2 + x^2/6 - ...


def test_beetstra_compiled_arithmetic_equals_numpy_formula():
    eps = np.repeat(np.linspace(0.3, 1.0, 36), 41)
    re = np.tile(np.concatenate([[0.0], np.logspace(-4, 4, 40)]), 36)
    phi = 1.0 - eps
    e2 = eps * eps
    with np.errstate(divide="ignore", invalid="ignore"):
        rs = re ** (0.5 + 2.0 * phi)
        num = re / eps + 3.0 * eps * phi * re + 8.4 * re**0.657
        inert_exp = 0.413 / (24.0 * e2) * num * rs / (rs + np.exp(6.907755278982138 * phi))
        inert_pow = 0.413 / (24.0 * e2) * num * rs / (rs + 10.0 ** (3.0 * phi))
    base = 10.0 * phi / e2 + e2 * (1.0 + 1.5 * np.sqrt(phi))
    got = drag.beetstra(eps, re)
    # the compiled form takes both powers of Re from one log and divides the fraction through
    # (_beetstra_value): the same F to round-off over eps 0.3-1 and Re 1e-4-1e4 (4.4e-16 measured)
    np.testing.assert_allclose(got, base + np.where(re > 0.0, inert_exp, 0.0), rtol=1e-15, atol=0)
    np.testing.assert_allclose(got, base + np.where(re > 0.0, inert_pow, 0.0), rtol=1e-15, atol=0)
    # the scalar twin is the same arithmetic, bit for bit; Re = 0 and tiny Re give the creeping-flow F
    assert all(drag.beetstra_scalar(a, b) == g for a, b, g in zip(eps, re, got))
    assert np.array_equal(drag.beetstra(eps, np.where(re > 0.0, 1e-300, 0.0)), base)
    # shapes and scalars as before
    assert drag.beetstra(np.full((2, 3), 0.5), 1.0).shape == (2, 3)
    assert isinstance(drag.beetstra(0.5, 2.0), float)
    assert drag.beetstra(1.0, 0.0) == pytest.approx(1.0, abs=1e-15)
