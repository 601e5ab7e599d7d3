"""A batch's copy of the learner reads the history of its own step, whatever the learner that
goes on observing writes into its ring buffers meanwhile (docs/decisions.md 63)."""

from __future__ import annotations

from itertools import islice

import numpy as np

from qlap_runtime.qlap import ModelLearner, Params
from qlap_runtime.runtime.batches import copy_for_batch
from tests.qlap.toyworld import SPECS, babble_stream


def learner_after(steps: int) -> ModelLearner:
    learner = ModelLearner(SPECS, Params(event_history=50))
    learner.auto_batches = False
    for t, obs in islice(babble_stream(400, seed=3), steps):
        learner.observe(t, obs)
    return learner


def test_a_batch_copy_keeps_its_history_while_the_learner_goes_on():
    learner = learner_after(120)                # its ring buffers have wrapped
    work = copy_for_batch(learner)
    for t, obs in islice(babble_stream(400, seed=3), 120, 150):
        learner.observe(t, obs)                 # the actor goes on while the batch computes
    hx, hq = learner_after(120).perception.history()
    batch_x, batch_q = work.perception.history()  # first read by the batch, after that
    assert len(hx) == 50
    assert np.array_equal(batch_x, hx, equal_nan=True)
    assert np.array_equal(batch_q, hq)
    live_x, _ = learner.perception.history()
    assert not np.array_equal(live_x, hx, equal_nan=True)
