"""The case key ``gas.pressure_solver`` reaches the gas solver of a coupled chute run."""

import pytest

from cfddem.config import load_case
from cfddem.coupling.exchange import build_coupled_gas
from cfddem.errors import CaseError
from cfddem.gas.multigrid import MGPressureSolver
from cfddem.gas.pressure import PressureSolver


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
    cg = build_coupled_gas(case, sys_)
    assert cg.gas.pressure_solver == (key or "mg")
    assert type(cg.gas.psolver) is cls
    info = cg.advance(20)
    assert info.ok


def test_pressure_solver_key_rejects_unknown(root):
    with pytest.raises(CaseError):
        load_case(root / "cases" / "chute_16rpm", overrides=["gas.enabled=true", "gas.pressure_solver='cg'"])
