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


async def test_a_batch_computes_in_the_actors_task_unless_the_clock_is_realtime():
    """In lockstep a learning actor computes its batches in its task, in a process of its own
    (the processes placement's learners, one actor per process, a distributed actor:
    docs/decisions.md 92) and beside the step chain (embedded, decision 110): a worker thread
    would only share the GIL. Under the realtime clock they go to worker threads, whatever
    the lag."""
    import zenoh

    from qlap_runtime.bus import embedded_config
    from qlap_runtime.placements.groups import ACTORS, LAYOUTS
    from qlap_runtime.runtime.actor import Actor
    from qlap_runtime.runtime.batches import Batches
    from qlap_runtime.runtime.context import RunContext

    def inline(groups: tuple, clock: str = "lockstep", lag: int = 500) -> bool:
        ctx = RunContext("inline-test", "core2d", 100, 0, Params(batch_lag=lag), clock=clock,
                         groups=groups)
        with Actor(session, ctx, "contingency") as actor:
            return Batches(actor, "dbn", 4).inline

    with zenoh.open(embedded_config()) as session:
        assert inline(LAYOUTS["two"]) and inline(LAYOUTS["each"]) and inline(())
        assert inline((ACTORS,)) and inline((ACTORS,), lag=0)       # embedded
        assert not inline(LAYOUTS["two"], clock="realtime")
        assert not inline((ACTORS,), clock="realtime")
        assert not inline((ACTORS,), clock="realtime", lag=0)
