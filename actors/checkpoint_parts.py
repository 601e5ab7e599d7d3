"""The parts of an actor placement's checkpoints that the executor does not hold.

The executor writes each checkpoint (``agent.json``, its follower learner), but two things a
checkpoint needs for an exact ``--resume`` live in other actors (docs/decisions.md 41): the
world's state (the world actor, ``world.json``) and the pair and window statistics of DBN
search (the contingency actor's learner, ``stats.json``/``stats.npz``, or in the embedded
placement with a lag the executor's own, which keeps them there, docs/decisions.md 72;
:func:`~qlap_runtime.qlap.checkpoint.load_learner` puts them into the follower learner). Each
actor writes its part into ``checkpoints/step-N/`` at the same step as the executor (after
step N − 1, in lockstep), each file atomically. The parts of the final state go to
``checkpoints/.final-parts/`` and the launcher moves them into ``final`` once every actor has
ended (:func:`place_final_parts`), or, in the distributed placement, the executor once the
world and contingency actors have ended (:func:`gather_final_parts`); a ``final`` that links
to ``step-N`` has them already.

A run the watchdog stops (an embedded run's actors are then cancelled) keeps what was learned:
the executor writes ``knowledge.json`` and ``checkpoints/final`` of its last complete step and
the world its state (:func:`keep_on_stall`); the contingency actor's statistics, of another
step, are not written, so such a checkpoint resumes without its pair statistics.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

from qlap_runtime.qlap.checkpoint import (
    STATS_PART,
    WORLD_FILE,
    save_statistics,
    save_world_state,
    step_name,
    world_state_of,
)
from qlap_runtime.runtime.context import RunContext

FINAL_PARTS = ".final-parts"


def _writes(ctx: RunContext) -> bool:
    """Checkpoints with parts: outputs, lockstep (realtime states depend on timing), and a
    retention that keeps some."""
    keep = ctx.keep_checkpoints
    return ctx.out is not None and not ctx.realtime and (keep is None or int(keep) != 0)


def part_dir(ctx: RunContext, t: int) -> Path | None:
    """``checkpoints/step-(t+1)`` when the executor takes a periodic checkpoint after step t,
    else None."""
    if (t + 1) % ctx.checkpoint_every or not _writes(ctx):
        return None
    directory = Path(ctx.out) / "checkpoints" / step_name(t + 1)  # type: ignore[arg-type]
    return None if _pruned(directory) else directory


def _pruned(directory: Path) -> bool:
    """A checkpoint the executor's retention already removed (a lagging or restarted actor
    writing a part late): a newer ``step-N`` exists and this one does not."""
    if directory.exists():
        return False
    return any(d.name > directory.name for d in directory.parent.glob("step-*"))


def final_dir(ctx: RunContext) -> Path | None:
    """Where an actor puts its part of the final checkpoint (None: no outputs)."""
    if not _writes(ctx):
        return None
    return Path(ctx.out) / "checkpoints" / FINAL_PARTS  # type: ignore[arg-type]


def save_world_part(directory: Path | None, world: Any) -> None:
    """The world actor's part: ``world.json`` (nothing for a world that cannot save it)."""
    if directory is not None:
        save_world_state(directory, world_state_of(world))


def save_statistics_part(directory: Path | None, learner: Any) -> None:
    """The contingency actor's part: the pair and window statistics."""
    if directory is not None:
        save_statistics(learner, directory)


def place_final_parts(checkpoints: Path) -> None:
    """Move the final parts into ``checkpoints/final`` when it is a directory of its own (a
    ``final`` linked to ``step-N`` has that checkpoint's parts), then remove them."""
    parts = Path(checkpoints) / FINAL_PARTS
    if not parts.is_dir():
        return
    final = Path(checkpoints) / "final"
    if final.is_dir() and not final.is_symlink() and (final / "agent.json").is_file():
        for name in (WORLD_FILE, f"{STATS_PART}.npz", f"{STATS_PART}.json"):
            if (parts / name).is_file():
                (parts / name).replace(final / name)
    # else: a link or a marker, whose step-N has the parts, or no final (the run failed)
    shutil.rmtree(parts, ignore_errors=True)


def discard_incomplete(checkpoints: Path) -> list[Path]:
    """After a run that stopped early (a full disk, Ctrl-C, an actor that failed): remove the
    ``step-N`` directories that hold another actor's part but no agent (the executor's write
    never came or failed), so that every checkpoint left is whole; returns them."""
    gone = []
    root = Path(checkpoints)
    for d in sorted(root.glob("step-*")) if root.is_dir() else ():
        if d.is_dir() and not d.is_symlink() and not (d / "agent.json").is_file():
            shutil.rmtree(d, ignore_errors=True)
            gone.append(d)
    return gone


FINAL_PARTS_WAIT_S = 60.0
"""How long a distributed run's executor waits for the world and contingency actors to end."""


async def gather_final_parts(session: Any, ctx: RunContext) -> None:
    """The distributed placement has no launcher to move the final parts into ``final``: the
    executor, its own outputs written, waits (at most :data:`FINAL_PARTS_WAIT_S`) until the
    world and contingency actors have ended — their parts are written before their tokens go —
    and moves the parts that reached its ``--out`` (the actors share it, e.g. on one machine
    or a shared file system) into ``final``."""
    if ctx.out is None or not _writes(ctx):
        return
    import trio

    from qlap_runtime.bus.bridge import alive_actors

    with trio.move_on_after(FINAL_PARTS_WAIT_S):
        while (await alive_actors(session, ctx.run_id)) & {"world", "contingency"}:  # noqa: ASYNC110
            await trio.sleep(0.05)
    place_final_parts(Path(ctx.out) / "checkpoints")


def stalled(ctx: RunContext) -> bool:
    """Whether the watchdog stopped this run (``ctx.board.stalled``)."""
    return getattr(getattr(ctx, "board", None), "stalled", None) is not None


def keep_on_stall(ctx: RunContext, agent: Any = None, world: Any = None) -> None:
    """Called by a cancelled actor: when the watchdog stopped the run, the executor's
    ``agent`` is kept (``knowledge.json``, ``checkpoints/final``) and the ``world``'s state
    goes to the final parts. Synchronous: it runs inside the cancelled scope."""
    if not stalled(ctx) or ctx.out is None:
        return
    from qlap_runtime.qlap.checkpoint import atomic_write_json, save_final_checkpoint

    if agent is not None:
        atomic_write_json(Path(ctx.out) / "knowledge.json", agent.knowledge())
        save_final_checkpoint(agent, Path(ctx.out) / "checkpoints", ctx.world)
    if world is not None:
        save_world_part(final_dir(ctx), world)
