"""Actor snapshots: what a restarted actor resumes from (docs/runtime.md, Faults).

An actor of the processes placement writes, every ``snapshot_every`` steps, its whole state at
the boundary of a step s into ``<snapshot dir>/<actor>/step-<s>/``:

- the algorithm's state with the checkpoint code (JSON + npz, no pickle, ``docs/checkpoint.md``):
  the agent's files for the executor, and for contingency and landmarks ``learner.frame``, the
  checkpoint's state as one frame of raw arrays (:func:`save_learner_snapshot`; a snapshot is
  read back only by a restart, so it is not compressed: docs/decisions.md 90),
  ``perception.{json,npz}`` (its quantity spaces and previous values) for perception;
- ``actor.json``: the step s, the actor's :class:`~.lockstep.DeltaBook` (deltas received but not
  yet applied, skipped steps, the last step handed out) and small actor-specific values.

The directory is written under a temporary name and renamed, then ``<actor>/latest.json`` is
replaced atomically to point at it, and older snapshots are removed: a crash at any point leaves
the previous snapshot intact and readable. Because lockstep makes each actor's state a function
of its input stream, the state at s plus the inputs after s give back exactly the state of an
actor that never died.
"""

from __future__ import annotations

import io
import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..qlap.checkpoint import (
    CheckpointError,
    atomic_file,
    atomic_write_bytes,
    atomic_write_json,
    check_learner,
    learner_state,
    load_learner,
    restore_learner,
)
from ..qlap.delta import Delta
from ..qlap.learner import ModelLearner
from ..qlap.perception import Perception
from .batch_process import read_frame, write_frame
from .lockstep import DeltaBook

FORMAT = "qlap-actor-snapshot"
VERSION = 1
DEFAULT_EVERY = 1000
"""Steps between two snapshots of an actor unless ``RunContext.snapshot_every`` says."""
KEEP = 1
"""Older snapshots kept besides the latest: the actors of a process group write theirs one
after the other, so a process killed between two writes still leaves a step that all of them
have (:func:`common_snapshot`)."""


def book_state(book: DeltaBook) -> dict[str, Any]:
    """A :class:`DeltaBook` as JSON: the schedule position and the deltas not yet applied."""
    return {"last": book.last, "skipped": sorted(book.skipped),
            "applied_versions": book.applied_versions, "waits": book.waits,
            "received": [[kind, d.to_json()] for (_, kind), d in sorted(book.received.items())]}


def restore_book(book: DeltaBook, state: dict[str, Any]) -> None:
    book.last = int(state["last"])
    book.skipped = {int(s) for s in state["skipped"]}
    book.applied_versions = int(state["applied_versions"])
    book.waits = int(state["waits"])
    book.received = {}
    for kind, d in state["received"]:
        book.add(str(kind), Delta.from_json(d))


LEARNER_FRAME = "learner.frame"


def save_learner_snapshot(learner: ModelLearner, directory: Path) -> None:
    """The learner's complete state (:func:`~qlap_runtime.qlap.checkpoint.learner_state`) as
    ``learner.frame``: one frame of the batch worker's format (a JSON header, then each array's
    raw bytes; no pickle). A learning actor snapshots every ``snapshot_every`` steps and only a
    restart reads it: the checkpoint's compressed npz cost 0.3 s a write at 25,000 core steps,
    the frame 0.02–0.03 s (docs/decisions.md 90)."""
    meta, arrays = learner_state(learner)
    with atomic_file(Path(directory) / LEARNER_FRAME, durable=False) as f:   # decision 124
        write_frame(f, {"meta": meta}, arrays)


def load_learner_snapshot(directory: Path) -> ModelLearner:
    """The learner of a snapshot: :func:`save_learner_snapshot`'s frame, checked as a
    checkpoint is, or a checkpoint's ``learner.{json,npz}`` (older snapshots)."""
    path = Path(directory) / LEARNER_FRAME
    if not path.exists():
        return load_learner(directory)
    try:
        with open(path, "rb") as f:
            frame = read_frame(f)
        if frame is None:
            raise EOFError("empty")
        meta, arrays = frame[0]["meta"], dict(frame[1])
        check_learner(meta, arrays, path)
        return restore_learner(meta, arrays)
    except CheckpointError:
        raise
    except (OSError, EOFError, ValueError, KeyError, TypeError, IndexError,
            AttributeError) as exc:
        raise CheckpointError(f"{path}: unreadable learner snapshot "
                              f"({type(exc).__name__}: {exc})") from None


def save_perception(per: Perception, directory: Path, name: str = "perception") -> None:
    """The perception actor's state: quantity spaces (its landmarks), previous values and the
    bounded history (``perceive`` reads the previous values; the history is small)."""
    meta, arrays = per.to_state()
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    atomic_write_bytes(directory / f"{name}.npz", buf.getvalue(), durable=False)
    atomic_write_json(directory / f"{name}.json", meta, durable=False)


def load_perception(per: Perception, directory: Path, name: str = "perception") -> None:
    """Restore :func:`save_perception`'s state into ``per`` (built for the same world)."""
    try:
        meta = json.loads((directory / f"{name}.json").read_text())
        with np.load(directory / f"{name}.npz", allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        per.load_state(meta, arrays)
    except (OSError, ValueError, KeyError, TypeError, IndexError) as exc:
        raise CheckpointError(f"{directory}: unreadable perception snapshot "
                              f"({type(exc).__name__}: {exc})") from None


def write_snapshot(root: Path, actor: str, step: int, state: dict[str, Any],
                   save: Callable[[Path], Any] | None = None, keep: int = KEEP) -> Path:
    """Write ``<root>/<actor>/step-<step>/`` (``save(dir)`` writes the algorithm's files, then
    ``actor.json`` holds ``state``), point ``latest.json`` at it, remove older ones but the
    ``keep`` newest (:data:`KEEP`)."""
    base = Path(root) / actor
    final = base / f"step-{step:09d}"
    tmp = base / f".step-{step:09d}.{os.getpid()}.tmp"
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    if save is not None:
        save(tmp)
    atomic_write_json(tmp / "actor.json", {"format": FORMAT, "version": VERSION,
                                           "actor": actor, "step": int(step), "state": state},
                      durable=False)
    if final.exists():          # written before a restart: the same state (determinism)
        shutil.rmtree(tmp)
    else:
        os.replace(tmp, final)
    atomic_write_json(base / "latest.json", {"step": int(step), "path": final.name},
                      durable=False)
    older = sorted((d for d in base.iterdir() if d.is_dir() and d.name != final.name
                    and d.name.startswith("step-")), reverse=True)
    for old in older[max(0, keep):]:
        shutil.rmtree(old, ignore_errors=True)
    return final


def snapshot_steps(root: Path, actor: str) -> dict[int, Path]:
    """Every complete snapshot of ``actor``: step -> directory (a ``step-*`` directory is
    complete: it is renamed into place once written)."""
    out: dict[int, Path] = {}
    try:
        dirs = list((Path(root) / actor).glob("step-*"))
    except OSError:
        return out
    for d in dirs:
        try:
            step = int(d.name.removeprefix("step-"))
        except ValueError:
            continue
        if (d / "actor.json").exists():
            out[step] = d
    return out


def common_snapshot(root: Path, actors: tuple[str, ...]) -> tuple[int, dict[str, Path]] | None:
    """(step, actor -> directory) of the newest step at which every one of ``actors`` has a
    snapshot (a process group resumes all its actors from one step), or None. For one actor
    it is its latest snapshot."""
    if len(actors) == 1:
        latest = latest_snapshot(root, actors[0])
        return None if latest is None else (latest[0], {actors[0]: latest[1]})
    each = [snapshot_steps(root, a) for a in actors]
    common = set.intersection(*(set(steps) for steps in each)) if each else set()
    if not common:
        return None
    step = max(common)
    return step, {a: steps[step] for a, steps in zip(actors, each, strict=True)}


def latest_snapshot(root: Path, actor: str) -> tuple[int, Path] | None:
    """(step, directory) of the actor's latest complete snapshot, or None."""
    base = Path(root) / actor
    try:
        meta = json.loads((base / "latest.json").read_text())
        path = base / str(meta["path"])
        step = int(meta["step"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return (step, path) if (path / "actor.json").exists() else None


def read_snapshot(path: Path, actor: str) -> tuple[int, dict[str, Any]]:
    """(step, actor state) of a snapshot directory; :class:`CheckpointError` if unusable."""
    jpath = Path(path) / "actor.json"
    try:
        meta = json.loads(jpath.read_text())
    except (OSError, ValueError) as exc:
        raise CheckpointError(f"{jpath}: unreadable snapshot ({exc})") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT \
            or meta.get("version") != VERSION or meta.get("actor") != actor:
        raise CheckpointError(f"{jpath}: not a {FORMAT} v{VERSION} snapshot of {actor}")
    return int(meta["step"]), dict(meta["state"])
