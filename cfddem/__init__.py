"""cfddem: coupled CFD-DEM for granular flows.

A Numba discrete-element particle solver two-way coupled to a volume-averaged
Navier-Stokes gas solver on a staggered finite-volume grid.
"""

import os as _os

# numpy's OpenBLAS starts one thread per core at the first BLAS call (a dot product in the
# pressure solve, a matrix-vector product on particle positions) and leaves them spinning
# after every call.  On a 2-core machine they take the cores from numba's threads: one
# coupling step of the 30,000-particle chute cost 26 ms of CPU with them and 14 ms without
# (the same wall-time minimum).  The hot loops are numba kernels and the BLAS calls are small,
# so BLAS runs on one thread unless the user sets these variables.  This only works if cfddem
# is imported before numpy (as `cfddem run` does); see docs/benchmarks.md.
for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")

__version__ = "0.1.0"
