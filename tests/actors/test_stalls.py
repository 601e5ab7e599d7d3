"""No silent hang (issue 13, item 2): the batchctx replay gap after two restarts, and the
watchdog that stops a run making no progress with one line naming who waits for what."""

from __future__ import annotations

import os
import re
import signal
import time

import pytest

from qlap_runtime.placements.launcher import run_processes
from qlap_runtime.runtime.snapshot import latest_snapshot
from qlap_runtime.runtime.supervisor import Supervisor
from qlap_runtime.runtime.watchdog import Board, RunStalled, Watchdog

from .test_faults import BASE, SNAPSHOT_EVERY, STEPS, context, sync_knowledge


class TwoKills:
    """SIGKILL the executor right after its snapshot at 999 (batchctx(999) for the batch at
    1000 went out before it), then, once the restarted executor has passed step 1100, the
    contingency actor, whose snapshot at 999 makes it need batchctx(999) again."""

    def __init__(self) -> None:
        self.executor_at: int | None = None
        self.contingency_at: int | None = None

    def __call__(self, sup: Supervisor) -> None:
        snaps = sup.snapshot_dir
        if self.executor_at is None:
            latest = latest_snapshot(snaps, "executor")
            if latest is not None and latest[0] >= 2 * SNAPSHOT_EVERY - 1:
                os.kill(sup.procs["executor"].pid, signal.SIGKILL)
                self.executor_at = latest[0]
        elif self.contingency_at is None and sup.attempts["executor"] == 1:
            done = sup.board.slot("executor").data[0]
            latest = latest_snapshot(snaps, "contingency")
            if done >= self.executor_at + 100 and latest is not None:
                os.kill(sup.procs["contingency"].pid, signal.SIGKILL)
                self.contingency_at = latest[0]


def test_executor_then_contingency_killed_around_a_snapshot_end_as_the_sync_loop(tmp_path):
    expected = sync_knowledge(BASE, seed=7)
    ctx = context(tmp_path, BASE, 7, "t-two-kills").with_(stall_s=20)
    kills = TwoKills()
    t0 = time.monotonic()
    summary = run_processes(ctx, on_poll=kills, groups="each")
    wall = time.monotonic() - t0
    assert kills.executor_at == 999
    assert kills.contingency_at == 999, "contingency passed its next snapshot: vacuous"
    assert [(r["actor"], r["from_step"]) for r in summary["restarted"]] == \
        [("executor", 999), ("contingency", 999)]
    assert summary["steps"] == STEPS
    assert (tmp_path / "knowledge.json").read_text() == expected
    print(f"two restarts, {STEPS} steps in {wall:.1f} s")


@pytest.mark.slow
def test_a_stopped_actor_is_a_stall_named_in_one_line_in_bounded_time(tmp_path):
    """SIGSTOP (alive, no progress): the supervisor sees no step for stall_s and stops."""
    ctx = context(tmp_path, BASE, 7, "t-stall").with_(stall_s=4)
    stopped: list[float] = []

    def freeze(sup: Supervisor) -> None:
        if not stopped and sup.board.slot("executor").data[0] >= 300:
            os.kill(sup.process_of("contingency").pid, signal.SIGSTOP)
            stopped.append(time.monotonic())

    with pytest.raises(RunStalled) as err:
        run_processes(ctx, on_poll=freeze)
    took = time.monotonic() - stopped[0]
    text = str(err.value)
    assert "\n" not in text
    assert text.startswith("run stalled: no progress for 4 s;")
    # The executor waits at t + L (L = 200) for the first batch t the stopped learners had not
    # published: 500 at 700, or a later one when they got that far before the signal (they
    # keep up with the chain since docs/decisions.md 90-92).
    wait = re.search(r"executor waits for delta/dbn\((\d+)\) at step (\d+)", text)
    assert wait is not None, text
    assert int(wait[1]) % 500 == 0 and int(wait[2]) == int(wait[1]) + 200, text
    assert took < 4 + 12, took
    print(text, f"(stopped {took:.1f} s after the SIGSTOP)")


def test_watchdog_ignores_pauses_and_batches_and_names_the_oldest_wait_first():
    now = [0.0]
    board = Board(("world", "contingency", "executor"))
    dog = Watchdog(board, stall_s=10, clock=lambda: now[0])
    board.slot("world").done(5999)
    board.slot("executor").wait("delta/dbn", 6000, 6200)
    board.slot("contingency").wait("batchctx", 5999, 6000)
    dog.check()
    now[0] = 9.9
    dog.check()                                     # 9.9 s: not yet
    board.slot("world").paused(True)
    now[0] = 30.0
    dog.check()                                     # paused: never a stall
    board.slot("world").paused(False)
    board.slot("contingency").busy(1)
    now[0] = 60.0
    dog.check()                                     # a batch is being computed
    board.slot("contingency").busy(0)
    now[0] = 69.0
    dog.check()
    now[0] = 70.5
    with pytest.raises(RunStalled, match=r"^run stalled: no progress for 10 s; contingency "
                       r"waits for batchctx\(5999\) at step 6000; executor waits for "
                       r"delta/dbn\(6000\) at step 6200$"):
        dog.check()
    board.slot("world").done(6000)                  # progress again
    now[0] = 75.0
    dog.check()
