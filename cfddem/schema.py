"""The building blocks of the case schema: :class:`Key` (one case-file key: type, default, unit,
meaning, allowed range) and its short constructors.

:mod:`cfddem.config` assembles the schema from its own sections and from the sections each
registered scene (:mod:`cfddem.scenes`) and contact law contributes; it imports nothing of
cfddem but the contact-law registry, so that scene modules can declare their keys without
importing the configuration loader.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

INF = float("inf")


@dataclass(frozen=True)
class Key:
    """One case-file key: its type, default, unit, meaning and allowed range."""

    type: str  # float | int | bool | str | vec3 | floats | ints | bools3 | rows | tables
    default: Any
    unit: str
    doc: str
    lo: float | None = None  # lower bound (of the value, or of every entry of a list)
    hi: float | None = None  # upper bound
    lo_open: bool = False  # lower bound excluded
    hi_open: bool = False
    choices: tuple[str, ...] | None = None
    required: bool = False
    length: int | None = None  # floats / ints: the number of entries (None: any, at least one); rows: per row

    def describe_range(self) -> str:
        if self.choices:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        n = (f"{self.length} entries" + (" per row" if self.type == "rows" else "")) if self.length else ""
        if self.lo is None and self.hi is None:
            return n
        lo = "-inf" if self.lo is None else f"{self.lo:g}"
        hi = "inf" if self.hi is None else f"{self.hi:g}"
        lb = "(" if (self.lo_open or self.lo is None) else "["
        hb = ")" if (self.hi_open or self.hi is None) else "]"
        return f"{lb}{lo}, {hi}{hb}" + (f", {n}" if n else "")


def number(default, unit, doc, **kw) -> Key:
    return Key("float", default, unit, doc, **kw)


def positive(default, unit, doc, **kw) -> Key:
    return Key("float", default, unit, doc, lo=0.0, lo_open=True, **kw)


def nonneg(default, unit, doc, **kw) -> Key:
    return Key("float", default, unit, doc, lo=0.0, **kw)


def fill_friction(until: str) -> Key:
    """A scene's ``fill_friction``: the particle-particle sliding friction while its sample is
    filled, the case's value from ``until`` on (-1: the case's friction throughout);
    :func:`cfddem.scenes.common.check_fill_friction` refuses the values between -1 and 0."""
    return Key("float", -1.0, "-", "particle-particle sliding friction during the fill (the blending thesis filled "
               f"with 0.15 to pack densely), the case's value from {until} on; walls and rolling friction keep "
               "theirs (-1: the case's friction throughout)", lo=-1.0)


def fill_rolling_friction(until: str) -> Key:
    """A scene's ``fill_rolling_friction``: the particle-particle rolling friction while its
    sample is filled, the case's value from ``until`` on (-1: the case's throughout)."""
    return Key("float", -1.0, "-", "particle-particle rolling friction during the fill (a fill with a high rolling "
               f"friction stays loose: 0 packs it densely), the case's value from {until} on; walls keep theirs "
               "(-1: the case's rolling friction throughout)", lo=-1.0)


def wall_override(what: str) -> dict:
    """Per-wall-group contact overrides of a scene (unset: contact.particle_wall): every key of
    every registered contact law (:func:`cfddem.particles.contact.contact_keys`);
    :func:`cfddem.particles.contact.check_contact_values` checks their ranges."""
    from .particles.contact import contact_keys

    return {k.name: Key("float", None, k.unit, f"{what}: {k.short} (default: contact.particle_wall.{k.name})",
                        lo=0.0)
            for k in contact_keys().values()}
