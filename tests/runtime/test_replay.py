"""Replay logs keep what their publishers encoded, answer queries over Zenoh with it, and a
snapshot keeps and restores an output's log byte for byte (real sessions on loopback)."""

from __future__ import annotations

import trio

from qlap_runtime.bus.replay import ReplayLog, fetch_replay
from qlap_runtime.bus.schema import QState, Sense, encode
from qlap_runtime.qlap import Params
from qlap_runtime.runtime.actor import Actor
from qlap_runtime.runtime.context import RunContext


def qstate(t: int) -> QState:
    return QState(t, {"x": t % 3}, (("x", 1, 1),), {"x": 0.25 * t})


async def test_a_log_keeps_payloads_and_serves_them_to_another_session(two_clients, run_id):
    writer, reader = two_clients
    with ReplayLog(writer, run_id, "qstate", keep=5) as log:
        for t in range(10):
            log.append(t, qstate(t), encode(qstate(t)) if t % 2 else None)
        assert [s for s, _ in log.payloads()] == [4, 5, 6, 7, 8, 9]   # at most 5 steps back
        assert log.payloads(8) == [(8, encode(qstate(8))), (9, encode(qstate(9)))]
        assert log.entries(9) == [(9, qstate(9))]                     # decoded again
        # The other session's route to the log's queryable may lag its declaration on a
        # loaded machine (a query then reaches nobody: []); consumers ask again, so does this.
        with trio.fail_after(10):
            while not (got := await fetch_replay(reader, run_id, "qstate", 7)):  # noqa: ASYNC110
                await trio.sleep(0.05)
    assert got == [qstate(7), qstate(8), qstate(9)]


async def test_a_snapshot_keeps_an_outputs_log_and_a_restart_serves_it_again(embedded):
    ctx = RunContext("replay-test", "core2d", 100, 0, Params())
    with Actor(embedded, ctx, "world") as first:
        out = first.output("sense")
        for t in range(4):
            out.put(t, Sense(t, {"x": float(t)}))
        saved = out.saved(2)
        payloads = out.log.payloads(2)
    assert [s for s, _ in saved] == [2, 3]
    with Actor(embedded, ctx, "world") as restarted:
        again = restarted.output("sense")
        restarted.restore_log(again, saved)
        assert again.log.payloads() == payloads
        got = await fetch_replay(embedded, ctx.run_id, "sense", 0)
    assert got == [Sense(2, {"x": 2.0}), Sense(3, {"x": 3.0})]
