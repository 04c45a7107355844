"""Gas phase: volume-averaged Navier-Stokes on a staggered grid for a given porosity field.

See docs/gas.md.  Public API::

    from cfddem.gas import (StaggeredGrid, Field, GasSolver, GasStepInfo, NoSlip, FreeSlip,
                            Velocity, Inlet, LidCrossWind, PressureOutlet, Patched, Periodic,
                            MGPressureSolver, PressureSolver)
"""

from cfddem.gas.boundaries import (BC, BoundarySet, FreeSlip, Inlet, LidCrossWind, NoSlip, Patched, Periodic,
                                   PressureOutlet, Velocity)
from cfddem.gas.grid import Field, StaggeredGrid
from cfddem.gas.multigrid import MGPressureSolver
from cfddem.gas.pressure import PressureSolver
from cfddem.gas.solver import GasSolver, GasStepInfo

__all__ = ["BC", "BoundarySet", "Field", "FreeSlip", "GasSolver", "GasStepInfo", "Inlet", "LidCrossWind",
           "MGPressureSolver", "NoSlip", "Patched", "Periodic", "PressureOutlet", "PressureSolver", "StaggeredGrid", "Velocity"]
