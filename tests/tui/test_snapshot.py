"""Snapshots of the screen fed a recorded run (tests/tui/record_fixture.py) over a real
embedded Zenoh session: deterministic content, so the SVGs are stable.

At 160×48 every panel shows (the wide layout); at 80×24 the compact layout shows the actions
and one other panel (Plans by default, then IAC and World, picked with the digit keys). The
cursor is left where the UI puts it: on the top row, the most reliable action.

Update after an intended change: ``pytest tests/tui/test_snapshot.py --snapshot-update``.
"""

from __future__ import annotations

import json
import time

import pytest
import zenoh

from qlap_runtime.bus.config import embedded_config
from tests.tui.record_fixture import FIXTURE, RUN
from tui import QlapApp
from tui.widgets import ActionsPanel


def feed(session: zenoh.Session, keys: tuple[str, ...] = ()):
    """A ``run_before`` that publishes the recording, one knowledge snapshot per UI refresh,
    then presses ``keys``."""
    records = [json.loads(line) for line in FIXTURE.read_text(encoding="utf-8").splitlines()]

    async def run_before(pilot) -> None:
        app = pilot.app
        for r in records:
            session.put(r["key"], r["payload"].encode())
            if r["key"].endswith("/knowledge"):
                step = json.loads(r["payload"])["step"]
                deadline = time.monotonic() + 10
                while app.knowledge is None or app.knowledge.step != step:
                    assert time.monotonic() < deadline
                    await pilot.pause(0.02)
        deadline = time.monotonic() + 10
        while (app.status is None or app.world is None or app.calllist is None
               or app.iac_seen < 16):
            assert time.monotonic() < deadline
            await pilot.pause(0.02)
        panel = app.query_one(ActionsPanel)
        panel.table.focus()
        assert panel.follow_top and panel.table.cursor_row == 0
        for key in keys:
            await pilot.press(key)
        await pilot.pause(0.2)
    return run_before


@pytest.mark.parametrize(("size", "keys"), [
    pytest.param((160, 48), (), id="160x48"),
    pytest.param((80, 24), (), id="80x24-plans"),
    pytest.param((80, 24), ("2",), id="80x24-iac"),
    pytest.param((80, 24), ("3",), id="80x24-world"),
])
def test_main_screen(snap_compare, size, keys):
    with zenoh.open(embedded_config()) as session:
        app = QlapApp(session, run_id=RUN)
        assert snap_compare(app, terminal_size=size, run_before=feed(session, keys))
