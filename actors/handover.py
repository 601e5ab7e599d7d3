"""The executor's side of the learners' handed batches (docs/decisions.md 72).

When the learning actors share the executor's process with a lag
(:func:`~qlap_runtime.runtime.batches.hands_over`), they keep no learner: the executor's
follower keeps the pair statistics too, hands them a batch copy at each batch step (after
observing ``qstate(t)``, before the deltas due at t) and writes the checkpoints' statistics
part, as the contingency actor's learner does otherwise. Off, every method does nothing.
"""

from __future__ import annotations

from qlap_runtime.qlap.learner import ModelLearner
from qlap_runtime.runtime.batch_process import wanted
from qlap_runtime.runtime.batches import HANDED, hands_over
from qlap_runtime.runtime.context import RunContext
from qlap_runtime.runtime.lockstep import batch_kinds

from .checkpoint_parts import final_dir, part_dir, save_statistics_part


class HandOver:
    """What the executor does for the learners when ``hands_over(ctx)``."""

    def __init__(self, ctx: RunContext, learner: ModelLearner) -> None:
        self.ctx, self.on = ctx, hands_over(ctx)
        if self.on:
            learner.keeps_pairs = True          # the statistics a batch reads

    def observed(self, t: int, learner: ModelLearner | None) -> ModelLearner | None:
        """After observing ``qstate(t)``: the batch copy of a batch step (None: step t was
        rejected, no batch starts there). Returns it when the batch computes on it in this
        process, applying its operations as it goes — the state the plan compilation of t
        reads once the batch's deltas are out (docs/decisions.md 86) — else None."""
        if self.on and batch_kinds(self.ctx.params, t):
            work = HANDED.put(self.ctx.run_id, t, learner)
            return None if wanted() else work   # a worker process: the copy stays as it is
        return None

    def after_step(self, t: int, learner: ModelLearner) -> None:
        """The checkpoints' statistics part of step ``t``."""
        if self.on:
            save_statistics_part(part_dir(self.ctx, t), learner)

    def final(self, learner: ModelLearner) -> None:
        if self.on:
            save_statistics_part(final_dir(self.ctx), learner)

    def end(self, last: int) -> None:
        """No batch copy after step ``last`` (the learners wait for none)."""
        if self.on:
            HANDED.end(self.ctx.run_id, last)
