"""Chute measurements on hand-built particle configurations with exactly known answers."""

import math

import numpy as np
import pytest

from cfddem.errors import CaseError
from cfddem.io.results import ResultsFile, read_measurements
from cfddem.measure.chute import (ChuteMeasurements, MeasurementCells, TimeAverager,
                                  bed_height_cells, bed_height_sensors, default_slices,
                                  depth_profiles, mean_streamwise_velocity, sphere_volume_below,
                                  surface_velocity_cells)

pytestmark = pytest.mark.nojit  # also run as plain Python (tests/unit/test_nojit_tier.py)

W = 0.08
R = 0.0015


def test_cells_for_chute():
    c = MeasurementCells.for_chute(W, (0.0, 0.9))
    assert c.shape == (16, 150)
    assert c.dx == pytest.approx(0.005) and c.z_edges[-1] == pytest.approx(0.9)
    np.testing.assert_allclose(c.x_centres[:2], [0.0025, 0.0075])
    idx = c.cell_index(np.array([[0.0001, 0.01, 0.0001], [0.0799, 0, 0.8999], [-1e-4, 0, 0.1],
                                 [0.01, 0, 0.9]]))
    assert idx.tolist() == [0, 15 * 150 + 149, -1, -1]
    with pytest.raises(CaseError):
        MeasurementCells.for_chute(W, (0.5, 0.1))


def _layer(heights, c):
    """One particle at the centre of every cell, the top at heights[i, k] (+ extra lower ones)."""
    X, Z = np.meshgrid(c.x_centres, c.z_centres, indexing="ij")
    top = np.asarray(heights)
    pos = np.column_stack([X.ravel(), (top - R).ravel(), Z.ravel()])
    below = pos.copy()
    below[:, 1] = R                       # a floor particle underneath in every cell
    return np.vstack([pos, below]), np.full(2 * pos.shape[0], R)


def test_bed_height_cells_layer_and_empty():
    c = MeasurementCells.for_chute(W, (0.0, 0.06))
    rng = np.random.default_rng(3)
    h = 0.004 + 0.02 * rng.random(c.shape)
    pos, rad = _layer(h, c)
    np.testing.assert_allclose(bed_height_cells(pos, rad, c), h, rtol=0, atol=1e-15)
    # drop every particle of cell (3, 4): NaN by default, the given value otherwise
    keep = c.cell_index(pos) != 3 * c.nz + 4
    b = bed_height_cells(pos[keep], rad[keep], c)
    assert np.isnan(b[3, 4]) and np.isfinite(np.delete(b.ravel(), 3 * c.nz + 4)).all()
    assert bed_height_cells(pos[keep], rad[keep], c, empty=0.0)[3, 4] == 0.0


def test_bed_height_sensors_uniform_and_linear():
    c = MeasurementCells.for_chute(W, (0.0, 0.3))
    flat = np.full(c.shape, 0.012)
    s = bed_height_sensors(flat, c, sensor_z=[0.05, 0.1, 0.2])
    assert s.shape == (3, 3)
    np.testing.assert_allclose(s, 0.012, rtol=1e-14)
    # a bed linear in x and z: the centred 5x5 rectangle average is the value at the sensor
    a, bx, bz = 0.01, 0.1, -0.02
    lin = a + bx * c.x_centres[:, None] + bz * c.z_centres[None, :]
    zs = np.array([0.05, 0.123, 0.2])
    s = bed_height_sensors(lin, c, sensor_z=zs)
    expect = a + bx * np.array([0.015, 0.035, 0.065])[:, None] + bz * zs[None, :]  # the default sensors
    np.testing.assert_allclose(s, expect, rtol=1e-12)
    # a NaN cell is left out; a sensor whose cells are all NaN gives NaN
    lin[2, :] = np.nan
    assert np.isfinite(bed_height_sensors(lin, c, sensor_z=zs)).all()
    assert np.isnan(bed_height_sensors(np.full(c.shape, np.nan), c, sensor_z=zs)).all()


def test_bed_height_sensor_block_weights():
    """Sensor at x = 0.015 sits on a cell edge: cells 0 and 5 count half, cells 1..4 fully."""
    c = MeasurementCells.for_chute(W, (0.0, 0.3))
    h = np.zeros(c.shape)
    h[0, :] = 1.0
    s = bed_height_sensors(h, c, sensor_x=[0.015], sensor_z=[0.15])
    assert s[0, 0] == pytest.approx(0.5 / 5.0, rel=1e-12)


def test_surface_velocity_six_highest():
    c = MeasurementCells.for_chute(W, (0.0, 0.06))
    # 10 particles in cell (2, 3) at distinct heights, velocities known
    x, z = c.x_centres[2], c.z_centres[3]
    y = np.array([0.001, 0.009, 0.003, 0.007, 0.005, 0.010, 0.002, 0.008, 0.004, 0.006]) + 0.01
    vz = np.arange(10, dtype=float)
    vx = -2.0 * np.arange(10, dtype=float)
    pos = np.column_stack([np.full(10, x), y, np.full(10, z)])
    vel = np.column_stack([vx, np.zeros(10), vz])
    # 3 particles in cell (5, 0)
    pos = np.vstack([pos, [[c.x_centres[5], 0.002, c.z_centres[0]]] * 3])
    vel = np.vstack([vel, [[0.1, 0, 1.0], [0.2, 0, 2.0], [0.3, 0, 3.0]]])
    rad = np.full(len(pos), R)
    rad[0] = 0.02          # the lowest centre, but its top y + r is the highest
    svz, svx, n = surface_velocity_cells(pos, vel, rad, c, n_top=6)
    top6 = np.argsort(-(y + rad[:10]))[:6]
    assert 0 in top6
    assert svz[2, 3] == pytest.approx(vz[top6].mean()) and svx[2, 3] == pytest.approx(vx[top6].mean())
    assert n[2, 3] == 6 and n[5, 0] == 3
    assert svz[5, 0] == pytest.approx(2.0) and svx[5, 0] == pytest.approx(0.2)
    assert np.isnan(svz).sum() == svz.size - 2 and n.sum() == 9


def test_mean_streamwise_velocity():
    pos = np.array([[0.01, 0.0, 0.05], [0.02, 0.01, 0.07], [0.03, 0.0, 0.15], [0.0, 0.0, 0.5]])
    vel = np.array([[0, 0, 1.0], [0, 0, 2.0], [0, 0, 4.0], [0, 0, 9.0]])
    m, n = mean_streamwise_velocity(pos, vel, [0.0, 0.1, 0.2, 0.3])
    np.testing.assert_allclose(m[:2], [1.5, 4.0])
    assert np.isnan(m[2]) and n.tolist() == [2, 1, 0]


def test_sphere_volume_below():
    r = np.array([0.002])
    assert sphere_volume_below(r, np.array([-1.0]))[0] == 0.0
    assert sphere_volume_below(r, np.array([0.0]))[0] == pytest.approx(2 / 3 * math.pi * 0.002 ** 3)
    assert sphere_volume_below(r, np.array([1.0]))[0] == pytest.approx(4 / 3 * math.pi * 0.002 ** 3)


def _simple_cubic(nx, ny, nz, d, x0=0.0, z0=0.0):
    i, j, k = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    pos = np.column_stack([x0 + (i.ravel() + 0.5) * d, (j.ravel() + 0.5) * d, z0 + (k.ravel() + 0.5) * d])
    return pos, j.ravel()


def test_depth_profile_simple_cubic_is_pi_over_6():
    d = 2 * R
    pos, layer = _simple_cubic(26, 8, 40, d)          # 0.078 wide, 0.024 high, 0.12 long
    vel = np.zeros_like(pos)
    vel[:, 2] = 0.1 * (layer + 1)                     # a shear profile, one velocity per layer
    rad = np.full(len(pos), R)
    slices = {"a": (0.0, 8 * d), "b": (5 * d, 13 * d)}  # whole lattice periods
    y_edges = np.arange(0, 10 * d + 1e-12, d / 2)     # half-diameter bins, two above the bed
    prof = depth_profiles(pos, vel, rad, slices, (10 * d, 30 * d), y_edges)
    for name in slices:
        phi = prof[name]["phi"]
        # exact in y, centre assignment in x and z with whole periods: pi/6 to round-off
        np.testing.assert_allclose(phi[:16], math.pi / 6, rtol=1e-12)
        np.testing.assert_allclose(phi[16:], 0.0, atol=1e-15)
        np.testing.assert_allclose(prof[name]["vz"][:16], 0.1 * (np.arange(16) // 2 + 1), rtol=1e-12)
        assert np.isnan(prof[name]["vz"][16:]).all()


def test_depth_profile_misaligned_window_error_is_edge_noise():
    """With a slice that is not a whole number of periods the error is bounded by the
    particles whose centre-assignment flips: at most one row of spheres per slice edge."""
    d = 2 * R
    pos, _ = _simple_cubic(26, 8, 40, d)
    rad = np.full(len(pos), R)
    x_lo, x_hi = 1.3 * d, 9.9 * d                     # 8.6 periods wide; assigned: 8 or 9 columns
    prof = depth_profiles(pos, np.zeros_like(pos), rad, {"s": (x_lo, x_hi)}, (10 * d, 30 * d),
                          [0.0, 8 * d])
    phi = prof["s"]["phi"][0]
    n_cols = np.sum((np.arange(26) + 0.5) * d >= x_lo) - np.sum((np.arange(26) + 0.5) * d >= x_hi)
    assert phi == pytest.approx(math.pi / 6 * n_cols * d / (x_hi - x_lo), rel=1e-12)
    assert abs(phi - math.pi / 6) <= math.pi / 6 * d / (x_hi - x_lo) + 1e-12


def test_default_slices():
    """Named as seen in the direction of flow: the x = 0 side is the right."""
    s = default_slices(W)
    assert s["right"] == (0.0, 0.025) and s["left"] == (0.055, 0.08)
    assert s["centre"] == pytest.approx((0.0275, 0.0525))
    assert s["right_half"] == (0.0, 0.04) and s["left_half"] == (0.04, 0.08)


def test_time_averager_nan_weights_start_state():
    av = TimeAverager(start_time=1.0)
    assert not av.add(0.5, "a", [100.0, 100.0])
    av.add(1.0, "a", [1.0, np.nan])
    av.add(1.5, "a", [3.0, 4.0], weight=[3.0, 2.0])
    av.add(2.0, "a", [np.nan, 6.0], weight=[1.0, 0.0])
    np.testing.assert_allclose(av.mean("a"), [(1 + 9) / 4, 4.0])
    assert av.n_samples("a") == 3 and av.first_time == 1.0 and av.last_time == 2.0
    av.add(2.0, "b", [np.nan])
    assert np.isnan(av.mean("b")[0])
    other = TimeAverager()
    other.set_state(av.get_state())
    np.testing.assert_array_equal(other.mean("a"), av.mean("a"))
    assert other.start_time == 1.0 and other.n_samples("a") == 3
    with pytest.raises(ValueError):
        av.add(3.0, "a", [1.0, 2.0, 3.0])


def _flow(rng, n=4000, length=0.3):
    pos = np.column_stack([rng.uniform(R, W - R, n), rng.uniform(R, 0.02, n), rng.uniform(0, length, n)])
    vel = np.column_stack([rng.normal(0, 0.1, n), np.zeros(n), 1.0 + 10 * pos[:, 1]])
    return pos, vel, np.full(n, R)


def test_chute_measurements_steady_state_and_restart(tmp_path):
    rng = np.random.default_rng(7)
    pos, vel, rad = _flow(rng)
    cm = ChuteMeasurements(W, (0.0, 0.3), start_time=0.1, stations=(0.05, 0.2))
    assert not cm.measure(0.0, pos, vel, rad)
    assert cm.results() == {"n_samples": 0}
    for t in (0.1, 0.2, 0.3):
        assert cm.measure(t, pos, vel, rad)
    r = cm.results()
    assert r["n_samples"] == 3 and r["t_first"] == 0.1 and r["t_last"] == 0.3
    c = cm.cells
    # a steady state averages to the instantaneous values
    np.testing.assert_allclose(r["bed_height_cells"], bed_height_cells(pos, rad, c, empty=0.0))
    vz, vx, _ = surface_velocity_cells(pos, vel, rad, c)
    np.testing.assert_allclose(r["surface_vz"], vz)
    np.testing.assert_allclose(r["surface_vx"], vx)
    np.testing.assert_allclose(r["mean_vz"], mean_streamwise_velocity(pos, vel, c.z_edges)[0])
    assert r["bed_height_sensor"].shape == (3, c.nz)
    assert r["profile_whole_phi"].shape == (2, 30) and r["profile_left_vz"].shape == (2, 30)
    prof = depth_profiles(pos, vel, rad, default_slices(W), (0.185, 0.215), cm.y_edges)
    np.testing.assert_allclose(r["profile_centre_phi"][1], prof["centre"]["phi"])
    # the surface is faster than the mean, as the synthetic profile says
    assert np.nanmean(r["surface_vz"]) > np.nanmean(r["mean_vz"])
    # checkpoint/restart gives identical averages
    cm2 = ChuteMeasurements(W, (0.0, 0.3), start_time=0.1, stations=(0.05, 0.2))
    cm2.set_state(cm.get_state())
    for k, v in cm2.results().items():
        np.testing.assert_array_equal(v, r[k])
    # checkpoint through HDF5 (slashes in the state keys become nested groups)
    import h5py
    from cfddem.io.results import _read_tree
    with h5py.File(tmp_path / "ck.h5", "w") as f:
        for k, v in cm.get_state().items():
            f[k] = v
    with h5py.File(tmp_path / "ck.h5", "r") as f:
        nested = _read_tree(f, False)
    cm3 = ChuteMeasurements(W, (0.0, 0.3), start_time=0.1, stations=(0.05, 0.2))
    cm3.set_state(nested)
    np.testing.assert_array_equal(cm3.results()["profile_left_phi"], r["profile_left_phi"])
    # stored and read back
    with ResultsFile(tmp_path / "r.h5") as rf:
        rf.write_measurements(cm.group, r, cm.attrs())
    back = read_measurements(tmp_path / "r.h5")["chute"]
    np.testing.assert_array_equal(back["surface_vz"], r["surface_vz"])


def test_sides_seen_in_the_direction_of_flow():
    """x = 0 is on the right of an observer facing down the chute (right = z x y = -x); the
    default sensors are physics.md's (0.015, 0.045, 0.065 m from the left wall, x = W) mirrored."""
    from cfddem.measure.chute import SENSOR_X, sensor_names, side_label, side_of, x_label

    assert np.cross([0, 0, 1.0], [0, 1.0, 0]) @ [1.0, 0, 0] == -1.0  # right = -x
    assert sensor_names(SENSOR_X, W) == ["right", "centre", "left"]
    np.testing.assert_allclose(sorted(W - np.array([0.015, 0.045, 0.065])), SENSOR_X, atol=1e-15)
    assert [side_of(x, W) for x in (0.0, 0.031, 0.0321, 0.045, 0.0479, 0.08)] == \
        ["right", "right", "centre", "centre", "centre", "left"]
    assert side_label("right", W) == "right (x = 0 side)"
    assert side_label("left_half", W) == "left half (x = 80 mm side)"
    assert side_label("centre", W) == "centre" and side_label("floor", W) == "floor"
    assert x_label(W) == "x across the chute [mm] (x = 0: right wall, x = 80 mm: left wall)"


def _old_file(path, rng):
    """A results file as written before the sides were named in the direction of flow: the
    x = 0 slice, half and wall called "left", sensor names "left,centre,right" at x = 0.015,
    0.045, 0.065, no ``sides`` attribute."""
    pos, vel, rad = _flow(rng)
    pos[:, 0] *= 0.5  # every particle on the x = 0 half
    cm = ChuteMeasurements(W, (0.0, 0.3), start_time=0.0, stations=(0.05, 0.2), sensor_x=(0.015, 0.045, 0.065))
    cm.measure(0.0, pos, vel, rad)
    r = cm.results()
    swap = {"right": "left", "left": "right", "right_half": "left_half", "left_half": "right_half"}
    old = {}
    for k, v in r.items():
        for new, was in sorted(swap.items(), key=lambda kv: -len(kv[0])):
            for pre in ("profile_", "slice_"):
                if k.startswith(pre + new + "_") or k == pre + new:
                    k = pre + was + k[len(pre + new):]
                    break
            else:
                continue
            break
        old[k] = v
    at = cm.attrs()
    del at["sides"]
    at["sensor_names"] = "left,centre,right"
    with ResultsFile(path) as rf:
        rf.write_measurements("chute", old, at)
        rf.write_measurements("momentum_budget", {"wall_left": np.array([-2.0]), "wall_left_err": np.array([0.1]),
                                                  "wall_right": np.array([-0.5]), "wall_floor": np.array([-3.0])})
    return r


def test_results_written_before_the_sides_are_read_with_todays_names(tmp_path):
    rng = np.random.default_rng(3)
    r = _old_file(tmp_path / "old.h5", rng)
    m = read_measurements(tmp_path / "old.h5", with_attrs=True)
    ch, at = m["chute"], m["chute"]["@attrs"]
    assert at["sensor_names"] == "right,centre,left" and at["sides_swapped_on_read"] == 1
    # the x = 0 slice and half are the right ones again, with all the solid in the right half
    np.testing.assert_array_equal(ch["slice_right"], [0.0, 0.025])
    np.testing.assert_array_equal(ch["slice_right_half"], [0.0, 0.04])
    np.testing.assert_array_equal(ch["profile_right_half_phi"], r["profile_right_half_phi"])
    np.testing.assert_array_equal(ch["profile_left_phi"], r["profile_left_phi"])
    assert np.nansum(ch["profile_right_half_phi"]) > 0.1 and np.nansum(ch["profile_left_half_phi"]) == 0.0
    b = m["momentum_budget"]
    assert b["wall_right"][0] == -2.0 and b["wall_right_err"][0] == 0.1 and b["wall_left"][0] == -0.5
    assert b["wall_floor"][0] == -3.0
    # without attributes the same names; a file written now is read as written
    assert read_measurements(tmp_path / "old.h5")["chute"].keys() == {k for k in ch if k != "@attrs"}
    cm = ChuteMeasurements(W, (0.0, 0.3), start_time=0.0, stations=(0.05, 0.2))
    pos, vel, rad = _flow(rng)
    cm.measure(0.0, pos, vel, rad)
    with ResultsFile(tmp_path / "new.h5") as rf:
        rf.write_measurements("chute", cm.results(), cm.attrs())
    new = read_measurements(tmp_path / "new.h5", with_attrs=True)["chute"]
    assert "sides_swapped_on_read" not in new["@attrs"] and new["@attrs"]["sensor_names"] == "right,centre,left"
    np.testing.assert_array_equal(new["slice_right"], [0.0, 0.025])


def test_checkpoint_before_the_sides_resumes_into_the_same_sums():
    """An older checkpoint's averages of the x = 0 slice ("left" then) continue as "right"."""
    rng = np.random.default_rng(5)
    pos, vel, rad = _flow(rng)
    cm = ChuteMeasurements(W, (0.0, 0.3), start_time=0.0, stations=(0.05, 0.2))
    cm.measure(0.0, pos, vel, rad)
    st = cm.get_state()
    old = {k.replace("/right/", "/@/").replace("/left/", "/right/").replace("/@/", "/left/")
           .replace("/right_half/", "/@/").replace("/left_half/", "/right_half/").replace("/@/", "/left_half/"): v
           for k, v in st.items() if k != "sides_flow_seen"}
    full = {"measure": old, "budget": {"rows": {"wall_left": np.ones((1, 2)), "wall_right": np.zeros((1, 2))}}}
    up = ChuteMeasurements.upgrade_checkpoint(full)
    cm2 = ChuteMeasurements(W, (0.0, 0.3), start_time=0.0, stations=(0.05, 0.2))
    cm2.set_state(up["measure"])
    for k, v in cm.results().items():
        np.testing.assert_array_equal(cm2.results()[k], v)
    np.testing.assert_array_equal(up["budget"]["rows/wall_right"], np.ones((1, 2)))
    np.testing.assert_array_equal(up["budget"]["rows/wall_left"], np.zeros((1, 2)))
    assert ChuteMeasurements.upgrade_checkpoint({"measure": st}) == {"measure": st}
