"""A box of six walls from ``geometry.lo`` to ``geometry.hi`` (``geometry.type = "box"``), any of
whose axes may be periodic instead (no walls on that axis).  Particles come from
``[[particles.initial]]`` or ``particles.initial_file``."""

from __future__ import annotations

import numpy as np

from ..errors import CaseError
from ..schema import Key
from . import Scene
from .common import WallSpec


class BoxScene(Scene):
    DOC = "'box': six walls lo..hi (periodic axes without walls)"
    EXAMPLE = "box_small"
    SCHEMA = {
        "geometry": {
            "lo": Key("vec3", [0.0, 0.0, 0.0], "m", "lower corner"),
            "hi": Key("vec3", [0.1, 0.1, 0.1], "m", "upper corner"),
            "periodic": Key("bools3", [False, False, False], "-", "periodic axes (no walls on those axes)"),
        },
    }

    @classmethod
    def check(cls, r: dict, case_dir) -> None:
        lo, hi = r["geometry"]["lo"], r["geometry"]["hi"]
        for i in range(3):
            if hi[i] <= lo[i]:
                raise CaseError("geometry.hi", f"hi[{i}] = {hi[i]:g} must be above lo[{i}] = {lo[i]:g}")

    @classmethod
    def wall_specs(cls, case) -> list[WallSpec]:
        geo = case.geometry
        lo, hi = np.array(geo.lo), np.array(geo.hi)
        walls = []
        for ax, name in enumerate("xyz"):
            if geo.periodic[ax]:
                continue
            for side, pt in (("-", lo), ("+", hi)):
                n = np.zeros(3)
                n[ax] = 1.0 if side == "-" else -1.0
                p = 0.5 * (lo + hi)
                p[ax] = pt[ax]
                walls.append(WallSpec(f"{name}{side}", "plane", p, n))
        return walls

    @classmethod
    def periodic(cls, case) -> tuple:
        geo = case.geometry
        return tuple((geo.lo[i], geo.hi[i]) if geo.periodic[i] else None for i in range(3))

    @classmethod
    def bounds(cls, case):
        return np.array([case.geometry.lo, case.geometry.hi], float)
