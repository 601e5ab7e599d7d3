"""What every actor shares: its run context, step-indexed inboxes and the delta inbox."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trio

from qlap_runtime.bus import keys
from qlap_runtime.bus.bridge import RejectionCounter, TrioSubscriber
from qlap_runtime.bus.schema import DeltaMsg, QState
from qlap_runtime.qlap.params import Params
from qlap_runtime.qlap.perception import Percept
from qlap_runtime.qlap.variables import Event, VariableTable
from qlap_runtime.runtime.lockstep import DeltaBook


@dataclass
class RunContext:
    """What an actor needs to know about the run (the same in every process)."""

    run_id: str
    world: str
    steps: int
    seed: int
    params: Params
    out: Path | None = None
    checkpoint_every: int = 10_000
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def realtime(self) -> bool:
        """The realtime clock (``extra["clock"] == "realtime"``, rate ``extra["hz"]``)."""
        return self.extra.get("clock") == "realtime"

    def to_json(self) -> dict[str, Any]:
        return {"run_id": self.run_id, "world": self.world, "steps": self.steps,
                "seed": self.seed, "params": self.params.to_dict(),
                "out": None if self.out is None else str(self.out),
                "checkpoint_every": self.checkpoint_every, "extra": self.extra}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> RunContext:
        return cls(d["run_id"], d["world"], int(d["steps"]), int(d["seed"]),
                   Params.from_dict(d["params"]), None if d["out"] is None else Path(d["out"]),
                   int(d["checkpoint_every"]), dict(d.get("extra", {})))


def world_variables(spec: str) -> tuple[Any, dict[str, Any]]:
    """The variable table and agent options of a world (the world is built and closed)."""
    import worlds

    w = worlds.make(spec)
    try:
        return w.variables, dict(getattr(w, "agent_options", {}) or {})
    finally:
        w.close()


class StepInbox:
    """Messages of one topic, indexed by step; ``await get(t)`` returns step t's message."""

    def __init__(self, sub: TrioSubscriber) -> None:
        self.sub = sub
        self.buf: dict[int, Any] = {}

    async def get(self, step: int) -> Any:
        while step not in self.buf:
            for r in await self.sub.receive_batch():
                self.buf[r.msg.step] = r.msg
        return self.buf.pop(step)


class DeltaInbox:
    """Receives ``delta/*`` and hands out those due at a step, in apply order."""

    def __init__(self, session: Any, ctx: RunContext, counter: RejectionCounter) -> None:
        self.book = DeltaBook(ctx.params)
        self.sub = TrioSubscriber(session, f"{keys.ROOT}/{ctx.run_id}/delta/*", counter=counter)
        self.wait_s = 0.0

    def _take(self, batch) -> None:
        for r in batch:
            msg: DeltaMsg = r.msg
            if msg.kind in ("dbn", "landmarks"):
                self.book.add(msg.kind, msg.to_delta())

    async def due(self, step: int) -> list:
        self._take(self.sub.receive_nowait())
        if not self.book.ready(step):
            self.book.waits += 1
            t0 = time.perf_counter()
            while not self.book.ready(step):
                self._take(await self.sub.receive_batch())
            self.wait_s += time.perf_counter() - t0
        return self.book.pop_due(step)

    async def due_now(self, step: int, realtime: bool) -> list:
        """Lockstep: :meth:`due` (waits). Realtime: what has arrived, applied on arrival."""
        if not realtime:
            return await self.due(step)
        self._take(self.sub.receive_nowait())
        return self.book.arrived_prefix(step)

    def close(self) -> None:
        self.sub.close()


def percept_from_qstate(msg: QState, table: VariableTable) -> Percept:
    """Rebuild the perception actor's :class:`Percept` from its message."""
    index = _name_index(table)
    n = len(table)
    x = np.full(n, np.nan)
    q = np.full(n, -1, dtype=np.int64)
    if msg.x:
        x[[index[k] for k in msg.x]] = list(msg.x.values())
    if msg.values:
        q[[index[k] for k in msg.values]] = list(msg.values.values())
    events = tuple(Event(index[name], int(v), int(d)) for name, v, d in msg.events)
    return Percept(msg.step, x, q, events, np.zeros(0, dtype=np.int64))


def _name_index(table: VariableTable) -> dict[str, int]:
    """name -> index of a table (kept on the table; an unknown name raises KeyError)."""
    index = getattr(table, "_name_index", None)
    if index is None:
        index = {v.name: v.index for v in table}
        table._name_index = index  # type: ignore[attr-defined]
    return index


def qstate_of(p: Percept, table: VariableTable) -> QState:
    names = [v.name for v in table]
    x = {names[i]: float(v) for i, v in enumerate(p.x) if not np.isnan(v)}
    q = {names[i]: int(v) for i, v in enumerate(p.q) if v >= 0}
    events = tuple((names[e.var], int(e.value), int(e.direction)) for e in p.events)
    return QState(p.step, q, events, x)


async def checkpoint_async(fn, *args) -> None:
    """Run a (blocking) checkpoint write off the trio thread."""
    await trio.to_thread.run_sync(fn, *args)
