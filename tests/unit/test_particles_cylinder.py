"""Wall geometry at faces, edges and corners: the cylinder wall (kind 2: inner face, rim beyond
the ends, the axis, the face/rim transition) and an inclined hopper side (a 60 deg rectangle:
face, outlet edge, corner with the front wall), plus a cylinder in a running system."""

import math

import numpy as np
import pytest

from cfddem.errors import CaseError
from cfddem.particles import CylinderWall, LinearContact, ParticleSystem, RectangleWall
from cfddem.particles.walls import wall_contact_py

pytestmark = pytest.mark.nojit  # also run as plain Python (tests/unit/test_nojit_tier.py)

C = LinearContact(k_n=1000.0, e_n=0.7, e_t=0.5, mu=0.3)
RC, H, r = 0.05, 0.02, 0.002


def _contact(wall, x, rad=r):
    ov, nx, ny, nz, qx, qy, qz = wall_contact_py(wall.geometry(), np.asarray(x, float), rad)
    return ov, np.array([nx, ny, nz]), np.array([qx, qy, qz])


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


# a tilted ring: axis (1, 1, 1)/sqrt 3 through (0.1, -0.2, 0.3); e1, e2 radial unit vectors
P0 = np.array([0.1, -0.2, 0.3])
AX = _unit([1, 1, 1])
E1 = _unit(np.cross(AX, [1, 0, 0]))
E2 = np.cross(AX, E1)
CYL = CylinderWall(contact=C, point=tuple(P0), axis=tuple(AX), radius=RC, half_height=H)


@pytest.mark.parametrize("phi", [0.0, 1.0, 2.5, -2.0])
def test_cylinder_inner_face(phi):
    u = math.cos(phi) * E1 + math.sin(phi) * E2  # radial direction
    delta = 3e-4
    x = P0 + 0.7 * H * AX + (RC - r + delta) * u
    ov, n, q = _contact(CYL, x)
    assert ov == pytest.approx(delta, rel=1e-9)
    np.testing.assert_allclose(n, -u, atol=1e-12)  # radially inwards, from the wall to the centre
    np.testing.assert_allclose(q, P0 + 0.7 * H * AX + RC * u, atol=1e-12)
    # no contact when the sphere is clear of the surface, or outside the ring
    assert _contact(CYL, P0 + (RC - r - 1e-5) * u)[0] < 0
    assert _contact(CYL, P0 + (RC + 0.5 * r) * u)[0] < 0


def test_cylinder_rim_above_the_top_end():
    """Centre 1 mm above the top end and 1 mm inside the radius: the sphere touches the rim
    circle at 45 degrees."""
    x = P0 + (H + 1e-3) * AX + (RC - 1e-3) * E1
    ov, n, q = _contact(CYL, x)
    assert ov == pytest.approx(r - math.sqrt(2) * 1e-3, rel=1e-9)
    np.testing.assert_allclose(n, _unit(AX - E1), atol=1e-12)
    np.testing.assert_allclose(q, P0 + H * AX + RC * E1, atol=1e-12)
    # below the bottom end, symmetric
    ov2, n2, _ = _contact(CYL, P0 - (H + 1e-3) * AX + (RC - 1e-3) * E1)
    assert ov2 == pytest.approx(ov, rel=1e-9)
    np.testing.assert_allclose(n2, _unit(-AX - E1), atol=1e-12)
    # far above the end: nothing
    assert _contact(CYL, P0 + (H + 1.5 * r) * AX + (RC - 1e-3) * E1)[0] < 0


def test_cylinder_point_on_the_axis():
    for s in (0.0, 0.5 * H, H + 0.5 * r):
        ov, n, q = _contact(CYL, P0 + s * AX)
        assert ov < 0 and np.all(np.isfinite(n))
    # even a sphere larger than the ring: no normal is defined, no contact (and no NaN)
    ov, n, q = _contact(CYL, P0, rad=2 * RC)
    assert ov < 0 and np.all(np.isfinite(n)) and np.all(np.isfinite(q))


def test_cylinder_face_rim_transition_is_continuous():
    rho = RC - 0.4 * r
    ovs, ns = [], []
    for s in (H - 1e-9, H, H + 1e-9, H + 1e-6):
        ov, n, _ = _contact(CYL, P0 + s * AX + rho * E2)
        ovs.append(ov)
        ns.append(n)
    assert ovs[0] == pytest.approx(0.6 * r, rel=1e-9)
    assert ovs[1] == pytest.approx(0.6 * r, rel=1e-9)
    assert ovs[2] == pytest.approx(0.6 * r, rel=1e-6)
    np.testing.assert_allclose(ns[2], -E2, atol=1e-6)
    # 1 um past the end: the rim normal has tilted by atan(1e-6 / (RC - rho)) only
    assert ovs[3] == pytest.approx(r - math.hypot(1e-6, RC - rho), rel=1e-12)
    assert np.dot(ns[3], -E2) == pytest.approx(math.cos(math.atan(1e-6 / (RC - rho))), rel=1e-12)


def test_cylinder_outside_surface():
    out = CylinderWall(contact=C, point=tuple(P0), axis=tuple(AX), radius=RC, half_height=H, inside=False)
    ov, n, _ = _contact(out, P0 + (RC + r - 2e-4) * E1)
    assert ov == pytest.approx(2e-4, rel=1e-9)
    np.testing.assert_allclose(n, E1, atol=1e-12)
    assert _contact(out, P0 + (RC - 0.5 * r) * E1)[0] < 0  # inside: the other side


@pytest.mark.parametrize("kw,key", [(dict(radius=0.0), "wall.radius"), (dict(half_height=-1.0), "wall.half_height"),
                                    (dict(axis=(0, 0, 0)), "wall.axis")])
def test_cylinder_bad_geometry(kw, key):
    args = dict(contact=C, point=(0, 0, 0), axis=(0, 0, 1), radius=RC, half_height=H)
    args.update(kw)
    with pytest.raises(CaseError) as ei:
        CylinderWall(**args).geometry()
    assert ei.value.key == key


# --- hopper side: a rectangle inclined at 60 degrees ---------------------------------------
TH = math.radians(60.0)
A1 = np.array([math.cos(TH), math.sin(TH), 0.0])  # up the slope
A2 = np.array([0.0, 0.0, 1.0])
N = np.array([-math.sin(TH), math.cos(TH), 0.0])  # into the hopper
H1, H2 = 0.05, 0.02
PH = np.array([0.02, 0.0, 0.0]) + H1 * A1  # centre; the outlet edge is at u1 = -H1
HOP = RectangleWall(contact=C, point=tuple(PH), normal=tuple(N), axis1=tuple(A1), half1=H1, half2=H2)
FRONT = RectangleWall(contact=C, point=(0.0, 0.05, H2), normal=(0, 0, -1), axis1=(1, 0, 0), half1=0.1, half2=0.1)


def test_hopper_face():
    x = PH + 0.3 * H1 * A1 - 0.5 * H2 * A2 + (r - 2e-4) * N
    ov, n, q = _contact(HOP, x)
    assert ov == pytest.approx(2e-4, rel=1e-9)
    np.testing.assert_allclose(n, N, atol=1e-12)
    np.testing.assert_allclose(q, x - (r - 2e-4) * N, atol=1e-12)
    assert _contact(HOP, x + 2 * r * N)[0] < 0


@pytest.mark.parametrize("phi_deg", [10.0, 45.0, 89.0])
def test_hopper_outlet_edge(phi_deg):
    """Centre beyond the outlet edge (u1 < -H1), on the particle side: the normal points from
    the edge to the centre, the overlap is r - distance."""
    phi = math.radians(phi_deg)
    d = _unit(-math.cos(phi) * A1 + math.sin(phi) * N)
    edge = PH - H1 * A1 + 0.25 * H2 * A2
    x = edge + (r - 3e-4) * d
    ov, n, q = _contact(HOP, x)
    assert ov == pytest.approx(3e-4, rel=1e-9)
    np.testing.assert_allclose(n, d, atol=1e-12)
    np.testing.assert_allclose(q, edge, atol=1e-12)
    # behind the wall (below the outlet edge, -N side): one-sided, no contact
    assert _contact(HOP, edge + (r - 3e-4) * _unit(-math.cos(phi) * A1 - math.sin(phi) * N))[0] < 0


def test_hopper_outlet_corner_and_front_wall():
    """At the corner of the outlet edge and the front wall: beyond the rectangle's corner the
    normal points from the corner; inside the hopper, in the corner between the hopper side and
    the front wall, both faces push with their own normals."""
    corner = PH - H1 * A1 + H2 * A2
    d = _unit(-A1 + A2 + N)
    ov, n, q = _contact(HOP, corner + (r - 1e-4) * d)
    assert ov == pytest.approx(1e-4, rel=1e-9)
    np.testing.assert_allclose(n, d, atol=1e-12)
    np.testing.assert_allclose(q, corner, atol=1e-12)
    # a sphere in the hopper touching both the inclined side and the front wall (z = H2)
    x = PH - 0.5 * H1 * A1 + (r - 1e-4) * N
    x[2] = H2 - (r - 2e-4)
    ov1, n1, _ = _contact(HOP, x)
    ov2, n2, _ = _contact(FRONT, x)
    assert ov1 == pytest.approx(1e-4, rel=1e-9)
    assert ov2 == pytest.approx(2e-4, rel=1e-9)
    np.testing.assert_allclose(n1, N, atol=1e-12)
    np.testing.assert_allclose(n2, [0, 0, -1], atol=1e-12)


# --- a cylinder in a running system ---------------------------------------------------------
def test_sphere_bounces_off_the_inner_face_and_moving_ring():
    """A sphere moving radially outwards inside a ring rebounds with e_n (normal inwards); a
    ring translating along its axis moves by v t and keeps the contact normal radial."""
    R, RHO = 1.5e-3, 2550.0
    m = RHO * 4 / 3 * math.pi * R**3
    ring = CylinderWall(contact=C, point=(0, 0, 0), axis=(0, 0, 1), radius=0.02, half_height=0.01, name="ring")
    s = ParticleSystem(pp=C, walls=[ring], dt=C.collision_time(m) / 1000)
    v = 0.3
    s.add_particles([[0.0, 0.02 - R - 1e-5, 0.0]], [[0.0, v, 0.0]], R, RHO)
    for _ in range(5000):
        s.step(1)
        if s.vel[0, 1] < 0 and s.pos[0, 1] < 0.02 - R - 1e-5:
            break
    assert s.vel[0, 1] == pytest.approx(-0.7 * v, rel=2e-3)
    assert abs(s.vel[0, 0]) < 1e-12 and abs(s.vel[0, 2]) < 1e-12
    s.set_wall_velocity("ring", (0, 0, 0.5))
    t0 = s.time
    s.step(100)
    np.testing.assert_allclose(s.wall_position("ring"), [0, 0, 0.5 * (s.time - t0)], rtol=1e-12)
