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
