"""Case files: validation, overrides, errors that name the key, the generated docs."""

import subprocess
import sys
import tomllib

import pytest

from cfddem.config import build_case, case_format_markdown, load_case, parse_override
from cfddem.errors import CaseError

from ..conftest import CASES, ROOT


def err(raw, overrides=None, case_dir="."):
    with pytest.raises(CaseError) as e:
        build_case(raw, case_dir=case_dir, overrides=overrides)
    return e.value


@pytest.mark.nojit
def test_shipped_cases_load():
    for name in ("chute_16rpm", "chute_0rpm"):
        c = load_case(CASES / name)
        assert c.name == name
        assert c.particles.diameter == 0.003
        assert c.contact.particle_particle.e_n == 0.97
        assert c.contact.particle_wall.mu == 0.22
        assert c.inlet.z == c.geometry.z_start  # derived default
        assert c.exit.z == pytest.approx(c.geometry.z_start + c.geometry.length)
    assert load_case(CASES / "chute_16rpm").frame.rpm == 16.0
    assert load_case(CASES / "chute_0rpm").frame.rpm == 0.0


@pytest.mark.nojit
def test_defaults_filled():
    c = build_case({})
    assert c.time.dt == 1e-5
    assert c.gas.enabled is False
    assert c.contact.particle_particle.mu_r == 0.0


@pytest.mark.nojit
def test_unknown_key_suggests():
    e = err({"particles": {"diamter": 0.003}})
    assert e.key == "particles.diamter"
    assert "did you mean 'diameter'" in str(e)
    e = err({"partcles": {}})
    assert "did you mean 'particles'" in str(e)
    e = err({"contact": {"particle_particle": {"k": 1.0}}})
    assert e.key == "contact.particle_particle.k"


@pytest.mark.nojit
@pytest.mark.parametrize("raw,key,words", [
    ({"particles": {"diameter": -0.003}}, "particles.diameter", "out of range"),
    ({"particles": {"diameter": 0}}, "particles.diameter", "out of range"),
    ({"particles": {"diameter": "big"}}, "particles.diameter", "expected a number"),
    ({"particles": {"density": True}}, "particles.density", "expected a number"),
    ({"contact": {"particle_particle": {"e_n": 0.0}}}, "contact.particle_particle.e_n", "out of range"),
    ({"contact": {"particle_particle": {"e_n": 1.2}}}, "contact.particle_particle.e_n", "out of range"),
    ({"contact": {"particle_wall": {"mu": -0.1}}}, "contact.particle_wall.mu", "out of range"),
    ({"contact": {"particle_wall": {"e_t": 0}}}, "contact.particle_wall.e_t", "out of range"),
    ({"time": {"dt": 0}}, "time.dt", "out of range"),
    ({"time": {"max_steps": 1.5}}, "time.max_steps", "expected an integer"),
    ({"time": {"threads": -1}}, "time.threads", "out of range"),
    ({"output": {"vtk": "yes"}}, "output.vtk", "expected true or false"),
    ({"frame": {"axis_point": [0, 0]}}, "frame.axis_point", "3 numbers"),
    ({"gravity": {"inclination_deg": 95}}, "gravity.inclination_deg", "out of range"),
    ({"geometry": {"type": "funnel"}}, "geometry.type", "not allowed"),
    ({"inlet": {"type": "sluice", "z": 2.0}}, "inlet.z", "outside the chute"),
    ({"inlet": {"type": "sluice", "height": 0.1}}, "inlet.height", "higher than the side walls"),
    ({"inlet": {"type": "sluice", "height": 0.001}}, "inlet.height", "does not fit"),
    ({"geometry": {"type": "box"}, "inlet": {"type": "sluice"}}, "inlet.type", "needs geometry.type"),
    ({"geometry": {"type": "box", "lo": [0, 0, 0], "hi": [1, 0, 1]}}, "geometry.hi", "must be above"),
    ({"particles": {"diameter_max": 0.001}}, "particles.diameter_max", "smaller than"),
    ({"particles": {"diameter": 0.1}}, "geometry.width", "not wider"),
    ({"exit": {"z": 5.0}}, "exit.z", "outside the chute"),
    ({"geometry": {"walls": [{"type": "sphere", "point": [0, 0, 0], "normal": [0, 1, 0]}]}},
     "geometry.walls[0].type", "not allowed"),
    ({"geometry": {"walls": [{"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 0]}]}},
     "geometry.walls[0].normal", "zero vector"),
    ({"geometry": {"walls": [{"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "mu": -1}]}},
     "geometry.walls[0].mu", ">= 0"),
    ({"geometry": {"walls": [{"type": "plane", "pont": [0, 0, 0], "normal": [0, 1, 0]}]}},
     "geometry.walls[0].pont", "did you mean 'point'"),
    ({"particles": {"initial": [{"pos": [0, 0]}]}}, "particles.initial[0].pos", "3 numbers"),
    ({"particles": {"initial": [{"pos": [0, 0, 0], "radius": -1}]}}, "particles.initial[0].radius", "positive"),
    ({"particles": {"initial_file": "nope.csv"}}, "particles.initial_file", "not found"),
    ({"measurements": {"start_time": 10.0}, "time": {"end_time": 1.0}}, "measurements.start_time", "nothing would"),
    ({"gas": {"cells": [16, 0, 150]}}, "gas.cells", ">= 1"),
    ({"gas": {"drag": "beetsra"}}, "gas.drag", "did you mean 'beetstra'"),
    ({"time": []}, "time", "expected a table"),
])
def test_bad_values_name_the_key(raw, key, words):
    e = err(raw)
    assert e.key == key, str(e)
    assert words in str(e)
    assert "\n" not in str(e)


@pytest.mark.nojit
def test_overrides_parse_as_toml_and_validate():
    assert parse_override("particles.diameter=0.004") == ("particles.diameter", 0.004)
    assert parse_override("inlet.type=sluice") == ("inlet.type", "sluice")
    assert parse_override("geometry.periodic=[true,false,false]") == ("geometry.periodic", [True, False, False])
    c = build_case({}, overrides=["particles.diameter=0.004", "frame.rpm=8"])
    assert c.particles.diameter == 0.004 and c.frame.rpm == 8.0
    e = err({}, overrides=["particles.diamter=0.004"])
    assert "did you mean 'diameter'" in str(e)
    e = err({}, overrides=["nonsense"])
    assert "KEY=VALUE" in str(e)


@pytest.mark.nojit
def test_resolved_toml_round_trip():
    c = load_case(CASES / "chute_16rpm", overrides=["time.end_time=0.5", "measurements.start_time=0.2"])
    again = tomllib.loads(c.to_toml())
    c2 = build_case(again)
    assert c2.resolved == c.resolved


@pytest.mark.nojit
def test_case_format_doc_is_current():
    doc = (ROOT / "docs" / "case-format.md").read_text()
    assert doc == case_format_markdown(), "regenerate: python -m cfddem.config > docs/case-format.md"


@pytest.mark.nojit
def test_malformed_toml(write_case):
    d = write_case("[time\nend_time = 1")
    with pytest.raises(CaseError) as e:
        load_case(d)
    assert "malformed TOML" in str(e.value)


def test_cli_bad_input_one_line_exit_2(write_case):
    d = write_case("[particles]\ndiamter = 0.003\n")
    for cmd in (["check", str(d)], ["run", str(d), "--out", str(d / "o")]):
        p = subprocess.run([sys.executable, "-m", "cfddem.cli", *cmd], capture_output=True, text=True)
        assert p.returncode == 2
        lines = p.stderr.strip().splitlines()
        assert len(lines) == 1, p.stderr
        assert "particles.diamter" in lines[0] and "did you mean 'diameter'" in lines[0]
        assert "Traceback" not in p.stderr
