"""Clump templates in the case (particles.clump = 'template', particles.clump_spheres): shape and
mass properties, validation with one-line errors naming the key, and a fill that inserts them."""

import math

import numpy as np
import pytest

from cfddem.config import load_case
from cfddem.errors import CaseError
from cfddem.particles.clumps import check_template, particle_shape, pellet, shape_from_case, spheres_per_body
from cfddem.simulation import Simulation

from ..conftest import CASES

THESIS = [[-0.125, 0.0, 0.0, 0.5], [0.125, 0.0, 0.0, 0.5]]  # 3 mm spheres 0.75 mm apart (d = 3 mm)
ROD = "[" + ",".join(f"[{0.5 * k:g},0,0,0.5]" for k in range(-15, 16)) + "]"


def test_template_equals_the_preset_pellet():
    d, rho = 0.004, 950.0
    t = shape_from_case("template", d, rho, [[-0.25, 0, 0, 0.5], [0.25, 0, 0, 0.5]])
    p = pellet(2, d, rho)
    assert t.mass == pytest.approx(p.mass, rel=1e-12)
    np.testing.assert_allclose(t.inertia, p.inertia, rtol=1e-12)
    np.testing.assert_allclose(np.sort(np.abs(t.offsets[:, 0])), np.sort(np.abs(p.offsets[:, 0])), atol=1e-15)


def test_thesis_clump_mass_is_the_union_of_two_spheres():
    d, rho = 0.003, 950.0
    shape = particle_shape({"clump": "template", "diameter": d, "density": rho, "clump_spheres": THESIS})
    r, s = 0.5 * d, 0.25 * d
    lens = math.pi * (4 * r + s) * (2 * r - s) ** 2 / 12.0  # the overlap of two equal spheres
    exact = rho * (2 * 4.0 / 3.0 * math.pi * r**3 - lens)
    assert shape.mass == pytest.approx(exact, rel=5e-3)
    assert np.linalg.norm(shape.offsets[0] - shape.offsets[1]) == pytest.approx(s, rel=1e-12)
    assert spheres_per_body("template", THESIS) == 2


@pytest.mark.parametrize("rows,key,words", [
    ([[0, 0, 0, 0.5], [0.3, 0, 0, 0.0]], "particles.clump_spheres[1]", "must be positive"),
    ([[0, 0, 0, 0.5], [1.5, 0, 0, 0.5]], "particles.clump_spheres[1]", "does not touch"),
    ([[0, 0, 0, 0.5], [0.1, 0, 0, 0.2]], "particles.clump_spheres[1]", "inside sphere 0"),
    ([], "particles.clump_spheres", "at least one sphere"),
])
def test_template_errors(rows, key, words):
    with pytest.raises(CaseError) as e:
        check_template(rows)
    assert e.value.key == key and words in e.value.reason


@pytest.mark.parametrize("ov,key,words", [
    (["particles.clump='template'", "particles.clump_spheres=[[0,0,0,0.5],[0.2,0,0]]"],
     "particles.clump_spheres[1]", "expected 4 numbers"),
    (["particles.clump='template'", "particles.clump_spheres=[[0,0,0,0.5],[2,0,0,0.5]]"],
     "particles.clump_spheres[1]", "does not touch"),
    (["particles.clump_spheres=[[0,0,0,0.5]]"], "particles.clump_spheres", "needs particles.clump = 'template'"),
    (["particles.clump='template'", "particles.clump_spheres=" + ROD],  # a rod of 16 d through a 10 d slot
     "particles.clump_spheres", "does not fit through the outlet"),
])
def test_template_case_errors(ov, key, words):
    with pytest.raises(CaseError) as e:
        load_case(CASES / "silo_flat", overrides=ov)
    assert e.value.key == key and words in e.value.reason, str(e.value)


def test_silo_fill_inserts_template_clumps(tmp_path):
    case = load_case(CASES / "silo_flat", overrides=[
        "particles.clump='template'", f"particles.clump_spheres={THESIS}", "particles.diameter=0.003",
        "silo.n_particles=200", "time.max_steps=40", "output.vtk=false", "output.plots=false",
        "checkpoint.wall_interval=0", "time.threads=1"])
    sim = Simulation(case, tmp_path / "run", overwrite=True, echo=False, progress=False, threads=1)
    assert sim.run().status == "stopped"
    assert sim.system.n == 2 * 200 and sim.system.clumps.nb == 200
    shape = particle_shape(case.particles)
    assert float(np.sum(sim.system.clumps.mass[:200])) == pytest.approx(200 * shape.mass, rel=1e-12)
