"""cfddem calibrate: a two-point sweep of the small shear cell through the CLI (table, CSV, PNG),
bulk friction rising with particle friction; target interpolation; bad input."""

import csv
import math

import pytest

from cfddem.calibrate import interpolate_target
from cfddem.cli import main

from .test_shear_cell import CASE


def test_calibrate_sweep_writes_table_and_plot(write_case, tmp_path, one_numba_thread):
    d = write_case(CASE.format(clump="none", variant="bulk", n=330), name="cal")
    out = tmp_path / "cal_out"
    rc = main(["calibrate", str(d), "--mu", "0.1,0.6", "--out", str(out), "--target", "0.3", "--threads", "1"])
    assert rc == 0
    rows = list(csv.DictReader(open(out / "calibration.csv")))
    assert [float(r["mu"]) for r in rows] == [0.1, 0.6]
    f = [float(r["friction"]) for r in rows]
    assert all(math.isfinite(x) for x in f)
    assert f[1] > f[0] + 0.05  # more particle friction, more bulk friction
    assert all(abs(float(r["load_error"])) < 0.01 for r in rows)
    assert (out / "calibration.png").stat().st_size > 5000
    md = (out / "calibration.md").read_text()
    assert "| 0.1 | 0 |" in md and "Target bulk friction 0.3" in md


def test_interpolate_target():
    assert interpolate_target([0.2, 0.4, 0.6], [0.3, 0.5, 0.6], 0.4) == pytest.approx(0.3)
    assert interpolate_target([0.6, 0.2], [0.6, 0.3], 0.45) == pytest.approx(0.4)
    assert math.isnan(interpolate_target([0.2, 0.4], [0.3, 0.5], 0.9))


def test_calibrate_bad_input(write_case, tmp_path, capsys):
    d = write_case(CASE.format(clump="none", variant="bulk", n=330), name="cal")
    assert main(["calibrate", str(d), "--mu", "0.1,x", "--out", str(tmp_path / "o")]) == 2
    box = write_case("[geometry]\ntype = 'box'\n", name="box")
    assert main(["calibrate", str(box), "--mu", "0.1", "--out", str(tmp_path / "o2")]) == 2
    err = capsys.readouterr().err
    assert "--mu" in err and "geometry.type" in err
