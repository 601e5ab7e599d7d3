"""The headless progress bar of `qlap run` (qlap_runtime/runtime/progress.py)."""

from __future__ import annotations

from qlap_runtime.bus.schema import AgentStatus
from qlap_runtime.runtime.progress import _show, progress_bar


def test_the_bar_says_when_a_viewer_paused_the_run():
    bar = progress_bar(1000)
    task = bar.tasks[0]
    _show(bar, task.id, AgentStatus(99, 1234.0, "practice"), start=0)
    assert (task.completed, task.fields["rate"], task.fields["state"]) == (99, "1,234", "")
    _show(bar, task.id, AgentStatus(120, 0.0, "practice", paused=True), start=0)
    assert task.completed == 120 and "paused" in task.fields["state"]
    _show(bar, task.id, AgentStatus(999, 0.0, "idle", paused=True, finished=True), start=0)
    assert task.fields["state"] == ""
