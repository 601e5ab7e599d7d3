"""The UI fed hand-made messages over an embedded Zenoh session (no agent): the selection that
stays on the top row, the goal dialog's pre-fill, quick key presses, a finished run, the two
layouts and the IAC panel. Deterministic, so each asserts exactly what the screen holds.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Iterator

import pytest
import zenoh

from qlap_runtime.bus import keys
from qlap_runtime.bus.config import embedded_config
from qlap_runtime.bus.schema import (
    ActionInfo,
    AgentStatus,
    IACChoice,
    Knowledge,
    KnowledgeCounters,
    PlanInfo,
    WorldView,
    encode,
)
from qlap_runtime.telemetry import pretty
from tui import QlapApp
from tui.widgets import ActionsPanel, GoalScreen, IACPanel, RuntimePanel, StatusBar, WorldPanel
from tui.widgets._format import fit_columns, real, signed
from tui.widgets.actions import COLUMNS

RUN = "panels"
VALUES = {"h_x": ("(-inf, 0.5)", "0.5", "(0.5, +inf)"), "z_F.dot": ("[-]", "[0]", "[+]"),
          "h_x.dot": ("[-]", "[0]", "[+]")}


def action(label: str, variable: str, value: str, index: int, rel: float, calls: int = 60,
           weight: float = 0.05, plans: int = 1) -> ActionInfo:
    plan = PlanInfo(1, 1, f"⟨{{}}: u_x→(0.3, +∞) ⇒ {label}⟩", "change", 0.9, 0.5, (), rel, calls,
                    4)
    return ActionInfo(label, variable, value, index, rel, calls, int(rel * calls), rel > 0.9,
                      weight, tuple([rel] * 16), (plan,) * plans)


A_HX = action(pretty("a(h_x, (0.5, +inf))"), "h_x", "(0.5, +inf)", 2, 0.50, calls=200)
A_ZF = action(pretty("a(z_F.dot, [+])"), "z_F.dot", "[+]", 2, 0.90, weight=0.12)
A_HD = action(pretty("a(h_x.dot, [-])"), "h_x.dot", "[-]", 0, 0.70, weight=0.001)


def knowledge(step: int, *actions: ActionInfo) -> Knowledge:
    return Knowledge(step, 1, actions, {}, KnowledgeCounters(practice_calls=9, babble_commands=2),
                     VALUES, ())


def status(step: int, **kw) -> AgentStatus:
    return AgentStatus(step, 0.0, "practice", world="core2d", **kw)


@pytest.fixture
def session() -> Iterator[zenoh.Session]:
    with zenoh.open(embedded_config()) as s:
        yield s


def put(session: zenoh.Session, topic: str, msg) -> None:
    session.put(keys.key(RUN, topic), encode(msg))


async def until(pilot, predicate, within: float = 10.0) -> None:
    deadline = time.monotonic() + within
    while not predicate():
        assert time.monotonic() < deadline, "condition not reached in the UI"
        await pilot.pause(0.03)


async def show(pilot, session, k: Knowledge) -> None:
    put(session, "knowledge", k)
    await until(pilot, lambda: pilot.app.knowledge is not None and pilot.app.knowledge.step
                == k.step)
    await pilot.pause(0.05)


def run(session, main, size=(160, 48)):
    async def go():
        app = QlapApp(session, run_id=RUN)
        async with app.run_test(size=size) as pilot:
            await main(app, pilot)
    asyncio.run(go())


def test_the_cursor_stays_on_the_top_row_until_the_user_moves_it(session):
    async def main(app, pilot):
        panel = app.query_one(ActionsPanel)
        await show(pilot, session, knowledge(1, A_HX, A_ZF))
        assert panel.selected == A_ZF.label and panel.follow_top
        assert app.query_one("PlansPanel").action.label == A_ZF.label
        # Another action becomes the most reliable: the cursor stays on the top row.
        better = action(A_HX.label, "h_x", "(0.5, +inf)", 2, 0.97)
        await show(pilot, session, knowledge(2, better, A_ZF, A_HD))
        assert panel.selected == better.label and panel.table.cursor_row == 0
        assert app.query_one("PlansPanel").action.label == better.label
        # The user moves: the selection follows that action wherever it goes.
        panel.table.focus()
        await pilot.press("down")
        assert panel.selected == A_ZF.label and not panel.follow_top
        await show(pilot, session, knowledge(3, better, action(A_ZF.label, "z_F.dot", "[+]", 2,
                                                               0.3), A_HD))
        assert panel.selected == A_ZF.label and panel.table.cursor_row == 2
        # home: back to the top row, which is followed again.
        await pilot.press("home")
        assert panel.follow_top and panel.selected == better.label
    run(session, main)


def test_the_goal_dialog_starts_with_the_most_reliable_action_in_the_tables_notation(session):
    async def main(app, pilot):
        await show(pilot, session, knowledge(1, A_HX, A_ZF, A_HD))
        panel = app.query_one(ActionsPanel)
        panel.sort_by = "plans"
        panel.action_cycle_sort()               # by calls: the top row is not the most reliable
        assert panel.sort_by == "calls" and panel.selected == A_HX.label
        await pilot.press("g")
        await until(pilot, lambda: isinstance(app.screen, GoalScreen))
        await pilot.pause(0.2)
        var = app.screen.query_one("#goal-var")
        value = app.screen.query_one("#goal-value")
        assert var.value == "z_F.dot" and value.value == "[+]"
        shown = [str(p) for p, v in var._options if v == "z_F.dot"]
        assert shown == [pretty("z_F.dot")] == ["z\u0307_F"]  # ż_F, as the table writes it
        hint = str(app.screen.query_one("#goal-hint").render())
        assert "most reliable" in hint and A_ZF.label in hint and ".dot" not in hint
        labels = [str(p) for p, _ in app.screen.query_one("#goal-var")._options]
        assert not any(".dot" in lbl for lbl in labels)
        await pilot.press("escape")
        # Once the user picks an action, the dialog starts with that one.
        panel.table.focus()
        row = panel.table.get_row_index(A_HD.label)
        assert row > 0
        for _ in range(row - panel.table.cursor_row):
            await pilot.press("down")
        assert panel.selected == A_HD.label
        await pilot.press("g")
        await until(pilot, lambda: isinstance(app.screen, GoalScreen))
        await pilot.pause(0.2)
        assert app.screen.query_one("#goal-var").value == "h_x.dot"
        assert app.screen.query_one("#goal-value").value == "[-]"
        assert "the selected action" in str(app.screen.query_one("#goal-hint").render())
        await pilot.press("escape")
        # The value labels are in the same notation too.
        var = app.screen_stack[0]
        assert var is app.screen
        goal = GoalScreen(dict(VALUES), [("h_x", "(0.5, +inf)")])
        await app.push_screen(goal)
        await pilot.pause(0.2)
        assert goal.query_one("#goal-value").value == "(0.5, +inf)"
        assert [str(p) for p, _ in goal.query_one("#goal-value")._options if p] == [
            "(−∞, 0.5)", "0.5", "(0.5, +∞)"]
    run(session, main)


def test_quick_presses_of_plus_and_minus_and_p_are_not_lost(session):
    sent: list[dict] = []
    sub = session.declare_subscriber(keys.key(RUN, "control"),
                                     lambda s: sent.append(json.loads(s.payload.to_bytes())))

    async def main(app, pilot):
        put(session, "status", status(10))
        await until(pilot, lambda: app.status is not None)
        await pilot.press("minus", "minus", "minus")         # no status in between
        await until(pilot, lambda: len(sent) == 3)
        assert [c["args"]["steps_per_s"] for c in sent] == [1000.0, 300.0, 100.0]
        put(session, "status", status(11, speed=1000.0))     # the first answer, late
        await until(pilot, lambda: app.status.step == 11)
        await pilot.press("plus")
        await until(pilot, lambda: len(sent) == 4)
        assert sent[-1]["args"]["steps_per_s"] == 300.0      # from 100, not from 1000
        await pilot.press("p", "p")
        await until(pilot, lambda: len(sent) == 6)
        assert [c["command"] for c in sent[-2:]] == ["pause", "resume"]
    try:
        run(session, main)
    finally:
        sub.undeclare()


def test_a_finished_run_stays_finished_and_takes_no_command_to_pause_or_step(session):
    sent: list[dict] = []
    sub = session.declare_subscriber(keys.key(RUN, "control"),
                                     lambda s: sent.append(json.loads(s.payload.to_bytes())))

    async def main(app, pilot):
        put(session, "status", status(199, finished=True, paused=True, wall_s=12.0,
                                      message="finished 200 steps"))
        await until(pilot, lambda: app.status is not None)
        await pilot.press("p", "s")
        await pilot.pause(0.3)
        assert sent == []
        runtime = str(app.query_one(RuntimePanel).render())
        assert "FINISHED  step 200" in runtime and "PAUSED" not in runtime
        assert "FINISHED  step 200" in str(app.query_one(StatusBar).render())
        assert any("finished at step 200" in n.message for n in app._notifications)
    try:
        run(session, main)
    finally:
        sub.undeclare()


def world_view() -> WorldView:
    return WorldView(41, "core2d", "core2d t=42 hand=(0.0,0.5)\n" + ("." * 44 + "\n") * 12,
                     {"h_x": -0.0001, "z_F": 10.5}, {"u_x": -0.0},
                     {"u_x": "-0", "h_x": "(-inf, 0.5)", "h_x.dot": "[+]", "z_F": "(-inf, +inf)",
                      "z_F.dot": "[0]"})


@pytest.mark.parametrize("size", [(80, 24), (160, 48)])
def test_both_layouts_fit_every_column_and_the_compact_one_switches_views(session, size):
    async def main(app, pilot):
        await show(pilot, session, knowledge(1, A_HX, A_ZF, A_HD))
        put(session, "world", world_view())
        put(session, "status", status(41))
        await until(pilot, lambda: app.world is not None and app.status is not None)
        await pilot.pause(0.2)
        assert app.compact == (size == (80, 24))
        for table in app.query("DataTable"):
            if not table.display or not table.columns:
                continue
            for col in table.columns.values():                 # no header cut
                assert col.width >= len(str(col.label)), (table.id, col.label, col.width)
            assert table.max_scroll_x == 0, table.id            # nothing behind a scroll
        world = app.query_one(WorldPanel)
        assert world.border_title == "World core2d · step 42"
        rows = [r.plain for r in world.rows(60)]
        assert rows[0].split() == ["u_x", "0.000", "0"]        # no -0 anywhere
        assert rows[1].split() == ["h_x", "0.000", "↑", "(−∞,", "0.5)"]
        if app.compact:
            assert app.query_one("#iac").display is False
            await pilot.press("v")
            assert app.view == "iac" and app.query_one("#iac").display
            await pilot.press("3")
            assert app.view == "world" and app.query_one("#world").display
            assert not app.query_one("#plans").display
        else:
            for key in ("plans", "iac", "world", "calllist", "landmarks", "counters",
                        "runtime"):
                assert app.query_one(f"#{key}").display
            assert not app.query_one("#viewtabs").display
    run(session, main, size=size)


def test_the_iac_panel_shows_choices_with_their_w_a_and_the_top_learning_progress(session):
    async def main(app, pilot):
        a1 = action(pretty("a(y_BT.dot, [-])"), "y_BT.dot", "[-]", 0, 0.6, calls=80, weight=0.18)
        a2 = action(pretty("a(y_TB.dot, [-])"), "y_TB.dot", "[-]", 0, 0.7, calls=70, weight=0.05)
        floor = action(pretty("a(h_y.dot, [+])"), "h_y.dot", "[+]", 2, 0.9, calls=300, weight=0.001)
        young = action(pretty("a(h_x.dot, [-])"), "h_x.dot", "[-]", 0, 0.5, calls=10, weight=0.9)
        await show(pilot, session, knowledge(1, a1, a2, floor, young))
        for i, c in enumerate([IACChoice(100, a2.label, 0.3, 4, False, {"#0": 1.0}),
                               IACChoice(110, "", 0.0, 0, True),
                               IACChoice(120, a1.label, 0.6, 4, False, {"#0": 1.0})]):
            put(session, "iac", c)
            await until(pilot, lambda i=i: app.query_one(IACPanel).choices == i + 1)
        panel = app.query_one(IACPanel)
        assert [a.label for a, _ in panel.top_progress(3)] == [a1.label, a2.label, floor.label]
        text = panel.render_text(51, 16).plain.splitlines()
        assert text[1].split()[:4] == ["120", *a1.label.split(), "0.180"]   # newest first
        assert "babble" in text[2]
        assert text[3].split()[:4] == ["100", *a2.label.split(), "0.050"]
        lp = text.index(next(line for line in text if line.startswith("learning progress")))
        assert text[lp + 1].split()[2] == "+0.180" and text[lp + 2].split()[2] == "+0.050"
        assert "(eq. 6.1), 3 actions" in text[lp]              # young: eq. 6.2, not progress
        assert text[-1].startswith("Σ progress 0.230")
    run(session, main)


def test_formatting_has_one_zero_and_fits_columns():
    assert real(-0.0) == real(-0.0004) == real(0.0) == "0.000" and real(-0.5) == "-0.500"
    assert signed(-0.0) == "0.00" and signed(1.5) == "+1.50" and signed(-2.0) == "-2.00"
    cols = fit_columns(COLUMNS, 40, first=32, flex="hist", flex_max=32)
    assert [c.key for c, _ in cols] == ["action", "rel"]     # rel(a) always stays
    assert sum(w + 2 for _, w in cols) <= 40
    cols = dict((c.key, w) for c, w in fit_columns(COLUMNS, 120, first=30, flex="hist",
                                                   flex_max=32))
    assert cols["action"] == 30 and cols["hist"] == 32


def test_iac_rows_line_up_whether_or_not_the_label_has_a_combining_dot():
    """pretty() writes ż as z + U+0307: one cell, two characters. Padding by characters put
    such a row's columns one cell to the left of the others."""
    from rich.cells import cell_len

    dotted, plain = pretty("a(z_BT.dot, [+])"), pretty("a(T_L, [-5.954, -5.78911])")
    assert len(dotted) == cell_len(dotted) + 1                 # the combining dot
    panel = IACPanel()
    panel.weights = {dotted: 0.021, plain: 0.030}
    panel.recent.extend([IACChoice(101638, dotted, 0.01, 112, False, {}),
                         IACChoice(101648, plain, 0.01, 113, False, {})])
    rows = panel.render_text(64, 8).plain.splitlines()[1:3]
    ends = [cell_len(row[:row.index(w) + len(w)]) for row, w in zip(rows, ("0.030", "0.021"),
                                                                      strict=True)]
    assert ends[0] == ends[1]
    assert cell_len(rows[0]) == cell_len(rows[1])
