"""ResultsFile: layout, NaN-filled series, snapshots, measurements, append mode."""

import json

import h5py
import numpy as np
import pytest

from cfddem.io.results import (ResultsFile, list_snapshots, read_config, read_measurements,
                               read_metadata, read_series, read_snapshot)


def test_config_and_metadata_roundtrip(tmp_path):
    p = tmp_path / "r.h5"
    toml = 'name = "chute"\n[particles]\nradius = 0.0015\n'
    resolved = {"name": "chute", "particles": {"radius": np.float64(0.0015), "n": np.int64(3)},
                "stations": (0.0, 0.2)}
    with ResultsFile(p) as rf:
        rf.write_config(toml, resolved)
        rf.write_metadata(version="0.1.0", threads=2, start_time="2026-01-01T00:00:00",
                          options={"a": 1}, note=None)
    text, res = read_config(p)
    assert text == toml
    assert res == {"name": "chute", "particles": {"radius": 0.0015, "n": 3}, "stations": [0.0, 0.2]}
    md = read_metadata(p)
    assert md["version"] == "0.1.0" and md["threads"] == 2
    assert json.loads(md["options"]) == {"a": 1} and md["note"] == ""


def test_series_missing_values_are_nan(tmp_path):
    p = tmp_path / "r.h5"
    with ResultsFile(p) as rf:
        rf.append_series(time=0.0, n_particles=0)
        rf.append_series(time=0.1, n_particles=10, kinetic_energy=2.5)
        rf.append_series(time=0.2, kinetic_energy=3.0)
        rf.flush()
        # readable while open after a flush
        assert read_series(p)["time"].tolist() == [0.0, 0.1, 0.2]
    s = read_series(p)
    assert set(s) == {"time", "n_particles", "kinetic_energy"}
    np.testing.assert_array_equal(s["n_particles"], [0, 10, np.nan])
    np.testing.assert_array_equal(s["kinetic_energy"], [np.nan, 2.5, 3.0])
    with h5py.File(p) as f:
        assert f["series/time"].chunks is not None and f["series/time"].maxshape == (None,)


def test_append_mode_continues(tmp_path):
    p = tmp_path / "r.h5"
    rng = np.random.default_rng(1)
    pos = rng.random((5000, 3))
    with ResultsFile(p) as rf:
        rf.append_series(time=0.0, mass_out=0.0)
        rf.write_snapshot(0.0, 0, pos=pos, ids=np.arange(5000))
    with ResultsFile(p, mode="a") as rf:
        assert rf.n_series_rows == 1
        rf.append_series(time=0.5, mass_out=1.25)
        rf.write_snapshot(0.5, 200, pos=pos[:3], radius=np.full(3, 1.5e-3))
    assert read_series(p)["mass_out"].tolist() == [0.0, 1.25]
    assert list_snapshots(p) == [(0, 0.0, 0), (1, 0.5, 200)]
    s0 = read_snapshot(p, 0)
    np.testing.assert_array_equal(s0["pos"], pos)
    assert s0["ids"].dtype == np.int64
    s1 = read_snapshot(p, -1)
    assert s1["step"] == 200 and s1["time"] == 0.5 and s1["pos"].shape == (3, 3)
    with pytest.raises(KeyError):
        read_snapshot(p, 7)


def test_measurements_groups_scalars_and_overwrite(tmp_path):
    p = tmp_path / "r.h5"
    with ResultsFile(p) as rf:
        rf.write_measurements("chute", {"z": np.arange(3.0), "profiles": {"left": np.ones(2)}},
                              {"n_samples": 4})
        rf.write_measurements("chute", {"z": np.arange(4.0)}, {"n_samples": 9})
        rf.write_measurements("discharge_rate", 1.6, {"units": "kg/s"})
        rf.write_measurements(None, {"bulk_density": 1500.0})
    m = read_measurements(p)
    np.testing.assert_array_equal(m["chute"]["z"], np.arange(4.0))
    np.testing.assert_array_equal(m["chute"]["profiles"]["left"], [1.0, 1.0])
    assert float(m["discharge_rate"]) == 1.6 and float(m["bulk_density"]) == 1500.0
    ma = read_measurements(p, with_attrs=True)
    assert ma["chute"]["@attrs"]["n_samples"] == 9


def test_bad_mode(tmp_path):
    with pytest.raises(ValueError):
        ResultsFile(tmp_path / "x.h5", mode="r")


def test_flush_min_interval_defers_the_rewrite(tmp_path):
    """flush(min_interval) skips the rewrite within that much wall time of the last one; a plain
    flush (and close) always writes what is pending."""
    p = tmp_path / "results.h5"
    rf = ResultsFile(p)
    rf.append_series(time=0.0, mass_out=0.0)
    rf.flush()
    rf.append_series(time=0.5, mass_out=1.0)
    rf.flush(min_interval=3600.0)
    assert read_series(p)["time"].tolist() == [0.0]  # deferred
    rf.flush(min_interval=0.0)
    assert read_series(p)["time"].tolist() == [0.0, 0.5]
    rf.append_series(time=1.0, mass_out=2.0)
    rf.flush(min_interval=3600.0)
    rf.close()
    assert read_series(p)["time"].tolist() == [0.0, 0.5, 1.0]
