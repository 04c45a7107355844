"""cfddem: coupled CFD-DEM for granular flows.

A Numba discrete-element particle solver two-way coupled to a volume-averaged
Navier-Stokes gas solver on a staggered finite-volume grid.
"""

__version__ = "0.1.0"
