"""An embedded run stopped by the watchdog keeps what was learned (issue 13): the executor
writes knowledge.json and checkpoints/final of its last complete step, the world its state
beside it, and the run ends with the one-line RunStalled."""

from __future__ import annotations

import json

import pytest
import trio

import worlds
from qlap_runtime.bus.bridge import declare_alive
from qlap_runtime.placements import launcher
from qlap_runtime.qlap.checkpoint import (
    load_agent,
    load_world_state,
    restore_world,
    statistics_missing,
)
from qlap_runtime.runtime.watchdog import RunStalled

from .test_faults import BASE, context


def test_a_stalled_embedded_run_writes_a_final_checkpoint(tmp_path, monkeypatch):
    """The contingency actor is alive but never works (as if stuck): the executor waits for
    delta/dbn(500) at step 500 + lag = 700 and the watchdog stops the run after 3 s."""
    real = launcher._run_unit

    async def stuck_contingency(unit, session, ctx, ready=None):
        if unit != "learners":
            return await real(unit, session, ctx, ready)
        # In the embedded placement the learners' task carries both learning actors
        # (docs/decisions.md 54): both are alive and stuck.
        with declare_alive(session, ctx.run_id, "contingency"), \
                declare_alive(session, ctx.run_id, "landmarks"):
            await trio.sleep_forever()

    monkeypatch.setattr(launcher, "_run_unit", stuck_contingency)
    out = tmp_path / "run"
    ctx = context(out, BASE, 3, "t-stall-keep").with_(stall_s=3)
    with pytest.raises(BaseException) as err:   # noqa: PT011 - RunStalled, maybe in a group
        launcher.run_embedded(ctx)
    leaf = err.value
    while isinstance(leaf, BaseExceptionGroup):
        leaf = leaf.exceptions[0]
    assert isinstance(leaf, RunStalled)
    assert "executor waits for delta/dbn(500) at step 700" in str(leaf)
    assert "\n" not in str(leaf)
    final = out / "checkpoints" / "final"
    agent = load_agent(final)
    assert agent.step_count == 699                  # the last step the executor completed
    assert json.loads((out / "knowledge.json").read_text())["step"] == 699
    state = load_world_state(final)
    assert state is not None and state["step_count"] == 700     # motor(699) applied
    assert statistics_missing(final)                 # the learner's pair statistics: not kept
    world = worlds.make("core2d")
    restore_world(world, state, final)               # and it continues
    assert world.step({"u_x": 500.0}) is not None
    assert not (out / "checkpoints" / ".final-parts").exists()
