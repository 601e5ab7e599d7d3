"""argparse value types shared by the command lines (``qlap``, ``qlap experiment``, scripts)."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path


def _integer_at_least(text: str, least: int, what: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    if value < least:
        raise argparse.ArgumentTypeError(f"expected {what}, got {value}")
    return value


def positive_int(text: str) -> int:
    """An integer ≥ 1, with a one-line error naming the value."""
    return _integer_at_least(text, 1, "a positive integer")


def count(text: str) -> int:
    """An integer ≥ 0, with a one-line error naming the value."""
    return _integer_at_least(text, 0, "a non-negative integer")


def _float_in(text: str, what: str, ok: Callable[[float], bool]) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    if not (math.isfinite(value) and ok(value)):
        raise argparse.ArgumentTypeError(f"expected {what}, got {text}")
    return value


def positive_float(text: str) -> float:
    """A finite number > 0 (a rate, a duration), with a one-line error naming the value."""
    return _float_in(text, "a finite number > 0", lambda v: v > 0)


def non_negative_float(text: str) -> float:
    """A finite number ≥ 0, with a one-line error naming the value."""
    return _float_in(text, "a finite number >= 0", lambda v: v >= 0)


def path_arg(text: str) -> Path:
    """A path given on the command line; an empty one is refused (``Path('')`` is the current
    directory, which a user who typed ``--out ''`` did not mean)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty path")
    return Path(text)


def goal_arg(text: str):  # -> worlds.base.Goal
    """``VAR=VALUE`` (e.g. ``T_L.dot=+``, ``bang=true``) as a world Goal; a one-line error
    naming the text otherwise. Whether VAR and VALUE exist is checked against the agent."""
    from worlds.base import Goal

    var, sep, value = text.partition("=")
    if not sep or not var.strip() or not value.strip():
        raise argparse.ArgumentTypeError(f"expected VAR=VALUE (e.g. T_L.dot=+), got {text!r}")
    return Goal(var.strip(), value.strip())


class Once(argparse.Action):
    """An option that may be given once: a second value is an error, not a silent
    replacement of the first."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: object, option_string: str | None = None) -> None:
        if getattr(namespace, self.dest, self.default) is not self.default:
            raise argparse.ArgumentError(self, "given twice: give it once")
        setattr(namespace, self.dest, values)
