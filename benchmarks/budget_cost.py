"""Cost of the stepped momentum budget on a developed 16 rpm chute (about 30,000 beads, no gas):
the same 250 steps with and without the budget attached, 10 alternating rounds, 1 numba thread.

    python benchmarks/budget_cost.py RUN/checkpoints/ckpt_XXXX.h5   # a checkpoint of cases/chute_16rpm
"""
import subprocess, sys, time
from pathlib import Path
import numpy as np
from cfddem.config import load_case
from cfddem.simulation import Simulation
from cfddem._jit import set_threads

CKPT = sys.argv[1]
print(subprocess.run("lscpu | grep 'Model name'; uptime", shell=True, capture_output=True, text=True).stdout)
set_threads(1)
case = load_case(Path("cases/chute_16rpm"), overrides=["gas.enabled=false", "checkpoint.start_from=" + CKPT,
                                                      "measurements.start_time=3.0", "study.compare_without_gas=false"])
sim = Simulation(case, Path("/tmp/bcost"), echo=False, progress=False, threads=1, overwrite=True)
sim.build()
sim._branch_from(Path(CKPT))
s, b = sim.system, sim.budget
b.sample(s.time, s)
s.step(50)  # compile both paths
s.step_hook = None
s.step(50)
times = {"off": [], "on": []}
for r in range(10):
    for mode in ("off", "on"):
        s.step_hook = b.accumulate if mode == "on" else None
        t0 = time.perf_counter()
        st = s.step(250)
        assert st.ok
        times[mode].append(time.perf_counter() - t0)
print("n particles", s.n)
for k, v in times.items():
    print(k, [round(x, 3) for x in v])
r = np.array(times["on"]) / np.array(times["off"])
print("ratio on/off per round", np.round(r, 4), "median", round(float(np.median(r)), 4))
print(subprocess.run("uptime", shell=True, capture_output=True, text=True).stdout)
