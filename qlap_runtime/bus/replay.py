"""Replay logs: a writer's recent lockstep messages, for a consumer restarted from a snapshot.

A consumer restarted by the supervisor resumes from the step of its snapshot, so it needs the
messages of its input topics published since then, which it missed while it was dead. Their
writer keeps them in a :class:`ReplayLog` — a bounded log of ``(step, message)`` answering Zenoh
queries on ``qlap/<run-id>/replay/<topic>?from=STEP`` — and :func:`fetch_replay` gets them
(docs/runtime.md, Faults; docs/bus.md).

The log keeps each message as the payload its publisher already encoded, copied to its size (a
core ``qstate`` is about 0.6 kB of JSON against 2.8 kB as Python objects, and a log holds
thousands of steps of several topics): the step chain pays a deque append and a copy, a query
is answered with the stored bytes, and only the rare readers of the messages themselves
(snapshots) decode them again. The query callback (a Zenoh thread) reads a copy taken under a
lock and never touches actor state.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from typing import Any

import trio
import zenoh

from . import keys
from .bridge import RejectionCounter, TrioInbox
from .qrecord import QRecord
from .schema import Message, decode, encode

log = logging.getLogger("qlap.bus")


class ReplayLog:
    """The last ``keep`` steps of one topic written by this actor, served to queries.

    ``append(step, msg, payload)`` after publishing ``msg`` (``payload``: its encoding, if the
    publisher has it); entries whose step is more than ``keep`` below the newest are dropped. A
    query ``...?from=S`` gets the entries with step >= S in append order (all of them without
    ``from``).
    """

    def __init__(self, session: zenoh.Session, run_id: str, topic: str, keep: int) -> None:
        self.key = keys.replay_key(run_id, topic)
        self.topic_key = keys.key(run_id, topic)
        self.keep = int(keep)
        self._lock = threading.Lock()
        self._entries: deque[tuple[int, bytes]] = deque()
        self._q = session.declare_queryable(self.key, self._on_query)

    def append(self, step: int, msg: Message, payload: bytes | None = None) -> None:
        # A compact copy: orjson's result keeps the 8 kB buffer it was written into (a core
        # qstate of 0.6 kB then holds 8 kB; 7,100 steps of three topics held 170 MB). A
        # qstate record's payload is joined to its size already (docs/decisions.md 98).
        if type(msg) is not QRecord or payload is None:
            payload = bytes(memoryview(encode(msg) if payload is None else payload))
        with self._lock:
            self._entries.append((int(step), payload))
            horizon = int(step) - self.keep
            while self._entries and self._entries[0][0] < horizon:
                self._entries.popleft()

    def payloads(self, from_step: int | None = None) -> list[tuple[int, bytes]]:
        """The logged ``(step, payload)`` pairs with step >= ``from_step``."""
        with self._lock:
            items = list(self._entries)
        return items if from_step is None else [e for e in items if e[0] >= from_step]

    def entries(self, from_step: int | None = None) -> list[tuple[int, Message]]:
        """The logged ``(step, message)`` pairs with step >= ``from_step`` (decoded again)."""
        return [(s, decode(self.topic_key, p)) for s, p in self.payloads(from_step)]

    def _on_query(self, query: zenoh.Query) -> None:
        try:
            raw = query.parameters.get("from")
            from_step = int(raw) if raw not in (None, "") else None
        except (TypeError, ValueError):
            from_step = None                        # a malformed parameter: answer with all
        try:
            for _, payload in self.payloads(from_step):
                query.reply(self.key, payload, encoding=zenoh.Encoding.APPLICATION_JSON)
        except Exception:
            log.exception("replay query on %s failed", self.key)

    def close(self) -> None:
        try:
            self._q.undeclare()
        except zenoh.ZError:  # pragma: no cover
            pass

    def __enter__(self) -> ReplayLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


_DONE: Any = object()


async def fetch_replay(session: zenoh.Session, run_id: str, topic: str, from_step: int = 0, *,
                       counter: RejectionCounter | None = None,
                       query_timeout: float = 10.0
                       ) -> list[Message]:
    """Every message the writers of ``topic`` logged with step >= ``from_step``, decoded as
    messages of ``topic`` (``topic`` may end in ``*``, e.g. ``delta/*``). Invalid replies are
    counted in ``counter``; an unanswered query gives ``[]``."""
    counter = counter if counter is not None else RejectionCounter()
    run = keys.validate_run_id(run_id)
    prefix = f"{keys.ROOT}/{run}/{keys.REPLAY}/"
    inbox: TrioInbox[Any] = TrioInbox()

    def on_reply(reply: zenoh.Reply) -> None:
        try:
            ok = reply.ok
            if ok is not None:
                inbox.push((str(ok.key_expr), ok.payload.to_bytes()))
        except Exception:
            log.exception("replay reply callback failed")

    session.get(f"{prefix}{topic}?from={int(from_step)}",
                zenoh.handlers.Callback(on_reply, lambda: inbox.push(_DONE)),
                target=zenoh.QueryTarget.ALL, consolidation=zenoh.ConsolidationMode.NONE,
                timeout=query_timeout)
    out: list[Message] = []
    t0 = time.monotonic()
    with trio.move_on_after(query_timeout + 1.0):
        while True:
            for item in await inbox.get_batch():
                if item is _DONE:
                    log.debug("replay of %s from %d: %d messages in %.3f s", topic, from_step,
                              len(out), time.monotonic() - t0)
                    return out
                k, payload = item
                if not k.startswith(prefix):
                    counter.reject(k, "reply outside the replay keys")
                    continue
                msg = counter.decode(f"{keys.ROOT}/{run}/{k[len(prefix):]}", payload)
                if msg is not None:
                    out.append(msg)
    return out
