"""cfddem calibrate on the small shear cell through the CLI: bulk friction rising with particle
friction; replicas give a standard deviation; a study grows by calls with other labels and reuses
finished runs; rotation locked raises the bulk friction; the wall-friction sweep; target
interpolation; bad input."""

import csv
import math

import pytest

import numpy as np

from cfddem.calibrate import interpolate_target, points
from cfddem.measure.shear import window_rise
from cfddem.cli import main

from .test_shear_cell import CASE


def _rows(path):
    return list(csv.DictReader(open(path)))


def test_calibrate_sweep_writes_table_and_plot(write_case, tmp_path, one_numba_thread):
    d = write_case(CASE.format(clump="none", variant="bulk", n=330), name="cal")
    out = tmp_path / "cal_out"
    rc = main(["calibrate", str(d), "--mu", "0,0.1,0.6", "--out", str(out), "--target", "0.3", "--threads", "1"])
    assert rc == 0
    rows = _rows(out / "calibration.csv")
    assert [float(r["x"]) for r in rows] == [0.0, 0.1, 0.6]
    assert all(r["label"] == "spheres" and r["rotation"] == "free" and r["n"] == "1" for r in rows)
    f = [float(r["friction"]) for r in rows]
    assert all(math.isfinite(x) for x in f)
    # more particle friction, more bulk friction. One sample of this 330-sphere cell scatters by
    # 0.04-0.05 (seeds 5-10: mu = 0 gave 0.10-0.20, mu = 0.1 0.24-0.36, mu = 0.6 0.29-0.40), so
    # the steps asserted are the ones that stand above that scatter for every seed: from
    # frictionless spheres to any friction; between 0.1 and 0.6 the curve flattens (spheres
    # free to roll) and one sample cannot resolve it
    assert f[1] > f[0] + 0.05
    assert f[2] > f[0] + 0.08
    assert all(abs(float(r["load_error"])) < 0.01 for r in rows)
    # the scraped sample's solid fraction of each point (a random packing of spheres: 0.55-0.64;
    # a fill without friction packs densest)
    phi = [float(r["solid_fraction"]) for r in rows]
    assert all(0.5 < x < 0.65 for x in phi) and phi[0] > phi[2]
    assert (out / "calibration.png").stat().st_size > 5000
    md = (out / "calibration.md").read_text()
    assert "| spheres | free | 0 | 0.1 |" in md and "Target bulk friction 0.3" in md
    # the second call with another label adds to the study; the first label's runs are reused
    mtime = (out / "spheres_free_mur0_mu0.1_s5" / "results.h5").stat().st_mtime
    rc = main(["calibrate", str(d), "--mu", "0.1", "--rotation", "locked", "--label", "locked_only", "--out",
               str(out), "--threads", "1"])
    assert rc == 0
    rows = _rows(out / "calibration.csv")
    assert {(r["label"], r["rotation"], r["x"]) for r in rows} == {
        ("spheres", "free", "0.0"), ("spheres", "free", "0.1"), ("spheres", "free", "0.6"),
        ("locked_only", "locked", "0.1")}
    assert (out / "spheres_free_mur0_mu0.1_s5" / "results.h5").stat().st_mtime == mtime
    # particles that cannot roll shear harder at the same contact friction (the sample poured
    # with locked spins is another packing too; at mu = 0.1 the gap in this cell is 0.07-0.23
    # over seeds 5-10)
    locked = [float(r["friction"]) for r in rows if r["label"] == "locked_only"][0]
    assert locked > f[1] + 0.03  # seeds 5-10: locked 0.40-0.50 against free 0.24-0.36


def test_replicas_and_reuse(write_case, tmp_path, one_numba_thread, capsys):
    d = write_case(CASE.format(clump="none", variant="bulk", n=330), name="cal")
    out = tmp_path / "rep"
    assert main(["calibrate", str(d), "--mu", "0.5", "--replicas", "2", "--out", str(out), "--threads", "1"]) == 0
    runs = _rows(out / "runs.csv")
    assert sorted(int(r["seed"]) for r in runs) == [5, 6]
    f = [float(r["friction"]) for r in runs]
    assert f[0] != f[1]  # two packings
    pt = _rows(out / "calibration.csv")[0]
    assert int(pt["n"]) == 2
    assert float(pt["friction"]) == pytest.approx(sum(f) / 2, rel=1e-12)
    assert float(pt["friction_std"]) == pytest.approx(abs(f[0] - f[1]) / math.sqrt(2), rel=1e-9)
    capsys.readouterr()
    # the same call again: nothing is run again, the numbers are the same
    assert main(["calibrate", str(d), "--mu", "0.5", "--replicas", "2", "--out", str(out), "--threads", "1"]) == 0
    assert capsys.readouterr().out.count("reused") == 2
    assert [float(r["friction"]) for r in _rows(out / "runs.csv")] == f


def test_wall_friction_sweep(write_case, tmp_path, one_numba_thread):
    d = write_case(CASE.format(clump="none", variant="bulk", n=200), name="calw")
    out = tmp_path / "wall"
    assert main(["calibrate", str(d), "--mu-wall", "0.1,0.5", "--mu-r", "0", "--rotation", "free,locked",
                 "--out", str(out), "--threads", "1"]) == 0
    rows = _rows(out / "calibration.csv")
    f = {(r["rotation"], float(r["x"])): float(r["friction"]) for r in rows}
    # free spheres roll on the plate: the wall friction stays below the plate's contact friction
    # (0.092 and 0.070 in this 2 mm shear of 160 spheres: rolling, not the plate, sets it)
    assert 0.0 < f["free", 0.1] < 0.1 and 0.0 < f["free", 0.5] < 0.5
    # locked spheres can only slide: the wall friction is the plate's contact friction, less the
    # share of the load the ring's wall carries (0.0997 and 0.446 measured)
    assert 0.9 * 0.1 < f["locked", 0.1] <= 1.02 * 0.1
    assert 0.85 * 0.5 < f["locked", 0.5] <= 1.02 * 0.5
    assert "wall friction against `shear.plate.mu`" in (out / "calibration.md").read_text()


def test_an_interrupted_run_stops_the_sweep(write_case, tmp_path, monkeypatch, capsys):
    """Ctrl-C (or SIGTERM) ends the current run as 'interrupted'; the sweep must stop there, not
    go on to the next point."""
    import cfddem.simulation as simulation

    class Summary:
        status = "interrupted"

    calls = []
    monkeypatch.setattr(simulation.Simulation, "run", lambda self: calls.append(1) or Summary())
    d = write_case(CASE.format(clump="none", variant="bulk", n=330), name="cal")
    rc = main(["calibrate", str(d), "--mu", "0.1,0.3,0.6", "--out", str(tmp_path / "o")])
    assert rc == 130 and len(calls) == 1
    assert "the sweep stops here" in capsys.readouterr().out
    assert len(_rows(tmp_path / "o" / "runs.csv")) == 1


def test_points_mean_and_std():
    rows = [dict(label="a", rotation="free", mu_r=0.0, x=0.2, friction=v, rise=0.1, shear_force=1.0, normal_force=2.0,
                 load_error=0.0, solid_fraction=0.58, wall_s=1.0) for v in (0.3, 0.4, math.nan)]
    rows += [dict(rows[0], x=1.0, friction=v) for v in (13.8, 14.6)]
    p, q = points(rows)
    assert p["n"] == 2 and p["friction"] == pytest.approx(0.35) and p["friction_std"] == pytest.approx(0.0707107)
    assert p["wall_s"] == 3.0 and p["rise"] == pytest.approx(0.1) and not p["jammed"]
    assert p["solid_fraction"] == pytest.approx(0.58)
    assert q["jammed"]  # a shear force 14 times the normal load is no friction of the sample


def test_window_rise():
    d = np.linspace(0.0, 0.006, 61)
    n = np.full(61, 11.0)  # normal force + weight above
    w = (0.003, 0.006)
    assert window_rise(d, np.full(61, 5.5), n, w) == 0.0
    # a shear force still growing in proportion to the travel (a jammed sample): the 31 samples
    # from 3 to 6 mm split 15 / 16, the halves' means 3.7 and 5.25 (x 1/11), the whole 4.5
    assert window_rise(d, 1000.0 * d, n, w) == pytest.approx((5.25 - 3.7) / 4.5, rel=1e-9)
    assert math.isnan(window_rise(d, np.full(61, 5.5), n, (0.0031, 0.0033)))


def test_interpolate_target():
    assert interpolate_target([0.2, 0.4, 0.6], [0.3, 0.5, 0.6], 0.4) == pytest.approx(0.3)
    assert interpolate_target([0.6, 0.2], [0.6, 0.3], 0.45) == pytest.approx(0.4)
    assert math.isnan(interpolate_target([0.2, 0.4], [0.3, 0.5], 0.9))


def test_calibrate_bad_input(write_case, tmp_path, capsys):
    d = write_case(CASE.format(clump="none", variant="bulk", n=330), name="cal")
    assert main(["calibrate", str(d), "--mu", "0.1,x", "--out", str(tmp_path / "o")]) == 2
    box = write_case("[geometry]\ntype = 'box'\n", name="box")
    assert main(["calibrate", str(box), "--mu", "0.1", "--out", str(tmp_path / "o2")]) == 2
    assert main(["calibrate", str(d), "--mu", "0.1", "--mu-wall", "0.2", "--out", str(tmp_path / "o3")]) == 2
    assert main(["calibrate", str(d), "--mu", "0.1", "--rotation", "fixed", "--out", str(tmp_path / "o4")]) == 2
    assert main(["calibrate", str(d), "--mu", "0.1", "--replicas", "0", "--out", str(tmp_path / "o5")]) == 2
    err = capsys.readouterr().err
    assert "--mu" in err and "geometry.type" in err and "--rotation" in err and "--replicas" in err
    assert not any((tmp_path / f"o{k}").exists() for k in ("", "2", "3", "4", "5"))
