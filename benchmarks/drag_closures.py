"""Compare the five drag closures of cfddem.coupling.drag.

    python benchmarks/drag_closures.py --out DIR

Writes DIR/drag_closures.png (top row: F against porosity at Re = 0.1, 10, 1000; bottom
row: F against Re at eps = 0.4, 0.6, 0.9; F = F_d/(3 pi mu d eps |u - v|), Re on the
superficial slip), DIR/drag_closures.json (the plotted samples, minimum fluidisation and
terminal velocities of 3 mm glass beads in air per closure) and prints the evaluation
throughput of the numpy closures and of the compiled scalar twins (compile time excluded).
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

from cfddem.coupling import drag

STYLE = {
    "beetstra": dict(color="k", lw=2.0),
    "wen_yu": dict(color="tab:blue"),
    "ergun_gidaspow": dict(color="tab:orange", ls="--"),
    "di_felice": dict(color="tab:green", ls="-."),
    "koch_hill": dict(color="tab:red", ls=":", lw=2.0),
}


def samples():
    eps = np.linspace(0.36, 0.999, 300)
    re = np.logspace(-2, 4, 300)
    by_eps = {r: {n: fn(eps, np.full_like(eps, r)).tolist() for n, fn in drag.CLOSURES.items()} for r in (0.1, 10.0, 1000.0)}
    by_re = {e: {n: fn(np.full_like(re, e), re).tolist() for n, fn in drag.CLOSURES.items()} for e in (0.4, 0.6, 0.9)}
    return eps, re, by_eps, by_re


def plot(path, eps, re, by_eps, by_re):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(14, 8.5), constrained_layout=True)
    for ax, (r, curves) in zip(axes[0], by_eps.items()):
        for n, f in curves.items():
            ax.semilogy(eps, f, label=n, **STYLE[n])
        ax.set_title(f"Re = {r:g}")
        ax.set_xlabel("porosity eps")
        ax.set_ylabel("F = F_d / (3 pi mu d eps |u-v|)")
        ax.axvline(0.8, color="0.8", lw=0.8)
        ax.grid(True, which="both", alpha=0.3)
    for ax, (e, curves) in zip(axes[1], by_re.items()):
        for n, f in curves.items():
            ax.loglog(re, f, label=n, **STYLE[n])
        ax.set_title(f"eps = {e:g}")
        ax.set_xlabel("Re = eps rho |u-v| d / mu")
        ax.set_ylabel("F")
        ax.grid(True, which="both", alpha=0.3)
    axes[0, 0].legend(fontsize=9)
    fig.suptitle("cfddem drag closures (Beetstra normalisation; grey line: Ergun/Wen-Yu switch at eps = 0.8)")
    fig.savefig(path, dpi=120)
    plt.close(fig)


def throughput(n=1_000_000):
    rng = np.random.default_rng(0)
    eps = rng.uniform(0.4, 1.0, n)
    re = 10.0 ** rng.uniform(-2, 3, n)
    out = np.empty(n)
    rows = {}
    for name, fn in drag.CLOSURES.items():
        cid = drag.closure_id(name)
        drag.drag_scalar_array(cid, eps[:10], re[:10], out[:10])  # compile
        t0 = time.perf_counter()
        fn(eps, re)
        t1 = time.perf_counter()
        drag.drag_scalar_array(cid, eps, re, out)
        t2 = time.perf_counter()
        rows[name] = {"numpy_ns_per_eval": 1e9 * (t1 - t0) / n, "compiled_ns_per_eval": 1e9 * (t2 - t1) / n}
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="output folder")
    ap.add_argument("--no-timing", action="store_true", help="skip the throughput measurement")
    args = ap.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    eps, re, by_eps, by_re = samples()
    png = os.path.join(args.out, "drag_closures.png")
    plot(png, eps, re, by_eps, by_re)
    glass = dict(rho_p=2550.0, rho_g=1.2, d=3e-3, mu=1.8e-5)
    summary = {
        "normalisation": "F = F_d/(3 pi mu d eps |u-v|), Re = eps rho |u-v| d/mu, beta = 18 mu (1-eps) eps F/d^2",
        "glass_3mm_in_air": {
            n: {
                "U_mf_eps0.4_m_s": drag.minimum_fluidisation_velocity(0.4, closure=n, **glass),
                "terminal_velocity_m_s": drag.terminal_velocity(glass["rho_p"], glass["rho_g"], glass["d"], glass["mu"], closure=n),
            }
            for n in drag.CLOSURES
        },
        "F_vs_eps": {"eps": eps.tolist(), "curves": {str(k): v for k, v in by_eps.items()}},
        "F_vs_re": {"re": re.tolist(), "curves": {str(k): v for k, v in by_re.items()}},
    }
    if not args.no_timing:
        summary["throughput"] = throughput()
    with open(os.path.join(args.out, "drag_closures.json"), "w") as fh:
        json.dump(summary, fh, indent=1)
    print(f"wrote {png}")
    for n, v in summary["glass_3mm_in_air"].items():
        print(f"{n:15s} U_mf(eps=0.4) = {v['U_mf_eps0.4_m_s']:.3f} m/s   v_t = {v['terminal_velocity_m_s']:.2f} m/s")
    for n, v in summary.get("throughput", {}).items():
        print(f"{n:15s} numpy {v['numpy_ns_per_eval']:6.1f} ns/eval   compiled {v['compiled_ns_per_eval']:6.1f} ns/eval")


if __name__ == "__main__":
    main()
