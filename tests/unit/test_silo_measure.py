"""Silo measurements on synthetic data: flow-rate fit, bulk density of a known lattice, Beverloo
fit, flow-channel boundary, free-surface height, velocity-field averaging."""

import math

import numpy as np
import pytest

from cfddem.measure.silo import (VelocityField, beverloo_rate, bulk_density, channel_boundary, fit_beverloo,
                                 fit_mass_flow, surface_height)

pytestmark = pytest.mark.nojit  # also run as plain Python (tests/unit/test_nojit_tier.py)


def test_mass_flow_fit_recovers_the_steady_rate_and_ignores_start_and_end():
    # start-up (quadratic) to t = 0.5 s, steady 0.25 kg/s to t = 3.5 s, then slowing to 0.8 kg
    t = np.arange(0.0, 5.0, 0.01)
    m = np.where(t < 0.5, 0.25 * t ** 2, 0.25 * (t - 0.25))
    m = np.where(t > 3.5, 0.8125 - 0.05 * np.exp(-(t - 3.5)) + 0.05 - 0.0625, m)
    m = np.minimum(np.maximum.accumulate(m), 0.8)
    rng = np.random.default_rng(1)
    noisy = m + rng.normal(0, 2e-4, len(t))
    fit = fit_mass_flow(t, noisy, 0.2, 0.8)
    assert fit["rate"] == pytest.approx(0.25, rel=0.01)
    assert fit["m_lo"] == pytest.approx(0.2 * noisy[-1])
    assert 0.5 < fit["t_lo"] < 1.0 and 2.5 < fit["t_hi"] < 3.0
    assert fit["residual_rms"] == pytest.approx(2e-4, rel=0.3)
    assert fit["n_points"] > 150


def test_mass_flow_fit_without_enough_points_is_nan():
    fit = fit_mass_flow([0.0, 1.0], [0.0, 0.1])
    assert math.isnan(fit["rate"]) and fit["n_points"] == 0
    fit = fit_mass_flow(np.arange(10.0), np.zeros(10))
    assert math.isnan(fit["rate"])


def test_bulk_density_of_a_simple_cubic_lattice():
    a, d, rho_p = 0.004, 0.0038, 950.0
    m = rho_p * math.pi / 6 * d ** 3
    g = (np.arange(40) + 0.5) * a
    X, Y, Z = np.meshgrid(g, g, g[:10], indexing="ij")
    pos = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    mass = np.full(len(pos), m)
    # box of 20 x 20 x 10 lattice cells, faces between lattice planes
    rho, n = bulk_density(pos, mass, [5 * a, 5 * a, 0.0], [25 * a, 25 * a, 10 * a])
    assert n == 20 * 20 * 10
    assert rho == pytest.approx(m / a ** 3, rel=1e-12)
    assert rho == pytest.approx(rho_p * math.pi / 6 * (d / a) ** 3, rel=1e-12)  # 0.45 solid fraction here
    rho2, _ = bulk_density(pos, mass, [0, 0, 0], [0, 1, 1])
    assert math.isnan(rho2)


def test_beverloo_fit_recovers_C_and_k():
    rho_b, L, d, g = 600.0, 0.04, 0.0038, 9.81
    b = np.array([0.012, 0.016, 0.02, 0.025, 0.03, 0.04])
    W = beverloo_rate(b, 0.58, 1.5, rho_b, L, d, g)
    rng = np.random.default_rng(3)
    f = fit_beverloo(b, W * (1 + rng.normal(0, 0.005, len(b))), rho_b, L, d, g)
    assert f["C"] == pytest.approx(0.58, rel=0.03)
    assert f["k"] == pytest.approx(1.5, abs=0.1)
    assert f["rms_rel_residual"] < 0.01
    exact = fit_beverloo(b, W, rho_b, L, d, g)
    assert exact["C"] == pytest.approx(0.58, rel=1e-6) and exact["k"] == pytest.approx(1.5, abs=1e-5)
    # the law itself: W = C rho_b sqrt(g) L (b - k d)^1.5
    assert beverloo_rate(0.03, 0.5, 1.0, 500.0, 0.04, 0.004, 9.0) == pytest.approx(0.5 * 500 * 3 * 0.04 * 0.026 ** 1.5)
    assert beverloo_rate(0.003, 0.5, 1.0, 500.0, 0.04, 0.004) == 0.0
    with pytest.raises(ValueError):
        fit_beverloo([0.02], [0.1], rho_b, L, d)


def test_channel_boundary_of_a_gaussian_profile():
    x = (np.arange(30) + 0.5) * 0.005  # 0..0.15
    xc, sigma = 0.075, 0.02
    rows = np.array([1.0, 0.5])
    vy = -rows[:, None] * np.exp(-0.5 * ((x - xc) / sigma) ** 2)[None, :]
    ch = channel_boundary(vy, x, xc, fraction=0.1)
    half = sigma * math.sqrt(2 * math.log(10.0))  # where the profile is 10 % of its peak
    np.testing.assert_allclose(ch["x_right"], xc + half, atol=0.0015)
    np.testing.assert_allclose(ch["x_left"], xc - half, atol=0.0015)
    np.testing.assert_allclose(ch["centre_speed"], rows, rtol=0.01)
    # a row at rest has no channel
    ch0 = channel_boundary(np.zeros((1, 30)), x, xc)
    assert np.isnan(ch0["x_left"][0]) and np.isnan(ch0["centre_speed"][0])


def test_surface_height_and_velocity_field():
    rng = np.random.default_rng(0)
    pos = np.column_stack([rng.uniform(0, 0.1, 2000), rng.uniform(0, 0.2, 2000), rng.uniform(0, 0.01, 2000)])
    h = surface_height(pos, 0.0, 0.1, 0.01)
    assert 0.195 < h <= 0.2
    f = VelocityField(0.0, 0.1, 0.0, 0.2, 0.01)
    assert (f.nx, f.ny) == (10, 20)
    vel = np.column_stack([np.full(2000, 0.1), -pos[:, 0], np.zeros(2000)])
    f.sample(pos, vel)
    f.sample(pos, vel)
    vx, vy = f.mean()
    assert f.count.sum() == 4000 and f.n_samples == 2
    np.testing.assert_allclose(vx[np.isfinite(vx)], 0.1)
    # cell means of -x lie within the cell
    assert np.all(np.abs(vy + f.x[None, :]) <= 0.005 + 1e-12)
    st = f.get_state()
    g = VelocityField(0.0, 0.1, 0.0, 0.2, 0.01)
    g.set_state(st)
    np.testing.assert_array_equal(g.mean()[1], vy)


def test_column_bulk_density_leaves_a_crater_out():
    """A cubic lattice (spacing 1 mm, mass 1e-6 kg each: 1000 kg/m3) 60 mm wide and 40 mm high with
    a V crater 30 mm deep over its middle: the columns give the lattice's density; the silo's
    box below the median surface would count the crater as empty."""
    from cfddem.measure.silo import column_bulk_density

    g = np.stack(np.meshgrid(np.arange(60) + 0.5, np.arange(40) + 0.5, np.arange(10) + 0.5, indexing="ij"),
                 -1).reshape(-1, 3) * 1e-3
    crater = g[:, 1] > 0.040 - 0.030 * np.clip(1 - np.abs(g[:, 0] - 0.030) / 0.015, 0, None)
    pos = g[~crater]
    rho, k = column_bulk_density(pos, np.full(len(pos), 1e-6), 0.0, 0.060, 0.004, 0.002, 0.010, 0.003)
    # each 4 mm column holds whole lattice rows from y0 up to 3 mm below its top centre: the
    # column volume counts (top - margin - y0); lattice rows at half-integer mm make it exact to
    # within one row per column
    assert rho == pytest.approx(1000.0, rel=0.05) and k > 10000  # 977.6 (985.5 without the crater)
