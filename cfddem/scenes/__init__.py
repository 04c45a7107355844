"""Scenes: everything a geometry brings to the generic run of :class:`cfddem.simulation.Simulation`.

The run loop (clock, outputs, checkpoints, contacts, gas) is the same for every case.  A scene
is the one module that knows its geometry: ``geometry.type`` names it, and adding a scene is one
new module plus its entry in :data:`SCENES`.  Nothing outside ``cfddem/scenes/`` branches on a
scene's name.

What a scene supplies, all optional (the base class :class:`Scene` gives the neutral answer):

Before a run, from the case alone (class methods; ``cfddem check`` uses them too):

- ``SCHEMA``: the case keys the scene adds, ``{section: {key: cfddem.schema.Key}}`` (a new
  section such as ``[silo]``, or keys added to a shared one such as ``[geometry]``); a key of
  another scene set to a non-default value is refused ("belongs to geometry.type = ...")
- ``check(r, case_dir)``: its consistency checks on the resolved dict (and derived defaults)
- ``wall_specs(case)``: its walls (:class:`cfddem.scenes.common.WallSpec`; the extra
  ``[[geometry.walls]]`` are added by :func:`cfddem.scenes.common.wall_specs`)
- ``periodic(case)``: per axis ``(lo, hi)`` of a periodic axis or None
- ``bounds(case)``: (2, 3) corners that belong to the scene's bounding box besides its walls
- ``has_particles(case)``, ``expected_particles(case)``: whether it creates particles, how many
- ``inserts_clumps(r)``: whether its fill or inlet inserts clumps (``particles.clump``)
- ``speed_scale(case)``: the fastest expected particle (or gas) speed, for the collision time
  and the gas step
- ``describe(case)``: extra lines for ``cfddem check``
- ``gas_domain(case)``: the :class:`cfddem.gas.domain.GasDomain` (box, grid, a boundary
  condition per face, initial fields) when the scene supports gas; None: gas is refused
- ``plots(results_h5, out_dir)``: its PNG plots of a finished run (beside the time series)

During a run (instance methods; ``self.sim`` is the Simulation):

- ``make_inlet()``: an inlet object (``insert``, ``get_state``...) or None
- ``make_measurements()``: a sampled measurement object (``measure``, ``results``...) or None
- ``exit_plane()``: (point, outward normal) of the plane that particles leave the scene through
  (None: no exit); they leave at the engine's next neighbour rebuild (``ParticleSystem.set_sink``)
- ``start()`` once after the system is built and before the first output (not on resume)
- ``next_time(t)``, ``max_steps()``: when the loop must stop next for the scene
- ``after_steps()`` after every chunk of steps (control, gates, sampling)
- ``series()``: extra ``/series`` columns; ``measurements()``: (group, arrays, attrs) or None
- ``stop_reason()``: None or the sentence that ends the run (status "done")
- ``get_state()`` / ``set_state(d)``: what a checkpoint must hold for a bit-identical restart
"""

from __future__ import annotations

import importlib
import math

#: geometry.type -> "module:Class" (imported on first use)
SCENES: dict[str, str] = {
    "chute": "cfddem.scenes.chute:ChuteScene",
    "chute_segment": "cfddem.scenes.chute_segment:ChuteSegmentScene",
    "box": "cfddem.scenes.box:BoxScene",
    "silo": "cfddem.scenes.silo:SiloScene",
    "silo_blender": "cfddem.scenes.blender:BlenderScene",
    "shear_cell": "cfddem.scenes.shear:ShearCellScene",
    "drum": "cfddem.scenes.drum:DrumScene",
    "none": "cfddem.scenes:Scene",
}
SCENE_TYPES: tuple[str, ...] = tuple(SCENES)
#: the scene of a case that does not name one
DEFAULT_SCENE = "chute"


class Scene:
    """The neutral scene (``geometry.type = "none"``: walls from ``[[geometry.walls]]`` only, no
    inlet, no exit, no measurements); the base of every scene (see the module docstring)."""

    #: one line for the case-format reference
    DOC = "'none': walls only from [[geometry.walls]]"
    #: the keys this scene adds to the case format
    SCHEMA: dict = {}
    #: whether ``gas_domain`` gives a domain (``gas.enabled`` is refused otherwise)
    HAS_GAS: bool = False
    #: the folder under ``cases/`` of the scene's example case (the scene contract test runs it)
    EXAMPLE = "cylinder_drop"

    def __init__(self, sim):
        self.sim = sim
        self.case = sim.case

    # -------------------------------------------------------------- from the case alone
    @classmethod
    def check(cls, r: dict, case_dir) -> None:
        pass

    @classmethod
    def wall_specs(cls, case) -> list:
        return []

    @classmethod
    def periodic(cls, case) -> tuple:
        return (None, None, None)

    @classmethod
    def bounds(cls, case):
        return None

    @classmethod
    def has_particles(cls, case) -> bool:
        return False

    @classmethod
    def expected_particles(cls, case) -> int:
        return 0

    @classmethod
    def inserts_clumps(cls, r: dict) -> bool:
        return False

    #: the scene pours its particles with free rotation and calls
    #: ``ParticleSystem.lock_rotation`` itself at the end of its fill (``particles.rotation``)
    locks_rotation_after_fill = False

    @classmethod
    def speed_scale(cls, case) -> float:
        return 0.0

    @classmethod
    def describe(cls, case) -> list[str]:
        return []

    @classmethod
    def gas_domain(cls, case):
        return None

    @classmethod
    def plots(cls, results_h5, out_dir) -> list:
        """The scene's plots of a finished run: ``(file name, path or None, why skipped)`` each
        (``cfddem report`` and the end of a run draw them beside the time series)."""
        return []

    # -------------------------------------------------------------- during a run
    def make_inlet(self):
        return None

    def make_measurements(self):
        return None

    def make_budget(self):
        """A :class:`cfddem.measure.budget.MomentumBudget` sampled with the measurements, or None."""
        return None

    def exit_plane(self):
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


def scene_class(geometry_type: str) -> type[Scene]:
    """The Scene subclass registered for ``geometry_type``."""
    mod, cls = SCENES[geometry_type].split(":")
    return getattr(importlib.import_module(mod), cls)


def scene_of(case) -> type[Scene]:
    """The Scene subclass of a case (a :class:`cfddem.config.Case`)."""
    return scene_class(case.geometry.type)


def scene_schemas() -> dict[str, dict]:
    """geometry.type -> the keys that scene adds (``{section: {key: Key}}``)."""
    return {name: scene_class(name).SCHEMA for name in SCENES}


def scene_docs() -> str:
    """One phrase per scene for the reference of ``geometry.type``."""
    return "; ".join(scene_class(name).DOC for name in SCENES)
