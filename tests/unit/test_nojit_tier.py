"""The no-JIT tier: the tests marked ``nojit`` (config validation, drag closures and their
compiled twins, grid operators and halo fills, contact kernels and single collisions, wall
geometry, neighbour search, inlets, measurements) run again with ``NUMBA_DISABLE_JIT=1``, so
every kernel they reach is also checked as plain Python (a kernel that only works compiled, or
only interpreted, fails one of the two runs)."""

import os
import re
import subprocess
import sys

from ..conftest import ROOT

#: how many tests carry the mark (parametrised cases counted one by one); the closing line of
#: the run must report at least this many passed
N_NOJIT = 188


def test_nojit_tier_passes_as_plain_python():
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    r = subprocess.run([sys.executable, "-m", "pytest", "-m", "nojit", "-q", "-p", "no:cacheprovider"],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    lines = r.stdout.strip().splitlines()
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    m = re.search(r"(\d+) passed", lines[-1])
    assert m, lines[-1]
    assert int(m.group(1)) >= N_NOJIT, lines[-1]
    assert "failed" not in lines[-1] and "error" not in lines[-1], lines[-1]
