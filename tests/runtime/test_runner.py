"""The runner contract (qlap_runtime/runtime/runner.py) that the executor actor and the UI's
local runner share: the same control stream gives the same state and answers, malformed
commands are refused and counted, ``save`` stays inside the run directory, and the display
topics reach a subscriber on a real embedded Zenoh session."""

from __future__ import annotations

from pathlib import Path

import trio

import worlds
from qlap_runtime.bus import keys
from qlap_runtime.bus.bridge import RejectionCounter, TrioSubscriber
from qlap_runtime.bus.schema import AgentStatus, Control
from qlap_runtime.qlap import Params
from qlap_runtime.qlap.agent import Agent
from qlap_runtime.runtime.controls import RunControl
from qlap_runtime.runtime.runner import Display, Runner


def agent() -> Agent:
    world = worlds.make("core2d")
    try:
        a = Agent(world.variables, Params(), seed=0)
        obs = world.reset(seed=0)
        for t in range(3):
            obs = world.step(a.step(t, obs))
        return a
    finally:
        world.close()


def test_the_control_stream_sets_the_clock_and_the_agent(tmp_path: Path):
    counter = RejectionCounter("t")
    r = Runner(agent(), "core2d", out=tmp_path, counter=counter)
    assert r.apply([Control("pause")]) and r.clock.paused and r.message == "paused"
    r.apply([Control("step", {"n": 3})])
    assert r.clock.budget == 3 and r.clock.may_step
    r.apply([Control("speed", {"steps_per_s": 40})])
    assert r.clock.speed == 40 and r.message == "speed 40 steps/s"
    r.apply([Control("goal", {"var": "h_x.dot", "value": "[+]"})])
    assert r.message.startswith("goal ") and r.agent.goal is not None
    r.apply([Control("goal", {"clear": True})])
    assert r.message == "goal cleared" and r.agent.goal is None and r.agent_changes == 2
    r.apply([Control("save")])
    saved = Path(r.message.removeprefix("saved "))
    assert saved.parent == tmp_path / "checkpoints" and (saved / "agent.json").is_file()
    r.apply([Control("save", {"path": "mine"})])
    assert r.message == f"saved {(tmp_path / 'mine').resolve()}"
    assert counter.snapshot().total == 0
    r.apply([Control("step", {"n": "many"}), Control("speed", {"steps_per_s": [1]}),
             Control("save", {"path": "../elsewhere"}), Control("save", {"path": "a\x00b"}),
             Control("goal", {"var": 3})])
    assert counter.snapshot().total == 5
    assert r.message.startswith("goal refused") and not (tmp_path.parent / "elsewhere").exists()
    assert r.clock.budget == 3 and r.clock.speed == 40          # the refused changed nothing
    r.finished = True
    r.apply([Control("resume")])
    assert "resume ignored" in r.message and r.clock.paused
    r.apply([Control("quit")])
    assert r.clock.quit and not r.clock.may_step


async def test_display_publishes_the_status_a_viewer_reads(embedded):
    a = agent()
    clock = RunControl(paused=True, message="paused")
    with Display(embedded, "runner-test", placement="embedded", world="core2d", seed=0) as d, \
            TrioSubscriber(embedded, keys.key("runner-test", "status")) as sub:
        d.publish(a, clock, clock_name="lockstep", force=True)
        with trio.fail_after(10):
            batch = await sub.receive_batch()
        status = batch[-1].msg
        assert isinstance(status, AgentStatus)
        assert status.paused and status.message == "paused" and status.world == "core2d"
        assert status.step == a.step_count and not status.finished
        await trio.sleep(0.05)
        a.step_count += 50                      # 50 steps since the first status, then done
        d.finish()
        d.publish(a, clock, clock_name="lockstep", force=True)
        with trio.fail_after(10):
            batch = await sub.receive_batch()
        assert batch[-1].msg.finished and not batch[-1].msg.paused
        # A finished run shows its mean rate, not the last second's (no steps: 0).
        t, step = d.first
        assert step == a.step_count - 50
        assert batch[-1].msg.steps_per_s == round(50 / (d.finished_at - t), 1) > 0


async def test_a_goal_dropped_by_a_landmark_is_told_once_in_the_status(embedded):
    """A landmark that splits the goal's value drops the goal (docs/decisions.md 121); the next
    status says why, once, and a later command's answer replaces it."""
    a = agent()
    clock = RunControl(message="goal a(h_x, (-inf, 0))")
    with Display(embedded, "runner-drop", placement="embedded", world="core2d", seed=0) as d:
        a.goal_dropped = (a.step_count, "goal on h_x dropped at step 3: …")
        assert d.status(a, clock, clock_name="free", now=0.0).message == \
            "goal on h_x dropped at step 3: …"
        clock.message = "paused"
        assert d.status(a, clock, clock_name="free", now=0.1).message == "paused"
