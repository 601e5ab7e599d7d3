"""The UI's controls obeyed by the actor runtime (embedded placement, real Zenoh, no mocks).

A pilot task on the run's own session (``run_embedded_async(extra=...)``) publishes
:class:`Control` messages on ``qlap/<run>/control`` and watches ``sense`` (the world's steps) and
``status`` (the executor's answer), as the terminal UI does.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import trio

import worlds
from qlap_runtime import agent_run
from qlap_runtime.agent_run import params_for_world
from qlap_runtime.bus import keys
from qlap_runtime.bus.bridge import TrioSubscriber
from qlap_runtime.bus.schema import AgentStatus, Control, encode
from qlap_runtime.placements.launcher import free_port, run_embedded_async
from qlap_runtime.qlap import Params
from qlap_runtime.runtime.context import RunContext

PARAMS = Params(babble_steps=1000, dbn_period=250, landmark_period=500, min_data_points=10)
"""Short periods and a low data threshold: DBNs from ~1,000 steps on (a few seconds)."""


def context(tmp_path: Path, run_id: str, steps: int, seed: int, params: Params = PARAMS,
            **extra: Any) -> RunContext:
    world = worlds.make("core2d")
    params = params_for_world(world, params)
    world.close()
    return RunContext(run_id, "core2d", steps, seed, params, out=tmp_path, **extra)


def sync_knowledge(ctx: RunContext, steps: int) -> str:
    """knowledge.json of the synchronous loop (equal to an uninterrupted lockstep run's:
    tests/actors/test_lockstep.py)."""
    return agent_run.sync_knowledge("core2d", steps, ctx.seed, ctx.params)


class Pilot:
    """What the UI would see and do: the world's latest step (``sense``), the executor's
    latest status, and ``put`` of controls."""

    def __init__(self, session: Any, ctx: RunContext) -> None:
        self.session, self.ctx = session, ctx
        self.step = -1
        self.status: AgentStatus | None = None
        self.statuses = 0

    def put(self, command: str, **args: Any) -> None:
        self.session.put(keys.key(self.ctx.run_id, "control"), encode(Control(command, args)))

    async def until(self, predicate: Callable[[], bool], within: float = 30.0) -> None:
        with trio.fail_after(within):
            while not predicate():  # noqa: ASYNC110 - the state is set by the watch tasks
                await trio.sleep(0.01)

    async def rate_at(self, steps_per_s: float, seconds: float = 1.0) -> float:
        """Set the speed, resume, and measure the world's steps per second over ``seconds``."""
        self.put("speed", steps_per_s=steps_per_s)
        self.put("resume")
        await self.until(lambda: not self.status.paused and self.status.speed == steps_per_s)
        s, t0 = self.step, time.monotonic()
        await trio.sleep(seconds)
        return (self.step - s) / (time.monotonic() - t0)

    async def steady_step(self, quiet: float = 0.5) -> int:
        """The world's step once it has not moved for ``quiet`` seconds (it is paused)."""
        while True:
            s = self.step
            await trio.sleep(quiet)
            if self.step == s:
                return s

    async def _watch(self, topic: str, on: Callable[[Any], None]) -> None:
        with TrioSubscriber(self.session, keys.key(self.ctx.run_id, topic)) as sub:
            async for batch in sub:
                for r in batch:
                    on(r.msg)

    def _on_status(self, msg: AgentStatus) -> None:
        self.status = msg
        self.statuses += 1

    @classmethod
    def task(cls, script: Callable[[Pilot], Any]) -> Callable[[Any, RunContext], Any]:
        """An ``extra`` task for run_embedded_async running ``script(pilot)``."""
        async def run(session: Any, ctx: RunContext) -> None:
            pilot = cls(session, ctx)
            async with trio.open_nursery() as nursery:
                nursery.start_soon(pilot._watch, "sense",
                                   lambda m: setattr(pilot, "step", max(pilot.step, m.step)))
                nursery.start_soon(pilot._watch, "status", pilot._on_status)
                await script(pilot)
                nursery.cancel_scope.cancel()
        return run


async def test_pause_single_step_goal_save_speed_and_resume(tmp_path):
    steps = 3000
    ctx = context(tmp_path, "ctl-ui", steps, seed=1)
    seen: dict[str, Any] = {}

    async def script(p: Pilot) -> None:
        await p.until(lambda: p.step >= 100 and p.status is not None)
        # Paced, so that the run cannot end before the script has paused it: unpaced, the
        # embedded chain makes these steps in about a second.
        p.put("speed", steps_per_s=400)
        # Another run's control, and malformed ones: ignored (counted), the run goes on.
        p.session.put("qlap/another-run/control", encode(Control("pause")))
        p.session.put(keys.key(ctx.run_id, "control"), b"{not json")
        p.put("step", n="many")
        p.put("speed", steps_per_s=[1])
        s = p.step
        await trio.sleep(0.3)
        assert p.step > s and not p.status.paused

        p.put("pause")
        await p.until(lambda: p.status.paused)
        s = await p.steady_step(0.2)
        n = p.statuses
        await trio.sleep(0.6)                         # ~0.5 s paused: no step at all
        assert p.step == s
        assert p.statuses > n, "no status while paused"
        assert p.status.paused and p.status.message == "paused"

        p.put("step", n=5)                            # exactly five more steps
        await p.until(lambda: p.step >= s + 5)
        await trio.sleep(0.5)
        assert p.step == s + 5 and p.status.paused

        p.put("goal", var="h_x.dot", value="[+]")
        await p.until(lambda: p.status.goal != "")
        assert p.status.message.startswith("goal ") and "[+]" in p.status.goal
        seen["goal"] = p.status.goal
        p.put("save")
        await p.until(lambda: p.status.message.startswith("saved "))
        seen["saved"] = Path(p.status.message.removeprefix("saved "))
        p.put("goal", clear=True)
        await p.until(lambda: p.status.goal == "" and p.status.message == "goal cleared")
        assert p.step == s + 5                        # goal and save took no step

        rate = await p.rate_at(40)
        assert 10 < rate < 60, rate
        seen["rate"] = rate
        p.put("speed", steps_per_s=0)                 # free again: run to the end
        await p.until(lambda: p.status.speed == 0)

    summary = await run_embedded_async(ctx, extra=(Pilot.task(script),))
    assert summary["steps"] == steps
    assert summary["actors"]["world"]["steps"] == steps            # resumed, ran to the end
    assert summary["actors"]["world"]["paused_s"] > 0.5
    assert summary["actors"]["world"]["rejected"] >= 3              # the malformed controls
    assert summary["actors"]["executor"]["rejected"] >= 3
    saved = seen["saved"]
    assert saved.parent == tmp_path / "checkpoints" and saved.name.startswith("step-")
    assert (saved / "agent.json").is_file()
    assert (tmp_path / "knowledge.json").is_file()


async def test_a_paused_and_resumed_run_learns_what_an_uninterrupted_run_learns(tmp_path):
    steps = 1500
    ctx = context(tmp_path, "ctl-det", steps, seed=4, params=PARAMS.replace(batch_lag=100))
    expected = sync_knowledge(ctx, steps)

    async def script(p: Pilot) -> None:
        await p.until(lambda: p.step >= 1)
        p.put("speed", steps_per_s=600)            # paced: the last pause comes before the end
        for at in (300, 1020):                     # before babbling ends; a batch in flight
            await p.until(lambda at=at: p.step >= at)
            p.put("pause")
            await p.until(lambda: p.status is not None and p.status.paused)
            await trio.sleep(0.3)
            p.put("resume")
            await p.until(lambda: not p.status.paused)

    summary = await run_embedded_async(ctx, extra=(Pilot.task(script),))
    assert summary["actors"]["world"]["paused_s"] > 0.4
    got = (tmp_path / "knowledge.json").read_text()
    assert json.loads(got)["dbns"], "nothing was learned: the comparison would be empty"
    assert got == expected


async def test_quit_ends_every_actor_after_the_same_step_and_writes_the_outputs(tmp_path):
    ctx = context(tmp_path, "ctl-quit", 100_000, seed=6)
    seen: dict[str, int] = {}

    async def script(p: Pilot) -> None:
        await p.until(lambda: p.step >= 900)
        p.put("quit")
        await p.until(lambda: p.status is not None and p.status.finished)
        seen["step"] = p.step
        assert p.status.message.startswith("run ended after step ")

    with trio.fail_after(60):
        summary = await run_embedded_async(ctx, extra=(Pilot.task(script),))
    world, executor = summary["actors"]["world"], summary["actors"]["executor"]
    last = world["quit_at_step"]
    assert last == seen["step"] and world["steps"] == last + 1
    assert executor["quit_at_step"] == last and executor["steps_done"] == last + 1
    assert (tmp_path / "checkpoints" / "final" / "agent.json").is_file()
    written = json.loads((tmp_path / "summary.json").read_text())
    assert written["placement"] == "embedded"
    assert summary["steps"] == written["steps"] == last + 1      # the steps made, not asked
    # The outputs describe the run that was made: the synchronous loop's first last+1 steps.
    assert (tmp_path / "knowledge.json").read_text() == sync_knowledge(ctx, last + 1)


async def test_realtime_pause_does_not_count_missed_ticks_and_speed_sets_the_tick_rate(tmp_path):
    steps = 250
    ctx = context(tmp_path, "ctl-rt", steps, seed=8, clock="realtime", hz=100.0)

    async def script(p: Pilot) -> None:
        await p.until(lambda: p.step >= 30 and p.status is not None)
        assert p.status.clock == "realtime" and p.status.speed == 100
        p.put("pause")
        await p.until(lambda: p.status.paused)
        s = await p.steady_step(0.2)
        await trio.sleep(1.0)                   # 100 ticks' worth: none of them missed
        assert p.step == s
        rate = await p.rate_at(40)
        assert 10 < rate < 55, rate
        p.put("speed", steps_per_s=0)           # realtime: back to the configured rate
        await p.until(lambda: p.status.speed == 100)

    summary = await run_embedded_async(ctx, extra=(Pilot.task(script),))
    assert summary["actors"]["world"]["steps"] == steps
    assert summary["missed_ticks"] < 60, summary["missed_ticks"]   # the pause is not counted


def test_the_terminal_ui_pauses_and_resumes_an_attached_embedded_run(tmp_path):
    """`qlap tui --connect` on `qlap run --headless --placement embedded --listen ...`."""
    import asyncio

    from tui import QlapApp

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    ctx = context(tmp_path, "ctl-tui", 100_000, seed=7)
    done = threading.Event()
    errors: list[BaseException] = []

    async def until_done(session: Any, ctx: RunContext) -> None:
        while not done.is_set():  # noqa: ASYNC110 - a thread's event; then quit the run
            await trio.sleep(0.05)
        session.put(keys.key(ctx.run_id, "control"), encode(Control("quit")))

    def agent() -> None:
        try:
            trio.run(lambda: run_embedded_async(ctx, (endpoint,), extra=(until_done,)))
        except BaseException as e:               # reported by the test below
            errors.append(e)

    thread = threading.Thread(target=agent, daemon=True)
    thread.start()

    async def until(pilot, predicate, within: float = 30.0) -> None:
        deadline = time.monotonic() + within
        while not predicate():
            assert time.monotonic() < deadline, "condition not reached in the UI"
            await pilot.pause(0.05)

    async def main() -> None:
        # The run listens with authentication (docs/security.md): the UI is its `tui` user.
        from qlap_runtime.bus.auth import CREDENTIALS_FILE, read_credentials

        cred = tmp_path / CREDENTIALS_FILE
        deadline = time.monotonic() + 60
        while not cred.exists():
            assert time.monotonic() < deadline, "no credentials written"
            await asyncio.sleep(0.05)
        user, password, _ = read_credentials(cred, "tui")
        app = QlapApp(connect=endpoint, run_id=ctx.run_id, user=user, password=password)
        async with app.run_test(size=(160, 50)) as pilot:
            await until(pilot, lambda: app.status is not None and app.status.step > 50)
            assert app.status.placement == "embedded" and app.status.clock == "lockstep"
            await pilot.press("p")
            await until(pilot, lambda: app.status.paused)
            await pilot.pause(0.3)
            s = app.status.step
            await pilot.pause(0.5)
            assert app.status.step == s and app.status.paused
            await pilot.press("s")                  # single step
            await until(pilot, lambda: app.status.step == s + 1)
            await pilot.press("p")
            await until(pilot, lambda: not app.status.paused and app.status.step > s + 1)
            await pilot.press("q")

    try:
        asyncio.run(main())
    finally:
        done.set()
        thread.join(60)
    assert not thread.is_alive() and not errors, errors
    assert (tmp_path / "knowledge.json").is_file()
