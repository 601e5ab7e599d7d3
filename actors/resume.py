"""Actors started from a checkpoint (``qlap run --resume CKPT --placement embedded|processes``;
docs/checkpoint.md, docs/decisions.md 50).

A resumed run's context names the checkpoint (``RunContext.resume_checkpoint``) and starts at
its step N (``start_step``: the checkpoint holds the state after step N − 1). Every actor that
has no snapshot of its own starts from it: the world from ``world.json`` with the motor values
the agent applied last, perception from the learner's perception, the batch actors from the
learner (with an actor placement's ``stats`` part put in), the executor from the agent. A batch
that is in flight at N (computed before N, applied at or after it) is not in an actor
placement's checkpoint, so such checkpoints are refused before the run
(:func:`batch_in_flight`; :mod:`qlap_runtime.placements.resume`).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from qlap_runtime.qlap.checkpoint import CheckpointError, resolve_checkpoint
from qlap_runtime.qlap.delta import batch_kinds
from qlap_runtime.qlap.params import Params
from qlap_runtime.runtime.context import RunContext


def checkpoint_of(ctx: RunContext, snapshot: Path | None) -> Path | None:
    """The checkpoint an actor starts from: ``ctx.resume_checkpoint`` unless it restarts from
    a snapshot of its own (``snapshot``)."""
    return None if snapshot is not None else ctx.resume_checkpoint


def batch_in_flight(params: Params, step: int) -> int | None:
    """The step of a batch computed before ``step`` whose delta applies at or after it (at
    its step + lag), or None: a checkpoint at ``step`` then lacks that delta in an actor
    placement (its consumers hold it, not the checkpoint)."""
    lag = params.batch_lag
    for computed in range(max(1, step - lag), step):
        if batch_kinds(params, computed):
            return computed
    return None


def applied_motors(checkpoint: Path) -> dict[str, float]:
    """The motor values the checkpoint's agent applied last (``agent.json`` ``motor``): what
    the world actor applies until the first motor of the resumed run arrives."""
    path = resolve_checkpoint(checkpoint) / "agent.json"
    try:
        motor = json.loads(path.read_text()).get("motor")
        return {str(k): float(v) for k, v in dict(motor).items()}
    except (OSError, ValueError, TypeError, AttributeError) as exc:
        raise CheckpointError(f"{path}: no motor values to resume from ({exc})") from None


def restore_world(world: Any, checkpoint: Path) -> dict[str, float]:
    """Put ``world`` in the checkpoint's state; returns the observation after step N − 1."""
    from qlap_runtime.qlap.checkpoint import WORLD_FILE, load_world_state
    from qlap_runtime.qlap.checkpoint import restore_world as restore

    state = load_world_state(checkpoint)
    where = resolve_checkpoint(checkpoint) / WORLD_FILE
    if state is None:
        raise CheckpointError(f"{where}: missing (the world's state is needed to resume)")
    return restore(world, state, where)


def start_world(world: Any, ctx: RunContext) -> tuple[dict[str, float], dict[str, float]]:
    """The world actor's first observation and the motor values it applies until the first
    motor arrives: the checkpoint's (a resumed run), or a reset with every motor at 0."""
    applied = {v.name: 0.0 for v in world.variables
               if getattr(v.kind, "value", v.kind) == "motor"}
    if ctx.resume_checkpoint is None:
        return world.reset(seed=ctx.seed), applied
    obs = restore_world(world, ctx.resume_checkpoint)
    applied.update(applied_motors(ctx.resume_checkpoint))
    return obs, applied
