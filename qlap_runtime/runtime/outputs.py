"""The run directory is checked before a run starts (every placement): it must be a directory
that can be written, with room for at least a checkpoint (docs/outputs.md).

A grown core agent's checkpoint takes about 11 MB (250,000 steps); ``MIN_FREE`` asks for some
more, so that a run does not learn for hours and then lose its knowledge at the first write.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

from ..errors import CliError
from ..qlap.checkpoint import atomic_write_json
from .context import RunContext

MIN_FREE = 32 * 2**20
"""Bytes that must be free under ``--out`` before a run starts."""


class OutputError(CliError):
    """The run directory cannot hold the run's outputs (exit status 2)."""


def check_out(out: Path, min_free: int = MIN_FREE) -> None:
    """Create ``out`` if needed, write and remove a probe file (64 KiB, fsynced) and check
    that ``min_free`` bytes are free there; :class:`OutputError` in one line otherwise. A
    directory this check created is removed again when it refuses (no empty run left)."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise OutputError(f"--out {out}: exists and is not a directory")
    created = missing_dirs(out)
    try:
        _probe(out, min_free)
    except OutputError:
        remove_empty(created)
        raise


def missing_dirs(out: Path) -> list[Path]:
    """``out`` and its parents that do not exist yet, innermost first: what making ``out``
    creates, for :func:`remove_empty` when the command is refused after all."""
    return [p for p in (Path(out), *Path(out).parents) if not p.exists()]


def remove_empty(created: list[Path]) -> None:
    """Remove the directories of :func:`missing_dirs` again, innermost first, as long as they
    are empty (a refused command leaves no empty directory behind)."""
    for d in created:
        try:
            d.rmdir()
        except OSError:
            break


def _probe(out: Path, min_free: int) -> None:
    probe = out / f".qlap-probe-{os.getpid()}"
    try:
        out.mkdir(parents=True, exist_ok=True)
        with open(probe, "wb") as f:
            f.write(b"\0" * 65536)
            f.flush()
            os.fsync(f.fileno())
        probe.unlink()
    except OSError as exc:
        try:
            probe.unlink(missing_ok=True)
        except OSError:
            pass
        raise OutputError(f"--out {out}: cannot write there ({exc.strerror or exc})") from None
    free = shutil.disk_usage(out).free
    if free < min_free:
        raise OutputError(f"--out {out}: {free / 2**20:.1f} MB free, a run needs at least "
                          f"{min_free / 2**20:.0f} MB (room for a checkpoint)")


def write_failure_summary(ctx: RunContext, world_actor: dict[str, Any]) -> None:
    """``summary.json`` of a run whose world failed (nothing without ``ctx.out``): the
    executor's summary (``actors/executor.json``, when it wrote one) with the failure and the
    world actor's result added."""
    if ctx.out is None:
        return
    out = Path(ctx.out)
    executor = out / "actors" / "executor.json"
    try:
        summary = json.loads(executor.read_text()) if executor.exists() else {}
    except (OSError, ValueError):
        summary = {}
    summary.update(placement=ctx.placement, world=ctx.world, seed=ctx.seed,
                   steps=world_actor["steps"], world_error=world_actor["world_error"],
                   world_actor=world_actor)
    atomic_write_json(out / "summary.json", summary)
