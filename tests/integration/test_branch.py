"""checkpoint.start_from: a run continues another run's state with other settings (a branch
from a developed flow): same particles, contact history and clock; its own time step."""

import numpy as np
import pytest

from cfddem.config import load_case
from cfddem.errors import CaseError
from cfddem.io.checkpoint import latest_checkpoint
from cfddem.io.results import read_series
from cfddem.simulation import Simulation

from .test_runs import box_case


def test_branch_continues_state_with_another_time_step(tmp_path):
    d = box_case(tmp_path, end=0.04, ck=0.02)
    a = Simulation(load_case(d), tmp_path / "a", echo=False, progress=False)
    assert a.run().status == "done"
    path, st = latest_checkpoint(tmp_path / "a" / "checkpoints")
    t0 = float(st["system"]["time"])
    assert t0 == pytest.approx(0.04)
    b_case = load_case(d, overrides={"checkpoint.start_from": str(tmp_path / "a"), "time.dt": 1e-5,
                                     "time.end_time": 0.05, "checkpoint.interval": 0.0})
    b = Simulation(b_case, tmp_path / "b", echo=False, progress=False)
    sb = b.run()
    assert sb.status == "done" and sb.time == pytest.approx(0.05)
    # 0.01 s at the new dt
    assert sb.steps - int(st["system"]["step_count"]) == 1000
    ser = read_series(tmp_path / "b" / "results.h5")
    assert ser["time"][0] == pytest.approx(t0)
    assert ser["n_particles"][0] == st["system"]["n"]
    # the same state continued at the same dt is the original run, bit for bit
    c_case = load_case(d, overrides={"checkpoint.start_from": str(path), "time.end_time": 0.06})
    c = Simulation(c_case, tmp_path / "c", echo=False, progress=False)
    c.run()
    full = Simulation(load_case(d, overrides={"time.end_time": 0.06}), tmp_path / "full", echo=False,
                      progress=False)
    full.run()
    assert np.array_equal(c.system.pos, full.system.pos) and np.array_equal(c.system.vel, full.system.vel)


def test_branch_from_missing_source_names_the_key(tmp_path):
    d = box_case(tmp_path)
    with pytest.raises(CaseError, match="checkpoint.start_from"):
        load_case(d, overrides={"checkpoint.start_from": "nowhere"})


def test_branch_onto_another_gas_grid_starts_the_gas_afresh(tmp_path):
    """A branch may change the gas grid (the gas-grid axis of the speed-accuracy study): the
    particles continue, the gas starts from rest on the new grid (logged), the run completes."""
    root = __import__("pathlib").Path(__file__).resolve().parents[2]
    ov = {"gas.enabled": True, "gas.cells": [8, 5, 50], "time.dt": 1e-5, "time.end_time": 0.002,
          "measurements.start_time": 0.0, "study.compare_without_gas": False, "output.vtk": False,
          "checkpoint.every_steps": 100}
    a = Simulation(load_case(root / "cases" / "chute_16rpm", overrides=ov), tmp_path / "a", echo=False,
                   progress=False, threads=1)
    assert a.run().status == "done"
    ov_b = dict(ov, **{"gas.cells": [4, 5, 25], "time.end_time": 0.0025, "checkpoint.every_steps": 0,
                       "checkpoint.start_from": str(tmp_path / "a")})
    b = Simulation(load_case(root / "cases" / "chute_16rpm", overrides=ov_b), tmp_path / "b", echo=False,
                   progress=False, threads=1)
    sb = b.run()
    assert sb.status == "done" and sb.time == pytest.approx(0.0025)
    assert b.gas.grid.shape == (4, 5, 25) and b.gas.n_couplings > 0
    assert "gas starts afresh" in (tmp_path / "b" / "run.log").read_text()


def test_perturbed_branches_are_replicas(tmp_path):
    """checkpoint.perturb_velocity: branches with the same seed are identical, with another seed
    they differ (the perturbation grows in the chaotic flow), without it they are the plain
    branch; the log says so once."""
    d = box_case(tmp_path, end=0.02, ck=0.02)
    assert Simulation(load_case(d), tmp_path / "a", echo=False, progress=False).run().status == "done"

    def branch(name, **ov):
        o = {"checkpoint.start_from": str(tmp_path / "a"), "time.end_time": 0.04, "checkpoint.interval": 0.0}
        o.update({f"checkpoint.{k}": v for k, v in ov.items()})
        s = Simulation(load_case(d, overrides=o), tmp_path / name, echo=False, progress=False)
        assert s.run().status == "done"
        i = np.argsort(s.system.ids)
        return s.system.pos[i], s.system.vel[i]

    p0, v0 = branch("plain")
    p1, v1 = branch("s1", perturb_velocity=1e-6, perturb_seed=1)
    p1b, v1b = branch("s1b", perturb_velocity=1e-6, perturb_seed=1)
    p2, v2 = branch("s2", perturb_velocity=1e-6, perturb_seed=2)
    assert np.array_equal(p1, p1b) and np.array_equal(v1, v1b)
    for p in (p1, p2):
        assert not np.array_equal(p, p0)
    # two independent 1e-6 m/s RMS kicks drift sqrt(2) x 1e-6 m/s x 0.02 s = 2.8e-8 m apart without
    # contacts (3.4e-8 m measured with them)
    sep = np.sqrt(np.mean(np.sum((p2 - p1) ** 2, axis=1)))
    assert 1.5e-8 < sep < 1e-6
    log = (tmp_path / "s2" / "run.log").read_text()
    assert log.count("perturbed by 1e-06 m/s RMS (checkpoint.perturb_seed = 2)") == 1
    assert "m/s RMS" not in (tmp_path / "plain" / "run.log").read_text()
