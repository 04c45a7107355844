"""The scene contract: every registered scene's example case validates, builds, runs a few
steps and writes its results and measurements, with and without gas where the scene declares a
gas domain; a scene's keys are refused in another scene's case; gas is refused where a scene
declares no domain."""

from pathlib import Path

import h5py
import numpy as np
import pytest

from cfddem.config import SCHEMA, _SCENE_KEY_OWNER, load_case
from cfddem.errors import CaseError
from cfddem.scenes import SCENES, Scene, scene_class
from cfddem.scenes.common import wall_specs
from cfddem.simulation import Simulation, describe_case, expected_particles, has_particles

ROOT = Path(__file__).resolve().parents[2]
STEPS = 120


def _variants():
    for name in SCENES:
        cls = scene_class(name)
        yield pytest.param(name, False, id=f"{name}")
        if cls.HAS_GAS:
            yield pytest.param(name, True, id=f"{name}-gas")


@pytest.mark.parametrize("name,gas", list(_variants()))
def test_scene_example_runs(name, gas, tmp_path):
    cls = scene_class(name)
    assert issubclass(cls, Scene)
    folder = ROOT / "cases" / cls.EXAMPLE
    ov = [f"time.max_steps={STEPS}", "output.vtk=false", "output.plots=false", "time.threads=1",
          "measurements.start_time=0.0", "output.series_interval=1e-4", f"gas.enabled={'true' if gas else 'false'}",
          "study.compare_without_gas=false", "checkpoint.wall_interval=0"]
    case = load_case(folder, overrides=ov)
    assert case.geometry.type == name
    lines = describe_case(case)  # what `cfddem check` prints
    assert any(x.startswith("gas: ") for x in lines)
    assert has_particles(case) and expected_particles(case) >= 1
    specs = wall_specs(case)
    assert specs and all(np.isclose(np.linalg.norm(w.normal), 1.0) or np.linalg.norm(w.normal) > 0 for w in specs)
    sim = Simulation(case, tmp_path / "run", overwrite=True, echo=False, progress=False, threads=1)
    s = sim.run()
    assert s.status == "stopped" and s.steps == STEPS, s.message
    assert sim.system.n >= 1 and np.all(np.isfinite(sim.system.pos))
    with h5py.File(tmp_path / "run" / "results.h5", "r") as f:
        assert f["series/time"].shape[0] >= 2
        assert "config" in f or "case" in f.attrs or len(f.attrs) > 0
        groups = set(f["measurements"].keys()) if "measurements" in f else set()
        if sim.measure is not None:
            assert sim.measure.group in groups
        m = sim.scene.measurements()
        if m is not None:  # (group, arrays, attrs); group None: the arrays at the top of /measurements
            names = {k for k in m[1] if not k.startswith("@")}
            assert (m[0] in groups) if m[0] else names <= groups
        if gas:
            assert "gas_pressure_iterations" in f["series"]
            assert "gas" in groups
    assert (tmp_path / "run" / "case.resolved.toml").exists()
    # the scene's plots (cfddem report): each written as PNG or skipped with its reason
    from cfddem.report.plots import write_run_report

    files = write_run_report(tmp_path / "run" / "results.h5", tmp_path / "rep")
    text = files[-1].read_text()
    assert files[0].name == "series.png" and files[0].stat().st_size > 5000
    for fname, path, reason in cls.plots(tmp_path / "run" / "results.h5", tmp_path / "rep2"):
        assert (f"written  {fname}" in text) if path else (f"skipped  {fname}: {reason}" in text)


def test_every_scene_declares_its_keys_and_example():
    for name in SCENES:
        cls = scene_class(name)
        assert (ROOT / "cases" / cls.EXAMPLE / "case.toml").exists(), name
        assert name in SCHEMA["geometry"]["type"].choices
        for sec, keys in cls.SCHEMA.items():
            for k in keys:
                assert name in _SCENE_KEY_OWNER[(sec, k)]


@pytest.mark.parametrize("name", [n for n in SCENES if n not in _SCENE_KEY_OWNER[("geometry", "width")]])
def test_chute_keys_refused_elsewhere(name):
    folder = ROOT / "cases" / scene_class(name).EXAMPLE
    with pytest.raises(CaseError) as e:
        load_case(folder, overrides=["geometry.width=0.2"])
    assert e.value.key == "geometry.width" and "geometry.type = 'chute'" in e.value.reason


@pytest.mark.parametrize("name", [n for n in SCENES if not scene_class(n).HAS_GAS])
def test_gas_refused_without_a_domain(name):
    folder = ROOT / "cases" / scene_class(name).EXAMPLE
    with pytest.raises(CaseError) as e:
        load_case(folder, overrides=["gas.enabled=true"])
    assert e.value.key == "gas.enabled" and "declares no gas domain" in e.value.reason
