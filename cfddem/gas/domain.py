"""The gas domain a scene declares: the box and its grid, a boundary condition per face, the
body forces of the frame, and the initial fields.  :func:`cfddem.coupling.exchange.build_coupled_gas`
turns it into a running coupled gas; the scene module (``gas_domain(case)``) is the one place
that knows its geometry."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

from cfddem.gas.grid import StaggeredGrid


@dataclass
class GasDomain:
    grid: StaggeredGrid
    #: "x-", "x+", "y-", "y+", "z-", "z+" -> a boundary condition of :mod:`cfddem.gas.boundaries`
    bcs: dict
    gravity: tuple
    omega: tuple = (0.0, 0.0, 0.0)
    axis_point: tuple = (0.0, 0.0, 0.0)
    #: initial gas velocity (x, y, z) -> (u, v, w), and pressure (x, y, z) -> p, on arrays
    velocity: Callable | None = None
    pressure: Callable | None = None
    #: the fastest expected gas speed (m/s), for the Courant estimate of ``cfddem check``
    speed_scale: float = 0.0
    #: extra lines for ``cfddem check`` (what the boundaries are set to)
    notes: list[str] = field(default_factory=list)
    #: the axis (0, 1, 2) of the gas's momentum budget over the domain
    #: (:class:`cfddem.measure.gas_budget.GasBudget`, /measurements/gas_budget), None for none
    budget_axis: int | None = None
    #: names of the sides for the budget's table, e.g. ``{"y-": "floor"}``
    side_names: dict = field(default_factory=dict)
