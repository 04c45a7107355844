"""cfddem._jit's threading layer choice holds whether a script imports numba before cfddem
or after it (numba reads its layer priority at import, and picks TBB first on its own)."""

import os
import subprocess
import sys

SCRIPT = """
import sys
if sys.argv[1] == "numba_first":
    import numba  # noqa: F401
from cfddem._jit import parallel_kernel, prange, set_threads
import numba
import numpy as np

@parallel_kernel
def f(a):
    for i in prange(a.size):
        a[i] += 1.0

set_threads(2)
f(np.zeros(64))
print(numba.threading_layer())
"""


def _layer(order, **env):
    e = dict(os.environ, CFDDEM_NUMBA_CACHE="0", **env)
    for k in ("NUMBA_THREADING_LAYER", "NUMBA_THREADING_LAYER_PRIORITY"):
        if k not in env:
            e.pop(k, None)
    p = subprocess.run([sys.executable, "-c", SCRIPT, order], capture_output=True, text=True, env=e, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:]
    return p.stdout.strip().splitlines()[-1]


def test_layer_does_not_depend_on_the_import_order():
    first = _layer("cfddem_first")
    assert _layer("numba_first") == first
    # OpenMP when numba has it (the layer the kernels were tuned with), else what numba finds
    assert first in ("omp", "tbb", "workqueue")


def test_a_layer_chosen_by_the_user_is_kept():
    assert _layer("numba_first", NUMBA_THREADING_LAYER="workqueue") == "workqueue"
    assert _layer("cfddem_first", NUMBA_THREADING_LAYER_PRIORITY="workqueue omp tbb") == "workqueue"


def _spin(**env):
    e = dict(os.environ, CFDDEM_NUMBA_CACHE="0", **env)
    if "GOMP_SPINCOUNT" not in env:
        e.pop("GOMP_SPINCOUNT", None)
    code = "import cfddem._jit, os; print(os.environ['OMP_WAIT_POLICY'], os.environ['GOMP_SPINCOUNT'])"
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=e, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:]
    return p.stdout.split()


def test_threads_spin_briefly_before_sleeping_unless_the_user_says_otherwise():
    policy, spin = _spin()
    assert int(spin) == 1000
    assert _spin(GOMP_SPINCOUNT="0")[1] == "0"
