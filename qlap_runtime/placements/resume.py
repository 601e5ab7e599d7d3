"""``qlap run --resume CKPT`` in the actor placements: the run context of a resumed run, and
why a checkpoint cannot be resumed exactly there (one line, with what to use instead).

A checkpoint of any placement (sync, embedded, processes) resumes exactly in embedded and
processes when it holds the world's state, the learner's pair statistics (a sync checkpoint's
learner, or an actor placement's ``stats`` part), and no batch in flight
(:func:`actors.resume.batch_in_flight`; none with the defaults, whose checkpoints fall on DBN
batch steps and whose lag is shorter than a DBN period). The resumed run keeps the
checkpoint's parameters, its lag included, as the synchronous loop's ``--resume`` does.
"""

from __future__ import annotations

import json
from pathlib import Path

from ..errors import CliError
from ..qlap.checkpoint import (
    CheckpointError,
    load_agent,
    load_world_state,
    resolve_checkpoint,
    statistics_missing,
)
from ..runtime.context import RunContext


class ResumeRefused(CliError):
    """A checkpoint the actor placements cannot resume exactly (one line)."""


def from_actor_placement(checkpoint: Path) -> bool:
    """True for a checkpoint an actor placement wrote (the executor's follower learner)."""
    try:
        meta = json.loads((resolve_checkpoint(checkpoint) / "learner.json").read_text())
        return bool(meta.get("follower", False))
    except (OSError, ValueError, AttributeError):
        return False


def in_flight_problem(checkpoint: Path, params, step: int, placement: str) -> str | None:
    """Why a batch in flight at ``step`` makes the checkpoint inexact in ``placement``, or
    None. A sync checkpoint keeps its pending deltas (the sync loop resumes it exactly); an
    actor placement's does not (its consumers held them)."""
    from actors.resume import batch_in_flight

    computed = batch_in_flight(params, step)
    if computed is None:
        return None
    what = (f"the batch of step {computed} was in flight at step {step} (applied at step "
            f"{computed + params.batch_lag})")
    if from_actor_placement(checkpoint):
        return (f"{what} and an actor placement's checkpoint does not hold its delta: no "
                f"placement resumes it exactly; use a checkpoint at a multiple of "
                f"dbn_period ({params.dbn_period})")
    if placement != "sync":
        return f"{what}: only --placement sync resumes it exactly (its pending deltas)"
    return None


def why_no_stats(ckpt: Path) -> str:
    """Why an actor placement's checkpoint has no ``stats`` part: its run's clock was realtime
    (the learners keep none under it), or the part was lost."""
    import json

    try:
        summary = json.loads((ckpt.parent.parent / "summary.json").read_text())
    except (OSError, ValueError):
        summary = {}
    if isinstance(summary, dict) and summary.get("clock") == "realtime":
        return "a run under --clock realtime, whose learners keep none"
    return "an actor placement's checkpoint without its stats part"


def resume_context(ctx: RunContext, checkpoint: Path) -> RunContext:
    """``ctx`` started from ``checkpoint``: its parameters, its step, the checkpoint named
    for the actors (:mod:`actors.resume`). Raises :class:`ResumeRefused` or
    :class:`~qlap_runtime.qlap.checkpoint.CheckpointError` (one line each) when the resumed
    run could not equal the uninterrupted one."""
    if ctx.realtime:
        raise ResumeRefused("--resume needs the lockstep clock: a realtime run depends on "
                            "timing and cannot continue exactly")
    ckpt = resolve_checkpoint(Path(checkpoint)).resolve()
    agent = load_agent(ckpt)
    if statistics_missing(ckpt):
        raise ResumeRefused(f"{ckpt}: the learner has no pair statistics ({why_no_stats(ckpt)}): "
                            "no placement resumes it exactly; --placement sync runs it "
                            "inexactly")
    if load_world_state(ckpt) is None:
        raise ResumeRefused(f"{ckpt}: the checkpoint holds no world state: the actor "
                            "placements resume only exactly; --placement sync restarts the "
                            "world from reset(seed)")
    _check_world(ctx.world, ckpt)
    params = agent.learner.params
    step = agent.step_count + 1
    problem = in_flight_problem(ckpt, params, step, ctx.placement or "embedded")
    if problem is not None:
        raise ResumeRefused(problem)
    return ctx.with_(params=params, start_step=step, resume_checkpoint=ckpt)


def _check_world(spec: str, ckpt: Path) -> None:
    """The world state restores into ``spec`` (a state of another world is one line here,
    before any actor starts)."""
    import worlds
    from actors.resume import restore_world

    world = worlds.make(spec)
    try:
        restore_world(world, ckpt)
    except CheckpointError as exc:
        raise ResumeRefused(str(exc)) from None
    finally:
        world.close()
