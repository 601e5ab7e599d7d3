"""Helpers every ``qlap`` command shares: the checks made before anything starts
(:func:`check_args`, :func:`file_problem` for an output file, :func:`lag_problem` for
``--lag``), making a world from its spec with a one-line error (:func:`make_world`), and telling
a checkpoint learned in another world (:func:`world_mismatch`)."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

from ..errors import CliError, expected_error, one_line


def check_args(args: argparse.Namespace) -> None:
    """Inputs wrong before anything starts: a negative --babble-steps, an output file whose
    directory does not exist (--record, snapshot/record --out)."""
    babble = getattr(args, "babble_steps", None)
    if babble is not None and babble < 0:
        raise CliError(f"--babble-steps {babble}: expected a non-negative integer")
    outputs = {"run": ("record", "--record"), "snapshot": ("out", "--out"),
               "record": ("out", "--out")}
    attr, flag = outputs.get(args.command, (None, None))
    value = getattr(args, attr, None) if attr else None
    if value is not None:
        problem = file_problem(Path(value))
        if problem is None and args.command == "snapshot" \
                and Path(value).suffix.lower() != ".png":
            problem = "a snapshot is a PNG image: give a file ending in .png"
        if problem is None and args.command != "snapshot" and Path(value).exists():
            problem = "exists: give a new file (a recording is never overwritten)"
        if problem is not None:
            raise CliError(f"{flag} {value}: {problem}")


def file_problem(path: Path) -> str | None:
    """Why an output file cannot be written at ``path``, found before any work starts (a
    directory there, no parent directory, or a parent that refuses a probe file); None if it
    can."""
    import tempfile

    if path.is_dir():
        return "is a directory, not a file"
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        return f"directory {parent} does not exist"
    try:                                # a probe, as the file is written: a temp file there
        fd, probe = tempfile.mkstemp(dir=parent, prefix=f".{path.name}.", suffix=".tmp")
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        return f"cannot write in {parent} ({exc.strerror or exc})"
    return None


def make_world(spec: str, command: str):
    import worlds

    try:
        return worlds.make(spec)
    except Exception as exc:
        if expected_error(exc) is None and not isinstance(
                exc, ValueError | ImportError | AttributeError):
            raise
        print(f"qlap {command}: --world {spec}: {one_line(exc)}", file=sys.stderr)
        return None


def lag_problem(lag: int) -> str | None:
    """Why ``--lag`` cannot be ``lag`` (one line), or None: a batch's delta is applied before
    the next batch starts, so 0 <= L < the DBN batch period (Algorithm 2)."""
    from ..qlap import Params

    period = Params().dbn_period
    if 0 <= lag < period:
        return None
    return (f"--lag {lag}: must be in [0, {period}) — a batch's delta is applied before the "
            f"next batch, every {period} steps, starts")


def world_mismatch(checkpoint: Path, world: Any, spec: str) -> str | None:
    """Why a checkpoint's agent cannot act in ``world`` (its variables are not the world's:
    it was learned in another world), or None (also when the checkpoint cannot be read:
    loading it says why)."""
    from ..analysis.runs import recorded_world
    from ..qlap.checkpoint import CheckpointError, resolve_checkpoint

    try:
        meta = json.loads((resolve_checkpoint(checkpoint) / "learner.json").read_text())
        names = [v["name"] for v in meta["variables"] if v.get("source", -1) == -1]
    except (OSError, ValueError, KeyError, TypeError, AttributeError, CheckpointError):
        return None
    if names == [v.name for v in world.variables]:
        return None
    learned = recorded_world(checkpoint)
    missing = [n for n in names if n not in {v.name for v in world.variables}]
    detail = (f" (which has no {', '.join(missing[:3])}{', …' if len(missing) > 3 else ''})"
              if missing else " (its variables differ)")
    if learned == spec:             # the checkpoint names this world but its variables are not
        return (f"{checkpoint}: its variables are not those of world {spec!r}{detail}: a "
                "damaged checkpoint, or one from another version of the world")
    where = f"world {learned!r}" if learned else "another world"
    return f"{checkpoint} was learned in {where}, not --world {spec!r}{detail}"


def say(*values: object) -> None:
    """``print`` to stdout for a run's report: a reader that left (``qlap run … | head``)
    silences the rest instead of failing a run that has its outputs to write."""
    from ..metrics import print_to

    print_to(sys.stdout, *values)

