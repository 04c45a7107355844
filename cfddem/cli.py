"""Command-line interface: a thin layer over the Python API.

    cfddem run CASE [--out DIR] [--set K=V]... [--end-time T] [--overwrite | --resume] [--threads N] [--force]
    cfddem check CASE [--set K=V]...
    cfddem compare RUN_A RUN_B [--out DIR]
    cfddem sweep CASE --vary KEY=V1,V2,... [--scheduler ADDRESS] [--workers N]
    cfddem stability CASE --vary KEY=V1,V2,... [--vary ...] [--out DIR]   (or --map drag|courant|cells)
    cfddem accuracy SWEEP_DIR [--reference NAME] [--floor-from NAME]
    cfddem beverloo SILO_CASE --widths B1,B2,... [--set K=V]... [--out DIR] [--workers N]
    cfddem coarse-grain RUN_DIR_OR_CHECKPOINT [--spacing H] [--width W] [--out DIR] [--janssen MU_SIDE,MU_FRONT --phi DEG]
    cfddem report OUT

Exit codes: 0 success, 2 bad input (one line on stderr), 3 a run that failed (blow-up or solver
failure, with its message), 128 + signal number for a run stopped by SIGINT/SIGTERM (after
writing a checkpoint).
"""

from __future__ import annotations

import argparse
import math
import sys

from .errors import CaseError, CfddemError, RunError


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit code 2
        print(f"cfddem: error: {message}", file=sys.stderr)
        raise SystemExit(2)


def _parser() -> argparse.ArgumentParser:
    p = _Parser(prog="cfddem", description="Coupled CFD-DEM for granular flows")
    from . import __version__

    p.add_argument("--version", action="version", version=f"cfddem {__version__}")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)

    r = sub.add_parser("run", help="run a case")
    r.add_argument("case", help="case folder (holding case.toml) or a case.toml file")
    r.add_argument("--out", help="output folder (default: CASE/output)")
    r.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a case key, e.g. --set particles.diameter=0.004 (value parsed as TOML)")
    r.add_argument("--end-time", type=float, help="stop at this simulated time (s), overriding time.end_time")
    r.add_argument("--overwrite", action="store_true", help="replace an existing run folder")
    r.add_argument("--resume", action="store_true", help="continue the run in --out from its newest checkpoint")
    r.add_argument("--threads", type=int, help="numba threads (default: time.threads, 0 = all cores)")
    r.add_argument("--force", action="store_true", help="run even when dt > t_c/5 or above the stable step")
    r.add_argument("--quiet", action="store_true", help="no progress line, log to file only")

    c = sub.add_parser("check", help="validate a case and print its derived numbers")
    c.add_argument("case")
    c.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")

    cmp_ = sub.add_parser("compare", help="compare two runs (e.g. gas against no gas): Markdown/HTML report")
    cmp_.add_argument("run_a", help="run folder A (the reference, e.g. without gas)")
    cmp_.add_argument("run_b", help="run folder B")
    cmp_.add_argument("--out", help="report folder (default: RUN_B/compare)")
    cmp_.add_argument("--labels", nargs=2, metavar=("A", "B"), help="labels of the runs in the report")

    acc = sub.add_parser("accuracy", help="speed against accuracy chart of a sweep folder")
    acc.add_argument("sweep_dir", help="a folder written by cfddem sweep")
    acc.add_argument("--reference", help="a variant (folder name) of the setting taken as the most accurate one "
                                         "(with its replicas)")
    acc.add_argument("--floor-from", help="a variant whose setting's replicas give the run-to-run scatter when "
                                          "the reference is not repeated (e.g. the case's step, cheaper to repeat)")
    acc.add_argument("--out", help="output folder (default: the sweep folder)")

    blr = sub.add_parser("blending-report", help="one report (concentration, VRR, RTD, velocity maps, cost) of a "
                                                 "blending sweep folder")
    blr.add_argument("sweep_dir", nargs="+", help="one or more folders written by cfddem sweep over silo-blender "
                                                  "variants (e.g. one per flow pattern)")
    blr.add_argument("--out", help="report folder (default: SWEEP_DIR/blending_report)")

    try:
        from .sweep import add_sweep_parser
    except ImportError:  # pragma: no cover
        add_sweep_parser = None
    if add_sweep_parser is not None:
        add_sweep_parser(sub)

    from .stability import add_stability_parser

    add_stability_parser(sub)

    from .silo_study import add_beverloo_parser

    add_beverloo_parser(sub)

    from .calibrate import add_calibrate_parser

    add_calibrate_parser(sub)

    cg = sub.add_parser("coarse-grain", help="density, velocity and stress fields of a run's checkpoint on a grid")
    cg.add_argument("src", metavar="RUN_DIR_OR_CHECKPOINT", help="a run folder (its newest checkpoint) or a checkpoint file")
    cg.add_argument("--spacing", help="cell size in m: one value or x,y,z (default: the width)")
    cg.add_argument("--width", type=float, help="Gaussian kernel's standard deviation in m (default: 3 mean radii)")
    cg.add_argument("--cutoff", type=float, default=3.0, help="kernel cutoff in widths (default 3)")
    cg.add_argument("--edges", choices=("open", "correct"), default="open", help="treatment of the grid's edges")
    cg.add_argument("--lo", help="grid's lower corner x,y,z in m (default: the particles' extent + the cutoff)")
    cg.add_argument("--hi", help="grid's upper corner x,y,z in m")
    cg.add_argument("--case", dest="case_dir", help="the case folder, when the run's case.resolved.toml cannot be used")
    cg.add_argument("--out", help="output folder (default: RUN/coarse)")
    cg.add_argument("--janssen", metavar="MU_SIDE,MU_FRONT",
                    help="add Janssen's curve: friction of the walls across the first / second horizontal axis")
    k = cg.add_mutually_exclusive_group()
    k.add_argument("--K", type=float, help="Janssen's lateral pressure ratio")
    k.add_argument("--phi", type=float, help="bulk friction angle in degrees: K = (1 - sin phi) / (1 + sin phi)")
    k.add_argument("--bulk-friction", type=float, help="bulk friction tan(phi) (e.g. from cfddem calibrate)")

    rep = sub.add_parser("report", help="(re)write the PNG plots of a finished run")
    rep.add_argument("out", help="a run folder (holding results.h5)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        return _dispatch(args)
    except CaseError as e:
        print(f"cfddem: error: {e}", file=sys.stderr)
        return 2
    except RunError as e:
        print(f"cfddem: run failed: {e}", file=sys.stderr)
        return 3
    except CfddemError as e:
        print(f"cfddem: error: {e}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print("cfddem: interrupted", file=sys.stderr)
        return 130


def _dispatch(args) -> int:
    from .config import load_case

    if args.command == "check":
        from .simulation import check_time_step, describe_case

        case = load_case(args.case, overrides=args.overrides)
        print(f"case {case.name}: OK")
        for line in describe_case(case):
            print("  " + line)
        ratio = check_time_step(case)
        if ratio > 0.05:
            print(f"cfddem: warning: time.dt is {ratio * 20:.1f} t_c/20: collisions resolved by fewer than 20 steps",
                  file=sys.stderr)
        return 0
    if args.command == "run":
        from .simulation import run_case

        overrides = list(args.overrides)
        if args.force:
            overrides.append("time.force=true")
        if args.end_time is not None:
            overrides.append(f"time.end_time={args.end_time!r}")
        case = load_case(args.case, overrides=overrides)
        if args.resume and args.overwrite:
            raise CaseError("--resume", "cannot be combined with --overwrite")
        summary, comparison = run_case(case, out_dir=args.out, overwrite=args.overwrite, resume=args.resume,
                                       threads=args.threads, echo=not args.quiet, progress=not args.quiet)
        print(f"cfddem: {summary.status}: t = {summary.time:.4g} s, {summary.steps} steps, "
              f"{summary.wall_time:.1f} s wall; results in {summary.out_dir}")
        if summary.message:
            print(f"cfddem: {summary.message}")
        if comparison is not None:
            c = comparison
            jit = (" (numba's first compilation of the kernels left out)"
                   if max(c.get("compile_time_a", 0.0), c.get("compile_time_b", 0.0)) >= 0.1 else "")
            print(f"cfddem: gas against no gas: {c['headline']}; the gas costs {c['wall_time_ratio']:.2f}x "
                  f"the wall time{jit}; report: {summary.out_dir}/compare/report.html")
        if summary.status == "interrupted":
            import signal as _signal

            return 128 + int(_signal.SIGINT if "SIGINT" in summary.message else _signal.SIGTERM)
        return 0
    if args.command == "compare":
        from pathlib import Path

        from .report.compare import compare_runs

        out = Path(args.out) if args.out else Path(args.run_b) / "compare"
        summary = compare_runs(args.run_a, args.run_b, out, labels=tuple(args.labels) if args.labels else (None, None))
        if "velocity_end_a" in summary:
            print(f"velocity at the chute end: A {summary['velocity_end_a']:.4f} m/s, B {summary['velocity_end_b']:.4f} m/s, "
                  f"(B - A)/A = {100 * summary['relative_difference_end']:+.2f} %; wall time B/A = "
                  f"{summary['wall_time_ratio']:.3f}")
        else:
            print(f"{summary['headline']}; wall time B/A = {summary['wall_time_ratio']:.3f}")
        print(f"report: {out / 'report.md'}, {out / 'report.html'}, {out / 'summary.json'}")
        return 0
    if args.command == "accuracy":
        from .report.speed_accuracy import markdown, speed_accuracy

        res = speed_accuracy(args.sweep_dir, reference=args.reference, out=args.out, floor_from=args.floor_from)
        print(markdown(res), end="")
        return 0
    if args.command == "blending-report":
        from .report.blending import blending_report

        res = blending_report(args.sweep_dir, out=args.out)
        for e in res["rows"]:
            print(f"  {e['name']}: {e['status']}" + (f", {e['flow_pattern']} flow" if e.get("flow_pattern") else "")
                  + (f", VRR {e['vrr']:.3g}" if isinstance(e.get("vrr"), float) and math.isfinite(e["vrr"]) else ""))
        print(f"report: {res['files'][0]}")
        return 0
    if args.command == "sweep":
        from .sweep import run_sweep_from_args

        return run_sweep_from_args(args)
    if args.command == "stability":
        from .stability import run_stability_from_args

        return run_stability_from_args(args)
    if args.command == "beverloo":
        from .silo_study import run_beverloo_from_args

        return run_beverloo_from_args(args)
    if args.command == "calibrate":
        from .calibrate import run_calibrate_from_args

        return run_calibrate_from_args(args)
    if args.command == "coarse-grain":
        from .measure.coarse import coarse_grain_run, lateral_pressure_ratio

        def floats(key, text, n):
            try:
                v = [float(x) for x in text.split(",")]
            except ValueError:
                raise CaseError(key, f"expected {n} comma-separated numbers, got {text!r}") from None
            if len(v) not in ({1, 3} if n == "1 or 3" else {n}):
                raise CaseError(key, f"expected {n} comma-separated numbers, got {text!r}")
            return v

        K = args.K
        if args.phi is not None:
            K = lateral_pressure_ratio(math.tan(math.radians(args.phi)))
        elif args.bulk_friction is not None:
            K = lateral_pressure_ratio(args.bulk_friction)
        res = coarse_grain_run(args.src, args.out, spacing=floats("--spacing", args.spacing, "1 or 3") if args.spacing else None,
                               width=args.width, cutoff=args.cutoff, edges=args.edges,
                               lo=floats("--lo", args.lo, 3) if args.lo else None,
                               hi=floats("--hi", args.hi, 3) if args.hi else None, case_dir=args.case_dir,
                               janssen_walls=floats("--janssen", args.janssen, 2) if args.janssen else None, K=K)
        print(f"{res['checkpoint']}: t = {res['time']:.4g} s; grid {res['shape']} of "
              f"{'x'.join(f'{1e3 * h:.3g}' for h in res['spacing'])} mm, width {1e3 * res['width']:.3g} mm; "
              f"mass on the grid {res['mass_on_grid']:.6g} kg of {res['mass']:.6g} kg")
        print(f"bulk density {res['rho_b']:.4g} kg/m3, equivalent fill height {1e3 * res['H']:.4g} mm, "
              f"section {1e3 * res['W']:.4g} x {1e3 * res['T']:.4g} mm")
        if "z_c" in res:
            print(f"Janssen: K = {res['K']:.3g}, z_c = {1e3 * res['z_c']:.4g} mm"
                  + (f"; at 10-20 % of the height: DEM {res['pressure_low']:.4g} Pa, Janssen {res['janssen_low']:.4g} Pa"
                     if "pressure_low" in res else ""))
        for f in res["files"]:
            print(f)
        return 0
    if args.command == "report":
        from pathlib import Path

        from .report.plots import write_run_report

        out = Path(args.out)
        h5 = out / "results.h5"
        if not h5.exists():
            raise CaseError("OUT", f"no results.h5 in {out}")
        files = write_run_report(h5, out / "report")
        for f in files:
            print(f)
        return 0
    raise AssertionError(args.command)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
