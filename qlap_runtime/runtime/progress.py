"""A progress bar for a run of actors, fed from the bus like any other viewer.

The executor publishes ``status`` (step, steps/s) and ``knowledge`` (counters of DBNs, plans,
landmarks) on display topics (docs/tui.md); this watcher subscribes to both and draws the same
rich progress bar as the synchronous ``qlap run``. It only reads, so it cannot slow the agent
more than any subscriber would (display topics are DROP: a slow terminal loses frames).
"""

from __future__ import annotations

import time
from typing import Any

import trio

from ..bus import keys
from ..bus.bridge import RejectionCounter, TrioSubscriber
from ..bus.schema import AgentStatus, Knowledge


def progress_bar(total: int) -> Any:
    """The rich progress bar of ``qlap run`` (steps, steps/s, DBNs, plans, landmarks)."""
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeRemainingColumn,
    )

    bar = Progress(TextColumn("[bold]QLAP[/]"), BarColumn(), MofNCompleteColumn(),
                   TextColumn("{task.fields[rate]:>7} steps/s"),
                   TextColumn("DBNs {task.fields[dbns]:>4}  plans {task.fields[plans]:>3}  "
                              "landmarks {task.fields[lms]:>3}"),
                   TimeRemainingColumn(), TextColumn("{task.fields[state]}"), transient=False)
    bar.add_task("run", total=total, rate="-", dbns=0, plans=0, lms=0, state="")
    return bar


async def watch_progress(session: Any, ctx: Any, stop: trio.Event, bar: Any = None) -> None:
    """Update ``bar`` (made here if None) from the run's ``status`` and ``knowledge`` until
    ``stop`` is set; the bar then shows the whole run as done."""
    bar = bar if bar is not None else progress_bar(ctx.steps)
    task = bar.task_ids[0]
    start = ctx.start
    counter = RejectionCounter("progress")
    t0 = time.perf_counter()
    bar.start()
    try:
        with TrioSubscriber(session, keys.key(ctx.run_id, "status"), counter=counter) as st, \
                TrioSubscriber(session, keys.key(ctx.run_id, "knowledge"),
                               counter=counter) as kn:
            async with trio.open_nursery() as nursery:
                async def follow(sub: TrioSubscriber) -> None:
                    async for batch in sub:
                        for r in batch:
                            _show(bar, task, r.msg, start)

                nursery.start_soon(follow, st)
                nursery.start_soon(follow, kn)
                await stop.wait()
                nursery.cancel_scope.cancel()
        # The last frame: the whole run's rate, as summary.json has it (not the last instant's).
        elapsed = time.perf_counter() - t0
        bar.update(task, completed=ctx.steps,
                   rate=f"{ctx.steps / elapsed:,.0f}" if elapsed > 0 else "-")
    finally:
        bar.stop()


def _show(bar: Any, task: Any, msg: Any, start: int) -> None:
    if isinstance(msg, AgentStatus):
        bar.update(task, completed=max(0, msg.step - start), rate=f"{msg.steps_per_s:,.0f}",
                   state="[yellow]paused (a viewer's control; resume it there)[/]"
                   if msg.paused and not msg.finished else "")
    elif isinstance(msg, Knowledge):
        c = msg.counters
        # landmarks as summary.json and the metrics log count them: the initial ones included
        # (the message's counter has the learned ones only)
        bar.update(task, dbns=c.dbns, plans=c.plans,
                   lms=sum(len(rows) for rows in msg.landmarks.values()))
