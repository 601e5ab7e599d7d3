"""A run's checkpoints: ``step-NNNNNNN`` every N steps (§7.2), retention, ``final``, the world.

``final`` is a directory or, when the last ``step-N`` holds exactly the final state, a symbolic
link to it (a small marker file where links cannot be made; :func:`~.files.resolve_checkpoint`
follows both). :func:`prune_checkpoints` keeps the newest N; ``world.json`` holds the world's
state for an exact ``--resume``.
"""

from __future__ import annotations

import json
import os
import re
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

from .agent_files import AGENT_FILE, WORLD_FILE, save_agent
from .files import LINK_MARKER, CheckpointError, resolve_checkpoint, write_compact_json

_STEP_DIR = re.compile(r"step-(\d+)")


def step_name(step: int) -> str:
    """``step-NNNNNNN``: the checkpoint taken when the agent has observed ``step`` steps."""
    return f"step-{int(step):07d}"


def step_checkpoints(checkpoints: str | Path) -> list[tuple[int, Path]]:
    """The ``step-N`` directories of a run's ``checkpoints/``, by step."""
    root = Path(checkpoints)
    found = []
    for d in root.glob("step-*") if root.is_dir() else ():
        m = _STEP_DIR.fullmatch(d.name)
        if m and d.is_dir() and not d.is_symlink():
            found.append((int(m[1]), d))
    return sorted(found)


def final_target(checkpoints: str | Path) -> Path | None:
    """The directory ``checkpoints/final`` stands for (None when there is no final)."""
    final = Path(checkpoints) / "final"
    if not final.exists():
        return None
    return resolve_checkpoint(final).resolve()


def prune_checkpoints(checkpoints: str | Path, keep: int | None) -> list[Path]:
    """Remove all but the newest ``keep`` ``step-N`` directories (None: keep all); the one
    ``final`` stands for is never removed. Returns the removed directories."""
    if keep is None:
        return []
    target = final_target(checkpoints)
    steps = step_checkpoints(checkpoints)
    doomed = steps[:max(0, len(steps) - keep)]
    removed = []
    for _, d in doomed:
        if target is not None and d.resolve() == target:
            continue
        shutil.rmtree(d, ignore_errors=True)
        removed.append(d)
    return removed


def save_world_state(directory: str | Path, state: Any) -> None:
    """Write ``world.json`` (a ``World.get_state()``; None writes nothing) atomically."""
    if state is not None:
        write_compact_json(Path(directory) / WORLD_FILE, state)


def load_world_state(directory: str | Path) -> dict[str, Any] | None:
    """The world state a checkpoint holds (None: it has none, e.g. written before world
    states were saved). A corrupt file raises :class:`CheckpointError` naming it."""
    path = resolve_checkpoint(directory) / WORLD_FILE
    try:
        state = json.loads(path.read_text())
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        raise CheckpointError(f"{path}: corrupt world state ({exc})") from None
    if not isinstance(state, dict) or state.get("format") != "qlap-world-state":
        raise CheckpointError(f"{path}: not a qlap-world-state file")
    return state


def world_state_of(world: Any) -> dict[str, Any] | None:
    """``world.get_state()`` for a checkpoint, or None for a world that cannot save one (a
    plug-in world without the method, a replayed world whose caller moved things)."""
    get = getattr(world, "get_state", None)
    if get is None:
        return None
    try:
        return get()
    except (ValueError, NotImplementedError):
        return None


def restore_world(world: Any, state: dict[str, Any], where: str | Path) -> dict[str, float]:
    """``world.set_state(state)``, any failure a one-line :class:`CheckpointError` naming
    ``where``; returns the observation the agent sees now."""
    try:
        return world.set_state(state)
    except (ValueError, KeyError, TypeError, IndexError, AttributeError, OverflowError) as exc:
        what = f"{type(exc).__name__}: {exc}" if not isinstance(exc, ValueError) else str(exc)
        raise CheckpointError(f"{where}: the world state cannot be restored ({what})") from None


def save_step_checkpoint(agent: Any, checkpoints: str | Path, step: int,
                         world: str | None = None, keep: int | None = None,
                         world_state: Any = None) -> Path | None:
    """The periodic checkpoint ``checkpoints/step-NNNNNNN`` (``step``: steps observed), with
    the world's state when given, then the retention of ``keep`` (None: keep all; 0: write
    none). Returns its path (None with ``keep == 0``)."""
    if keep == 0:
        return None
    path = save_agent_checkpoint(agent, Path(checkpoints) / step_name(step), world, world_state)
    prune_checkpoints(checkpoints, keep)
    return path


def save_agent_checkpoint(agent: Any, target: str | Path, world: str | None = None,
                          world_state: Any = None, merge: bool = True) -> Path:
    """The agent (and the world's state, when given) as one checkpoint directory ``target``,
    written whole or not at all (:func:`write_checkpoint_dir`)."""

    def write(d: Path) -> None:
        save_agent(agent, d, world)
        save_world_state(d, world_state)

    return write_checkpoint_dir(target, write, merge)


def write_checkpoint_dir(target: str | Path, write: Callable[[Path], None],
                         merge: bool = True) -> Path:
    """A checkpoint directory written whole or not at all: ``write`` fills a hidden sibling
    (``.NAME.PID.tmp``), which is then renamed to ``target``. Where ``target`` already exists
    as a directory it is replaced, or with ``merge`` (the actor placements' world and
    statistics parts are written into it first; a second save at one step) the files move in
    one by one, ``agent.json`` — what makes a directory a checkpoint — last. If ``write``
    fails (a full disk), the sibling is removed and the error raised: no half-written
    checkpoint is left under a checkpoint's name."""
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.parent / f".{target.name}.{os.getpid()}.tmp"
    _remove(tmp)
    try:
        tmp.mkdir()
        write(tmp)
        if target.is_dir() and not target.is_symlink() and merge:
            for name in sorted((p.name for p in tmp.iterdir()),
                               key=lambda n: (n == AGENT_FILE, n)):
                os.replace(tmp / name, target / name)
            tmp.rmdir()
        else:
            _remove(target)             # rename(2) puts a directory only where none is
            os.replace(tmp, target)
    except BaseException:
        _remove(tmp)
        raise
    return target


def _remove(path: Path) -> None:
    if path.is_symlink() or path.is_file():
        path.unlink()
    elif path.is_dir():
        shutil.rmtree(path)


def save_final_checkpoint(agent: Any, checkpoints: str | Path, world: str | None = None,
                          same_as: str | Path | None = None, world_state: Any = None) -> Path:
    """Write ``checkpoints/final`` (with the world's state when given). ``same_as``: a
    ``step-N`` directory beside it that holds exactly this agent's state (saved at this step,
    nothing changed since); ``final`` is then a relative symbolic link to it (a marker file
    where links cannot be made), not a copy."""
    root = Path(checkpoints)
    root.mkdir(parents=True, exist_ok=True)
    final = root / "final"
    same = Path(same_as) if same_as is not None else None
    if same is None or same.parent.resolve() != root.resolve() \
            or not (same / AGENT_FILE).is_file():
        return save_agent_checkpoint(agent, final, world, world_state, merge=False)
    tmp = root / f".final-{os.getpid()}.tmp"
    _remove(tmp)
    try:
        os.symlink(same.name, tmp, target_is_directory=True)
    except OSError:                                         # no links here: a marker file
        tmp.write_text(f"{LINK_MARKER} {same.name}\n")
    if final.is_dir() and not final.is_symlink():
        shutil.rmtree(final)
    os.replace(tmp, final)
    return final

