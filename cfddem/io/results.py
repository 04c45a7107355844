"""The HDF5 results file of a run (``results.h5``) and helpers to read it back.

Layout (see ``docs/outputs.md`` for units and the full list)::

    /config/case.toml        string   the case file as given
    /config/resolved.json    string   the resolved configuration (defaults filled in), JSON
    /metadata                group    attrs: version, start time, threads, host, ...
    /series/time             float64  (n_rows,)  one row per append_series call
    /series/<name>           float64  (n_rows,)  NaN where a row did not give <name>
    /snapshots/000000        group    attrs time, step; datasets pos, vel, omega, radius, ids, ...
    /measurements/<group>/<name>      arrays (attrs on the group)
    /measurements/<name>              scalars or arrays written without a group

The file is rewritten atomically at every output interval (:meth:`ResultsFile.flush`), and
snapshots live in ``results_snapshots/NNNNNN.h5`` (each written atomically), linked into
``/snapshots`` by HDF5 external links: a run killed at any moment, even by SIGKILL, leaves a
readable ``results.h5`` with everything up to the last flush.
"""

from __future__ import annotations

import json
import math
import os
import time as _time
from pathlib import Path
from typing import Any

import h5py
import numpy as np

_STR = h5py.string_dtype(encoding="utf-8")
_SERIES_CHUNK = 1024


def _jsonable(obj: Any):
    """``json.dumps`` default hook: numpy scalars/arrays and paths become plain JSON."""
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (Path, set, tuple)):
        return str(obj) if isinstance(obj, Path) else list(obj)
    if hasattr(obj, "__dict__"):
        return {k: v for k, v in vars(obj).items() if not k.startswith("_")}
    raise TypeError(f"cannot store {type(obj).__name__} in resolved.json")


def _attr_value(v: Any):
    """An HDF5-storable attribute value (None -> '', dict/list of mixed -> JSON string)."""
    if v is None:
        return ""
    if isinstance(v, (str, bytes, int, float, bool, np.generic)):
        return v
    if isinstance(v, Path):
        return str(v)
    if isinstance(v, (list, tuple, np.ndarray)):
        arr = np.asarray(v)
        if arr.dtype.kind in "biuf":
            return arr
    return json.dumps(v, default=_jsonable)


class ResultsFile:
    """Writer for ``results.h5``, crash-safe.

    Everything small (configuration, metadata, time series, measurements) is kept in memory
    and ``results.h5`` is rewritten *atomically* at every :meth:`flush` (temporary file,
    fsync, ``os.replace``): a process killed at any moment (SIGKILL included) leaves the
    previous complete file, with every record flushed before the kill (a run flushes at most
    every 2 s of wall time, and always before a checkpoint and at its end).  Particle snapshots
    are written once each, atomically too, to ``<stem>_snapshots/NNNNNN.h5`` beside it, and
    appear inside ``results.h5`` as ``/snapshots/NNNNNN`` through HDF5 external links (h5py
    follows them transparently; keep the folder beside the file when moving a run).

    ``mode="w"`` starts a new file, ``mode="a"`` loads an existing one (a restarted run):
    series rows, snapshots and measurements continue where they were.
    Use as a context manager or call :meth:`close`.
    """

    def __init__(self, path: str | Path, mode: str = "w"):
        if mode not in ("w", "a"):
            raise ValueError(f"mode must be 'w' or 'a', not {mode!r}")
        self.path = Path(path)
        self.snap_dir = self.path.parent / f"{self.path.stem}_snapshots"
        self._config: dict[str, str] = {}
        self._meta: dict[str, Any] = {}
        self._series: dict[str, list[float]] = {}
        self._rows = 0
        self._meas = {}  # nested dict of arrays; attrs under "@attrs"
        self._snaps: list[tuple[str, float, int]] = []
        self._closed = False
        self._last_flush = -math.inf  # perf_counter() of the last rewrite
        if mode == "a" and self.path.exists():
            self._load()
        elif mode == "w" and self.snap_dir.exists():
            for f in self.snap_dir.glob("*.h5"):
                f.unlink()
        self._dirty = True
        self.flush()

    def _load(self) -> None:
        with h5py.File(self.path, "r") as f:
            if "config" in f:
                self._config = {k: ds.asstr()[()] for k, ds in f["config"].items()}
            if "metadata" in f:
                self._meta = {k: _decode(v) for k, v in f["metadata"].attrs.items()}
            if "series" in f:
                self._series = {k: [float(x) for x in ds[()]] for k, ds in f["series"].items()}
                self._rows = len(self._series.get("time", []))
            if "measurements" in f:
                self._meas = _read_tree(f["measurements"], True)
            if "snapshots" in f:
                for name in sorted(f["snapshots"]):
                    link = f["snapshots"].get(name, getlink=True)
                    if not (self.snap_dir / f"{name}.h5").exists() and isinstance(link, h5py.ExternalLink):
                        continue  # a snapshot file lost: skip it rather than fail
                    g = f["snapshots"][name]
                    self._snaps.append((name, float(g.attrs["time"]), int(g.attrs["step"])))

    # ------------------------------------------------------------------ context manager
    def __enter__(self) -> "ResultsFile":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def closed(self) -> bool:
        return self._closed

    def flush(self, min_interval: float = 0.0) -> None:
        """Rewrite ``results.h5`` atomically with everything recorded so far (a no-op when
        nothing changed).  ``min_interval`` > 0: not if the last rewrite was less than that many
        seconds of wall time ago (a run calls it after every chunk of steps: each rewrite with
        its fsync costs ~10 ms, 2-3 % of the flagship's run when done for every series row)."""
        if not self._dirty:
            return
        if min_interval > 0.0 and _time.perf_counter() - self._last_flush < min_interval:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_name(f".{self.path.name}.tmp")
        with h5py.File(tmp, "w") as f:
            g = f.create_group("config")
            for name, text in self._config.items():
                g.create_dataset(name, data=text, dtype=_STR)
            m = f.create_group("metadata")
            for k, v in self._meta.items():
                m.attrs[k] = _attr_value(v)
            sg = f.create_group("series")
            for name, vals in self._series.items():
                sg.create_dataset(name, data=np.asarray(vals, dtype="f8"), maxshape=(None,),
                                  chunks=(_SERIES_CHUNK,) if len(vals) else None)
            self._write_tree(f.create_group("measurements"), self._meas)
            sn = f.create_group("snapshots")
            for name, _, _ in self._snaps:
                sn[name] = h5py.ExternalLink(f"{self.snap_dir.name}/{name}.h5", "/")
        _fsync(tmp)
        os.replace(tmp, self.path)
        self._dirty = False
        self._last_flush = _time.perf_counter()

    def close(self) -> None:
        if not self._closed:
            self.flush()
            self._closed = True

    # ------------------------------------------------------------------ configuration
    def write_config(self, toml_text: str, resolved: dict) -> None:
        """Store the case file text and the resolved configuration (as JSON)."""
        self._config["case.toml"] = toml_text
        self._config["resolved.json"] = json.dumps(resolved, default=_jsonable, indent=1, sort_keys=True)
        self._dirty = True

    def write_metadata(self, **attrs) -> None:
        """Set attributes of ``/metadata`` (version, start time, threads, ...).

        Values that HDF5 cannot hold directly (dicts, mixed lists) are stored as JSON
        strings; ``None`` becomes ``''``.
        """
        self._meta.update(attrs)
        self._dirty = True

    # ------------------------------------------------------------------ time series
    def append_series(self, time: float, **scalars: float) -> None:
        """Append one row: ``time`` and any number of named scalars.

        Every series gets one new entry per call; a series not named in this call gets
        NaN, and a series first named at row k is created with k leading NaNs.
        """
        n = self._rows
        values = dict(scalars, time=time)
        for name in values:
            if name not in self._series:
                self._series[name] = [math.nan] * n
        for name, col in self._series.items():
            v = values.get(name, math.nan)
            col.append(math.nan if v is None else float(v))
        self._rows = n + 1
        self._dirty = True

    @property
    def n_series_rows(self) -> int:
        return self._rows

    def last_series_time(self) -> float | None:
        """Time of the last series row (None when there is none)."""
        t = self._series.get("time")
        return t[-1] if t else None

    def truncate_after(self, time: float, eps: float = 1e-12) -> None:
        """Drop series rows and snapshots after ``time`` and all measurements (a run resumed
        from a checkpoint at ``time`` writes them again)."""
        t = np.asarray(self._series.get("time", []), float)
        keep = int(np.searchsorted(t, time + eps, side="right"))
        for name in self._series:
            del self._series[name][keep:]
        self._rows = keep
        kept = []
        for name, ts, step in self._snaps:
            if ts > time + eps:
                (self.snap_dir / f"{name}.h5").unlink(missing_ok=True)
            else:
                kept.append((name, ts, step))
        self._snaps = kept
        self._meas = {}
        self._dirty = True

    # ------------------------------------------------------------------ snapshots
    def write_snapshot(self, time: float, step: int, **arrays) -> str:
        """Write snapshot ``NNNNNN`` (next free index) with attrs time and step and one
        dataset per array (pos, vel, omega, radius, ids, ...); returns its name.  The
        snapshot file is complete on disk when this returns; ``results.h5`` links it at the
        next :meth:`flush`.

        Arrays with more than 4096 elements are gzip-compressed (level 4) with shuffle.
        """
        k = int(self._snaps[-1][0]) + 1 if self._snaps else 0
        name = f"{k:06d}"
        self.snap_dir.mkdir(parents=True, exist_ok=True)
        final = self.snap_dir / f"{name}.h5"
        tmp = self.snap_dir / f".{name}.h5.tmp"
        with h5py.File(tmp, "w") as g:
            g.attrs["time"] = float(time)
            g.attrs["step"] = int(step)
            for key, arr in arrays.items():
                a = np.asarray(arr)
                if a.size > 4096:
                    g.create_dataset(key, data=a, compression="gzip", compression_opts=4, shuffle=True)
                else:
                    g.create_dataset(key, data=a)
        _fsync(tmp)
        os.replace(tmp, final)
        self._snaps.append((name, float(time), int(step)))
        self._dirty = True
        return name

    # ------------------------------------------------------------------ measurements
    def write_measurements(self, group: str | None, arrays, attrs: dict | None = None) -> None:
        """Write measurement results.

        * ``arrays`` a dict: datasets ``/measurements/<group>/<name>`` (nested dicts become
          subgroups); ``attrs`` go on that group. ``group`` ``None`` or ``""`` writes the
          datasets directly under ``/measurements``.
        * ``arrays`` a scalar or array: the single dataset ``/measurements/<group>``
          (``attrs`` on that dataset).

        Existing datasets of the same name are replaced (measurements are rewritten with
        the longer time average at every output).
        """
        attrs = attrs or {}
        if not isinstance(arrays, dict):
            if not group:
                raise ValueError("a single measurement needs a name")
            self._meas[group] = np.asarray(arrays)
            if attrs:
                self._meas[f"@attrs:{group}"] = dict(attrs)
            self._dirty = True
            return
        tree = self._meas
        if group:
            for part in group.split("/"):
                tree = tree.setdefault(part, {})
        _merge(tree, arrays)
        if attrs:
            tree.setdefault("@attrs", {}).update(attrs)
        self._dirty = True

    def _write_tree(self, g: h5py.Group, tree: dict) -> None:
        for k, v in tree.items():
            if k == "@attrs":
                for a, av in v.items():
                    g.attrs[a] = _attr_value(av)
            elif k.startswith("@attrs:"):
                continue
            elif isinstance(v, dict):
                self._write_tree(g.create_group(k), v)
            elif isinstance(v, str):
                g.create_dataset(k, data=v, dtype=_STR)
            else:
                ds = g.create_dataset(k, data=np.asarray(v))
                for a, av in tree.get(f"@attrs:{k}", {}).items():
                    ds.attrs[a] = _attr_value(av)


def _merge(dst: dict, src: dict) -> None:
    for k, v in src.items():
        if isinstance(v, dict):
            _merge(dst.setdefault(k, {}) if isinstance(dst.get(k), dict) else dst.setdefault(k, {}), v)
        else:
            dst[k] = v.copy() if isinstance(v, np.ndarray) else v


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


# ---------------------------------------------------------------------- readers
def _read_tree(g: h5py.Group, with_attrs: bool) -> dict:
    out: dict = {}
    for k, obj in g.items():
        if isinstance(obj, h5py.Group):
            out[k] = _read_tree(obj, with_attrs)
        elif obj.dtype.kind in "SO":
            out[k] = obj.asstr()[()]
        else:
            out[k] = obj[()]
    if with_attrs and len(g.attrs):
        out["@attrs"] = {k: _decode(v) for k, v in g.attrs.items()}
    return out


def _decode(v):
    return v.decode() if isinstance(v, bytes) else v


def read_series(path: str | Path) -> dict[str, np.ndarray]:
    """All ``/series/<name>`` arrays (``time`` included) as a dict of float64 arrays."""
    with h5py.File(path, "r") as f:
        if "series" not in f:
            return {}
        return {k: ds[()] for k, ds in f["series"].items()}


def list_snapshots(path: str | Path) -> list[tuple[int, float, int]]:
    """``[(index, time, step), ...]`` for every snapshot, in index order."""
    with h5py.File(path, "r") as f:
        if "snapshots" not in f:
            return []
        return [(int(k), float(g.attrs["time"]), int(g.attrs["step"]))
                for k, g in sorted(f["snapshots"].items())]


def read_snapshot(path: str | Path, k: int) -> dict:
    """Snapshot number ``k`` (negative counts from the last) as a dict of arrays plus
    ``time`` and ``step``."""
    with h5py.File(path, "r") as f:
        names = sorted(f["snapshots"]) if "snapshots" in f else []
        if not names:
            raise KeyError(f"{path}: no snapshots")
        name = names[k] if k < 0 else f"{k:06d}"
        if name not in f["snapshots"]:
            raise KeyError(f"{path}: no snapshot {k} (have {len(names)})")
        g = f["snapshots"][name]
        out = {key: ds[()] for key, ds in g.items()}
        out["time"] = float(g.attrs["time"])
        out["step"] = int(g.attrs["step"])
        return out


def read_measurements(path: str | Path, with_attrs: bool = False) -> dict:
    """``/measurements`` as a nested dict of arrays (scalars as numpy scalars, strings as
    str). With ``with_attrs`` each group's attributes appear under the key ``"@attrs"``.
    A chute file written before the side names were those seen in the direction of flow
    (no ``sides`` attribute on its chute group) is read with today's names
    (:func:`cfddem.measure.chute.upgrade_legacy_sides`)."""
    from ..measure.chute import upgrade_legacy_sides

    with h5py.File(path, "r") as f:
        if "measurements" not in f:
            return {}
        meas = upgrade_legacy_sides(_read_tree(f["measurements"], True))
    return meas if with_attrs else _without_attrs(meas)


def _without_attrs(tree: dict) -> dict:
    return {k: _without_attrs(v) if isinstance(v, dict) else v for k, v in tree.items() if k != "@attrs"}


def read_config(path: str | Path) -> tuple[str, dict]:
    """``(case.toml text, resolved configuration dict)``."""
    with h5py.File(path, "r") as f:
        g = f["config"]
        return g["case.toml"].asstr()[()], json.loads(g["resolved.json"].asstr()[()])


def read_metadata(path: str | Path) -> dict:
    with h5py.File(path, "r") as f:
        if "metadata" not in f:
            return {}
        return {k: _decode(v) for k, v in f["metadata"].attrs.items()}
