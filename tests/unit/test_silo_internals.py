"""The multi-flow blender's internals (cfddem/scenes/silo_internals.py): the inserts reproduce the
thesis's area ratios, the tube's inlet height, no overlap with the hopper, the contact of a plate,
one-line case errors, the channel-velocity measurement and a short conserving run."""

import math

import numpy as np
import pytest

from cfddem.config import load_case
from cfddem.errors import CaseError
from cfddem.measure.silo import VelocityField, centreline_speeds, channel_velocities
from cfddem.scenes.common import wall_specs
from cfddem.scenes.silo_internals import INSERT_RATIOS

from ..conftest import CASES

SMALL = CASES / "blender_multiflow_small"
FULL = CASES / "blender_multiflow"


def ends(w):
    """The two in-plane (x, y) end points of a depth-spanning rectangle, lower one first."""
    a = w.point - w.half_extents[0] * w.u_axis
    b = w.point + w.half_extents[0] * w.u_axis
    return (a[:2], b[:2]) if a[1] <= b[1] else (b[:2], a[:2])


def case_of(path, **silo):
    return load_case(path, overrides={f"silo.{k}": v for k, v in silo.items()})


@pytest.mark.parametrize("path", [FULL, SMALL])
@pytest.mark.parametrize("insert", list(INSERT_RATIOS))
def test_insert_reproduces_the_table_ratios(path, insert):
    case = case_of(path, insert=insert, tube=True)
    s = case.resolved["silo"]
    W, b = s["width"], s["outlet_width"]
    a = math.radians(s["hopper_angle_deg"])
    th = math.pi / 2 - a
    xc, yA = W / 2, -b / 2 * math.tan(a)
    Rt = W / 2 / math.sin(th)
    walls = {w.name: w for w in wall_specs(case)}
    Eo, Ei = ends(walls["insert_right_outer"])
    Io, Ii = ends(walls["insert_right_inner"])
    apex = np.array([xc, yA])
    # the insert's inlet (both upper corners) lies on the arc through the transition
    assert np.linalg.norm(Ei - apex) == pytest.approx(Rt, rel=1e-12)
    assert np.linalg.norm(Ii - apex) == pytest.approx(Rt, rel=1e-12)
    # its outlet level with the tube's outlet
    tb = walls["tube_right_bottom"].point[1]
    assert Eo[1] == pytest.approx(tb, abs=1e-12) and Io[1] == pytest.approx(tb, abs=1e-12)
    c = walls["tube_right_outer"].point[0] - xc  # the tube's outer face
    psi = lambda p: math.atan2(p[0] - xc, p[1] - yA)  # noqa: E731
    ext_in = Rt * (th - psi(Ei))
    ext_out = (tb - yA) * math.tan(th) - (Eo[0] - xc)
    int_in = Rt * (psi(Ii) - math.asin(c / Rt))
    int_out = Io[0] - xc - c
    A_i, A_e, A_r = INSERT_RATIOS[insert]
    assert int_in / int_out == pytest.approx(A_i, rel=1e-9)
    assert ext_in / ext_out == pytest.approx(A_e, rel=1e-9)
    assert (ext_in / ext_out) / (int_in / int_out) == pytest.approx(A_r, rel=0.01)  # the table's rounding
    # a plate of the chosen thickness: its faces parallel, t apart
    t = s["insert_thickness"]
    n = walls["insert_right_outer"].normal[:2]
    assert abs(np.dot(walls["insert_right_inner"].normal[:2], n)) == pytest.approx(1.0, abs=1e-12)
    assert np.dot(Ei - Ii, n) == pytest.approx(t, rel=1e-9) and np.dot(Eo - Io, n) == pytest.approx(t, rel=1e-9)
    # the left plate mirrors the right one
    Lo, Li = ends(walls["insert_left_outer"])
    np.testing.assert_allclose([W - Lo[0], Lo[1], W - Li[0], Li[1]], [*Eo, *Ei], atol=1e-12)


@pytest.mark.parametrize("path", [FULL, SMALL])
def test_tube_inlet_is_15_percent_of_the_width_above_the_transition(path):
    case = case_of(path)
    s = case.resolved["silo"]
    walls = {w.name: w for w in wall_specs(case)}
    y_h = (s["width"] - s["outlet_width"]) / 2 * math.tan(math.radians(s["hopper_angle_deg"]))
    for side in ("left", "right"):
        assert walls[f"tube_{side}_top"].point[1] - y_h == pytest.approx(0.15 * s["width"], rel=1e-12)
    # clear width: the outlet's
    gap = walls["tube_right_inner"].point[0] - walls["tube_left_inner"].point[0]
    assert gap == pytest.approx(s["outlet_width"], rel=1e-12)


@pytest.mark.parametrize("insert", list(INSERT_RATIOS))
def test_internals_keep_clear_of_the_hopper_and_side_walls(insert):
    """Every corner of the internals lies inside the silo, more than 3 pellet lengths from the
    hopper planes and the side walls (the narrowest channel the scene accepts)."""
    case = case_of(SMALL, insert=insert)
    s = case.resolved["silo"]
    W, b = s["width"], s["outlet_width"]
    a = math.radians(s["hopper_angle_deg"])
    walls = wall_specs(case)
    d_site = 1.25 * case.particles.diameter  # the thesis pellet's bounding diameter
    for w in walls:
        if not w.name.startswith(("insert", "tube")):
            continue
        for p in ends(w):
            for sgn, edge in ((1.0, W / 2 - b / 2), (-1.0, W / 2 + b / 2)):
                n = np.array([sgn * math.sin(a), math.cos(a)])  # hopper normals (towards the particles)
                dist = np.dot(p - np.array([edge, 0.0]), n)
                assert dist > 3 * d_site * math.cos(math.pi / 2 - a) - 1e-12, (w.name, p)
            assert 3 * d_site < p[0] < W - 3 * d_site


@pytest.mark.parametrize("face, sign", [("outer", 1.0), ("inner", -1.0), ("top", 0.0), ("bottom", 0.0)])
def test_a_sphere_against_an_insert_plate_is_pushed_out_along_the_face_normal(face, sign, one_numba_thread):
    from cfddem.particles.system import ParticleSystem
    from cfddem.simulation import contact_law, engine_wall

    case = case_of(SMALL, insert="converging")
    specs = wall_specs(case)
    w = {x.name: x for x in specs}[f"insert_right_{face}"]
    n = w.normal / np.linalg.norm(w.normal)
    if sign:  # the outer face looks towards the right hopper wall (+x), the inner one towards the tube
        assert np.sign(n[0]) == sign
    elif face == "top":
        assert n[1] > 0.9
    else:
        assert n[1] == pytest.approx(-1.0)
    sys_ = ParticleSystem(pp=contact_law(case.resolved["contact"]["particle_particle"]),
                          walls=[engine_wall(x) for x in specs], dt=1e-6, gravity=(0.0, 0.0, 0.0))
    r = 0.5 * case.particles.diameter
    sys_.add_particles(np.array([w.point + 0.9 * r * n]), np.zeros(3), r, 950.0)
    assert sys_.step(1).ok
    v = sys_.vel[0]
    # only this face touches it (the plate's far face does not pull it through), along its normal
    np.testing.assert_allclose(v / np.linalg.norm(v), n, atol=1e-9)


@pytest.mark.parametrize("silo, key", [
    ({"insert": "straight", "hopper_angle_deg": 0.0}, "silo.insert"),
    ({"insert": "none", "tube": True, "hopper_angle_deg": 0.0}, "silo.tube"),
    ({"tube_width": 0.03}, "silo.tube_width"),
    ({"insert": "diverging", "insert_outlet_level": 0.3}, "silo.insert"),
    ({"insert": "converging", "insert_thickness": 0.012}, "silo.insert"),
    ({"insert": "cone"}, "silo.insert"),
    ({"insert_outlet_level": 1.0}, "silo.insert_outlet_level"),
    ({"internals": {"mu": -0.1}}, "silo.internals.mu"),
    ({"height": 0.13}, "silo.height"),
])
def test_bad_keys_give_one_line_errors_naming_the_key(silo, key):
    with pytest.raises(CaseError) as e:
        case_of(SMALL, **{k: v for k, v in silo.items() if k != "internals"},
                **({"internals.mu": silo["internals"]["mu"]} if "internals" in silo else {}))
    assert e.value.key == key
    assert "\n" not in str(e.value)


def test_channel_velocities_and_centreline_of_a_known_field():
    f = VelocityField(0.0, 0.1, 0.0, 0.1, 0.01)  # 10 x 10 cells
    x = f.x
    # one row (y = 0.055) : v_y = -1 in x < 0.03 and x > 0.07, -4 in 0.04 < x < 0.06; two samples
    pos = np.array([[xi, 0.055, 0.0] for xi in x] * 2)
    vy = np.where((pos[:, 0] > 0.04) & (pos[:, 0] < 0.06), -4.0, -1.0)
    vel = np.stack([np.zeros_like(vy), vy, np.zeros_like(vy)], axis=1)
    f.sample(pos, vel)
    f.sample(pos, vel)
    ch = channel_velocities(f, 5, {"outer": [(0.0, 0.03), (0.07, 0.1)], "middle": [(0.04, 0.06)]})
    assert ch["outer"]["cells"] == 6 and ch["middle"]["cells"] == 2
    assert ch["outer"]["mean_vy"] == pytest.approx(-1.0) and ch["middle"]["mean_vy"] == pytest.approx(-4.0)
    mean = (6 * -1.0 + 2 * -4.0) / 8
    assert ch["cross_section_mean_vy"] == pytest.approx(mean)
    assert ch["middle"]["relative"] == pytest.approx(-4.0 / mean) and ch["outer"]["relative"] == pytest.approx(-1 / mean)
    # the centreline speed at the row's height, NaN outside the field
    sp = centreline_speeds(f, 0.05, [0.055, 0.5])
    assert sp[0] == pytest.approx(4.0) and math.isnan(sp[1])


def test_short_reduced_run_conserves_particles(tmp_path, one_numba_thread):
    from cfddem.io.results import read_measurements, read_series
    from cfddem.simulation import Simulation

    case = case_of(SMALL, insert="converging", n_particles=240, gate="time", gate_time=0.06,
                   fit_range=[0.0, 1.0], field_start=0.0)
    case = load_case(SMALL, overrides={**case.overrides, "time.end_time": 0.16, "output.plots": False,
                                       "output.vtk_interval": 1.0, "output.snapshot_interval": 1.0})
    out = tmp_path / "bms"
    summary = Simulation(case, out, echo=False, progress=False).run()
    assert summary.status == "done"
    s = read_series(out / "results.h5")
    np.testing.assert_array_equal(s["mass_lost"], 0.0)
    np.testing.assert_array_equal(s["n_particles"] + s["discharged_count"], s["inserted_count"])
    np.testing.assert_array_equal(s["inserted_count"], 2 * s["inserted_bodies"])
    assert s["inserted_bodies"][-1] == 240
    assert s["discharged_bodies"][-1] > 0  # a real discharge through the internals
    m = read_measurements(out / "results.h5")["silo"]
    assert set(m["channels"]) >= {"exterior", "interior", "tube", "cross_section_mean_vy"}
    assert m["centreline"]["speed"].shape == (3,)
