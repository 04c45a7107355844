"""The one place that holds the numba flags and the cache policy.

Every compiled kernel in cfddem is decorated with :func:`kernel` (serial) or
:func:`parallel_kernel` (one ``prange`` loop).  The flags are chosen once here:

* ``cache``: on by default so that a second run starts in seconds; set
  ``CFDDEM_NUMBA_CACHE=0`` to switch it off (CI starts from an empty
  ``NUMBA_CACHE_DIR``).  Kernels take arrays and scalars only: constants are passed
  as arguments because numba freezes globals into the cache.
* ``fastmath``: off.  It would let LLVM drop the NaN checks the kernels rely on to
  report blow-ups.
* ``error_model="numpy"``: division by zero gives inf/nan instead of raising, so no
  exception machinery inside kernels.
* ``boundscheck``: off, except when ``CFDDEM_BOUNDSCHECK=1`` (debugging).

``NUMBA_DISABLE_JIT=1`` runs every kernel as plain Python (slow, for debugging and
for a test tier).
"""

from __future__ import annotations

import os

# Threading: prefer OpenMP with passive waiting after a short spin.  With numba's TBB layer (chosen silently once
# libtbb is installed) or with spinning OpenMP threads, the per-step kernels ran 10-20x slower
# on 2 cores shared with other processes (measured on the chute: 1.5 s against 30 s for 6000
# steps of ~3000 particles).  Users can still override both variables.
_USER_LAYER = any(k in os.environ for k in ("NUMBA_THREADING_LAYER", "NUMBA_THREADING_LAYER_PRIORITY"))
os.environ.setdefault("NUMBA_THREADING_LAYER_PRIORITY", "omp tbb workqueue")
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
# ... but a short spin first: with no spin at all every parallel loop pays a futex wake-up of its
# threads (45-65 us on these VMs, six loops per particle step), with 1,000 spins (a few us) the
# threads that finish one loop are still awake for the next one.  Periodic 30k chute, 2 threads,
# alternating runs: 1.13-1.27x faster on a quiet machine, 0.89-1.04x with one busy process
# sharing the two cores (no spin gave 1x, the full default spin of 300,000 0.5x there).
# libgomp reads it when the OpenMP layer is loaded, at the first parallel launch.
os.environ.setdefault("GOMP_SPINCOUNT", "1000")

import numba  # noqa: E402
from numba import prange  # noqa: E402, F401  (re-exported for kernel modules)

# numba reads the priority above into numba.config when it is first imported, so a script
# that imports numba before cfddem would keep numba's own order (TBB first; measured: the
# 30k-particle chute's particle step 1.6x slower on 2 threads).  The layer itself is chosen
# at the first parallel launch, so setting the config here still takes effect then (unless
# the user chose a layer, or a parallel function already ran).
if not _USER_LAYER:
    numba.config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]

CACHE = os.environ.get("CFDDEM_NUMBA_CACHE", "1") != "0"
BOUNDSCHECK = os.environ.get("CFDDEM_BOUNDSCHECK", "0") == "1"

FLAGS = dict(cache=CACHE, fastmath=False, error_model="numpy", nogil=True, boundscheck=BOUNDSCHECK)
PARALLEL_FLAGS = dict(FLAGS, parallel=True)


def kernel(fn=None, **extra):
    """Decorate a serial compiled function (``@kernel`` or ``@kernel(inline="always")``)."""
    flags = dict(FLAGS, **extra)
    if fn is None:
        return lambda f: numba.njit(**flags)(f)
    return numba.njit(**flags)(fn)


def parallel_kernel(fn=None, **extra):
    """Decorate a compiled function holding one ``prange`` loop."""
    flags = dict(PARALLEL_FLAGS, **extra)
    if fn is None:
        return lambda f: numba.njit(**flags)(f)
    return numba.njit(**flags)(fn)


def set_threads(n: int | None) -> int:
    """Set the numba thread count (0 or None: all available); return the count in use."""
    maxt = numba.config.NUMBA_NUM_THREADS
    if not n:
        n = maxt
    n = max(1, min(int(n), maxt))
    numba.set_num_threads(n)
    return n


def get_threads() -> int:
    return numba.get_num_threads()
