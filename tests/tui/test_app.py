"""Pilot tests: the UI against a real agent (the local driver on an embedded Zenoh session).

pytest runs async tests under trio (``trio_mode``); Textual needs asyncio, so each test is a
plain function running its coroutine with ``asyncio.run``.
"""

from __future__ import annotations

import asyncio
import threading
import time

import pytest

from qlap_runtime.bus import keys
from tests.tui.conftest import make_driver
from tui import QlapApp
from tui.widgets import ActionsPanel, GoalScreen, PlansPanel, RuntimePanel, WorldPanel

SIZE = (160, 50)


@pytest.fixture(autouse=True)
def _leave_the_shared_agent_running(request):
    """A test that fails while the shared agent is paused must not stall the next ones."""
    yield
    if "driver" in request.fixturenames:
        request.getfixturevalue("driver").command("resume")


async def until(pilot, predicate, within: float = 60.0) -> None:
    deadline = time.monotonic() + within
    while not predicate():
        assert time.monotonic() < deadline, "condition not reached in the UI"
        await pilot.pause(0.05)


async def select(pilot, panel: ActionsPanel, label: str) -> None:
    """Put the cursor on ``label``'s row as the user would (rows move as the snapshot re-sorts
    them; a row chosen by the user is followed)."""
    panel.table.focus()
    row = panel.table.get_row_index(label)
    panel.table.move_cursor(row=row, animate=False)
    panel.user_moved(row)
    await until(pilot, lambda: panel.selected == label)
    await pilot.pause(0.1)


def test_actions_appear_and_selecting_one_shows_its_plans(driver):
    async def main():
        app = QlapApp(driver.session, run_id=driver.run_id)
        async with app.run_test(size=SIZE) as pilot:
            await until(pilot, lambda: app.knowledge is not None and any(
                a.plans for a in app.knowledge.actions))
            await pilot.press("p")                       # a still table: rows stop moving
            await until(pilot, lambda: app.status.paused)
            await pilot.pause(0.4)
            panel = app.query_one(ActionsPanel)
            await until(pilot, lambda: panel.table.row_count > 0)
            with_plans = [a.label for a in app.knowledge.actions if a.plans]
            await select(pilot, panel, with_plans[0])
            keys = ("up", "down") if panel.table.cursor_row else ("down", "up")
            await pilot.press(*keys)                          # the keys move the selection
            await until(pilot, lambda: panel.selected == with_plans[0])
            plans = app.query_one(PlansPanel)
            assert plans.action is not None and plans.action.label == panel.selected
            assert plans.plan_labels() and all(lbl.startswith("⟨") for lbl in plans.plan_labels())
            assert plans.query_one("DataTable").row_count == len(plans.action.plans)
            assert app.status is not None and app.status.world == "core2d"
            assert "agent" in app.alive
            assert app.world is not None and app.world.world == "core2d"
            before = panel.sort_by
            await pilot.press("o")
            assert panel.sort_by != before
            await pilot.press("p")
            await until(pilot, lambda: not app.status.paused)
    asyncio.run(main())


def test_pause_stops_the_step_counter_single_step_and_resume(driver):
    async def main():
        app = QlapApp(driver.session, run_id=driver.run_id)
        async with app.run_test(size=SIZE) as pilot:
            await until(pilot, lambda: app.status is not None and not app.status.paused)
            await pilot.press("p")
            await until(pilot, lambda: app.status.paused)
            step = app.status.step
            await pilot.pause(0.5)
            assert app.status.step == step == driver.agent.step_count
            await pilot.press("s")
            await until(pilot, lambda: app.status.step == step + 1)
            await pilot.pause(0.3)
            assert driver.agent.step_count == step + 1 and app.status.paused
            await pilot.press("p")
            await until(pilot, lambda: not app.status.paused and app.status.step > step + 50)
    asyncio.run(main())


def test_speed_checkpoint_and_help(driver, tmp_path):
    async def main():
        app = QlapApp(driver.session, run_id=driver.run_id)
        async with app.run_test(size=SIZE) as pilot:
            await until(pilot, lambda: app.status is not None)
            await pilot.press("minus")
            await until(pilot, lambda: app.status.speed == 1000.0
                        and app.status.clock == "realtime")
            await pilot.press("minus")
            await until(pilot, lambda: app.status.speed == 300.0)
            await pilot.press("plus", "plus")
            await until(pilot, lambda: app.status.speed == 0.0 and app.status.clock == "free")
            await pilot.press("minus", "minus", "minus")        # quick presses: none is lost
            await until(pilot, lambda: app.status.speed == 100.0)
            await pilot.press("plus", "plus", "plus")
            await until(pilot, lambda: app.status.speed == 0.0)
            await pilot.press("p")
            await until(pilot, lambda: app.status.paused)
            await pilot.pause(0.3)
            await pilot.press("c")
            await until(pilot, lambda: app.status.message.startswith("saved "))
            saved = app.status.message.removeprefix("saved ")
            assert (driver.checkpoint_dir / saved.rsplit("/", 1)[-1]).is_dir()
            # The checkpoint is named by the step on the screen.
            assert saved.endswith(f"step-{app.status.step + 1:07d}")
            assert f"step {app.status.step + 1}" in str(app.query_one(RuntimePanel).render())
            await pilot.press("p")
            await pilot.press("question_mark")
            assert app.screen.__class__.__name__ == "HelpScreen"
            await pilot.press("escape")
            assert app.screen.__class__.__name__ != "HelpScreen"
    asyncio.run(main())


def test_goal_dialog_sets_and_clears_a_goal(driver):
    async def main():
        app = QlapApp(driver.session, run_id=driver.run_id)
        async with app.run_test(size=SIZE) as pilot:
            await until(pilot, lambda: app.knowledge is not None and any(
                a.plans for a in app.knowledge.actions))
            await pilot.press("p")              # still knowledge: labels cannot be renumbered
            await until(pilot, lambda: app.status.paused)
            await pilot.pause(0.4)
            target = next(a for a in app.knowledge.actions if a.plans)
            panel = app.query_one(ActionsPanel)
            await select(pilot, panel, target.label)
            await pilot.press("g")
            assert isinstance(app.screen, GoalScreen)
            await pilot.pause(0.5)              # let the dialog mount fully on a loaded machine
            await pilot.click("#goal-set")      # pre-filled with the selected action
            await until(pilot, lambda: app.status.goal != "", within=30)
            assert app.status.goal == target.label
            assert driver.agent.goal is not None
            assert app.status.mode in ("goal", "idle", "babble")
            await pilot.press("g")
            await pilot.click("#goal-clear")
            await until(pilot, lambda: app.status.goal == "")
            assert driver.agent.goal is None
            await pilot.press("p")
            await until(pilot, lambda: not app.status.paused)
    asyncio.run(main())


def test_a_finished_run_shows_finished_stops_its_clock_and_takes_no_more_steps():
    d = make_driver(run_id="finish-test", steps=300)
    d.start()

    async def main():
        app = QlapApp(driver=d)
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.status is not None and app.status.finished)
            assert app.status.step + 1 == d.agent.step_count + 1 == 300
            wall = app.status.wall_s
            notices: list[str] = []
            notify = app.notify
            app.notify = lambda message, **kw: (notices.append(message),  # type: ignore
                                                notify(message, **kw))[1]
            await pilot.press("p")                 # the UI says so and sends nothing
            await pilot.press("s")
            await pilot.pause(0.5)
            assert notices == ["the run finished at step 300: nothing to pause or resume",
                               "the run finished at step 300: no more steps to take"]
            d.command("pause")                     # another viewer's pause: ignored too
            d.command("step", n=1)
            await until(pilot, lambda: "ignored" in app.status.message)
            await pilot.pause(1.2)                 # the status goes out again, clock stopped
            assert app.status.finished and not app.status.paused
            assert d.agent.step_count + 1 == 300 and app.status.wall_s == wall
            assert "FINISHED  step 300" in str(app.query_one(RuntimePanel).render())
            assert app.query_one(WorldPanel).border_title.endswith("step 300")
            assert app.world.text.startswith("core2d t=300 ")     # the world's own clock
            await pilot.press("q")

    asyncio.run(main())
    assert not d.alive


def test_quit_closes_everything_and_stops_an_owned_driver():
    before = {t.ident for t in threading.enumerate()}
    d = make_driver(run_id="quit-test")
    d.start()

    async def main():
        app = QlapApp(driver=d)
        async with app.run_test(size=SIZE) as pilot:
            await until(pilot, lambda: app.status is not None and app.status.step > 0)
            await pilot.press("q")
        return app

    t0 = time.monotonic()
    app = asyncio.run(main())
    assert time.monotonic() - t0 < 30
    assert not d.alive and d._session is None and app._session is None
    assert app.return_code in (0, None)
    time.sleep(0.2)
    leftover = [t.name for t in threading.enumerate() if t.ident not in before]
    assert leftover == [], leftover


def test_a_viewer_on_loopback_attaches_to_a_listening_driver(tmp_path):
    """`qlap tui --connect`: the driver listens on loopback, the UI connects as a client."""
    import zenoh

    from qlap_runtime.bus import router_config
    from tests.runtime.conftest import free_port

    port = free_port()
    with zenoh.open(router_config([f"tcp/127.0.0.1:{port}"])):
        d = make_driver(run_id="remote", session=None)
        d._listen = []
        from qlap_runtime.bus.config import client_config

        d._session = zenoh.open(client_config([f"tcp/127.0.0.1:{port}"]))
        d._own_session = True
        d.start()
        try:
            async def main():
                app = QlapApp(connect=f"tcp/127.0.0.1:{port}")     # run id learned from the bus
                async with app.run_test(size=SIZE) as pilot:
                    await until(pilot, lambda: app.status is not None and app.status.step > 0)
                    assert app.run_id == "remote" and "agent" in app.alive
                    await pilot.press("p")
                    await until(pilot, lambda: app.status.paused)
                    await pilot.press("q")
                return app
            app = asyncio.run(main())
            assert app._session is None
            assert d.alive and d.paused            # quitting a viewer does not stop the agent
        finally:
            d.stop()
    assert keys.validate_run_id("remote")


def test_a_selection_queued_at_shut_down_is_skipped_not_a_crash():
    """Once the app's screens are gone (shutting down), a panel lookup is NoMatches and a
    selection message still queued is skipped (it raised IndexError on a loaded machine)."""
    from textual.css.query import NoMatches

    app = QlapApp(connect="tcp/127.0.0.1:1")             # never run: no screen at all
    assert app.screen_stack == []
    with pytest.raises(NoMatches, match="shutting down"):
        app._panel(PlansPanel)
    app.knowledge = type("K", (), {"actions": []})()
    app.on_actions_panel_selected(ActionsPanel.Selected("a(ḣ_x, [+])"))   # no exception
