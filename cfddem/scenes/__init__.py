"""Scenes: what a geometry type adds to the generic run loop of :class:`cfddem.simulation.Simulation`.

The run loop (clock, outputs, checkpoints, inlet, exit, gas) is shared by every case.  A scene
adds, for its geometry type, the walls it builds, the wall control it needs during the run
(a silo gate that opens, a shear ring that moves, a servo-controlled lid), its own measurements
and time series, and a stop condition (discharge complete, clogged).  The chute and the plain
box need none of this (their measurements live in :mod:`cfddem.measure.chute`).

A scene module registers a subclass of :class:`Scene` under its geometry type in ``SCENES``
(``"module:Class"``, imported on first use).  The hooks, all optional:

- ``wall_specs()`` -> list of :class:`cfddem.scene.WallSpec` (the scene's walls; None: the
  generic ones of :func:`cfddem.scene.wall_specs`)
- ``start()`` once after the system is built and before the first output (a fresh run only;
  not on resume)
- ``next_time(t)`` the next simulated time at which the loop must stop for the scene
  (``inf`` if none); ``max_steps()`` the most steps between two ``after_steps`` calls
- ``after_steps()`` after every chunk of steps (control, gates, sampling)
- ``series()`` extra columns of ``/series`` (floats; the same keys at every call)
- ``measurements()`` -> (group, arrays, attrs) or None, stored under ``/measurements/<group>``
  at snapshots and at the end
- ``stop_reason()`` -> None or one sentence: the run ends (status "done") with that message
- ``get_state()`` / ``set_state(d)``: what a checkpoint must hold for a bit-identical restart
"""

from __future__ import annotations

import importlib
import math

SCENES: dict[str, str] = {
    "silo": "cfddem.scenes.silo:SiloScene",
    "shear_cell": "cfddem.scenes.shear:ShearCellScene",
}


class Scene:
    """Base scene: does nothing (see the module docstring for the hooks)."""

    def __init__(self, sim):
        self.sim = sim
        self.case = sim.case

    def wall_specs(self):
        return None

    def start(self) -> None:
        pass

    def next_time(self, t: float) -> float:
        return math.inf

    def max_steps(self) -> int:
        return 1 << 62

    def after_steps(self) -> None:
        pass

    def series(self) -> dict:
        return {}

    def measurements(self):
        return None

    def stop_reason(self) -> str | None:
        return None

    def get_state(self) -> dict:
        return {}

    def set_state(self, d: dict) -> None:
        pass


def scene_class(geometry_type: str):
    """The Scene subclass registered for ``geometry_type`` (None if the type has no scene)."""
    ref = SCENES.get(geometry_type)
    if ref is None:
        return None
    mod, cls = ref.split(":")
    return getattr(importlib.import_module(mod), cls)
