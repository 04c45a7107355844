"""Stability maps against their analytic limits (docs/stability.md): the velocity-Verlet limit
of an undamped linear contact, the forward-Euler limit of explicit drag, and a three-setting
map through the command line that names the cause of a known unstable setting."""

import csv
import math

import numpy as np
import pytest

from cfddem import stability as st
from cfddem.cli import main

pytestmark = pytest.mark.usefixtures("one_numba_thread")


def test_undamped_contact_map_at_the_verlet_limit(root, tmp_path):
    """cases/contact_verlet (one bead on an undamped wall contact): the boundary of the
    dt/t_c map lies within one grid step of dt = 2 t_c / pi (omega dt = 2), for two stiffnesses;
    every setting below it is stable, every one above it unstable."""
    grid = [round(float(v), 4) for v in np.geomspace(0.1, 1.0, 9)]  # steps of 1.33x
    variants = [{"dt/t_c": r, "contact.particle_wall.k_n": k} for r in grid for k in (1000.0, 10000.0)]
    res = st.run_case_map(root / "cases" / "contact_verlet", variants, tmp_path, x="dt/t_c",
                          y="contact.particle_wall.k_n", echo=None)
    assert len(res["limits"]) == 2
    limit = 2.0 / math.pi
    for lim in res["limits"]:
        assert lim["last_stable"] < limit < lim["first_unstable"], lim
        assert grid.index(lim["first_unstable"]) == grid.index(lim["last_stable"]) + 1  # one grid step
        assert not lim["stable_above"]
    # the analytic line drawn is the same limit (the tangential mode is undamped too)
    assert res["lines"][0]["x"] == pytest.approx(limit, rel=1e-12)
    for p in res["points"]:
        assert p["stable"] is (p["values"]["dt/t_c"] < limit), p
    assert (tmp_path / "stability.png").stat().st_size > 10_000


def test_explicit_drag_map_at_the_forward_euler_limit():
    """One particle relaxing in a uniform gas, dt_g/tau from 0.1 to 100 (8 per decade), 3 mm
    and 0.1 mm glass: explicit drag turns unstable within one grid step of dt_g = 2 tau (energy
    growth: the slip grows by |1 - dt_g/tau| per interval); implicit drag is stable everywhere."""
    ratios = np.geomspace(0.1, 100.0, 25)
    res = st.drag_map(diameters=(3e-3, 1e-4), ratios=ratios)
    lims = {(lim["panel"], lim["y"]): lim for lim in res["limits"]}
    assert len(lims) == 4
    for d in (3.0, 0.1):
        ex = lims[("explicit", d)]
        assert ex["last_stable"] < 2.0 < ex["first_unstable"], ex
        assert ex["first_unstable"] / ex["last_stable"] == pytest.approx(10 ** 0.125, rel=1e-9)  # one step
        assert ex["cause"] == st.ENERGY and not ex["stable_above"]
        im = lims[("implicit", d)]
        assert im["first_unstable"] is None and im["last_stable"] == pytest.approx(100.0)
    # exact relaxation: the implicit slip after 40 intervals is exp(-40 dt_g/tau) down (to the
    # level the gas's own motion leaves), forward Euler's at dt_g = tau is zero after one
    by = {(p["values"]["drag"], p["values"]["d [mm]"], round(p["values"]["dt_g/tau"], 6)): p for p in res["points"]}
    assert by[("implicit", 3.0, 0.1)]["numbers"]["slip_ratio_end"] == pytest.approx(math.exp(-4.0), rel=0.02)
    assert by[("explicit", 0.1, 1.0)]["numbers"]["slip_ratio_end"] < 1e-6


def test_three_setting_map_names_the_cause(root, tmp_path, capsys):
    """Three time steps of the undamped contact through `cfddem stability`: t_c/20 and 0.3 t_c
    stable, 3 t_c unstable, stopped by the engine's overlap check (overlap > 0.5 R)."""
    rc = main(["stability", str(root / "cases" / "contact_verlet"), "--vary", "dt/t_c=0.05,0.3,3.0",
               "--out", str(tmp_path)])
    assert rc == 0
    out = capsys.readouterr().out
    assert "last stable dt/t_c = 0.3, first unstable 3 (overlap)" in out
    rows = {r["dt/t_c"]: r for r in csv.DictReader((tmp_path / "stability.csv").open())}
    assert rows["0.05"]["stable"] == "true" and rows["0.3"]["stable"] == "true"
    assert rows["3.0"]["stable"] == "false" and rows["3.0"]["cause"] == st.OVERLAP
    assert "overlap/radius" in rows["3.0"]["detail"]
    assert float(rows["0.05"]["energy_ratio"]) < 1.0
    for f in ("stability.png", "stability.json", "stability.md"):
        assert (tmp_path / f).is_file()
