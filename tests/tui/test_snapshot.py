"""Snapshot of the main screen fed a recorded run (tests/tui/record_fixture.py) over a real
embedded Zenoh session: deterministic content, so the SVG is stable.

Update after an intended change: ``pytest tests/tui/test_snapshot.py --snapshot-update``.
"""

from __future__ import annotations

import json
import time

import zenoh

from qlap_runtime.bus.config import embedded_config
from tests.tui.record_fixture import FIXTURE, RUN
from tui import QlapApp
from tui.widgets import ActionsPanel


def feed(session: zenoh.Session):
    """A ``run_before`` that publishes the recording, one knowledge snapshot per UI refresh."""
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
        while app.status is None or app.world is None or app.calllist is None:
            assert time.monotonic() < deadline
            await pilot.pause(0.02)
        panel = app.query_one(ActionsPanel)
        label = next(a.label for a in app.knowledge.actions if a.plans)
        panel.table.focus()
        panel.table.move_cursor(row=panel.table.get_row_index(label), animate=False)
        await pilot.pause(0.2)
    return run_before


def test_main_screen(snap_compare):
    with zenoh.open(embedded_config()) as session:
        app = QlapApp(session, run_id=RUN)
        assert snap_compare(app, terminal_size=(160, 50), run_before=feed(session))
