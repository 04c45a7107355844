"""Mass properties of unions of spheres against closed forms."""

import math

import numpy as np

from cfddem.particles.clumps import ClumpShape, union_mass_properties
from tests.analytic import SpherePair


def test_two_overlapping_equal_spheres_volume_and_centre():
    R, d, rho = 0.002, 0.0015, 1000.0
    v_exact = SpherePair(R, R, d).volume
    M, com, I, mm = union_mass_properties([[0, 0, 0], [d, 0, 0]], R, rho)
    assert abs(M / (rho * v_exact) - 1.0) < 5e-4
    assert np.allclose(com, [0.5 * d, 0, 0], atol=1e-4 * R)
    assert abs(mm.sum() - M) < 1e-15 * M
    # the axial moment of the union is below that of two full spheres (overlap counted once)
    two = 2 * (0.4 * rho * 4 / 3 * math.pi * R**3 * R**2)
    assert I[0, 0] < two
    # grid convergence of the inertia: 24 vs 48 cells per radius
    _, _, I2, _ = union_mass_properties([[0, 0, 0], [d, 0, 0]], R, rho, cells_per_radius=48)
    assert np.max(np.abs(I - I2)) / I2[0, 0] < 2e-3


def test_unequal_overlap_volume():
    R1, R2, d, rho = 0.002, 0.0013, 0.0025, 1.0
    v_exact = SpherePair(R1, R2, d).volume
    M, com, I, mm = union_mass_properties([[0, 0, 0], [0, d, 0]], [R1, R2], rho)
    assert abs(M / v_exact - 1.0) < 5e-4


def test_separate_spheres_exact():
    R, rho, a = 0.001, 2000.0, 0.003
    M, com, I, _ = union_mass_properties([[-a, 0, 0], [a, 0, 0]], R, rho)
    m = rho * 4 / 3 * math.pi * R**3
    assert abs(M - 2 * m) < 1e-15
    assert np.allclose(np.diag(I), SpherePair(R, R, 2 * a).separated_inertia(rho), rtol=1e-12, atol=0)


def test_shape_principal_frame_and_user_override():
    c = np.array([[0, 0, 0], [0.002, 0.001, 0], [0.0, 0.0, 0.0025]])
    sh = ClumpShape.from_spheres(c, 0.0015, 1000.0)
    # offsets have zero mass-weighted mean only for the true union; principal moments sorted
    assert np.all(np.diff(sh.inertia) >= 0)
    assert abs(np.linalg.det(sh.frame) - 1.0) < 1e-12
    # offsets map back to the given centres
    assert np.allclose(sh.offsets @ sh.frame.T + sh.com_given, c, atol=1e-15)
    user = ClumpShape.from_spheres(c, 0.0015, 1000.0, mass=1e-3, inertia=np.diag([1e-9, 2e-9, 3e-9]))
    assert user.mass == 1e-3 and np.allclose(user.inertia, [1e-9, 2e-9, 3e-9], rtol=1e-12, atol=0)
    assert abs(user.member_mass.sum() - 1e-3) < 1e-15
