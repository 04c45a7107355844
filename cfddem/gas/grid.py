"""Staggered (marker-and-cell) grid and located fields.

A :class:`StaggeredGrid` is a box ``[x0, x0+Lx] x [y0, y0+Ly] x [z0, z0+Lz]`` split into
``nx x ny x nz`` cells of uniform size ``dx = Lx/nx`` (per direction).  Scalars (pressure,
porosity) live at cell centres; each velocity component lives on the faces normal to it
(Harlow & Welch 1965, the MAC grid):

=========  ===============================  ===============================
location   meaning                          interior shape
=========  ===============================  ===============================
``ccc``    cell centres (p, eps)            ``(nx,   ny,   nz)``
``fcc``    x-faces (u)                      ``(nx+1, ny,   nz)``
``cfc``    y-faces (v)                      ``(nx,   ny+1, nz)``
``ccf``    z-faces (w)                      ``(nx,   ny,   nz+1)``
=========  ===============================  ===============================

Every field array carries ``halo`` ghost layers on each side in every direction, so the
array of a ``fcc`` field has shape ``(nx+1+2h, ny+2h, nz+2h)``.  Interior index ``i``
(0-based) is array index ``i + h``.  Face ``i`` of a face field sits at ``x0 + i*dx``;
cell ``i`` lies between faces ``i`` and ``i+1``, its centre at ``x0 + (i+1/2) dx``.
Boundary conditions are applied by filling the halos (see :mod:`cfddem.gas.boundaries`),
so interior stencils never branch (the Oceananigans.jl design).

A :class:`Field` couples an array to its location; arithmetic between fields of different
locations raises ``ValueError`` (the jax-cfd ``GridArray`` offset check).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cfddem.errors import CaseError

LOCATIONS = ("ccc", "fcc", "cfc", "ccf")


@dataclass(frozen=True)
class StaggeredGrid:
    """Uniform staggered grid.

    Parameters
    ----------
    shape: (nx, ny, nz) number of cells.
    lengths: (Lx, Ly, Lz) box size [m].
    origin: (x0, y0, z0) lower corner [m].
    halo: number of ghost layers (1 suffices for central stencils, 2 for the TVD advection).
    """

    shape: tuple
    lengths: tuple
    origin: tuple = (0.0, 0.0, 0.0)
    halo: int = 2

    def __post_init__(self):
        if len(self.shape) != 3 or any(int(n) < 1 for n in self.shape):
            raise CaseError("gas.grid.shape", f"need three positive cell counts, got {self.shape}")
        if len(self.lengths) != 3 or any(float(L) <= 0 for L in self.lengths):
            raise CaseError("gas.grid.lengths", f"need three positive lengths, got {self.lengths}")
        if self.halo not in (1, 2):
            raise CaseError("gas.grid.halo", f"halo must be 1 or 2, got {self.halo}")
        object.__setattr__(self, "shape", tuple(int(n) for n in self.shape))
        object.__setattr__(self, "lengths", tuple(float(L) for L in self.lengths))
        object.__setattr__(self, "origin", tuple(float(o) for o in self.origin))

    # --- spacing and coordinates -------------------------------------------------------
    @property
    def spacing(self) -> tuple:
        return tuple(L / n for L, n in zip(self.lengths, self.shape))

    @property
    def ncells(self) -> int:
        return int(np.prod(self.shape))

    @property
    def cell_volume(self) -> float:
        return float(np.prod(self.spacing))

    def centres(self, d: int) -> np.ndarray:
        """Cell-centre coordinates along direction d (interior only), length n_d."""
        n, h, o = self.shape[d], self.spacing[d], self.origin[d]
        return o + (np.arange(n) + 0.5) * h

    def faces(self, d: int) -> np.ndarray:
        """Face coordinates along direction d (interior only), length n_d + 1."""
        n, h, o = self.shape[d], self.spacing[d], self.origin[d]
        return o + np.arange(n + 1) * h

    def coords(self, loc: str, d: int, with_halo: bool = True) -> np.ndarray:
        """Coordinates along direction d of the points of location ``loc`` (incl. halos)."""
        staggered = loc[d] == "f"
        n, h, o, g = self.shape[d], self.spacing[d], self.origin[d], self.halo
        if staggered:
            idx = np.arange(-g, n + 1 + g) if with_halo else np.arange(n + 1)
            return o + idx * h
        idx = np.arange(-g, n + g) if with_halo else np.arange(n)
        return o + (idx + 0.5) * h

    def interior_shape(self, loc: str) -> tuple:
        check_location(loc)
        return tuple(n + (1 if loc[d] == "f" else 0) for d, n in enumerate(self.shape))

    def array_shape(self, loc: str) -> tuple:
        return tuple(n + 2 * self.halo for n in self.interior_shape(loc))

    def interior(self, loc: str) -> tuple:
        """Slices selecting the interior of an array of location ``loc``."""
        g = self.halo
        return tuple(slice(g, g + n) for n in self.interior_shape(loc))

    def zeros(self, loc: str) -> "Field":
        return Field(self, loc, np.zeros(self.array_shape(loc)))

    def mesh(self, loc: str, with_halo: bool = False):
        """(X, Y, Z) coordinate arrays of location ``loc`` (ij indexing)."""
        return np.meshgrid(*(self.coords(loc, d, with_halo) for d in range(3)), indexing="ij")


def check_location(loc: str) -> None:
    if loc not in LOCATIONS:
        raise ValueError(f"unknown field location {loc!r}; expected one of {LOCATIONS}")


class Field:
    """An array (with halos) at a staggered location on a grid.

    ``field.data`` is the full array incl. halos; ``field.interior`` a view of the interior.
    Adding or subtracting fields of different locations (or grids) raises ``ValueError``.
    """

    __slots__ = ("grid", "location", "data")

    def __init__(self, grid: StaggeredGrid, location: str, data: np.ndarray | None = None):
        check_location(location)
        self.grid = grid
        self.location = location
        shape = grid.array_shape(location)
        if data is None:
            data = np.zeros(shape)
        data = np.asarray(data, dtype=np.float64)
        if data.shape != shape:
            raise ValueError(f"{location} field on grid {grid.shape} needs array shape {shape}, got {data.shape}")
        self.data = data

    @property
    def interior(self) -> np.ndarray:
        return self.data[self.grid.interior(self.location)]

    @interior.setter
    def interior(self, values) -> None:
        self.data[self.grid.interior(self.location)] = values

    def copy(self) -> "Field":
        return Field(self.grid, self.location, self.data.copy())

    def _check(self, other) -> None:
        if isinstance(other, Field):
            if other.location != self.location:
                raise ValueError(f"location mismatch: {self.location} field combined with {other.location} field")
            if other.grid is not self.grid and other.grid != self.grid:
                raise ValueError("fields live on different grids")

    def _binary(self, other, op):
        self._check(other)
        o = other.data if isinstance(other, Field) else other
        return Field(self.grid, self.location, op(self.data, o))

    def __add__(self, other):
        return self._binary(other, np.add)

    def __sub__(self, other):
        return self._binary(other, np.subtract)

    def __mul__(self, other):
        return self._binary(other, np.multiply)

    __radd__ = __add__
    __rmul__ = __mul__

    def __iadd__(self, other):
        self._check(other)
        self.data += other.data if isinstance(other, Field) else other
        return self

    def __isub__(self, other):
        self._check(other)
        self.data -= other.data if isinstance(other, Field) else other
        return self

    def __repr__(self) -> str:
        return f"Field({self.location}, interior {self.grid.interior_shape(self.location)})"
