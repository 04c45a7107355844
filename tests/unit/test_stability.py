"""cfddem.stability: the classifier, the energy-growth checks, the Verlet limit of one
contact, the limits found on a grid, the map files and the command's bad input."""

import json
import math

import numpy as np
import pytest

from cfddem import stability as st
from cfddem.cli import main
from cfddem.errors import CaseError

# messages as the code writes them (particles/system.py, simulation.py, coupling/exchange.py)
MESSAGES = {
    st.NAN: "step 120: particle id 3 has a non-finite position, velocity or spin; likely cause: time step too large "
            "for this stiffness: dt = 12 t_c/20",
    st.OVERLAP: "step 487: a contact reached overlap/radius = 0.505 > 0.5; likely cause: time step too large for "
                "this stiffness: dt = 10 t_c/20 (or particles inserted into each other / too fast)",
    st.WALL: "step 40, t = 0.0004 s: particle 7 went through wall 'floor' since step 30 (now 1.2 mm behind it, "
             "speed 3 m/s); likely cause: time step too large for this stiffness and speed",
    st.COURANT: "gas CFL number 1.3 above 1 at t = 0.2 s (gas step 0.001 s, stable step 0.0004 s): the gas step is "
                "too large for this flow; lower gas.coupling_interval (cfddem check recommends one)",
    st.DEFECT: "gas mass balance defect 0.002 above 0.0001 at t = 0.1 s: the pressure solve no longer enforces "
               "continuity (porosity changing too fast for the gas step; lower gas.coupling_interval)",
    st.POROSITY: "porosity -0.2 <= 0 in gas cell (1, 2, 3) at t = 0.1 s: more particle volume than the cell holds "
                 "(2 cells); use larger gas cells (about 3 particle diameters or more) or set an eps_floor",
    st.GAS: "gas step failed at t = 0.1 s: pressure solve did not converge in 200 iterations",
}


@pytest.mark.parametrize("cause", list(MESSAGES))
def test_classify_failed_runs_by_message(cause):
    oc = st.classify("failed", MESSAGES[cause])
    assert oc.stable is False and oc.cause == cause and oc.detail == MESSAGES[cause]
    assert oc.label == f"unstable: {cause}"


def test_classify_gas_nan_is_nan_and_flags_win():
    msg = "gas step failed at t = 0.3 s: non-finite gas u = nan at fcc index (1, 2, 3) (x, y, z = 0, 0, 0)"
    assert st.classify("failed", msg).cause == st.NAN
    assert st.classify("failed", "anything", flag="overlap").cause == st.OVERLAP
    assert st.classify("failed", MESSAGES[st.COURANT], flag="gas").cause == st.COURANT  # "gas": by message
    assert st.classify("failed", "neighbour list could not grow").cause == st.OTHER


def test_classify_finished_and_undecided_runs():
    assert st.classify("done").stable is True
    assert st.classify("skipped", growth=0.99).stable is True
    oc = st.classify("done", growth=1.01, growth_detail="KE 12 J/kg")
    assert oc.stable is False and oc.cause == st.ENERGY and oc.detail == "KE 12 J/kg"
    for status in ("stopped", "interrupted", "bad input"):
        oc = st.classify(status, "wall-time limit reached")
        assert oc.stable is None and oc.label == "undecided"


def test_classify_real_engine_failure():
    """A real StepStatus (two spheres overlapping by 0.6 R): the message alone gives the cause
    its flag names."""
    from cfddem.particles.contact import LinearContact
    from cfddem.particles.system import ParticleSystem

    sys_ = ParticleSystem(pp=LinearContact(k_n=1000.0, e_n=1.0, e_t=1.0, mu=0.3), walls=[], dt=1e-5)
    sys_.add_particles(np.array([[0.0, 0.0, 0.0], [0.0021, 0.0, 0.0]]), np.zeros((2, 3)), 0.0015, 2500.0)
    s = sys_.step(5)
    assert not s.ok and s.flag == "overlap"
    assert st.classify("failed", s.message).cause == st.classify("failed", "", flag=s.flag).cause


def test_energy_checks():
    # closed: gain against 1 % of m g d (+ 1 % of the initial energy)
    m, g, d = 2.0, 9.81, 0.003
    scale = 0.01 * (m * g * d + 5.0)
    assert st.closed_energy_growth([5.0, 4.0, 5.0 + 0.5 * scale], m, g, d) == pytest.approx(0.5)
    assert st.closed_energy_growth([5.0, 5.0 + 2 * scale], m, g, d) == pytest.approx(2.0)
    assert st.closed_energy_growth([5.0, np.nan], m, g, d) == math.inf
    assert st.closed_energy_growth([5.0], m, g, d) == 0.0
    # open: max KE/M over 10 x the budget, NaN rows ignored
    assert st.runaway_growth([0.0, np.nan, 30.0, 12.0], 2.0) == pytest.approx(1.5)
    # decaying quantity: largest later value over 10 x the first
    assert st.ratio_growth([1.0, 0.5, 3.0]) == pytest.approx(0.3)
    assert st.ratio_growth([1.0, np.inf]) == math.inf


def _verlet_amplification(h, zeta, n=4000):
    """Largest |x| over n steps of the engine's scheme on x'' = -w^2 x - 2 zeta w x' (w = 1):
    v_half = v + dt/2 a; x += dt v_half; a = -x - 2 zeta v_half; v = v_half + dt/2 a."""
    x, v, a, big = 1.0, 0.0, -1.0, 1.0
    for _ in range(n):
        vh = v + 0.5 * h * a
        x += h * vh
        a = -x - 2.0 * zeta * vh
        v = vh + 0.5 * h * a
        big = max(big, abs(x))
        if big > 1e6:
            break
    return big


@pytest.mark.parametrize("zeta", [0.0, 0.2155, 0.9])
def test_verlet_step_limit_matches_the_scheme(zeta):
    h = st.verlet_step_limit(zeta)
    assert _verlet_amplification(0.98 * h, zeta) < 50.0
    assert _verlet_amplification(1.02 * h, zeta) > 1e6


def test_verlet_limit_values():
    assert st.verlet_limit(1.0) == pytest.approx(2.0 / math.pi, rel=1e-12)
    assert st.verlet_limit(0.5) == pytest.approx(0.50199, rel=1e-4)
    assert st.verlet_limit(1e-4) == pytest.approx(0.08846, rel=1e-3)


def _pt(x, y, stable, cause=""):
    return {"values": {"x": x, "y": y}, "stable": stable, "cause": cause, "detail": ""}


def test_find_limits_and_map_files(tmp_path):
    pts = [_pt(0.1, 1.0, True), _pt(0.2, 1.0, True), _pt(0.4, 1.0, False, st.NAN), _pt(0.8, 1.0, False, st.NAN),
           _pt(0.1, 10.0, True), _pt(0.2, 10.0, False, st.OVERLAP), _pt(0.4, 10.0, True), _pt(0.8, 10.0, None),
           _pt(0.1, 100.0, False, st.WALL), _pt(0.2, 100.0, False, st.WALL)]
    res = st.make_result(pts, "x", "y", title="test map", own={"x": 0.3, "y": 10.0},
                         lines=[{"x": 0.5, "kind": "analytic", "label": "limit"},
                                {"xy": [[0.1, 1.0], [0.3, 100.0]], "kind": "rule", "label": "rule"}])
    lim = {r["y"]: r for r in res["limits"]}
    assert lim[1.0]["last_stable"] == 0.2 and lim[1.0]["first_unstable"] == 0.4 and lim[1.0]["cause"] == st.NAN
    assert lim[1.0]["estimate"] == pytest.approx(math.sqrt(0.08)) and not lim[1.0]["stable_above"]
    assert lim[10.0]["first_unstable"] == 0.2 and lim[10.0]["stable_above"]
    assert lim[100.0]["last_stable"] is None and lim[100.0]["estimate"] is None
    files = st.write_map(res, tmp_path)
    assert files["png"].stat().st_size > 10_000
    rows = files["csv"].read_text().splitlines()
    assert rows[0].startswith("name,x,y,stable,cause") and len(rows) == 11
    assert json.loads(files["json"].read_text())["limits"][0]["first_unstable"] == 0.4
    md = files["md"].read_text()
    assert "| 1 | 0.2 | 0.4 | NaN | 0.2828 |" in md and "(stable again above)" in md


def test_categorical_axes_and_panels(tmp_path):
    pts = [{"values": {"C": c, "scheme": s, "re": r}, "stable": c < lim, "cause": "" if c < lim else st.ENERGY,
            "detail": ""} for s, lim in (("central", 0.3), ("tvd", 0.7)) for r in ("low", "high")
           for c in (0.1, 0.5, 1.0)]
    res = st.make_result(pts, "C", "re", "scheme", lines=[{"x": 0.5, "kind": "rule", "label": "r", "panel": "tvd"}])
    assert {(r["panel"], r["y"]): r["first_unstable"] for r in res["limits"]} == {
        ("central", "low"): 0.5, ("central", "high"): 0.5, ("tvd", "low"): 1.0, ("tvd", "high"): 1.0}
    assert st.draw_map(res, tmp_path / "m.png").stat().st_size > 10_000


def test_cli_bad_input(capsys, root):
    assert main(["stability"]) == 2
    assert "CASE" in capsys.readouterr().err
    assert main(["stability", str(root / "cases" / "box_small")]) == 2
    assert "--vary" in capsys.readouterr().err
    assert main(["stability", "--map", "drag", str(root / "cases" / "box_small")]) == 2
    assert main(["stability", str(root / "cases" / "box_small"), "--vary", "dt/t_c=0.1", "--y", "nope"]) == 2
    assert "not a varied key" in capsys.readouterr().err


def test_resolve_variant_sets_dt_from_the_collision_time(root):
    from cfddem.config import load_case
    from cfddem.simulation import collision_time

    case_arg = str(root / "cases" / "contact_verlet" / "case.toml")
    ov = st.resolve_variant(case_arg, {"dt/t_c": 0.25, "contact.particle_wall.k_n": 4000.0}, {})
    case = load_case(case_arg, overrides=ov)
    assert case.time.dt == pytest.approx(0.25 * collision_time(case), rel=1e-12)
    assert case.time.force and case.output.snapshot_interval == case.output.series_interval  # closed: energy
    with pytest.raises(CaseError, match="dt/t_c"):
        st.resolve_variant(case_arg, {"dt/t_c": -1.0}, {})
    assert st.own_setting(load_case(case_arg), "dt/t_c") == pytest.approx(1e-5 / collision_time(load_case(case_arg)))
    assert st.own_setting(load_case(case_arg), "contact.particle_wall.k_n") == 1000.0


def test_tied_keys_make_no_panel(root, tmp_path, monkeypatch):
    """Keys varied together (a --variants file setting both stiffnesses) are one axis, not
    panels: only a key that still varies at a fixed (x, y) splits the map."""
    calls = []

    def fake_run(case_arg, ov, out_dir, threads):
        calls.append(ov)
        return {"status": "failed", "error": "run failed: step 3: particle id 1 has a non-finite position"}

    monkeypatch.setattr("cfddem.sweep.run_variant", fake_run)
    variants = [{"contact.particle_particle.k_n": k, "contact.particle_wall.k_n": k, "dt/t_c": r}
                for k in (1000.0, 2000.0) for r in (0.1, 0.2)]
    res = st.run_case_map(root / "cases" / "contact_verlet", variants, tmp_path, x="dt/t_c",
                          y="contact.particle_particle.k_n", echo=None)
    assert res["panel"] is None and len(calls) == 4 and all(ov["time.force"] for ov in calls)
    assert {p["cause"] for p in res["points"]} == {st.NAN}


def test_the_limits_check_uses_are_the_committed_maps(root):
    """DT_MAPS and COURANT_TVD (what cfddem check reports) are the numbers of the maps in
    docs/stability/, and every time-step map's boundary lies within one grid step of the
    one-contact Verlet limit (or, for the Hertz-Mindlin chute, above it: conservative)."""
    for name, (lim, lo, hi) in st.DT_MAPS.items():
        res = json.loads((root / "docs" / "stability" / name / "stability.json").read_text())
        assert res["lines"][0]["kind"] == "analytic" and res["lines"][0]["x"] == pytest.approx(lim, rel=1e-3)
        assert {(r["last_stable"], r["first_unstable"]) for r in res["limits"]} == {(lo, hi)}
        assert lo < lim < hi or (name == "chute_hm" and lim < lo)
    res = json.loads((root / "docs" / "stability" / "courant" / "stability.json").read_text())
    tvd = {r["y"]: (r["last_stable"], r["first_unstable"]) for r in res["limits"] if r["panel"] == "tvd"}
    assert set(tvd) == set(st.COURANT_TVD)
    for re_h, (a, b) in st.COURANT_TVD.items():
        assert tvd[re_h] == (pytest.approx(a, rel=1e-3), pytest.approx(b, rel=1e-3))
        assert st.courant_limit(re_h) == (pytest.approx(a), pytest.approx(b))
    assert st.courant_limit(1e5) == pytest.approx(st.courant_limit(1000.0))  # beyond the map: its end row
    assert st.courant_limit(31.6)[0] == pytest.approx(math.sqrt(0.5448 * 0.3873), rel=1e-3)  # log-log middle


def test_check_predicts_the_failure(root, capsys):
    """cfddem check names the predicted failure, the limit and its source; a step above the
    one-contact limit of the thesis's Hertz-Mindlin shear cell (0.087 t_c, where the map's runs
    fail) is refused although it is below t_c/5."""
    from cfddem.config import load_case
    from cfddem.simulation import check_time_step, collision_time, describe_case

    thesis = ["contact.model=\"hertz_mindlin\"", "particles.density=950.0", "contact.particle_particle.nu=0.4",
              "contact.particle_wall.nu=0.4", "contact.particle_particle.e=1e-4", "contact.particle_wall.e=1e-4"]
    case = load_case(root / "cases" / "shear_jenike", overrides=thesis)
    pred = st.predicted_step_limit(case)
    tc = collision_time(case)
    assert pred["ratio"] == pytest.approx(0.0870, rel=2e-3) and pred["cause"] == st.OVERLAP
    assert "tangential" in pred["where"] and "docs/stability.md" in pred["source"]
    dt_bad = 0.1 * tc  # unstable on the map, between t_c/20 and t_c/5
    with pytest.raises(CaseError, match=r"the run would fail \(overlap\)") as ei:
        check_time_step(load_case(root / "cases" / "shear_jenike", overrides=thesis + [f"time.dt={dt_bad!r}"]))
    assert ei.value.key == "time.dt"
    assert check_time_step(load_case(root / "cases" / "shear_jenike",
                                     overrides=thesis + [f"time.dt={0.07 * tc!r}"])) == pytest.approx(0.07)
    states = {}
    for r in (0.05, 0.07, 0.1):
        text = "\n".join(describe_case(load_case(root / "cases" / "shear_jenike",
                                                 overrides=thesis + [f"time.dt={r * tc!r}", "time.force=true"])))
        states[r] = text.split("stable step: ")[1].split("(")[1].split(")")[0]
    assert states == {0.05: "OK", 0.07: "WARNING: within a grid step of the maps' failures",
                      0.1: "REFUSED: the run would fail, overlap"}
    assert st.STABLE_FRACTION == pytest.approx(0.35 / 0.502, rel=1e-3)
    assert main(["check", str(root / "cases" / "shear_jenike"), *[a for o in thesis for a in ("--set", o)],
                 "--set", f"time.dt={dt_bad!r}"]) == 2
    out, err = capsys.readouterr()
    assert "stable step: " in out and "REFUSED: the run would fail, overlap" in out
    assert "the run would fail (overlap)" in err
