"""What an actor's algorithm starts from: the actor's own snapshot (restarted by the
supervisor), the resumed run's checkpoint (``qlap run --resume``, docs/decisions.md 50), or a
fresh state for the run's world."""

from __future__ import annotations

from ..qlap.checkpoint import load_learner
from ..qlap.learner import ModelLearner
from ..qlap.perception import Perception
from ..qlap.variables import VariableTable
from .actor import Resume
from .context import RunContext, world_variables
from .snapshot import load_learner_snapshot, load_perception


def start_learner(ctx: RunContext, resume: Resume) -> ModelLearner:
    """A batch actor's learner; it computes batches only when its actor says so."""
    if resume.path is not None:
        learner = load_learner_snapshot(resume.path)
    elif resume.checkpoint is not None:     # a resumed run: the learner with its statistics
        learner = load_learner(resume.checkpoint)
        learner.follower = False
        learner.pending_deltas.clear()      # none: refused before the run otherwise
    else:
        specs, _ = world_variables(ctx.world)
        learner = ModelLearner(specs, ctx.params)
    learner.auto_batches = False
    return learner


def start_perception(ctx: RunContext, resume: Resume) -> Perception:
    """The perception actor's quantity spaces and previous values."""
    specs, _ = world_variables(ctx.world)
    per = Perception(VariableTable.from_specs(specs), ctx.params)
    if resume.path is not None:
        load_perception(per, resume.path)
    elif resume.checkpoint is not None:     # a resumed run: the learner's perception
        per = load_learner(resume.checkpoint).perception
    return per
