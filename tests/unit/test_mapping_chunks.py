"""Parallel deposits of the coupling step (MappingPlan.porosity, deposit_drag_pairs): the
z-chunk sort puts every particle in one chunk whose node range holds all the z nodes it
writes, chunks of one parity never share a node, and the sums equal the serial deposit to
round-off and are bit-identical for 1 and 2 threads."""

import numba
import numpy as np
import pytest

from cfddem.coupling import mapping as M


def skewed_points(rng, spec, n):
    """Particles crowded towards the low z end (as on the chute: a third in the first eighth),
    some exactly on nodes and some outside the box on the wall axes."""
    lo = np.array(spec.origin)
    L = np.array(spec.spacing) * np.array(spec.shape)
    u = rng.uniform(size=(n, 3))
    u[:, 2] = u[:, 2] ** 3
    pts = lo + u * L
    h = np.array(spec.spacing)
    pts[:50] = lo + np.round((pts[:50] - lo) / h) * h  # on nodes
    pts[50:60] = lo - 0.3 * h  # outside (clamped on wall axes, wrapped on periodic ones)
    pts[60:70] = lo + L + 0.2 * h
    return pts


GRIDS = [((16, 8, 150), (False, False, False)), ((4, 3, 5), (False, False, True)),
         ((3, 2, 2), (False, False, False)), ((3, 2, 1), (True, False, False)), ((3, 2, 3), (False, True, True)),
         ((5, 4, 40), (True, False, True))]


@pytest.mark.parametrize("shape,periodic", GRIDS)
def test_chunk_sort_invariants(shape, periodic):
    rng = np.random.default_rng(3)
    spec = M.GridSpec((0.0, -0.01, 0.2), (0.002, 0.003, 0.004), shape)
    pts = skewed_points(rng, spec, 6000)
    ws = {}
    plan = M.MappingPlan(spec, pts, periodic, workspace=ws)
    idx, _ = plan._compact()
    for face in (0, 1):
        pstart, perm = plan._chunks(face)
        nstart = ws["cs_nstart%d" % face]
        nb = nstart.shape[0] - 1
        nn = shape[2] + (face if not periodic[2] else 0)
        assert nb == 1 or (nb % 2 == 0 and nb == min(16, nn) // 2 * 2)
        assert nstart[0] == 0 and nstart[-1] == nn and np.all(np.diff(nstart) >= 1)
        assert pstart[0] == 0 and pstart[-1] == len(pts)
        assert np.array_equal(np.sort(perm), np.arange(len(pts)))
        for b in range(nb):
            members = perm[pstart[b]:pstart[b + 1]]
            assert np.all(np.diff(members) > 0)  # index order within a chunk
            lo_node, hi_node = idx[members, 8 + 2 * face], idx[members, 9 + 2 * face]
            assert np.all((lo_node >= nstart[b]) & (lo_node < nstart[b + 1]))
            wrapped = hi_node < lo_node
            if periodic[2]:
                # only the last node wraps, to node 0, and only from the last (odd) chunk
                assert np.all(hi_node[wrapped] == 0) and (not wrapped.any() or b == nb - 1)
            else:
                assert not wrapped.any()
            assert np.all(hi_node[~wrapped] <= nstart[b + 1])
        if nb > 1:  # balanced: no chunk above twice its share unless it is a single node
            sizes = np.diff(pstart)
            wide = np.diff(nstart) > 1
            assert np.all(sizes[wide] <= 2 * len(pts) / nb + np.bincount(idx[:, 8 + 2 * face]).max())


@pytest.mark.parametrize("shape,periodic", GRIDS)
def test_chunked_deposits_match_serial_and_threads(shape, periodic):
    rng = np.random.default_rng(4)
    spec = M.GridSpec((0.0, -0.01, 0.2), (0.002, 0.003, 0.004), shape)
    n = 8000
    pts = skewed_points(rng, spec, n)
    vel = rng.normal(size=(n, 3))
    keff = rng.uniform(0.0, 1e-3, n)
    r = rng.uniform(2e-4, 4e-4, n)
    vol = 4.0 / 3.0 * np.pi * r**3
    ref_plan = M.MappingPlan(spec, pts, periodic)
    solid_ref = ref_plan.deposit(vol, "ccc")  # serial deposit in particle index order
    dk_ref = ref_plan.deposit_faces(np.repeat(keff[:, None], 3, axis=1))
    dkv_ref = ref_plan.deposit_faces(keff[:, None] * vel)
    prev = numba.get_num_threads()
    runs = []
    try:
        for nt in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
            numba.set_num_threads(nt)
            plan = M.MappingPlan(spec, pts, periodic, workspace={})
            por = plan.porosity(r, volume=vol)
            pairs = [a.copy() for a in plan.deposit_drag_pairs(keff, vel)]
            runs.append((por, pairs))
    finally:
        numba.set_num_threads(prev)
    (por, pairs), (por2, pairs2) = runs
    assert np.array_equal(por.eps, por2.eps) and por[1:] == por2[1:]
    for a, b in zip(pairs, pairs2):
        assert np.array_equal(a, b)
    solid = (1.0 - por.eps) * spec.cell_volume
    np.testing.assert_allclose(solid, solid_ref, rtol=0, atol=1e-13 * solid_ref.max())
    assert por.solid_volume == pytest.approx(vol.sum(), rel=1e-13)
    wall = np.array([not p for p in periodic])
    lo = np.array(spec.origin)
    hi = lo + np.array(spec.spacing) * np.array(spec.shape)
    assert por.n_outside == int(np.count_nonzero(np.any(((pts < lo) | (pts > hi)) & wall, axis=1)))
    for c in range(3):
        for got, ref in ((pairs[c][..., 0], dk_ref[c]), (pairs[c][..., 1], dkv_ref[c])):
            scale = np.abs(ref).max() if ref.size and np.abs(ref).max() > 0 else 1.0
            np.testing.assert_allclose(got, ref, rtol=0, atol=1e-13 * scale)
