"""Rotating-drum measurements (cfddem.measure.drum): the surface fit recovers the angle of a
synthetic bed, ignores beads thrown above it and sees an S-shaped surface; Froude number,
Mellmann's regimes, block averages and the run's regime."""

import math

import numpy as np
import pytest

from cfddem.measure.drum import (block_average, classify_run, fit_surface, froude, mellmann_regimes,
                                 surface_profile)

R, D = 0.04, 0.003


def _bed(surface, n=6000, seed=1, length=0.024):
    """Random bead centres filling the part of the drum's cross-section below y = surface(x),
    at least a radius inside the wall, over a slab of ``length`` along z."""
    rng = np.random.default_rng(seed)
    p = rng.uniform(-R, R, (20 * n, 3))
    p[:, 2] *= 0.5 * length / R
    keep = (np.hypot(p[:, 0], p[:, 1]) < R - 0.5 * D) & (p[:, 1] < surface(p[:, 0]))
    return p[keep][:n]


@pytest.mark.parametrize("angle", [20.0, 35.0, -28.0])
def test_fit_recovers_the_angle_of_a_flat_bed(angle):
    t = math.tan(math.radians(angle))
    pos = _bed(lambda x: 0.002 + t * x)
    x, y, det = surface_profile(pos, R, D, D, wall_clearance=2 * D)
    fit = fit_surface(x, y, R, 0.6, sign=1.0 if angle > 0 else -1.0)
    print(f"{angle} deg: fitted {fit['angle_deg']:.3f} deg from {fit['n_fit']} of {len(x)} columns, "
          f"cubic {fit['cubic']:.3g}, rms {fit['rms_dev']:.3g} R")
    assert fit["angle_deg"] == pytest.approx(abs(angle), abs=1.0)
    assert abs(fit["cubic"]) < 0.05 and fit["rms_dev"] < 0.02
    assert det == 0 and fit["n_fit"] >= 10


def test_beads_thrown_above_the_bed_are_not_the_surface():
    t = math.tan(math.radians(30.0))
    pos = _bed(lambda x: t * x)
    x0, y0, _ = surface_profile(pos, R, D, D, 2 * D)
    fly = np.array([[0.0, 0.012, 0.0], [-0.01, 0.004, 0.005], [0.012, 0.03, -0.005]])  # 5-9 mm above the surface
    x, y, det = surface_profile(np.vstack([pos, fly]), R, D, D, 2 * D)
    assert det == 3
    assert np.array_equal(x, x0) and np.array_equal(y, y0)


def test_s_shaped_surface_has_a_cubic_term():
    """y = tan(30) x - 0.25 R (x / R)^3 (steeper in the middle, flatter at both ends, as a
    cascading bed): the cubic coefficient along the line is well beyond the flat bed's."""
    t = math.tan(math.radians(30.0))
    pos = _bed(lambda x: t * x - 0.25 * R * (x / R) ** 3)
    x, y, _ = surface_profile(pos, R, D, D, 2 * D)
    fit = fit_surface(x, y, R, 0.6)
    print(f"cubic {fit['cubic']:.3g}, max deviation {fit['max_dev']:.3g} R, angle {fit['angle_deg']:.2f}")
    assert fit["cubic"] < -0.15
    assert classify_run(0.5, fit["cubic"], 0.0) == "cascading"


def test_too_few_points_give_nan():
    fit = fit_surface([0.0, 0.01], [0.0, 0.01], R)
    assert math.isnan(fit["angle_deg"]) and fit["n_fit"] == 0
    x, y, det = surface_profile(np.zeros((0, 3)), R, D, D)
    assert len(x) == 0 and det == 0


def test_froude_and_mellmann_ranges():
    assert froude(30.0, 0.04) == pytest.approx(math.pi ** 2 * 0.04 / 9.81, rel=1e-12)
    assert froude(-30.0, 0.04) == froude(30.0, 0.04)
    assert mellmann_regimes(1e-6) == []
    assert mellmann_regimes(5e-5) == ["slumping"]
    assert mellmann_regimes(5e-4) == ["slumping", "rolling"]
    assert mellmann_regimes(5e-3) == ["rolling", "cascading"]
    assert mellmann_regimes(0.04) == ["cascading"]
    assert mellmann_regimes(0.5) == ["cataracting"]
    assert mellmann_regimes(1.0) == ["centrifuging"]


def test_block_average():
    v = np.repeat([1.0, 2.0, 3.0, 4.0, 5.0], 10)
    m, e = block_average(v, 5)
    assert m == 3.0 and e == pytest.approx(math.sqrt(2.5) / math.sqrt(5), rel=1e-12)
    m, e = block_average([1.0, math.nan, 3.0], 5)
    assert m == 2.0 and math.isnan(e)
    assert all(math.isnan(x) for x in block_average([], 5))


def test_classify_run():
    assert classify_run(3.0, 0.0, 0.0) == "slumping"
    assert classify_run(0.5, 0.0, 0.05) == "cataracting"
    assert classify_run(0.5, 0.2, 0.0) == "cascading"
    assert classify_run(0.5, -0.02, 0.0) == "rolling"
    assert classify_run(math.nan, 0.0, 0.0) == "unknown"
