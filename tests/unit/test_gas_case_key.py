"""The case keys ``gas.pressure_solver`` and ``gas.pressure_tol`` reach the gas solver of a coupled chute run."""

import pytest

from cfddem.config import load_case
from cfddem.coupling.exchange import build_coupled_gas
from cfddem.errors import CaseError
from cfddem.gas.multigrid import MGPressureSolver
from cfddem.gas.pressure import PressureSolver
from cfddem.scenes import scene_of


@pytest.mark.parametrize("key,cls", [(None, MGPressureSolver), ("mg", MGPressureSolver), ("amg", PressureSolver)])
def test_pressure_solver_key_reaches_solver(root, key, cls):
    from cfddem.particles.system import ParticleSystem
    from cfddem.simulation import contact_law

    ov = ["gas.enabled=true", "gas.cells=[4, 3, 10]"]
    if key is not None:
        ov.append(f"gas.pressure_solver='{key}'")
    case = load_case(root / "cases" / "chute_16rpm", overrides=ov)
    assert case.gas.pressure_solver == (key or "mg")
    sys_ = ParticleSystem(pp=contact_law(case.resolved["contact"]["particle_particle"]), walls=[], dt=1e-5)
    cg = build_coupled_gas(case, sys_, scene_of(case).gas_domain(case))
    assert cg.gas.pressure_solver == (key or "mg")
    assert type(cg.gas.psolver) is cls
    info = cg.advance(20)
    assert info.ok


def test_pressure_solver_key_rejects_unknown(root):
    with pytest.raises(CaseError):
        load_case(root / "cases" / "chute_16rpm", overrides=["gas.enabled=true", "gas.pressure_solver='cg'"])


@pytest.mark.parametrize("tol", [None, 1e-6])
def test_pressure_tol_key_reaches_solver(root, tol):
    """gas.pressure_tol sets the pressure solve's relative tolerance (default 1e-8), and the
    solve meets it."""
    from cfddem.particles.system import ParticleSystem
    from cfddem.simulation import contact_law

    ov = ["gas.enabled=true", "gas.cells=[4, 3, 10]"] + ([] if tol is None else [f"gas.pressure_tol={tol}"])
    case = load_case(root / "cases" / "chute_16rpm", overrides=ov)
    sys_ = ParticleSystem(pp=contact_law(case.resolved["contact"]["particle_particle"]), walls=[], dt=1e-5)
    cg = build_coupled_gas(case, sys_, scene_of(case).gas_domain(case))
    assert cg.gas.psolver.tol == (tol or 1e-8)
    assert cg.advance(20).ok
    info = cg.gas.last_info
    assert info.pressure_residual <= (tol or 1e-8) or info.max_divergence <= cg.gas.defect_tol


@pytest.mark.parametrize("bad", ["0", "-1e-6", "0.5"])
def test_pressure_tol_key_rejects_out_of_range(root, bad):
    with pytest.raises(CaseError, match="gas.pressure_tol"):
        load_case(root / "cases" / "chute_16rpm", overrides=["gas.enabled=true", f"gas.pressure_tol={bad}"])
