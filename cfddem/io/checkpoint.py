"""Checkpoints: the complete evolving state of a run in one HDF5 file, written atomically.

A checkpoint holds a nested dict of numpy arrays and scalars (particles with their contact
history, inlet, measurement accumulators, gas fields, the clock and the output schedules).  It is
written to ``ckpt_<step>.h5.tmp``, flushed and fsync'ed, then renamed to ``ckpt_<step>.h5``
(``os.replace`` is atomic on POSIX), so a process killed at any moment leaves either the previous
set of checkpoints or the new one, never a half-written file under a valid name.  The file's
root attribute ``complete = 1`` is written last; :func:`latest_checkpoint` ignores files without
it (and any that fail to open).  The newest ``keep`` checkpoints are kept.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import h5py
import numpy as np

_NAME = re.compile(r"^ckpt_(\d{12})\.h5$")


def _write_tree(g: h5py.Group, tree: dict) -> None:
    for k, v in tree.items():
        if isinstance(v, dict):
            _write_tree(g.create_group(k), v)
        elif isinstance(v, np.ndarray):
            g.create_dataset(k, data=v)
        elif isinstance(v, (bool, np.bool_)):
            g.attrs[k] = np.int8(bool(v))
            g.attrs[f"__bool__{k}"] = 1
        elif isinstance(v, (int, float, np.integer, np.floating, str)):
            g.attrs[k] = v
        elif v is None:
            g.attrs[f"__none__{k}"] = 1
        else:
            g.create_dataset(k, data=np.asarray(v))


def _read_tree(g: h5py.Group) -> dict:
    out: dict = {}
    for k, v in g.attrs.items():
        if k.startswith("__bool__") or k == "complete":
            continue
        if k.startswith("__none__"):
            out[k[len("__none__"):]] = None
            continue
        if f"__bool__{k}" in g.attrs:
            out[k] = bool(v)
        elif isinstance(v, bytes):
            out[k] = v.decode()
        elif isinstance(v, np.generic):
            out[k] = v.item()
        else:
            out[k] = v
    for k, v in g.items():
        out[k] = _read_tree(v) if isinstance(v, h5py.Group) else v[()]
    return out


def checkpoint_path(folder: Path, step: int) -> Path:
    return Path(folder) / f"ckpt_{step:012d}.h5"


def write_checkpoint(folder: str | Path, step: int, state: dict, keep: int = 2) -> Path:
    """Write ``state`` atomically as the checkpoint of ``step``; keep the newest ``keep``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    final = checkpoint_path(folder, step)
    tmp = final.with_suffix(".h5.tmp")
    with h5py.File(tmp, "w") as h:
        _write_tree(h, state)
        h.attrs["complete"] = 1
        h.flush()
    fd = os.open(tmp, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
    os.replace(tmp, final)
    try:  # make the rename itself durable
        dfd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)
    except OSError:
        pass
    for old in list_checkpoints(folder)[:-keep] if keep > 0 else []:
        old.unlink(missing_ok=True)
    return final


def list_checkpoints(folder: str | Path) -> list[Path]:
    """Checkpoint files in step order (names only; validity is checked by :func:`read_checkpoint`)."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.iterdir() if _NAME.match(p.name))


def read_checkpoint(path: str | Path) -> dict:
    with h5py.File(path, "r") as h:
        if int(h.attrs.get("complete", 0)) != 1:
            raise OSError(f"{path} is incomplete")
        return _read_tree(h)


def latest_checkpoint(folder: str | Path) -> tuple[Path, dict] | None:
    """The newest checkpoint that opens and is complete, with its state (or None)."""
    for p in reversed(list_checkpoints(folder)):
        try:
            return p, read_checkpoint(p)
        except (OSError, KeyError, ValueError):
            continue
    return None

