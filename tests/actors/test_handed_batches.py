"""The embedded placement's learners keep no learner with a lag (docs/decisions.md 72): their
batches compute on the copies of the executor's learner it hands over at each batch step, and
the knowledge and checkpoints stay the synchronous loop's."""

from __future__ import annotations

import trio

from qlap_runtime.placements.launcher import run_embedded
from qlap_runtime.qlap import Params
from qlap_runtime.qlap.checkpoint import load_learner, statistics_missing
from qlap_runtime.qlap.learner import ModelLearner
from qlap_runtime.runtime.batches import ENDED, HandedCopies, hands_over
from qlap_runtime.runtime.context import RunContext, world_variables

from .test_lockstep import BASE, context, sync_knowledge


def test_a_take_waits_for_its_put_and_ends_with_the_run():
    copies = HandedCopies()
    learner = ModelLearner(world_variables("core2d")[0])
    got: list = []

    async def main() -> None:
        async with trio.open_nursery() as nursery:
            async def taker() -> None:
                for step in (500, 1000, 1500):
                    got.append(await copies.take("r", step))
            nursery.start_soon(taker)
            await trio.sleep(0.01)
            assert got == []                        # waits for the executor's step 500
            copies.put("r", 500, learner)
            copies.put("r", 1000, None)             # a rejected step: no batch
            await trio.sleep(0.01)
            copies.end("r", 1200)                   # a quit after step 1200
    trio.run(main)
    assert isinstance(got[0], ModelLearner) and got[0] is not learner   # a copy
    assert got[1:] == [None, ENDED]
    copies.discard("r")
    assert not copies.copies and not copies.last


def test_only_learners_in_the_executors_process_with_a_lag_are_handed_copies():
    from qlap_runtime.placements.groups import ACTORS, LAYOUTS

    ctx = RunContext("r", "core2d", 10, 0, Params(batch_lag=200), placement="embedded",
                     groups=(ACTORS,))                     # as run_embedded sets it
    assert hands_over(ctx)
    assert not hands_over(ctx.with_(params=Params(batch_lag=0)))       # L = 0: own learner
    for layout in ("two", "each"):                         # the learners in another process
        assert not hands_over(ctx.with_(placement="processes", groups=LAYOUTS[layout]))
    assert not hands_over(ctx.with_(clock="realtime"))              # the copy would hold it


def test_embedded_learners_without_a_learner_equal_the_synchronous_loop(tmp_path, monkeypatch):
    import actors.learning

    def no_learner(*_: object) -> None:
        raise AssertionError("a learning actor made a learner of its own")

    monkeypatch.setattr(actors.learning, "start_learner", no_learner)
    monkeypatch.setenv("QLAP_BATCH_PROCESS", "1")           # batches in a worker process
    params = BASE.replace(batch_lag=200)
    expected = sync_knowledge("core2d", params, seed=4)
    ctx = context(tmp_path, "core2d", params, 4, "t-handed").with_(checkpoint_every=1000)
    summary = run_embedded(ctx)
    assert (tmp_path / "knowledge.json").read_text() == expected
    assert summary["rejected_messages"] == 0
    learners = summary["actors"]["contingency"]          # in the worker process (decision 80)
    assert learners["batches_in_process"] == learners["batches"] > 0
    # The statistics part comes from the executor now, of the checkpoint's own step.
    ckpt = tmp_path / "checkpoints" / "step-0002000"
    assert (ckpt / "stats.json").is_file() and not statistics_missing(ckpt)
    assert load_learner(ckpt).step == 1999      # merged: the part is of the same step
