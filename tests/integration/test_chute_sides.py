"""The chute's sides as the reference study names them (issue #20): with positive rpm
(counter-clockwise seen from above) the beads pile on the RIGHT side seen in the direction of
flow, the x = 0 side, whose wall then carries the friction; negative rpm mirrors it.

A small rotating run: the chute_16rpm case without gas, 0.3 m long, fed at 0.3 kg/s through a
10 mm sluice (about 2,800 particles), dt = 5e-5 s (t_c/12), 0.4 s with the averages from 0.2 s.
Measured (this setup): time-averaged bed height over the sensors at -0.06 < z < 0.15 m: right
7.0 mm, centre 3.4 mm, left 2.1 mm; solid in the right half 2.3 times that in the left at z = 0;
the right wall's streamwise friction -25 mN over the budget bins, the left wall's 0.
"""

import numpy as np
import pytest

from cfddem.config import load_case
from cfddem.io.results import read_measurements
from cfddem.simulation import Simulation

CASE = __import__("pathlib").Path(__file__).resolve().parents[2] / "cases" / "chute_16rpm"


def _run(rpm, out):
    ov = {"frame.rpm": rpm, "gas.enabled": False, "study.compare_without_gas": False, "output.vtk": False,
          "geometry.length": 0.3, "inlet.mass_rate": 0.3, "inlet.height": 0.01, "time.dt": 5e-5,
          "time.end_time": 0.4, "measurements.start_time": 0.2, "measurements.interval": 0.005,
          "measurements.stations": [0.0, 0.1], "output.snapshot_interval": 1.0, "output.series_interval": 0.05}
    sim = Simulation(load_case(CASE, overrides=ov), out, echo=False, progress=False, threads=1)
    assert sim.run().status == "done"
    m = read_measurements(out / "results.h5", with_attrs=True)
    c, b = m["chute"], m["momentum_budget"]
    assert c["@attrs"]["sensor_names"] == "right,centre,left"
    assert c["@attrs"]["sides"].endswith("right = the x = 0 side")
    z = c["sensor_z"]
    sel = (z > -0.06) & (z < 0.15)
    bed = dict(zip(("right", "centre", "left"), 1e3 * c["bed_height_sensor"][:, sel].mean(axis=1)))
    solid = {s: float(np.nansum(c[f"profile_{s}_half_phi"][0])) for s in ("right", "left")}
    wall = {s: float(np.sum(b[f"wall_{s}"])) for s in ("right", "left")}
    return bed, solid, wall


def test_positive_rpm_piles_the_beads_on_the_right_and_negative_on_the_left(tmp_path):
    bed, solid, wall = _run(16.0, tmp_path / "p16")
    assert bed["right"] - bed["left"] > 3.0, bed  # mm; measured 4.9
    assert bed["right"] > bed["centre"] > bed["left"], bed
    assert solid["right"] > 1.8 * solid["left"], solid  # measured 2.3
    assert wall["right"] < -0.01 and abs(wall["left"]) < 0.1 * abs(wall["right"]), wall  # N, along z
    mbed, msolid, mwall = _run(-16.0, tmp_path / "m16")
    assert mbed["left"] - mbed["right"] > 3.0, mbed
    assert mbed["left"] > mbed["centre"] > mbed["right"], mbed
    assert msolid["left"] > 1.8 * msolid["right"], msolid
    assert mwall["left"] < -0.01 and abs(mwall["right"]) < 0.1 * abs(mwall["left"]), mwall
    # the mirror image: the sides swap, the sizes stay (the sensors are symmetric about the centre
    # line but for the centre one, 5 mm off it)
    assert mbed["left"] == pytest.approx(bed["right"], abs=0.5) and mbed["right"] == pytest.approx(bed["left"], abs=0.5)
