"""Checkpoint files: atomic writes, the npz encoding of arrays, and what a path stands for.

Every file a run writes goes through :func:`atomic_file` (a temporary file in the same
directory, flushed, then renamed), so a crash never leaves half a file. Arrays are stored in
npz files read with ``allow_pickle=False``; the real-valued state rows are stored once in a
table of distinct rows (:func:`pack_rows`) and the per-DBN and per-plan arrays grouped into one
array per field (:func:`group_arrays`). Schema: ``docs/checkpoint.md``.
"""

from __future__ import annotations

import contextlib
import io
import json
import lzma
import os
import tempfile
import time
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

ROWS = "_rows"
"""The npz entry (version 2) holding the distinct state rows; an array ``K`` stored as rows is
written as ``K@rows``, the int32 index of each of its rows in that table."""
LINK_MARKER = "qlap-checkpoint-link"
"""First word of a marker file that stands for a checkpoint directory (``final`` where symbolic
links cannot be made): ``qlap-checkpoint-link step-0250000``."""


class CheckpointError(ValueError):
    """A checkpoint that cannot be read (missing, corrupt, wrong format or version)."""


class InconsistentArray(ValueError):
    """An array of an npz whose shape disagrees with the arrays it goes with (a grouped
    array's ``ids``/``shapes``, a row index and its table), found while decoding it: ``field``
    names the array. The loaders turn it into a :class:`CheckpointError` "FILE: inconsistent
    checkpoint: FIELD WHY"."""

    def __init__(self, field: str, why: str) -> None:
        super().__init__(f"{field} {why}")
        self.field, self.why = field, why


@contextlib.contextmanager
def atomic_file(path: Path, durable: bool = True) -> Iterator[BinaryIO]:
    """A binary file that becomes ``path`` when the block ends without an error: written as a
    temporary file in the same directory, flushed to disk (``durable``), then renamed over
    ``path``; on an error the temporary file is removed and ``path`` is left as it was. The file
    gets the permissions an ``open(path, "w")`` would (0666 less the umask), not mkstemp's 0600:
    results are for other users too. ``durable`` False skips the ``fsync``: still all or
    nothing for a process that dies, not for the machine (an actor's snapshot, which only a
    restart on the live machine reads, docs/decisions.md 124)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, 0o666 & ~_UMASK)
        with os.fdopen(fd, "wb") as f:
            yield f
            f.flush()
            if durable:
                os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _read_umask() -> int:
    """The process's umask, read once at import (setting it back at once; later threads never
    see it changed)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


_UMASK = _read_umask()


def atomic_write_bytes(path: Path, data: bytes, durable: bool = True) -> None:
    """Write ``data`` to ``path`` via a temporary file in the same directory and a rename
    (``durable``: as :func:`atomic_file`)."""
    with atomic_file(path, durable) as f:
        f.write(data)


def atomic_write_json(path: Path, obj: Any, durable: bool = True) -> None:
    """Human-readable JSON (indented, sorted keys): summary.json, knowledge.json."""
    atomic_write_bytes(path, json.dumps(obj, indent=1, sort_keys=True).encode(), durable)


def write_compact_json(path: Path, obj: Any) -> None:
    atomic_write_bytes(path, json.dumps(obj, separators=(",", ":")).encode())


def pack_rows(arrays: dict[str, np.ndarray], keys: list[str]) -> dict[str, np.ndarray]:
    """Store the 2-D float arrays ``keys`` as indices into one table of distinct rows."""
    keys = [k for k in keys if arrays[k].ndim == 2 and arrays[k].size]
    if not keys:
        return arrays
    width = arrays[keys[0]].shape[1]
    keys = [k for k in keys if arrays[k].shape[1] == width and arrays[k].dtype == np.float64]
    stacked = np.ascontiguousarray(np.concatenate([arrays[k] for k in keys]))
    rows = stacked.view(np.dtype((np.void, stacked.dtype.itemsize * width))).ravel()
    distinct, index = np.unique(rows, return_inverse=True)
    out = {k: v for k, v in arrays.items() if k not in keys}
    out[ROWS] = distinct.view(np.float64).reshape(len(distinct), width)
    index = index.astype(np.int32).ravel()
    at = 0
    for k in keys:
        n = arrays[k].shape[0]
        out[f"{k}@rows"] = index[at:at + n]
        at += n
    return out


def unpack_rows(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Inverse of :func:`pack_rows`; an index array that does not fit its table is an
    :class:`InconsistentArray` naming it (its shape is checked; an index out of range is
    found by the indexing itself, no scan)."""
    table = arrays.pop(ROWS, None)
    if table is not None and table.ndim != 2:
        raise InconsistentArray(ROWS, f"has shape {table.shape}, expected (rows, variables)")
    for k in [k for k in arrays if k.endswith("@rows")]:
        index = arrays.pop(k)
        if table is None:
            raise InconsistentArray(k, f"without the {ROWS} table")
        if index.ndim != 1 or index.dtype.kind not in "iu":
            raise InconsistentArray(k, f"has shape {index.shape} and type {index.dtype}, "
                                       f"expected one dimension of integers")
        try:
            arrays[k[:-5]] = table[index]
        except IndexError:
            raise InconsistentArray(k, f"indexes rows up to {int(index.max())} of a {ROWS} "
                                       f"table of {len(table)}") from None
    return arrays


def group_arrays(arrays: dict[str, np.ndarray], prefix: str) -> dict[str, np.ndarray]:
    """Store the per-object arrays ``<prefix>.<id>.<field>`` (one per DBN or plan) as one
    array per field: ``<prefix>.*.<field>`` (their values, flattened and concatenated in id
    order), ``….ids`` and ``….shapes``. Thousands of small npz entries cost more in headers
    than in data, and deflate does better on one long array."""
    fields: dict[str, list[tuple[int, np.ndarray]]] = {}
    rest = {}
    for k, v in arrays.items():
        parts = k.split(".", 2)
        if len(parts) == 3 and parts[0] == prefix and parts[1].isdigit():
            fields.setdefault(parts[2], []).append((int(parts[1]), np.asarray(v)))
        else:
            rest[k] = v
    for field, items in fields.items():
        items.sort(key=lambda item: item[0])
        dtype = np.result_type(*(a.dtype for _, a in items))
        if len({a.ndim for _, a in items}) > 1 or not all(
                a.dtype == dtype or np.array_equal(a.astype(dtype).astype(a.dtype), a)
                for _, a in items):
            rest.update({f"{prefix}.{i}.{field}": a for i, a in items})   # kept apart
            continue
        items = [(i, a.astype(dtype, copy=False)) for i, a in items]   # e.g. counts as float
        key = f"{prefix}.*.{field}"
        rest[key] = np.concatenate([a.ravel() for _, a in items])
        rest[f"{key}.ids"] = np.array([i for i, _ in items], dtype=np.int64)
        rest[f"{key}.shapes"] = np.array([a.shape for _, a in items], dtype=np.int64
                                         ).reshape(len(items), items[0][1].ndim)
    return rest


def ungroup_arrays(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Inverse of :func:`group_arrays` (for every prefix). The ``ids`` and ``shapes`` are
    checked against each other and the values (:func:`_check_group`, small arrays only): a
    mismatch is an :class:`InconsistentArray` naming the array."""
    for key in [k for k in arrays if ".*." in k and not k.endswith((".ids", ".shapes"))]:
        prefix, field = key.split(".*.", 1)
        data = arrays.pop(key)
        for part in ("ids", "shapes"):
            if f"{key}.{part}" not in arrays:
                raise InconsistentArray(key, f"without its {key}.{part}")
        ids, shapes = arrays.pop(f"{key}.ids"), arrays.pop(f"{key}.shapes")
        sizes = _check_group(key, data, ids, shapes)
        at = 0
        for i, shape, n in zip(ids.tolist(), shapes.tolist(), sizes.tolist(), strict=True):
            arrays[f"{prefix}.{i}.{field}"] = data[at:at + n].reshape(tuple(shape))
            at += n
    for key in [k for k in arrays if ".*." in k]:
        raise InconsistentArray(key, f"without its {key.rsplit('.', 1)[0]}")
    return arrays


def _check_group(key: str, data: np.ndarray, ids: np.ndarray, shapes: np.ndarray
                 ) -> np.ndarray:
    """The number of values of each object of the grouped array ``key`` (the product of its
    shape), once ``ids`` (one integer per object, increasing, as :func:`group_arrays` writes
    them), ``shapes`` (a row of non-negative integers per object) and ``data`` (one dimension,
    as many values as the shapes total) agree; else an :class:`InconsistentArray`."""
    if data.ndim != 1:
        raise InconsistentArray(key, f"has shape {data.shape}, expected one dimension")
    if ids.ndim != 1 or ids.dtype.kind not in "iu":
        raise InconsistentArray(f"{key}.ids", f"has shape {ids.shape} and type {ids.dtype}, "
                                              f"expected one dimension of integers")
    if shapes.ndim != 2 or shapes.dtype.kind not in "iu" or len(shapes) != len(ids):
        raise InconsistentArray(f"{key}.shapes", f"has shape {shapes.shape} and type "
                                                 f"{shapes.dtype}, expected ({len(ids)}, "
                                                 f"dimensions) integers ({key}.ids has "
                                                 f"{len(ids)})")
    if len(ids) > 1 and not bool(np.all(ids[1:] > ids[:-1])):
        raise InconsistentArray(f"{key}.ids", "are not increasing (group_arrays writes them "
                                              "sorted): mixed up with another array's")
    if len(ids) and int(ids[0]) < 0:
        raise InconsistentArray(f"{key}.ids", f"holds a negative id {int(ids[0])}")
    if shapes.size and int(shapes.min()) < 0:
        raise InconsistentArray(f"{key}.shapes", "holds a negative length")
    sizes = np.prod(shapes, axis=1, dtype=np.int64)
    total = int(sizes.sum())
    if total != len(data):
        raise InconsistentArray(key, f"has shape {data.shape}, expected ({total},) (the total "
                                     f"of {key}.shapes)")
    return sizes


XZ_ARRAYS = (ROWS, "plan.*.q_values")
"""The large tables of full-precision floats (the distinct state rows, the Q-values), stored
as ``K.npy.xz``: their ``.npy`` compressed with xz (LZMA, preset 0), about a fifth smaller than
deflate for a second or two per checkpoint."""


def write_npz(path: Path, arrays: dict[str, np.ndarray], fast: bool = False) -> None:
    """An npz (a zip of ``.npy`` files, deflated, as ``np.savez_compressed`` writes it), with
    the :data:`XZ_ARRAYS` stored as ``.npy.xz`` entries instead; ``fast``: stored, not
    compressed (``np.savez``). Each array is streamed into its entry, compressed on the way,
    into the file itself (:func:`atomic_file`): no copy of it is held in memory, neither
    plain nor compressed (docs/decisions.md 108)."""
    with atomic_file(path) as f, zipfile.ZipFile(f, "w", allowZip64=True) as zf:
        for key, value in arrays.items():
            array = np.asanyarray(value)
            xz = not fast and key in XZ_ARRAYS
            info = zipfile.ZipInfo(f"{key}.npy.xz" if xz else f"{key}.npy",
                                   date_time=time.localtime()[:6])
            info.compress_type = zipfile.ZIP_STORED if fast or xz else zipfile.ZIP_DEFLATED
            info.external_attr = 0o600 << 16            # as ZipFile.writestr gives an entry
            big = array.nbytes > zipfile.ZIP64_LIMIT // 2   # its size is not known up front
            with zf.open(info, "w", force_zip64=big) as entry:
                if xz:
                    with lzma.LZMAFile(entry, "w", preset=0) as packed:
                        np.lib.format.write_array(packed, array, allow_pickle=False)
                else:
                    np.lib.format.write_array(entry, array, allow_pickle=False)


def read_npz(path: Path) -> dict[str, np.ndarray]:
    """Every array of an npz written by :func:`write_npz` or ``np.savez`` (no pickle)."""
    out = {}
    with zipfile.ZipFile(path) as zf:
        for name in zf.namelist():
            if name.endswith(".npy.xz"):
                data = io.BytesIO(lzma.decompress(zf.read(name)))
                out[name[:-7]] = np.lib.format.read_array(data, allow_pickle=False)
            elif name.endswith(".npy"):
                with zf.open(name) as f:
                    out[name[:-4]] = np.lib.format.read_array(f, allow_pickle=False)
    return out


def resolve_checkpoint(path: str | Path) -> Path:
    """The checkpoint directory ``path`` stands for: itself, or the directory a marker file
    (``qlap-checkpoint-link NAME``, NAME beside it) names. Symbolic links need no help."""
    path = Path(path)
    if path.is_file() and path.stat().st_size < 256:
        text = path.read_text(errors="replace").split()
        if len(text) == 2 and text[0] == LINK_MARKER and "/" not in text[1] \
                and text[1] not in (".", ".."):
            return path.parent / text[1]
    return path


def not_a_checkpoint(directory: Path) -> str | None:
    """Why ``directory`` (resolved) cannot be a checkpoint at all — a file, or a run
    directory given for one of its checkpoints — or None."""
    if directory.is_file():
        return f"{directory}: a file, not a checkpoint directory"
    if not directory.exists():
        return f"{directory}: no such checkpoint directory"
    if (directory / "checkpoints").is_dir() and not (directory / "learner.json").exists():
        return (f"{directory} is a run directory, not a checkpoint: give "
                f"{directory / 'checkpoints' / 'final'} (or one of its step-… directories)")
    return None


