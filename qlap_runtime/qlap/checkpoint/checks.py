"""Checks shared by the learner's and the agent's checkpoint readers: a field that does not
fit the rest of the checkpoint is a one-line :class:`~.files.CheckpointError` naming it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .files import CheckpointError


def bad(where: Path, field: str, why: str) -> CheckpointError:
    """"WHERE: inconsistent checkpoint: FIELD WHY"."""
    return CheckpointError(f"{where}: inconsistent checkpoint: {field} {why}")


def one_line(exc: BaseException) -> str:
    """An exception's message on one line (the CLI prints a CheckpointError as one line)."""
    return " ".join(str(exc).split())


def is_int(v: Any) -> bool:
    """An integer of JSON (not a bool)."""
    return isinstance(v, int) and not isinstance(v, bool)


def numeric_array(where: Path, arrays: dict[str, np.ndarray], key: str) -> np.ndarray:
    """``arrays[key]``, a numeric array (a missing one is named, not a KeyError later)."""
    a = arrays.get(key)
    if a is None:
        raise bad(where, key, "is missing")
    if not isinstance(a, np.ndarray) or a.dtype.kind not in "biuf":
        raise bad(where, key, f"is not an array of numbers ({getattr(a, 'dtype', type(a))})")
    return a


def check_shape(where: Path, key: str, a: np.ndarray, shape: tuple[int, ...],
                why: str = "") -> None:
    """``a`` (the array ``key``) has ``shape``; ``why`` says where the shape comes from."""
    if a.shape != shape:
        raise bad(where, key, f"has shape {a.shape}, expected {shape}{why}")


def check_ring(where: Path, field: str, record: dict, names: tuple[str, str], cap: int) -> None:
    """A ring of ``cap`` stored rows (``Params.stored_activations``): its count and head
    (``names``, e.g. ``act_n``, ``act_head``) of ``record`` (``field``) in range."""
    for name, top in ((names[0], cap), (names[1], cap - 1)):
        v = record.get(name)
        if not is_int(v) or not 0 <= v <= top:
            raise bad(where, f"{field}.{name}", f"must be an integer in 0..{top} "
                                                f"(params.stored_activations), got {v!r}")


def new_id(where: Path, field: str, value: Any, ids: set[int]) -> int:
    """``value``, a non-negative integer not in ``ids`` (added to them): the id of a DBN or a
    plan of the checkpoint."""
    if not is_int(value) or value < 0 or value in ids:
        raise bad(where, field, f"must be a new non-negative integer, got {value!r}")
    ids.add(value)
    return value


def check_owned(where: Path, arrays: dict[str, np.ndarray], prefix: str, ids: set[int],
                owner: str) -> None:
    """Every ``<prefix>.<id>.<field>`` array belongs to an ``owner`` of ``ids``."""
    for key in arrays:
        parts = key.split(".", 2)
        if parts[0] == prefix and len(parts) == 3 and not (parts[1].isdigit()
                                                           and int(parts[1]) in ids):
            raise bad(where, key, f"belongs to no {owner} of the checkpoint")
