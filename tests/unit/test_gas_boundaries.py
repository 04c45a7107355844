"""Halo filling for every boundary-condition type (cfddem.gas.boundaries)."""

import numpy as np
import pytest

from cfddem.errors import CaseError
from cfddem.gas import (BoundarySet, FreeSlip, Inlet, LidCrossWind, NoSlip, Periodic, PressureOutlet,
                        StaggeredGrid, Velocity)

pytestmark = pytest.mark.nojit  # also run as plain Python (tests/unit/test_nojit_tier.py)

SIDES = ("x-", "x+", "y-", "y+", "z-", "z+")


def grid():
    return StaggeredGrid((4, 5, 6), (0.4, 0.5, 0.6), origin=(0.0, -0.25, 1.0), halo=2)


def random_velocity(g, seed=0):
    rng = np.random.default_rng(seed)
    return [rng.standard_normal(g.array_shape(loc)) for loc in ("fcc", "cfc", "ccf")]


def bset(g, **over):
    bcs = {s: NoSlip() for s in SIDES}
    bcs.update({k.replace("m", "-").replace("p", "+"): v for k, v in over.items()})
    return BoundarySet(g, bcs)


def test_noslip_wall_values():
    g = grid()
    h = g.halo
    u, v, w = random_velocity(g)
    bset(g).fill_velocity(u, v, w)
    # normal component: boundary faces zero, ghosts odd reflections
    assert np.all(u[h] == 0) and np.all(u[h + 4] == 0)
    assert np.allclose(u[h - 1], -u[h + 1]) and np.allclose(u[h - 2], -u[h + 2])
    # tangential: the wall value (mean of ghost and first interior point) is zero
    assert np.allclose(0.5 * (v[h - 1] + v[h]), 0.0, atol=1e-15)
    assert np.allclose(0.5 * (w[:, h + 5 - 1] + w[:, h + 5]), 0.0, atol=1e-15)
    assert np.allclose(v[h - 2], -v[h + 1])


def test_freeslip_mirrors_tangential():
    g = grid()
    h = g.halo
    u, v, w = random_velocity(g, 1)
    bset(g, ym=FreeSlip()).fill_velocity(u, v, w)
    assert np.all(v[:, h] == 0)
    assert np.allclose(u[:, h - 1], u[:, h]) and np.allclose(u[:, h - 2], u[:, h + 1])
    assert np.allclose(w[:, h - 1], w[:, h])


def test_prescribed_function_extends_linear_field_exactly():
    """The rotating lid cross-wind u = -Omega x (r - r_axis) is linear: with it prescribed on
    every side, the halos of the matching interior field equal the field itself."""
    g = grid()
    bc = LidCrossWind(omega=(0.3, 1.7, -0.4), axis_point=(0.1, 0.0, 1.2))
    bs = BoundarySet(g, {s: bc for s in SIDES})
    exact = []
    for c, loc in enumerate(("fcc", "cfc", "ccf")):
        X, Y, Z = g.mesh(loc, with_halo=True)
        exact.append(bc.velocity("x-", X, Y, Z)[c])
    vel = [e.copy() for e in exact]
    for a in vel:  # spoil the halos
        a[:2] = 99.0
        a[-2:] = -99.0
        a[:, :2] = 7.0
        a[:, :, -2:] = 5.0
    for a, e, loc in zip(vel, exact, ("fcc", "cfc", "ccf")):
        a[g.interior(loc)] = e[g.interior(loc)]
    bs.fill_velocity(*vel)
    for a, e in zip(vel, exact):
        assert np.allclose(a, e, atol=1e-13, rtol=0)


def test_inlet_and_constant_velocity():
    g = grid()
    h = g.halo
    u, v, w = random_velocity(g, 2)
    bs = bset(g, zm=Inlet(speed=lambda x, y, z: 2.0 + 0 * x), zp=Inlet(speed=0.5),
              ym=Velocity((0.3, 0.0, -0.1)))
    bs.fill_velocity(u, v, w)
    assert np.allclose(w[:, :, h], 2.0)          # into the box at z-: +z
    assert np.allclose(w[:, :, h + 6], -0.5)     # into the box at z+: -z
    assert np.allclose(w[:, :, h - 1], 4.0 - w[:, :, h + 1])
    assert np.allclose(0.5 * (u[:, :, h - 1] + u[:, :, h]), 0.0)
    assert np.allclose(0.5 * (u[:, h - 1] + u[:, h])[:, h:-h], 0.3)
    assert np.allclose(0.5 * (w[:, h - 1] + w[:, h])[:, h + 1:h + 6], -0.1)


def test_outlet_and_pressure():
    g = grid()
    h = g.halo
    u, v, w = random_velocity(g, 3)
    bs = bset(g, xp=PressureOutlet(p=lambda x, y, z: 3.0 + y))
    bs.fill_velocity(u, v, w)
    n = 4
    assert np.allclose(u[h + n + 1], u[h + n]) and np.allclose(u[h + n + 2], u[h + n])
    assert np.allclose(v[h + n], v[h + n - 1]) and np.allclose(w[h + n + 1], w[h + n - 1])
    assert bs.face_range[0] == (1, 5) and bs.pressure_bc["x+"] == "dirichlet"
    p = np.random.default_rng(4).standard_normal(g.array_shape("ccc"))
    bs.fill_pressure(p)
    y = g.coords("ccc", 1)
    assert np.allclose((0.5 * (p[h + n - 1] + p[h + n]) - 3.0 - y[:, None])[h:-h, h:-h], 0.0)
    assert np.allclose(p[h - 1], p[h]) and np.allclose(p[:, h - 2], p[:, h + 1])  # Neumann elsewhere
    bs.fill_pressure(p, homogeneous=True)
    assert np.allclose(p[h + n], -p[h + n - 1])


def test_periodic_wraps():
    g = grid()
    h = g.halo
    u, v, w = random_velocity(g, 5)
    bs = bset(g, xm=Periodic(), xp=Periodic())
    bs.fill_velocity(u, v, w)
    n = 4
    assert np.array_equal(u[h + n], u[h]) and np.array_equal(u[h - 2], u[h + n - 2])
    assert np.array_equal(u[h + n + 2], u[h + 2])
    assert np.array_equal(v[h - 1], v[h + n - 1]) and np.array_equal(v[h + n + 1], v[h + 1])
    assert bs.face_range[0] == (0, n) and bs.pressure_bc["x-"] == "periodic"
    e = np.random.default_rng(6).random(g.array_shape("ccc"))
    bs.fill_scalar(e)
    assert np.array_equal(e[h - 1], e[h + n - 1]) and np.array_equal(e[:, h - 1], e[:, h])


def test_bad_boundary_sets_raise():
    g = grid()
    with pytest.raises(CaseError, match="periodic"):
        bset(g, xm=Periodic())
    with pytest.raises(CaseError, match="missing"):
        BoundarySet(g, {"x-": NoSlip()})
    with pytest.raises(CaseError):
        bset(g, zp="wall")


@pytest.mark.parametrize("shape", [(4, 5, 7), (3, 1, 6), (1, 4, 1)])
@pytest.mark.parametrize("halo", [1, 2])
@pytest.mark.parametrize("case", ["walls", "chute", "periodic_z", "periodic_xy_outlet", "freeslip_velocity"])
def test_compiled_fills_equal_numpy_fills(case, halo, shape):
    """The compiled halo fills (recorded runs of elementwise operations) give the numpy slice
    fills bit for bit, for every array kind, halo width and a mix of all condition types,
    also with one cell along an axis (blocks whose lines have length 1)."""
    g = StaggeredGrid(shape, (0.4, 0.5, 0.7), origin=(0.0, -0.25, 1.0), halo=halo)
    out = PressureOutlet(p=lambda x, y, z: 3.0 * y - 2.0 * z + 0.5 * x)
    bcs = {
        "walls": {},
        "chute": dict(ym=NoSlip(), yp=LidCrossWind(omega=(0.1, 1.2, -0.7), axis_point=(0.2, 0.0, 1.3)),
                      zm=Inlet(speed=1.5, tangential=(0.2, -0.1, 0.0)), zp=out),
        "periodic_z": dict(zm=Periodic(), zp=Periodic(), xm=Velocity(value=lambda x, y, z: (0 * x + 1.0, y, z))),
        "periodic_xy_outlet": dict(xm=Periodic(), xp=Periodic(), ym=Periodic(), yp=Periodic(), zm=out,
                                   zp=PressureOutlet(p=2.0)),
        "freeslip_velocity": dict(xm=FreeSlip(), yp=FreeSlip(), zm=Velocity(value=(0.3, -0.4, 0.5)),
                                  zp=Inlet(speed=lambda x, y, z: 1.0 + x * y)),
    }[case]
    bs = bset(g, **bcs)
    vel = random_velocity(g, seed=3)
    ref = [a.copy() for a in vel]
    bs.fill_velocity(*vel)
    bs.fill_velocity(*ref, compiled=False)
    for a, b in zip(vel, ref):
        assert np.array_equal(a, b)
    changed = [not np.array_equal(a, b) for a, b in zip(vel, random_velocity(g, seed=3))]
    assert all(changed)  # the fills did write
    rng = np.random.default_rng(5)
    for hom in (False, True):
        p = rng.standard_normal(g.array_shape("ccc"))
        q = p.copy()
        bs.fill_pressure(p, homogeneous=hom)
        bs.fill_pressure(q, homogeneous=hom, compiled=False)
        assert np.array_equal(p, q)
    e = rng.uniform(0.3, 1.0, g.array_shape("ccc"))
    f = e.copy()
    bs.fill_scalar(e)
    bs.fill_scalar(f, compiled=False)
    assert np.array_equal(e, f)
    for c in range(3):  # one component alone, twice (the recorded list is reused; with one
        # cell along an axis a fill reads halo entries it wrote, so the numpy side runs twice too)
        a = rng.standard_normal(vel[c].shape)
        b = a.copy()
        bs.fill_component(a, c)
        bs.fill_component(a, c)
        bs.fill_component(b, c, compiled=False)
        bs.fill_component(b, c, compiled=False)
        assert np.array_equal(a, b)
