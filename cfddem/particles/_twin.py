"""Serial twins of parallel kernels.

A ``prange`` kernel launched on a few dozen particles costs far more in thread start-up than in
arithmetic (about 0.1 ms per launch measured on 2 busy cores).  ``serial_twin`` compiles the same
Python function once more without ``parallel`` (``prange`` then acts as ``range``) under its own
name, so the two have separate cache entries.  Both perform exactly the same floating-point
operations per particle or pair (the only reductions are exact max/count), so switching between
them by system size does not change results.
"""

from __future__ import annotations

import types

from cfddem._jit import kernel


def serial_twin(dispatcher):
    f = getattr(dispatcher, "py_func", dispatcher)  # NUMBA_DISABLE_JIT=1: a plain function
    g = types.FunctionType(f.__code__, f.__globals__, f.__name__ + "_serial", f.__defaults__,
                           f.__closure__)
    g.__qualname__ = f.__qualname__ + "_serial"
    g.__doc__ = f.__doc__
    g.__module__ = f.__module__
    return kernel(g)
