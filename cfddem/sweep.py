"""Parameter sweeps on Dask: ``cfddem sweep CASE --vary KEY=V1,V2,... [--vary ...]``.

A sweep runs every variant of a case (the cartesian product of the ``--vary`` lists, or the
rows of a ``--variants`` TOML/CSV file, or both combined) as one Dask task per variant, each
into its own run folder ``SWEEP_DIR/<key1>=<v1>__<key2>=<v2>`` (sanitised), and writes

* ``SWEEP_DIR/summary.csv``  one row per variant: the varied keys, ``status`` (done, failed,
  skipped; the run's own ``stopped`` or ``interrupted`` for a run that hit its step or
  wall-time limit or got SIGINT/SIGTERM), ``wall_time``, the
  numba ``threads`` of the task, the run's ``steps`` and final ``time``, the measurements
  ``n_particles``, ``mass_out``, final ``mean_velocity_z`` (last row of ``/series``) and every
  numeric scalar under ``/measurements`` of its ``results.h5`` (column ``/``-joined path),
  ``error``;
* ``SWEEP_DIR/summary.md``   the same as a Markdown table;
* ``SWEEP_DIR/chart_<measurement>.png``  the chosen measurement against the first varied key,
  one line per combination of the other varied keys.

Scheduling: by default an embedded :class:`distributed.LocalCluster` on this machine with
``W`` worker *processes* of one Dask thread each and ``T = max(1, cores // W)`` numba threads
per worker, so that W x T <= cores.  ``NUMBA_NUM_THREADS=T`` is set in the worker environment
(the nanny's ``env``, applied before numba is imported in the worker) and every task also calls
``numba.set_num_threads`` (the setting is per thread).  With ``scheduler="tcp://HOST:PORT"`` the
tasks go to an existing cluster instead (the run folders must then be on a file system the
workers share with this machine).

Restart: a variant whose folder holds a ``run.json`` with status ``"done"``, a readable
``results.h5`` and the same resolved configuration as the variant now is *skipped* (its
summary is read back from the folder).  A variant whose folder holds an unfinished run of the
same configuration with a checkpoint (a crash, a killed worker, a wall-time stop) is continued
with ``Simulation(..., resume=True)``; every other variant is run from the start.

Dask is an optional dependency (``pip install cfddem[sweep]``), imported only when a sweep
runs; without it the sweep stops with a one-line :class:`~cfddem.errors.CaseError`.
"""

from __future__ import annotations

import csv
import hashlib
import itertools
import json
import math
import os
import re
import sys
import time as _time
import tomllib
from pathlib import Path
from typing import Any, Callable, Iterable

from .errors import CaseError, RunError

STATUSES = ("done", "failed", "skipped", "stopped", "interrupted")
RUN_INFO = ("wall_time", "threads", "steps", "time")
BASE_MEASUREMENTS = ("n_particles", "mass_out", "mean_velocity_z")
MAX_NAME = 150  # characters of a variant folder name before it is shortened with a hash


# ----------------------------------------------------------------------------------------------
# variants
# ----------------------------------------------------------------------------------------------
def _parse_value(text: str) -> Any:
    """A value as on ``--set``: TOML (``0.1``, ``true``, ``[0, 1, 0]``, ``"a"``), else the bare
    string."""
    text = text.strip()
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def split_values(text: str) -> list[str]:
    """Split ``"0.1,0.2,[1, 2]"`` at the commas outside brackets and quotes."""
    out, cur, depth, quote = [], [], 0, None
    for ch in text:
        if quote:
            cur.append(ch)
            if ch == quote:
                quote = None
            continue
        if ch in "\"'":
            quote = ch
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        elif ch == "," and depth == 0:
            out.append("".join(cur).strip())
            cur = []
            continue
        cur.append(ch)
    out.append("".join(cur).strip())
    return out


def parse_vary(spec: str) -> tuple[str, list[Any]]:
    """``"contact.particle_wall.mu=0.1,0.3"`` -> ``("contact.particle_wall.mu", [0.1, 0.3])``."""
    if "=" not in spec:
        raise CaseError("--vary", f"{spec!r}: expected KEY=V1,V2,... e.g. --vary contact.particle_wall.mu=0.1,0.3")
    key, values = spec.split("=", 1)
    key = key.strip()
    if not key or any(not p for p in key.split(".")):
        raise CaseError("--vary", f"{spec!r}: expected a dotted key such as contact.particle_wall.mu")
    items = split_values(values)
    if any(not v for v in items):
        raise CaseError("--vary", f"{spec!r}: empty value in the list")
    vals = [_parse_value(v) for v in items]
    return key, vals


def expand_variants(varies: Iterable[tuple[str, list[Any]]]) -> list[dict[str, Any]]:
    """Cartesian product of ``[(key, values), ...]`` (first key outermost), as a list of
    ``{key: value}`` dicts in that order; no keys -> ``[{}]``."""
    varies = list(varies)
    keys = [k for k, _ in varies]
    dup = {k for k in keys if keys.count(k) > 1}
    if dup:
        raise CaseError("--vary", f"key given twice: {', '.join(sorted(dup))}")
    return [dict(zip(keys, combo)) for combo in itertools.product(*(v for _, v in varies))]


def _flatten(d: dict, prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flatten(v, key + "."))
        else:
            out[key] = v
    return out


def read_variants_file(path: str | Path) -> list[dict[str, Any]]:
    """Variants from a file, one ``{dotted key: value}`` per row.

    * TOML: an array of tables named ``variants`` (or ``variant``), e.g.
      ``[[variants]]`` / ``"contact.particle_wall.mu" = 0.1`` (dotted keys or nested tables);
    * CSV: a header line of dotted keys, then one row per variant; cells are parsed as TOML
      values (``0.1``, ``true``, ``[0, 0, 1]``) or else kept as strings; an empty cell leaves
      the key at the case's value for that row.
    """
    p = Path(path)
    if not p.is_file():
        raise CaseError("--variants", f"no file {p}")
    suffix = p.suffix.lower()
    if suffix == ".toml":
        try:
            data = tomllib.loads(p.read_text())
        except tomllib.TOMLDecodeError as e:
            raise CaseError("--variants", f"{p}: malformed TOML: {e}") from None
        rows = data.get("variants", data.get("variant"))
        if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
            raise CaseError("--variants", f"{p}: expected an array of tables [[variants]] (one per variant)")
        out = [_flatten(r) for r in rows]
    elif suffix == ".csv":
        with p.open(newline="") as f:
            reader = csv.reader(f)
            try:
                header = [h.strip() for h in next(reader)]
            except StopIteration:
                raise CaseError("--variants", f"{p}: empty file") from None
            if not header or any(not h for h in header):
                raise CaseError("--variants", f"{p}: the header line must name a key in every column")
            out = []
            for i, row in enumerate(reader, start=2):
                if not any(c.strip() for c in row):
                    continue
                if len(row) > len(header):
                    raise CaseError("--variants", f"{p} line {i}: {len(row)} cells for {len(header)} columns")
                out.append({k: _parse_value(c) for k, c in zip(header, row) if c.strip()})
    else:
        raise CaseError("--variants", f"{p}: expected a .toml or .csv file")
    if not out:
        raise CaseError("--variants", f"{p}: no variants")
    return out


def combine_variants(file_rows: list[dict] | None, varies: list[tuple[str, list[Any]]]) -> list[dict[str, Any]]:
    """The variants of a sweep: file rows x the ``--vary`` product (either may be absent)."""
    product = expand_variants(varies)
    if not file_rows:
        return product
    clash = {k for r in file_rows for k in r} & {k for k, _ in varies}
    if clash:
        raise CaseError("--vary", f"key also set by --variants: {', '.join(sorted(clash))}")
    return [dict(r, **v) for r in file_rows for v in product]


def varied_keys(variants: list[dict]) -> list[str]:
    """Every key of the variants, in order of first appearance."""
    keys: list[str] = []
    for v in variants:
        for k in v:
            if k not in keys:
                keys.append(k)
    return keys


# ----------------------------------------------------------------------------------------------
# folder names
# ----------------------------------------------------------------------------------------------
def format_value(v: Any) -> str:
    """Short text of a value for folder names and tables: ``0.1``, ``1e-05``, ``true``,
    ``0_0_1`` for a list."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        if v.is_integer() and abs(v) < 1e15:
            return f"{v:.1f}"
        return repr(v)
    if isinstance(v, (list, tuple)):
        return "_".join(format_value(x) for x in v)
    return str(v)


_UNSAFE = re.compile(r"[^A-Za-z0-9._=+-]+")


def sanitise(text: str) -> str:
    """Keep letters, digits and ``. _ = + -``; every other run of characters becomes ``_``;
    no leading dot or dash (hidden files, options)."""
    s = _clean(text).lstrip("._-")
    return s or "_"


def _clean(text: str) -> str:
    """Unsafe character runs -> ``_`` (a leading ``-`` kept: ``-0.2`` stays negative)."""
    return _UNSAFE.sub("_", text).strip("_") or "_"


def _digest(values: dict) -> str:
    return hashlib.sha1(json.dumps(values, sort_keys=True, default=str).encode()).hexdigest()[:8]


def variant_name(values: dict[str, Any]) -> str:
    """``{"a.b": 0.1, "c": 2}`` -> ``"a.b=0.1__c=2"`` (sanitised; ``"base"`` for no keys;
    names over :data:`MAX_NAME` characters are cut and given an 8-character hash)."""
    if not values:
        return "base"
    name = sanitise("__".join(f"{_clean(k)}={_clean(format_value(v))}" for k, v in values.items()))
    if len(name) > MAX_NAME:
        name = name[:MAX_NAME - 10] + "__" + _digest(values)
    return name


def variant_names(variants: list[dict]) -> list[str]:
    """Folder names of all variants, unique: a name shared by different variants (sanitising
    can merge them) gets the variant's hash appended; an identical variant twice is refused."""
    names = [variant_name(v) for v in variants]
    seen: dict[str, dict] = {}
    for v, n in zip(variants, names):
        if n in seen and seen[n] == v:
            raise CaseError("--vary", f"variant {n} appears twice")
        seen[n] = v
    counts = {n: names.count(n) for n in names}
    return [n if counts[n] == 1 else f"{n}__{_digest(v)}" for n, v in zip(names, variants)]


# ----------------------------------------------------------------------------------------------
# one run folder
# ----------------------------------------------------------------------------------------------
def _read_run_json(out: Path) -> dict | None:
    from .simulation import RUN_MARKER

    try:
        return json.loads((out / RUN_MARKER).read_text())
    except (OSError, ValueError):
        return None


def _canonical(resolved: dict) -> Any:
    """The resolved configuration as it reads back from results.h5 (JSON round trip)."""
    from .io.results import _jsonable

    return json.loads(json.dumps(resolved, default=_jsonable, sort_keys=True))


def run_is_complete(out: str | Path, case=None) -> bool:
    """True when ``out`` holds a finished run: ``run.json`` with status ``"done"`` and a readable
    ``results.h5``; with ``case``, its stored resolved configuration must also equal the case's
    (a changed base case or ``--set`` is not "the same sweep")."""
    out = Path(out)
    meta = _read_run_json(out)
    if not meta or meta.get("status") != "done" or not (out / "results.h5").is_file():
        return False
    return _same_config(out, case)


def _scalar(v) -> float | int | None:
    """A numeric 0-d value as a Python float (int for integer and boolean kinds: counters)."""
    import numpy as np

    if isinstance(v, (str, bytes, dict)):
        return None
    a = np.asarray(v)
    if a.ndim == 0 and a.dtype.kind in "biu":
        return int(a)
    if a.ndim == 0 and a.dtype.kind == "f":
        return float(a)
    return None


def read_run_summary(out: str | Path) -> dict:
    """The summary of a run folder: ``status``, ``error`` (the run's message), ``wall_time``,
    ``steps``, ``time``, ``n_particles``, ``mass_out`` (from ``run.json``), the final
    ``mean_velocity_z`` (last row of ``/series``) and ``measurements``: every numeric scalar
    under ``/measurements`` keyed by its ``/``-joined path.  Missing pieces are absent."""
    out = Path(out)
    row: dict[str, Any] = {"measurements": {}}
    meta = _read_run_json(out)
    if meta:
        row["status"] = meta.get("status", "")
        if meta.get("message"):
            row["error"] = meta["message"]
        for k in ("wall_time", "steps", "time", "n_particles", "mass_out"):
            if isinstance(meta.get(k), (int, float)):
                row[k] = meta[k]
    h5 = out / "results.h5"
    if h5.is_file():
        from .io.results import read_measurements, read_series

        try:
            s = read_series(h5)
            vz = s.get("mean_velocity_z")
            if vz is not None and len(vz):
                row["mean_velocity_z"] = float(vz[-1])
            for k in ("n_particles", "mass_out"):
                if k not in row and k in s and len(s[k]):
                    row[k] = float(s[k][-1])
        except Exception as e:  # an unreadable file is reported, not fatal
            row["read_error"] = f"results.h5 series: {e}"
        try:
            flat = _flatten_measurements(read_measurements(h5))
            row["measurements"] = flat
        except Exception as e:
            row["read_error"] = f"results.h5 measurements: {e}"
    return row


def _flatten_measurements(tree: dict, prefix: str = "") -> dict[str, float]:
    out: dict[str, float] = {}
    for k, v in tree.items():
        if k == "@attrs":
            continue
        path = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flatten_measurements(v, path + "/"))
        else:
            x = _scalar(v)
            if x is not None:
                out[path] = x
    return out


def _same_config(out: Path, case=None) -> bool:
    """``out/results.h5`` opens and holds the resolved configuration of ``case`` (any, without)."""
    try:
        from .io.results import read_config

        _, stored = read_config(out / "results.h5")
    except Exception:
        return False
    if case is None:
        return True
    cur = _canonical(case.resolved)
    return stored == cur or _same_with_new_defaults(cur, stored, _schema_defaults())


def _schema_defaults() -> dict:
    """The default of every case key (JSON round trip, as stored configurations read back)."""
    from .config import SCHEMA, _default_of

    return json.loads(json.dumps(_default_of(SCHEMA), sort_keys=True))


def _same_with_new_defaults(cur, stored, defaults) -> bool:
    """``cur`` equals ``stored`` except for keys that ``stored`` lacks (added to cfddem after that
    run was made) and that hold their default in ``cur``: such a key did not change the run."""
    if not (isinstance(cur, dict) and isinstance(stored, dict)):
        return cur == stored
    if any(k not in cur for k in stored):
        return False
    dflt = defaults if isinstance(defaults, dict) else {}
    for k, v in cur.items():
        if k not in stored:
            if k not in dflt or v != dflt[k]:
                return False
        elif not _same_with_new_defaults(v, stored[k], dflt.get(k)):
            return False
    return True


def can_resume(out: str | Path, case) -> bool:
    """True when ``out`` holds an unfinished run of exactly this case that left a checkpoint:
    ``run.json`` with a status other than ``"done"`` (``running`` after a crash or a killed
    worker, ``interrupted``, ``stopped``, ``failed``), ``results.h5`` holding the same resolved
    configuration, and a checkpoint file under ``checkpoints/``."""
    from .io.checkpoint import list_checkpoints

    out = Path(out)
    meta = _read_run_json(out)
    if not meta or meta.get("status") == "done" or not _same_config(out, case):
        return False
    return bool(list_checkpoints(out / "checkpoints"))


def simulation_kwargs(out: Path, case) -> dict:
    """Keyword arguments of ``Simulation`` for a sweep task: a fresh run (replacing what a
    cfddem run wrote in ``out``), or ``resume=True`` to continue from the newest valid
    checkpoint when :func:`can_resume` (the run API makes the result bit-identical to an
    uninterrupted run on the same machine and thread count)."""
    return dict(overwrite=True, echo=False, progress=False, resume=can_resume(out, case))


def task_threads(threads: int | None) -> int:
    """Numba threads for this task: ``threads`` if given, else ``NUMBA_NUM_THREADS`` of the
    worker environment, else cores / Dask threads of this worker; capped by numba's pool.
    Calls ``numba.set_num_threads`` (a per-thread setting: it must happen in the task)."""
    import numba

    n = threads or int(os.environ.get("NUMBA_NUM_THREADS") or 0)
    if not n:
        cores = _cores()
        per = 1
        try:
            from distributed import get_worker

            per = max(1, int(get_worker().state.nthreads))
        except Exception:
            pass
        n = max(1, cores // per)
    n = max(1, min(int(n), numba.config.NUMBA_NUM_THREADS))
    numba.set_num_threads(n)
    return n


def run_variant(case_path: str, overrides: dict[str, Any], out_dir: str, threads: int | None = None) -> dict:
    """The Dask task: run one variant through the Python API into ``out_dir`` and return its
    small summary dict (see :func:`read_run_summary`; ``status`` done/stopped/failed, ``error``,
    ``wall_time`` of the whole task: case loading, build, compile and run).  Never raises for a
    bad case or a failed run: those become ``status = "failed"`` with the message."""
    from .config import load_case
    from .simulation import Simulation

    t0 = _time.perf_counter()
    started = _time.time()
    out = Path(out_dir)
    status, error = "failed", ""
    n = task_threads(threads)
    resumed = False
    try:
        case = load_case(case_path, overrides=dict(overrides))
        kw = simulation_kwargs(out, case)
        resumed = kw["resume"]
        try:
            summary = Simulation(case, out, threads=n, **kw).run()
        except CaseError:
            if not resumed:
                raise
            resumed = False  # no usable checkpoint after all: run it afresh
            summary = Simulation(case, out, threads=n, **dict(kw, resume=False)).run()
        status, error = summary.status, summary.message
    except CaseError as e:
        error = f"bad input: {e}"
    except RunError as e:
        error = f"run failed: {e}"
    except Exception as e:  # an engine bug in one variant must not stop the sweep
        error = f"{type(e).__name__}: {e}"
    from .simulation import RUN_MARKER

    try:  # only what this attempt wrote (a stale folder of an earlier run is not this result)
        fresh = (out / RUN_MARKER).stat().st_mtime >= started - 1.0
    except OSError:
        fresh = False
    row = read_run_summary(out) if fresh else {"measurements": {}}
    row.pop("error", None)
    if row.get("read_error"):
        error = f"{error}; {row['read_error']}" if error else row["read_error"]
    row.update(status=status, error=error, wall_time=_time.perf_counter() - t0, threads=n, out_dir=str(out),
               resumed=resumed)
    return row


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover (not Linux)
        return os.cpu_count() or 1


# ----------------------------------------------------------------------------------------------
# summary files
# ----------------------------------------------------------------------------------------------
def measurement_names(rows: list[dict]) -> list[str]:
    """The measurement columns: n_particles, mass_out, mean_velocity_z, then every
    ``/measurements`` scalar met in the rows (first-seen order)."""
    names = list(BASE_MEASUREMENTS)
    for r in rows:
        for k in r.get("measurements", {}):
            if k not in names:
                names.append(k)
    return names


def summary_table(rows: list[dict], keys: list[str]) -> tuple[list[str], list[list[Any]]]:
    """Columns and cell values (None where absent) of the summary."""
    meas = measurement_names(rows)
    cols = ["name", *keys, "status", *RUN_INFO, *meas, "error"]
    table = []
    for r in rows:
        m = r.get("measurements", {})
        cells = [r.get("name")]
        cells += [r.get("values", {}).get(k) for k in keys]
        cells += [r.get("status")] + [r.get(k) for k in RUN_INFO]
        cells += [r.get(k, m.get(k)) for k in meas]
        cells.append(r.get("error") or "")
        table.append(cells)
    return cols, table


def _csv_cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, (bool, list, tuple)):
        return format_value(v)
    return str(v)


def write_summary_csv(rows: list[dict], keys: list[str], path: str | Path) -> Path:
    """``summary.csv``: one row per variant (floats at full precision, empty where absent)."""
    cols, table = summary_table(rows, keys)
    path = Path(path)
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        for cells in table:
            w.writerow([_csv_cell(c) for c in cells])
    return path


def _md_cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return f"{v:.4g}"
    s = format_value(v) if isinstance(v, (bool, list, tuple)) else str(v)
    return s.replace("|", "\\|").replace("\n", " ")


def write_summary_md(rows: list[dict], keys: list[str], path: str | Path, title: str = "Sweep") -> Path:
    """``summary.md``: the summary as a Markdown table (4 significant digits)."""
    cols, table = summary_table(rows, keys)
    counts = {s: sum(1 for r in rows if r.get("status") == s) for s in STATUSES}
    lines = [f"# {title}", "", ", ".join(f"{n} {s}" for s, n in counts.items() if n) + f" of {len(rows)} variants",
             "", "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for cells in table:
        lines.append("| " + " | ".join(_md_cell(c) for c in cells) + " |")
    path = Path(path)
    path.write_text("\n".join(lines) + "\n")
    return path


def default_chart(rows: list[dict]) -> str:
    """The measurement charted when none is named: the first one whose value differs between
    the finished variants, taking first the floating-point scalars under ``/measurements`` (in
    column order; integer scalars such as ``n_samples`` are counters) and then
    ``mean_velocity_z``, ``mass_out``, ``n_particles``; ``mean_velocity_z`` when none differs
    (a chart of a constant, such as the start of an averaging window, says nothing)."""
    finished = [r for r in rows if r.get("status") in ("done", "skipped", "stopped")]

    def value(r, name):
        return r.get(name, r.get("measurements", {}).get(name))

    floats = [n for n in measurement_names(rows)[len(BASE_MEASUREMENTS):]
              if any(isinstance(value(r, n), float) for r in finished)]
    for name in floats + ["mean_velocity_z", "mass_out", "n_particles"]:
        vals = {value(r, name) for r in finished if _is_number(value(r, name)) and math.isfinite(value(r, name))}
        if len(vals) > 1:
            return name
    return "mean_velocity_z"


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def write_chart(rows: list[dict], keys: list[str], measurement: str, path: str | Path) -> Path | None:
    """PNG of ``measurement`` against the first varied key, one line per combination of the
    other keys, from the rows with status done/skipped/stopped and a finite value.  Numeric
    keys on a numeric axis, others as categories.  Returns None when there is nothing to plot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not keys:
        return None
    k0, rest = keys[0], keys[1:]
    pts: dict[tuple, list[tuple[Any, float]]] = {}
    for r in rows:
        if r.get("status") not in ("done", "skipped", "stopped"):
            continue
        y = r.get(measurement, r.get("measurements", {}).get(measurement))
        if not _is_number(y) or not math.isfinite(y):
            continue
        vals = r.get("values", {})
        if k0 not in vals:
            continue
        group = tuple(format_value(vals[k]) if k in vals else "-" for k in rest)
        pts.setdefault(group, []).append((vals[k0], float(y)))
    if not pts:
        return None
    xs_all = [x for p in pts.values() for x, _ in p]
    numeric = all(_is_number(x) for x in xs_all)
    cats = [] if numeric else list(dict.fromkeys(format_value(x) for x in xs_all))
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for group, p in pts.items():
        if numeric:
            p = sorted(p, key=lambda t: t[0])
            xs = [x for x, _ in p]
        else:
            p = sorted(p, key=lambda t: cats.index(format_value(t[0])))
            xs = [cats.index(format_value(x)) for x, _ in p]
        label = ", ".join(f"{k} = {g}" for k, g in zip(rest, group)) or None
        ax.plot(xs, [y for _, y in p], marker="o", label=label)
    if not numeric:
        ax.set_xticks(range(len(cats)), cats)
    ax.set_xlabel(k0)
    ax.set_ylabel(measurement)
    ax.set_title(f"{measurement} against {k0}")
    ax.grid(alpha=0.3)
    if rest:
        ax.legend(fontsize=8)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return path


# ----------------------------------------------------------------------------------------------
# the sweep
# ----------------------------------------------------------------------------------------------
def _import_distributed():
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise CaseError(None, "cfddem sweep needs Dask: pip install 'cfddem[sweep]' "
                              "(dask[distributed])") from None
    return distributed


def _common_overrides(common) -> dict[str, Any]:
    from .config import parse_override

    if isinstance(common, dict):
        return dict(common)
    out: dict[str, Any] = {}
    for item in common or ():
        k, v = parse_override(item)
        out[k] = v
    return out


def run_sweep(case: str | Path, variants: list[dict[str, Any]], out: str | Path | None = None, *,
              common: Iterable[str] | dict | None = None, scheduler: str | None = None,
              workers: int | None = None, threads: int | None = None, chart: str | None = None,
              connect_timeout: float = 20.0, echo: Callable[[str], None] | None = print) -> list[dict]:
    """Run the ``variants`` (``{dotted key: value}`` dicts) of the case at ``case`` on Dask and
    write ``summary.csv``, ``summary.md`` and the chart into ``out`` (default ``CASE/sweep``).

    ``common`` are ``--set``-style overrides applied to every variant (before its own).
    ``scheduler`` (``"tcp://HOST:PORT"``): submit to that cluster; else a LocalCluster of
    ``workers`` processes (default: min(variants to run, cores)) with ``threads`` numba threads
    each (default: cores // workers).  Returns the rows (one dict per variant, in variant
    order, with ``name``, ``values``, ``status``, ``error``, ``wall_time``, measurements...)."""
    from .config import case_file, load_case

    say = echo or (lambda s: None)
    case_dir = case_file(case).parent.resolve()
    case_arg = str(case_file(case).resolve())
    sweep_dir = Path(out).resolve() if out is not None else case_dir / "sweep"
    if not variants:
        raise CaseError("--vary", "no variants to run")
    if workers is not None and workers < 1:
        raise CaseError("--workers", f"{workers} must be at least 1")
    if threads is not None and threads < 1:
        raise CaseError("--threads", f"{threads} must be at least 1")
    base = _common_overrides(common)
    keys = varied_keys(variants)
    names = variant_names(variants)
    try:
        sweep_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise CaseError("--out", f"cannot create {sweep_dir}: {e.strerror or e}") from None

    rows: list[dict] = []
    todo: list[tuple[int, dict]] = []
    for i, (values, name) in enumerate(zip(variants, names)):
        row: dict[str, Any] = {"name": name, "values": dict(values), "out_dir": str(sweep_dir / name)}
        overrides = dict(base, **values)
        try:
            vcase = load_case(case_arg, overrides=overrides)
        except CaseError as e:
            row.update(status="failed", error=f"bad input: {e}", measurements={})
            say(f"[{name}] failed: bad input: {e}")
        else:
            if run_is_complete(sweep_dir / name, vcase):
                s = read_run_summary(sweep_dir / name)
                s.pop("error", None)
                row.update(s, status="skipped", error="")
                say(f"[{name}] skipped: complete run found")
            else:
                todo.append((i, overrides))
        rows.append(row)

    if todo:
        _run_on_dask(case_arg, todo, rows, scheduler=scheduler, workers=workers, threads=threads,
                     connect_timeout=connect_timeout, say=say)

    write_summary_csv(rows, keys, sweep_dir / "summary.csv")
    write_summary_md(rows, keys, sweep_dir / "summary.md", title=f"Sweep of {case_dir.name}")
    name = chart or default_chart(rows)
    png = write_chart(rows, keys, name, sweep_dir / f"chart_{sanitise(name.replace('/', '.'))}.png")
    if png is None:
        say(f"no chart: no finished variant has a numeric '{name}' "
            f"(measurements: {', '.join(measurement_names(rows))})")
    counts = {s: sum(1 for r in rows if r["status"] == s) for s in STATUSES}
    say(f"sweep: {', '.join(f'{n} {s}' for s, n in counts.items() if n)} of {len(rows)}; "
        f"summary in {sweep_dir / 'summary.csv'}")
    return rows


def start_local_cluster(n_workers: int, threads: int):
    """An embedded Dask cluster on 127.0.0.1: ``n_workers`` worker processes of one Dask thread
    each, ``NUMBA_NUM_THREADS=threads`` (and ``OMP_NUM_THREADS=1``) in their environment, no
    dashboard, every port chosen free.  Worker processes are spawned: a script calling this (or
    :func:`run_sweep`) needs the ``if __name__ == "__main__":`` guard.  Returns ``(cluster, client)``; close both."""
    _import_distributed()
    import logging

    from distributed import Client, LocalCluster

    cluster = LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                           dashboard_address=None, silence_logs=logging.ERROR,
                           # no dashboard; its health/metrics HTTP server on a free port, not 8787
                           scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
                           env={"NUMBA_NUM_THREADS": str(threads), "OMP_NUM_THREADS": "1"})
    try:
        client = Client(cluster)
    except BaseException:
        cluster.close()
        raise
    return cluster, client


def _run_on_dask(case_arg: str, todo: list[tuple[int, dict]], rows: list[dict], *, scheduler, workers, threads,
                 connect_timeout, say) -> None:
    _import_distributed()
    from distributed import Client, as_completed

    cluster = client = None
    try:
        if scheduler:
            if workers is not None:
                say("note: --workers is ignored with --scheduler (the cluster has its own workers)")
            try:
                client = Client(scheduler, timeout=f"{connect_timeout}s")
            except (OSError, TimeoutError, ValueError) as e:
                raise CaseError("--scheduler", f"cannot connect to {scheduler}: {e}") from None
            task_t = threads  # None: each task decides from its worker (see task_threads)
        else:
            cores = _cores()
            nw = workers or max(1, min(len(todo), cores))
            task_t = threads or max(1, cores // nw)
            if nw * task_t > cores:
                say(f"note: {nw} workers x {task_t} threads exceeds the {cores} cores of this machine")
            cluster, client = start_local_cluster(nw, task_t)
            say(f"local Dask cluster: {nw} worker process(es) x 1 thread, {task_t} numba thread(s) each")
        futures = {}
        for i, overrides in todo:
            r = rows[i]
            fut = client.submit(run_variant, case_arg, overrides, r["out_dir"], task_t, pure=False,
                                key=f"cfddem-{r['name']}-{_digest({'t': _time.time(), 'i': i})}")
            futures[fut] = i
        done = 0
        for fut in as_completed(list(futures)):
            i = futures[fut]
            r = rows[i]
            try:
                res = fut.result()
            except Exception as e:  # worker died, result lost: this variant failed
                res = {"status": "failed", "error": f"{type(e).__name__}: {e}", "measurements": {}}
            res.pop("out_dir", None)
            r.update(res)
            done += 1
            msg = f": {r['error']}" if r.get("error") else ""
            wt = r.get("wall_time")
            say(f"[{done}/{len(todo)}] {r['name']} {r['status']}" + (" (resumed)" if r.get("resumed") else "")
                + (f" ({wt:.1f} s)" if isinstance(wt, float) else "") + msg)
    finally:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()


# ----------------------------------------------------------------------------------------------
# command line (wired into cfddem.cli by the lead)
# ----------------------------------------------------------------------------------------------
def add_sweep_parser(subparsers) -> Any:
    """Add ``cfddem sweep`` to an argparse ``subparsers`` object; returns the sub-parser."""
    s = subparsers.add_parser("sweep", help="run a parameter sweep of a case on Dask",
                              description="Run every variant of a case (cartesian product of --vary lists, "
                                          "or the rows of --variants) as Dask tasks; write summary.csv, "
                                          "summary.md and a chart into the sweep folder.")
    s.add_argument("case", help="case folder (holding case.toml) or a case.toml file")
    s.add_argument("--vary", action="append", default=[], metavar="KEY=V1,V2,...",
                   help="a key and its values (TOML values, comma-separated); repeat for a cartesian product")
    s.add_argument("--variants", metavar="FILE",
                   help="TOML ([[variants]] tables) or CSV (header of keys) file of variants, one per row")
    s.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a key in every variant (as for cfddem run)")
    s.add_argument("--out", help="sweep folder (default: CASE/sweep)")
    s.add_argument("--scheduler", metavar="ADDRESS", help="submit to an existing Dask cluster, e.g. tcp://host:8786")
    s.add_argument("--workers", type=int, help="local worker processes (default: min(variants, cores))")
    s.add_argument("--threads", type=int, help="numba threads per task (default: cores // workers)")
    s.add_argument("--chart", metavar="NAME",
                   help="measurement to chart against the first varied key (default: the first one "
                        "that differs between the variants, see docs/sweeps.md)")
    s.add_argument("--force", action="store_true", help="run variants even when dt > t_c/5 or above the stable step")
    return s


def run_sweep_from_args(args) -> int:
    """Run the sweep the parsed ``args`` describe; 0 when no variant failed, else 3 (as a failed
    ``cfddem run``).  Bad input raises :class:`CaseError` (the CLI prints one line, exit 2)."""
    varies = [parse_vary(v) for v in args.vary]
    rows_file = read_variants_file(args.variants) if args.variants else None
    if not varies and not rows_file:
        raise CaseError("--vary", "give at least one --vary KEY=V1,V2,... or --variants FILE")
    variants = combine_variants(rows_file, varies)
    common = list(args.overrides)
    if args.force:
        common.append("time.force=true")
    rows = run_sweep(args.case, variants, args.out, common=common, scheduler=args.scheduler,
                     workers=args.workers, threads=args.threads, chart=args.chart)
    failed = [r for r in rows if r["status"] == "failed"]
    if failed:
        print(f"cfddem: {len(failed)} of {len(rows)} variant(s) failed", file=sys.stderr)
        return RunError.exit_code
    return 0


def main(argv: list[str] | None = None) -> int:
    """``python -m cfddem.sweep CASE --vary ...`` (the same as ``cfddem sweep``)."""
    import argparse

    p = argparse.ArgumentParser(prog="cfddem")
    sub = p.add_subparsers(dest="command", required=True)
    add_sweep_parser(sub)
    args = p.parse_args(["sweep", *(sys.argv[1:] if argv is None else argv)])
    try:
        return run_sweep_from_args(args)
    except CaseError as e:
        print(f"cfddem: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
