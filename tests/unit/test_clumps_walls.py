"""The annulus wall (kind 3, the shear cell's ring faces): face, inner and outer rim, one-sided."""

import math

import numpy as np
import pytest

from cfddem.errors import CaseError
from cfddem.particles import LinearContact
from cfddem.particles.walls import AnnulusWall, wall_contact_py

LAW = LinearContact(k_n=1000.0, e_n=0.5, e_t=0.5, mu=0.3)
G = AnnulusWall(contact=LAW, point=(0.0, 0.013, 0.0), normal=(0.0, 1.0, 0.0), r_in=0.0475, r_out=0.0505).geometry()


def c(x, y, z, r=0.002):
    return wall_contact_py(G, np.array([x, y, z], float), r)


def test_face():
    ov, nx, ny, nz, qx, qy, qz = c(0.0, 0.0145, 0.049)  # over the face, 1.5 mm above it
    assert ov == pytest.approx(0.0005, abs=1e-15) and (nx, ny, nz) == (0.0, 1.0, 0.0)
    assert (qx, qy, qz) == pytest.approx((0.0, 0.013, 0.049), abs=1e-15)
    assert c(0.0, 0.0115, 0.049)[0] == pytest.approx(0.0035, abs=1e-15)  # below the face plane, over the face


def test_inner_and_outer_rim():
    # centre 1 mm inside the inner rim, 1 mm above the plane: distance sqrt(2) mm
    ov, nx, ny, nz, qx, qy, qz = c(0.0465, 0.014, 0.0)
    assert ov == pytest.approx(0.002 - math.sqrt(2) * 1e-3, rel=1e-12)
    assert (nx, ny) == pytest.approx((-1 / math.sqrt(2), 1 / math.sqrt(2)), rel=1e-12)
    assert (qx, qy) == pytest.approx((0.0475, 0.013), rel=1e-12)
    ov, nx, ny, nz, qx, qy, qz = c(0.0, 0.014, -0.0515)  # beyond the outer rim
    assert ov == pytest.approx(0.002 - math.sqrt(2) * 1e-3, rel=1e-12)
    assert qz == pytest.approx(-0.0505, rel=1e-12)


def test_one_sided_and_out_of_reach():
    assert c(0.0465, 0.012, 0.0)[0] < 0  # behind the plane, inside the inner rim: no contact
    assert c(0.0, 0.0155, 0.049)[0] < 0  # 2.5 mm above the face
    assert c(0.04, 0.014, 0.0)[0] < 0  # far inside the ring
    with pytest.raises(CaseError):
        AnnulusWall(contact=LAW, r_in=0.05, r_out=0.04).geometry()
