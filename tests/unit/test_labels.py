"""Tracer labels: every particle carries an integer label that insertion sets and that
sorting, removal, periodic wraps, clumps, checkpoints, snapshots and ParaView files keep."""

import h5py
import meshio
import numpy as np
import pytest

from cfddem.config import load_case
from cfddem.errors import CaseError
from cfddem.particles import LinearContact, ParticleSystem, PlaneWall
from cfddem.particles.clumps import pellet
from cfddem.simulation import Simulation

PP = LinearContact(k_n=2000.0, e_n=0.5, e_t=0.5, mu=0.4)


def _bed(n=400, seed=3):
    """A loose random bed of 3 mm spheres in a periodic x-z box falling on a floor."""
    rng = np.random.default_rng(seed)
    floor = PlaneWall(contact=PP, point=(0, 0, 0), normal=(0, 1, 0))
    s = ParticleSystem(pp=PP, walls=[floor], dt=2e-5, gravity=(0.3, -9.81, 0.2),
                       periodic=((0.0, 0.03), None, (0.0, 0.03)))
    side = int(np.ceil(n ** (1 / 3)))
    g = np.stack(np.meshgrid(*[np.arange(side)] * 3, indexing="ij"), -1).reshape(-1, 3)[:n]
    pos = 0.0035 * g + 0.002 + rng.uniform(-2e-4, 2e-4, (n, 3))
    return s, pos


def _label_of_id(s):
    return dict(zip(s.ids.tolist(), s.label.tolist()))


def test_labels_follow_their_particles_through_sorting_removal_and_wraps():
    s, pos = _bed()
    lab = np.arange(len(pos)) % 7
    s.add_particles(pos, np.zeros(3), 0.0015, 2500.0, label=lab)
    want = {int(i): int(l) for i, l in zip(s.ids, lab)}
    s.step(3000)  # falls, wraps sideways (the box is periodic in x and z), lists rebuilt and sorted
    assert s.n_rebuilds > 3
    assert _label_of_id(s) == want
    gone = s.pos[:, 1] > np.median(s.pos[:, 1])
    k, _ = s.remove_particles(gone)
    assert k == int(gone.sum()) > 100
    assert _label_of_id(s) == {i: want[i] for i in s.ids.tolist()}
    assert np.bincount(s.label, minlength=7).sum() == s.n


def test_labels_of_clumps_set_label_and_checkpoint_round_trip():
    sh = pellet(2, 0.003, 2500.0)
    s = ParticleSystem(pp=PP, walls=[], dt=2e-5)
    s.add_clumps(sh, [[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.02, 0.0, 0.0]], label=[1, 2, 3])
    assert s.label.tolist() == [1, 1, 2, 2, 3, 3]
    # one member selected: its whole clump is relabelled
    assert s.set_label(s.ids == s.ids[2], 9) == 2
    assert s.label.tolist() == [1, 1, 9, 9, 3, 3]
    st = s.get_state()
    t = ParticleSystem(pp=PP, walls=[], dt=2e-5)
    t.set_state(st)
    assert t.label.tolist() == [1, 1, 9, 9, 3, 3]
    # a checkpoint written before labels existed reads as label 0
    del st["p_label"]
    u = ParticleSystem(pp=PP, walls=[], dt=2e-5)
    u.set_state(st)
    assert u.label.tolist() == [0] * 6


def test_bad_labels_are_refused():
    s = ParticleSystem(pp=PP, walls=[], dt=2e-5)
    with pytest.raises(CaseError, match="label"):
        s.add_particles([[0, 0, 0]], np.zeros(3), 0.001, 2500.0, label=0.5)
    s.add_particles([[0, 0, 0]], np.zeros(3), 0.001, 2500.0)
    with pytest.raises(CaseError, match="label"):
        s.set_label([True], 1.5)


def _case(tmp_path, extra=""):
    d = tmp_path / "case"
    d.mkdir()
    (d / "case.toml").write_text(f"""
[case]
name = "labels"
[time]
end_time = 0.002
dt = 1e-5
[output]
series_interval = 0.001
snapshot_interval = 0.001
vtk = true
vtk_interval = 0.001
plots = false
[geometry]
type = "none"
[gravity]
inclination_deg = 0.0
[particles]
initial_file = "p.csv"
[[particles.initial]]
pos = [0.0, 0.01, 0.0]
label = 5
{extra}
""")
    (d / "p.csv").write_text("x,y,z,radius,label\n0.01,0.01,0,0.0015,2\n0.02,0.01,0,0.0015,3\n")
    return d


def test_run_writes_labels_to_snapshots_and_paraview(tmp_path):
    d = _case(tmp_path)
    out = tmp_path / "out"
    Simulation(load_case(d), out, echo=False, progress=False).run()
    with h5py.File(out / "results.h5") as h:
        snaps = sorted(h["snapshots"])
        g = h["snapshots"][snaps[-1]]
        got = dict(zip(g["ids"][()].tolist(), g["label"][()].tolist()))
    assert sorted(got.values()) == [2, 3, 5]
    vtus = sorted((out / "vtk" / "particles").glob("*.vtu"))
    m = meshio.read(vtus[-1])
    assert sorted(m.point_data["label"].tolist()) == [2, 3, 5]


def test_bad_label_in_case_names_the_key(tmp_path):
    d = _case(tmp_path, "[[particles.initial]]\npos = [0.05, 0.01, 0.0]\nlabel = 1.5\n")
    with pytest.raises(CaseError, match=r"particles\.initial\[1\]\.label"):
        load_case(d)
    (d / "case.toml").write_text((d / "case.toml").read_text().replace("label = 1.5\n", ""))
    (d / "p.csv").write_text("x,y,z,radius,label\n0.01,0.01,0,0.0015,2.5\n")
    with pytest.raises(CaseError, match="label must be an integer"):  # checked before any run folder
        load_case(d)


# ---------------------------------------------------------------------------- velocity zones
def _column(clumps: bool):
    """Particles falling in a periodic vertical column through a feeder zone that holds v_y."""
    s = ParticleSystem(pp=PP, walls=[], dt=2e-5, gravity=(0.0, -9.81, 0.0),
                       periodic=(None, (0.0, 0.2), None))
    s.add_velocity_zone([-1, 0.0, -1], [1, 0.05, 1], 1, -0.4)
    pos = [[0.01 * k, 0.19, 0.0] for k in range(4)]
    if clumps:
        s.add_clumps(pellet(2, 0.003, 2500.0), pos, vel=[[0.0, 0.0, 0.1]] * 4, omega=[[0, 0, 30.0]] * 4)
    else:
        s.add_particles(pos, [0.0, 0.0, 0.1], 0.0015, 2500.0)
    return s


@pytest.mark.parametrize("clumps", [False, True])
def test_velocity_zone_holds_the_feed_velocity_and_leaves_the_rest(clumps):
    s = _column(clumps)
    s.step(5000)  # 0.1 s: free fall from y = 0.19 m, not yet in the zone
    v = s.clumps.vel if clumps else s.vel
    assert s.zone_count == 0
    np.testing.assert_allclose(v[:, 1], -9.81 * 0.1, rtol=1e-9)
    s.step(5000)  # 0.2 s: reached the zone (y < 0.05 m after 0.17 s) and are fed through it
    v = s.clumps.vel if clumps else s.vel
    com = s.clumps.com if clumps else s.pos
    inside = com[:, 1] < 0.05
    assert inside.any() and s.zone_count == int(inside.sum())
    # the component ends every step at the zone's value; a particle that entered during the last
    # step had fallen freely until then
    np.testing.assert_allclose(v[inside, 1], -0.4, rtol=1e-12)
    np.testing.assert_allclose(v[:, 2], 0.1, rtol=1e-12)  # other components untouched
    if clumps:  # members move with their body: v_member = v_body + w x r
        c = s.clumps
        for b in range(c.nb):
            mem = c.members[c.start[b]:c.start[b + 1]]
            r = s.pos[mem] - c.com[b]
            np.testing.assert_allclose(s.vel[mem], c.vel[b] + np.cross(c.omega()[b], r), atol=1e-12)


def test_velocity_zone_bad_input():
    s = ParticleSystem(pp=PP, walls=[], dt=2e-5)
    with pytest.raises(CaseError, match="hi > lo"):
        s.add_velocity_zone([0, 0, 0], [1, 0, 1], 1, 0.4)
    with pytest.raises(CaseError, match="axis"):
        s.add_velocity_zone([0, 0, 0], [1, 1, 1], 3, 0.4)
