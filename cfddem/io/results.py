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

The file is flushed at every output interval (:meth:`ResultsFile.flush`) so that a run
killed between two outputs leaves a readable file with everything up to the last flush.
"""

from __future__ import annotations

import json
import math
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
    """Writer for ``results.h5``.

    ``mode="w"`` creates (truncates) the file, ``mode="a"`` appends to an existing one
    (a restarted run): series rows, snapshots and measurements continue where they were.
    Use as a context manager or call :meth:`close`.
    """

    def __init__(self, path: str | Path, mode: str = "w"):
        if mode not in ("w", "a"):
            raise ValueError(f"mode must be 'w' or 'a', not {mode!r}")
        self.path = Path(path)
        self._f = h5py.File(self.path, mode)
        self._series = self._f.require_group("series")
        self._f.require_group("snapshots")
        self._f.require_group("measurements")
        self._rows = int(self._series["time"].shape[0]) if "time" in self._series else 0

    # ------------------------------------------------------------------ context manager
    def __enter__(self) -> "ResultsFile":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def closed(self) -> bool:
        return not bool(self._f.id.valid)

    def flush(self) -> None:
        """Push everything written so far to disk (call at every output interval)."""
        self._f.flush()

    def close(self) -> None:
        if not self.closed:
            self._f.flush()
            self._f.close()

    # ------------------------------------------------------------------ configuration
    def write_config(self, toml_text: str, resolved: dict) -> None:
        """Store the case file text and the resolved configuration (as JSON)."""
        g = self._f.require_group("config")
        for name, text in (("case.toml", toml_text),
                           ("resolved.json", json.dumps(resolved, default=_jsonable, indent=1,
                                                        sort_keys=True))):
            if name in g:
                del g[name]
            g.create_dataset(name, data=text, dtype=_STR)

    def write_metadata(self, **attrs) -> None:
        """Set attributes of ``/metadata`` (version, start time, threads, ...).

        Values that HDF5 cannot hold directly (dicts, mixed lists) are stored as JSON
        strings; ``None`` becomes ``''``.
        """
        g = self._f.require_group("metadata")
        for k, v in attrs.items():
            g.attrs[k] = _attr_value(v)

    # ------------------------------------------------------------------ time series
    def append_series(self, time: float, **scalars: float) -> None:
        """Append one row: ``time`` and any number of named scalars.

        Every series gets one new entry per call; a series not named in this call gets
        NaN, and a series first named at row k is created with k leading NaNs.
        """
        n = self._rows
        names = set(scalars) | {"time"}
        values = dict(scalars, time=time)
        for name in names:
            if name not in self._series:
                ds = self._series.create_dataset(
                    name, shape=(n,), maxshape=(None,), dtype="f8",
                    chunks=(_SERIES_CHUNK,), fillvalue=np.nan)
                if n:
                    ds[:] = np.nan
        for name, ds in self._series.items():
            ds.resize((n + 1,))
            v = values.get(name, math.nan)
            ds[n] = np.nan if v is None else float(v)
        self._rows = n + 1

    @property
    def n_series_rows(self) -> int:
        return self._rows

    # ------------------------------------------------------------------ snapshots
    def write_snapshot(self, time: float, step: int, **arrays) -> str:
        """Write ``/snapshots/<NNNNNN>`` (next free index) with attrs time and step and one
        dataset per array (pos, vel, omega, radius, ids, ...); returns the group name.

        Arrays with more than 4096 elements are gzip-compressed (level 4) with shuffle.
        """
        snaps = self._f["snapshots"]
        k = len(snaps)
        name = f"{k:06d}"
        while name in snaps:  # an appended file with a gap: never overwrite
            k += 1
            name = f"{k:06d}"
        g = snaps.create_group(name)
        g.attrs["time"] = float(time)
        g.attrs["step"] = int(step)
        for key, arr in arrays.items():
            a = np.asarray(arr)
            if a.size > 4096:
                g.create_dataset(key, data=a, compression="gzip", compression_opts=4, shuffle=True)
            else:
                g.create_dataset(key, data=a)
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
        root = self._f["measurements"]
        attrs = attrs or {}
        if not isinstance(arrays, dict):
            if not group:
                raise ValueError("a single measurement needs a name")
            if group in root:
                del root[group]
            ds = root.create_dataset(group, data=np.asarray(arrays))
            for k, v in attrs.items():
                ds.attrs[k] = _attr_value(v)
            return
        g = root.require_group(group) if group else root
        self._write_tree(g, arrays)
        for k, v in attrs.items():
            g.attrs[k] = _attr_value(v)

    def _write_tree(self, g: h5py.Group, tree: dict) -> None:
        for k, v in tree.items():
            if k in g:
                del g[k]
            if isinstance(v, dict):
                self._write_tree(g.create_group(k), v)
            elif isinstance(v, str):
                g.create_dataset(k, data=v, dtype=_STR)
            else:
                g.create_dataset(k, data=np.asarray(v))


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
    str). With ``with_attrs`` each group's attributes appear under the key ``"@attrs"``."""
    with h5py.File(path, "r") as f:
        if "measurements" not in f:
            return {}
        return _read_tree(f["measurements"], with_attrs)


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
