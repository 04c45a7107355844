"""The coupling's fused slip-and-drag pass (cfddem.coupling.exchange._slip_drag_kernel) against
the three passes it replaces (the slip interpolation, the closure's compiled twin, K_eff): the
same numbers bit for bit, for every named closure, both drag treatments, a drag factor, and 1
and 2 threads."""

import numba
import numpy as np
import pytest

from cfddem.coupling import drag as D
from cfddem.coupling import mapping as M
from cfddem.coupling.exchange import _keff_kernel, _slip_drag_kernel
from tests.unit.test_mapping import SPEC, random_points


@pytest.mark.parametrize("closure", ["beetstra", "wen_yu", "ergun_gidaspow", "di_felice", "koch_hill"])
@pytest.mark.parametrize("implicit, factor", [(1, 1.0), (0, 0.7)])
def test_fused_slip_drag_is_the_three_passes_bit_for_bit(closure, implicit, factor):
    rng = np.random.default_rng(5)
    n = 2500
    pts = random_points(rng, n)
    vel = rng.normal(scale=0.5, size=(n, 3))
    rad = rng.uniform(0.5e-3, 1.5e-3, n)
    mass = 2500.0 * 4.0 / 3.0 * np.pi * rad**3
    eps = rng.uniform(0.35, 1.0, SPEC.shape)
    eps.flat[::7] = 1.3  # clipped to 1 at the particles
    u = [rng.normal(size=M.node_shape(SPEC, loc)) for loc in ("fcc", "cfc", "ccf")]
    rho, mu, dtg = 1.2, 1.8e-5, 6.4e-4
    cid = D.closure_id(closure)
    plan = M.MappingPlan(SPEC, pts, (True, False, False))
    d = 2.0 * rad
    e_ref, re = (x.copy() for x in plan.interpolate_slip(eps, *u, vel, d, rho, mu))
    F = D.drag_values(cid, e_ref, re)
    F *= factor
    k_ref = np.empty(n)
    _keff_kernel(F, e_ref, d, mass, 3.0 * np.pi * mu, dtg, implicit, k_ref)
    assert np.all(np.isfinite(k_ref)) and np.all(k_ref > 0.0)
    prev = numba.get_num_threads()
    try:
        for nt in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
            numba.set_num_threads(nt)
            e_a, keff = np.full(n, np.nan), np.full(n, np.nan)
            _slip_drag_kernel(*plan.slip_operands(eps, *u, vel), rad, rho, mu, np.int64(cid), factor, mass,
                              3.0 * np.pi * mu, dtg, implicit, e_a, keff)
            np.testing.assert_array_equal(e_a, e_ref)
            np.testing.assert_array_equal(keff, k_ref)
    finally:
        numba.set_num_threads(prev)
    if implicit == 1:  # the implicit K_eff is below K (the impulse never overshoots the gas velocity)
        K = 3.0 * np.pi * mu * d * e_ref * F
        assert np.all(k_ref <= K) and np.all(k_ref > 0.5 * K)
