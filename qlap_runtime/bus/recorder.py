"""Recording the bus to MCAP, and echoing it (docs/bus.md).

:func:`record` subscribes to ``qlap/<run-id>/**`` (or ``qlap/**``) and writes every valid
message to an MCAP file: one channel per key expression (the MCAP topic), JSON message encoding,
the message type's JSON Schema as a ``jsonschema`` schema, log time = receive time in ns. The
payload bytes are written as published (compact JSON), so a reader's ``decode(topic, data)``
equals the message that was put. Malformed messages are counted, logged and not recorded. The
file opens in Foxglove.

It runs in-process (an actor of the same run, sharing its session) or as
``qlap record --connect ENDPOINT --out FILE.mcap`` (its own client session).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import trio
import zenoh
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import Writer

from . import keys
from .bridge import Received, RejectionCounter, TrioSubscriber
from .config import client_config
from .schema import MESSAGE_TYPES, TOPIC_TYPES, decode, json_schema, schema_name

Source = zenoh.Session | zenoh.Config | str | Sequence[str]
"""Where to listen: an open session (shared, not closed here), a config to open, or the
endpoint(s) of a router to connect to as a client."""


@dataclass
class RecordSummary:
    """What :func:`record` wrote."""

    path: Path
    """The MCAP file."""
    messages: int = 0
    """Messages written."""
    by_topic: dict[str, int] = field(default_factory=dict)
    """Messages written per key expression."""
    rejected: int = 0
    """Malformed messages seen (not written)."""


class McapSink:
    """An MCAP writer with one schema per message type and one channel per key expression."""

    def __init__(self, out: IO[bytes], *, library: str = "qlap-runtime") -> None:
        self._w = Writer(out)
        self._w.start(profile="", library=library)
        self._schemas: dict[type, int] = {}
        self._channels: dict[str, int] = {}
        self._seq = 0
        for cls in MESSAGE_TYPES:
            self._schemas[cls] = self._w.register_schema(
                name=schema_name(cls), encoding=SchemaEncoding.JSONSchema,
                data=json.dumps(json_schema(cls), separators=(",", ":")).encode())

    def write(self, r: Received) -> None:
        cid = self._channels.get(r.key)
        if cid is None:
            cls = TOPIC_TYPES[keys.topic_of(r.key)]
            cid = self._w.register_channel(topic=r.key, message_encoding=MessageEncoding.JSON,
                                           schema_id=self._schemas[cls])
            self._channels[r.key] = cid
        self._seq += 1
        self._w.add_message(channel_id=cid, log_time=r.recv_ns, data=r.payload,
                            publish_time=r.recv_ns, sequence=self._seq)

    def finish(self) -> None:
        self._w.finish()


async def record(source: Source, run_id: str | None, out_path: Path | str,
                 stop_event: trio.Event, *, counter: RejectionCounter | None = None,
                 task_status: trio.TaskStatus[None] = trio.TASK_STATUS_IGNORED) -> RecordSummary:
    """Record ``qlap/<run_id>/**`` (every run when ``run_id`` is None) to ``out_path`` until
    ``stop_event`` is set; then write what has already arrived and finish the file.

    With ``nursery.start(record, ...)`` the call returns once the subscriber is declared, so
    nothing published afterwards is missed.
    """
    counter = counter if counter is not None else RejectionCounter("recorder")
    summary = RecordSummary(Path(out_path))
    before = counter.total
    with ExitStack() as stack:
        session = _session(source, stack)
        f = stack.enter_context(open(out_path, "wb"))  # noqa: ASYNC230 - a local file, streamed
        sink = McapSink(f)
        try:
            sub = stack.enter_context(
                TrioSubscriber(session, keys.run_pattern(run_id), counter=counter))
            task_status.started()

            def write(batch: list[Received]) -> None:
                for r in batch:
                    sink.write(r)
                    summary.by_topic[r.key] = summary.by_topic.get(r.key, 0) + 1
                summary.messages += len(batch)

            async with trio.open_nursery() as nursery:
                async def stop() -> None:
                    await stop_event.wait()
                    nursery.cancel_scope.cancel()
                nursery.start_soon(stop)
                async for batch in sub:  # a batch is taken whole: cancellation loses nothing
                    write(batch)
            write(sub.receive_nowait())
        finally:
            sink.finish()
    summary.rejected = counter.total - before
    return summary


def _session(source: Source, stack: ExitStack) -> zenoh.Session:
    if isinstance(source, zenoh.Session):
        return source
    cfg = source if isinstance(source, zenoh.Config) else client_config(source)
    return stack.enter_context(zenoh.open(cfg))


def read_mcap(path: Path | str) -> list[tuple[str, Any, int]]:
    """Every message of an MCAP file written by :func:`record` as (topic, decoded message,
    log time ns), in log-time order."""
    from mcap.reader import make_reader

    out = []
    with open(path, "rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages(log_time_order=True):
            out.append((channel.topic, decode(channel.topic, message.data), message.log_time))
    return out


async def echo(source: Source, key_expr: str, stop_event: trio.Event, *,
               out: IO[str] | None = None, raw: bool = False, limit: int | None = None,
               counter: RejectionCounter | None = None,
               task_status: trio.TaskStatus[None] = trio.TASK_STATUS_IGNORED) -> int:
    """Print every message on ``key_expr`` as ``KEY JSON`` lines until ``stop_event`` is set or
    ``limit`` messages were printed; return the count. Malformed messages are reported on
    stderr (and counted), not printed; ``raw=True`` prints payloads without decoding."""
    out = out if out is not None else sys.stdout
    counter = counter if counter is not None else RejectionCounter("echo")
    n = 0
    with ExitStack() as stack:
        session = _session(source, stack)
        sub = stack.enter_context(TrioSubscriber(session, key_expr, counter=counter,
                                                 decode=not raw))
        task_status.started()
        async with trio.open_nursery() as nursery:
            async def stop() -> None:
                await stop_event.wait()
                nursery.cancel_scope.cancel()
            nursery.start_soon(stop)
            async for batch in sub:
                for r in batch:
                    text = r.payload.decode("utf-8", "backslashreplace")
                    out.write(f"{r.key} {text}\n")
                    n += 1
                    if limit is not None and n >= limit:
                        nursery.cancel_scope.cancel()
                        break
                out.flush()
    return n
