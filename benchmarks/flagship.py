"""The flagship's cost, A against B, over the same continuation of a developed flow.

    python benchmarks/flagship.py --checkpoint runs/dev/checkpoints/ckpt_X.h5 --duration 0.2 \\
        --a-tree /path/to/old/checkout --b-set time.dt=8e-5 --b-set gas.coupling_interval=4 \\
        [--case cases/chute_16rpm] [--threads 2] [--rounds 2] [--out /tmp/flagship] \\
        [--a-env GOMP_SPINCOUNT=0] [--b-env ...] [--legacy-pairs]

Each side is ``cfddem run CASE`` from the checkpoint (``checkpoint.start_from``) for
``--duration`` seconds of flow, run from a code tree (``--a-tree``/``--b-tree``, default this
checkout: ``python -m cfddem.cli`` with the tree as the working directory imports that tree's
cfddem) with its own overrides (``--a-set``/``--b-set``, repeatable) and environment variables
(``--a-env``/``--b-env`` KEY=VALUE, repeatable; for example the OpenMP threads' waiting).  One untimed warm-up run per
side fills its numba cache; then the rounds run A, B then B, A, ... and the wall time of each
run (``wall_time`` of its results.h5, the time loop without start-up) and its cost split are
printed with the CPU model and the load before and after, and the ratio A/B per round.
Never run it beside another timing job or on a loaded machine.

``--legacy-pairs``: code from before commit c03cb13 (for example 1b56e68) cannot read the pair
list of a checkpoint written since (it expects per-pair force arrays ``l_pf``, ``l_pr``).  The
option writes ``OUT/start.h5``, a copy of the checkpoint with those arrays zero-filled and a
neighbour rebuild at the first step (the contact histories carry over through it), and starts
both sides from that copy, so that both do the same work.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import h5py
from machine import cpu_model  # benchmarks/machine.py


def load() -> str:
    return open("/proc/loadavg").read().split()[0] if os.path.exists("/proc/loadavg") else "?"


def checkpoint_time(path: str) -> float:
    with h5py.File(path, "r") as f:
        return float(f["clock"].attrs["time"])


def run_side(tree: str, case: str, sets: list, ckpt: str, t_end: float, out: Path, threads: int, cache: str,
             extra_env: dict | None = None):
    ckpt = str(Path(ckpt).resolve())
    case = str(Path(case).resolve())
    cmd = [sys.executable, "-m", "cfddem.cli", "run", case, "--set", f'checkpoint.start_from="{ckpt}"',
           "--set", f"time.end_time={t_end}", "--set", f"measurements.start_time={t_end - 0.01}",
           "--set", "study.compare_without_gas=false", "--set", "output.vtk=false",
           "--set", "output.plots=false", "--set", "checkpoint.wall_interval=0",
           "--out", str(out), "--force", "--overwrite", "--threads", str(threads)]
    for s in sets:
        cmd += ["--set", s]
    env = dict(os.environ, NUMBA_CACHE_DIR=cache, **(extra_env or {}))
    t0 = time.perf_counter()
    p = subprocess.run(cmd, cwd=tree, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        raise SystemExit(f"run failed in {tree}: {p.stderr.strip().splitlines()[-1] if p.stderr else p.returncode}")
    with h5py.File(out / "results.h5", "r") as f:
        meta = dict(f["metadata"].attrs)
    timings = {k[5:]: float(v) for k, v in meta.items() if k.startswith("time_")}
    return float(meta.get("wall_time", wall)), timings


def legacy_pairs(src: str, dst: Path) -> str:
    """Copy the checkpoint ``src`` to ``dst`` with the per-pair force arrays that code before
    commit c03cb13 reads (zeros: they are outputs of a force pass) and a forced rebuild."""
    import shutil

    import numpy as np

    shutil.copyfile(src, dst)
    with h5py.File(dst, "r+") as f:
        g = f["system"]
        n = g["l_pi"].shape[0]
        for name, width in (("l_pf", 6), ("l_pr", 3)):
            if name not in g:
                g[name] = np.zeros((n, width))
        g.attrs["need_rebuild"] = np.int64(1)
    return str(dst)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--duration", type=float, default=0.2)
    ap.add_argument("--case", default="cases/chute_16rpm")
    ap.add_argument("--a-tree", default=".")
    ap.add_argument("--b-tree", default=".")
    ap.add_argument("--a-set", action="append", default=[])
    ap.add_argument("--b-set", action="append", default=[])
    ap.add_argument("--a-env", action="append", default=[], help="KEY=VALUE for side A's environment")
    ap.add_argument("--b-env", action="append", default=[], help="KEY=VALUE for side B's environment")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--out", default="/tmp/flagship_bench")
    ap.add_argument("--legacy-pairs", action="store_true",
                    help="start both sides from a copy of the checkpoint that code before c03cb13 reads")
    a = ap.parse_args(argv)
    t_end = checkpoint_time(a.checkpoint) + a.duration
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    if a.legacy_pairs:
        a.checkpoint = legacy_pairs(a.checkpoint, out / "start.h5")
        print(f"start: {a.checkpoint} (pair arrays for code before c03cb13, rebuild at the first step)")
    sides = {"A": (a.a_tree, a.a_set), "B": (a.b_tree, a.b_set)}
    envs = {k: dict(e.split("=", 1) for e in v) for k, v in (("A", a.a_env), ("B", a.b_env))}
    print(f"CPU: {cpu_model()}; {os.cpu_count()} logical CPUs; threads {a.threads}; load {load()}")
    for name, (tree, sets) in sides.items():
        print(f"{name}: tree {Path(tree).resolve()}, overrides {sets or 'none'}, environment {envs[name] or 'as is'}")
        run_side(tree, a.case, sets, a.checkpoint, t_end, out / f"warm_{name}", a.threads, f"/tmp/nc_flagship_{name}",
                 envs[name])
    rows = []
    for r in range(a.rounds):
        res = {}
        for name in (["A", "B"] if r % 2 == 0 else ["B", "A"]):  # the order alternates
            tree, sets = sides[name]
            l0 = load()
            w, tm = run_side(tree, a.case, sets, a.checkpoint, t_end, out / f"r{r}_{name}", a.threads,
                             f"/tmp/nc_flagship_{name}", envs[name])
            res[name] = w
            split = ", ".join(f"{k} {v:.1f}" for k, v in sorted(tm.items()) if v > 0.05 and k != "total")
            print(f"round {r + 1} {name}: {w:.1f} s for {a.duration:g} s of flow ({split}); load {l0} -> {load()}",
                  flush=True)
        rows.append(res)
        print(f"round {r + 1}: A/B = {res['A'] / res['B']:.3f}", flush=True)
    (out / "flagship.json").write_text(json.dumps({"cpu": cpu_model(), "rounds": rows, "duration": a.duration,
                                                   "sides": {k: {"tree": str(Path(v[0]).resolve()), "set": v[1], "env": envs[k]}
                                                             for k, v in sides.items()}}, indent=1))


if __name__ == "__main__":
    main()
