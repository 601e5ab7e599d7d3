"""Recording the bus to MCAP, and echoing it (docs/bus.md).

:func:`record` subscribes to ``qlap/<run-id>/**`` (or ``qlap/**``) and writes every valid
message to an MCAP file that opens in Foxglove:

- one channel per topic, named the same in every recording, ``/qlap/<topic>`` (``/qlap/sense``,
  ``/qlap/delta/dbn``, ...), so that a Foxglove layout carries over from one recording to the
  next; the run id and the bus key are in the channel's metadata (``run_id``, ``key``);
- JSON message encoding, the message type's JSON Schema as a ``jsonschema`` schema
  (``qlap.<Type>``), log time = receive time in ns, payload bytes as published (compact JSON),
  so a reader's ``decode(key, data)`` equals the message that was put;
- one metadata record ``qlap.run`` per run (:func:`run_metadata`): run id, world, seed,
  placement, start time, software version, and the parameters when the caller passes the run's
  context (``info``, as ``qlap run --record`` does); otherwise world, seed and placement come
  from the run's ``status`` messages (``world`` messages name the world too);
- ``/qlap/scene``: the world's bodies (table, hand, block, ...) as ``foxglove.SceneUpdate``
  (:mod:`.foxglove`), drawn from ``sense`` messages at most ``scene_hz`` times a second of
  receive time, for Foxglove's 3D panel.

Malformed messages are counted, logged and not recorded. It runs in-process (an actor of the same
run, sharing its session) or as ``qlap record --connect ENDPOINT --out FILE.mcap`` (its own client
session).
"""

from __future__ import annotations

import json
import logging
import os
import sys
import time
from collections.abc import Mapping, Sequence
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import trio
import zenoh
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, Writer

from .. import __version__
from ..errors import one_line
from . import keys
from .bridge import Received, RejectionCounter, TrioSubscriber, cancel_when
from .config import client_config
from .qrecord import QRecord
from .schema import (
    MESSAGE_TYPES,
    TOPIC_TYPES,
    AgentStatus,
    Sense,
    WorldView,
    decode,
    encode,
    json_schema,
    qstate_of,
    schema_name,
)

log = logging.getLogger("qlap.bus")

Source = zenoh.Session | zenoh.Config | str | Sequence[str]
"""Where to listen: an open session (shared, not closed here), a config to open, or the
endpoint(s) of a router to connect to as a client."""

TOPIC_ROOT = "/qlap/"
"""Every channel's topic starts with it: ``/qlap/<topic>``, the run id left out."""

SCENE_TOPIC = "/qlap/scene"
"""The channel of the world's bodies (``foxglove.SceneUpdate``)."""

METADATA_NAME = "qlap.run"
"""The name of each run's MCAP metadata record."""

SCENE_HZ = 30.0
"""Default rate of scene updates, per second of receive time."""


def mcap_topic(topic: str) -> str:
    """The MCAP topic of a bus topic: ``sense`` -> ``/qlap/sense``."""
    return TOPIC_ROOT + topic


@dataclass
class RecordSummary:
    """What :func:`record` wrote."""

    path: Path
    """The MCAP file."""
    messages: int = 0
    """Bus messages written."""
    by_topic: dict[str, int] = field(default_factory=dict)
    """Bus messages written per key expression."""
    rejected: int = 0
    """Malformed messages seen (not written)."""
    scenes: int = 0
    """``foxglove.SceneUpdate`` messages written on ``/qlap/scene``."""
    runs: tuple[str, ...] = ()
    """Run ids recorded (one metadata record each)."""
    error: str = ""
    """Why the recording stopped before the end (a full disk): "" when the file is whole.
    What was written before is left in ``NAME.part`` (no MCAP footer) and NAME is not
    written; the run itself goes on."""


def run_metadata(run_id: str, info: Mapping[str, Any] | None = None, *,
                 start_ns: int | None = None) -> dict[str, str]:
    """The ``qlap.run`` metadata record of a run (every value a string, as MCAP wants):
    ``run_id``, ``world``, ``seed``, ``placement``, ``start_time`` (ISO 8601, UTC) and
    ``start_time_ns`` (the first message's receive time), ``software`` and
    ``software_version``, and what ``info`` has of ``steps``, ``params`` (JSON), ``clock``
    (``info`` is a run context's ``to_json()``: placement and clock are read from its
    ``extra`` too). Unknown values are left out."""
    info = dict(info or {})
    extra = info.get("extra") or {}
    out = {"run_id": run_id, "software": "qlap-runtime", "software_version": __version__}
    for k in ("world", "seed", "steps", "placement", "clock", "params"):
        v = info.get(k, extra.get(k))
        if v is None or v == "":
            continue
        out[k] = v if isinstance(v, str) else json.dumps(v, sort_keys=True,
                                                         separators=(",", ":"))
    if start_ns is not None:
        secs, ns = divmod(start_ns, 10**9)
        out["start_time"] = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(secs)) + \
            f".{ns:09d}Z"
        out["start_time_ns"] = str(start_ns)
    return out


class _Run:
    """What the sink knows of one run: its channels, its metadata, its scene."""

    def __init__(self, run_id: str, info: Mapping[str, Any] | None) -> None:
        self.run_id = run_id
        self.info: dict[str, Any] = dict(info or {})
        self.heard: dict[str, Any] = {}          # world, seed, placement from the bus
        self.channels: dict[str, int] = {}
        self.scene_channel: int | None = None
        self.start_ns: int | None = None
        self.maker: Any = None
        self.tried: set[str] = set()
        self.last_scene_ns: int | None = None

    def world(self) -> str:
        return str(self.info.get("world") or self.heard.get("world") or "")

    def learn(self, msg: Any) -> None:
        if isinstance(msg, AgentStatus) and msg.world:
            self.heard.update(world=msg.world, seed=msg.seed, placement=msg.placement)
        elif isinstance(msg, WorldView) and msg.world and "world" not in self.heard:
            self.heard["world"] = msg.world

    def metadata(self) -> dict[str, str]:
        info = dict(self.info)                   # the run's context wins over what was heard
        extra = info.get("extra") or {}
        for k, v in self.heard.items():
            if info.get(k) in (None, "") and k not in extra:
                info[k] = v
        return run_metadata(self.run_id, info, start_ns=self.start_ns)


def as_json(msg: Any, payload: bytes) -> tuple[Any, bytes]:
    """A received message and its payload as JSON: a ``qstate`` record becomes its JSON
    message (recordings and ``echo`` stay JSON, docs/decisions.md 98); others are as they
    came."""
    if isinstance(msg, QRecord):
        msg = qstate_of(msg)
        return msg, encode(msg)
    return msg, payload


class McapSink:
    """An MCAP writer with one schema per message type, one channel per (run, topic), a
    ``qlap.run`` metadata record per run and the world's scene (see the module docstring).

    ``info``: the run's context (``RunContext.to_json()``) when the caller knows it; it applies
    to the run ``info["run_id"]`` (to every run when it has none). ``scene_hz``: scene updates
    per second of receive time (0: one per ``sense``; None: no scene)."""

    def __init__(self, out: IO[bytes], *, info: Mapping[str, Any] | None = None,
                 scene_hz: float | None = SCENE_HZ, library: str = "") -> None:
        self._w = Writer(out, compression=CompressionType.ZSTD)
        self._w.start(profile="", library=library or f"qlap-runtime {__version__}")
        self._schemas: dict[type, int] = {}
        self._scene_schema: int | None = None
        self._info = dict(info) if info else None
        self._scene_period = None if scene_hz is None or scene_hz < 0 else \
            (0 if scene_hz == 0 else int(1e9 / scene_hz))
        self.runs: dict[str, _Run] = {}
        self.scenes = 0
        self._seq = 0
        for cls in MESSAGE_TYPES:
            self._schemas[cls] = self._w.register_schema(
                name=schema_name(cls), encoding=SchemaEncoding.JSONSchema,
                data=json.dumps(json_schema(cls), separators=(",", ":")).encode())
        if self._info and self._info.get("run_id"):
            self._run(str(self._info["run_id"]))

    def _run(self, run_id: str) -> _Run:
        run = self.runs.get(run_id)
        if run is None:
            info = self._info if self._info is not None and self._info.get(
                "run_id", run_id) == run_id else None
            run = self.runs[run_id] = _Run(run_id, info)
        return run

    def write(self, r: Received) -> None:
        run_id, topic = keys.parse(r.key)
        run = self._run(run_id)
        if run.start_ns is None:
            run.start_ns = r.recv_ns
        cid = run.channels.get(topic)
        if cid is None:
            cls = TOPIC_TYPES[topic]
            cid = self._w.register_channel(
                topic=mcap_topic(topic), message_encoding=MessageEncoding.JSON,
                schema_id=self._schemas[cls], metadata={"run_id": run_id, "key": r.key})
            run.channels[topic] = cid
        msg, payload = as_json(r.msg if r.msg is not None else decode(r.key, r.payload),
                               r.payload)
        self._add(cid, r.recv_ns, payload)
        if isinstance(msg, Sense):
            self._scene(run, msg, r.recv_ns)
        else:
            run.learn(msg)

    def _add(self, cid: int, log_ns: int, data: bytes) -> None:
        self._seq += 1
        self._w.add_message(channel_id=cid, log_time=log_ns, data=data, publish_time=log_ns,
                            sequence=self._seq)

    def _scene(self, run: _Run, msg: Sense, recv_ns: int) -> None:
        if self._scene_period is None or (run.last_scene_ns is not None
                                          and recv_ns - run.last_scene_ns < self._scene_period):
            return
        maker = self._maker(run)
        if maker is None:
            return
        data = maker(msg.values, recv_ns, msg.step)
        if data is None:
            return
        if run.scene_channel is None:
            from .foxglove import SCENE_SCHEMA, file_descriptor_set

            if self._scene_schema is None:
                self._scene_schema = self._w.register_schema(
                    name=SCENE_SCHEMA, encoding=SchemaEncoding.Protobuf,
                    data=file_descriptor_set())
            run.scene_channel = self._w.register_channel(
                topic=SCENE_TOPIC, message_encoding=MessageEncoding.Protobuf,
                schema_id=self._scene_schema, metadata={"run_id": run.run_id,
                                                        "world": maker.spec})
        self._add(run.scene_channel, recv_ns, data)
        run.last_scene_ns = recv_ns
        self.scenes += 1

    def _maker(self, run: _Run) -> Any:
        """The run's scene maker, built when its world is first known (again if a later message
        names another world); None while it is unknown or cannot be drawn."""
        spec = run.world()
        if run.maker is not None and run.maker.spec == spec:
            return run.maker
        if not spec or spec in run.tried:
            return run.maker
        run.tried.add(spec)
        from .foxglove import SceneMaker

        try:
            maker = SceneMaker(spec)
        except ValueError as e:
            log.warning("recorder: no scene for run %s: %s", run.run_id, e)
            return run.maker
        if run.maker is not None:
            run.maker.close()
        run.maker = maker
        return maker

    def finish(self) -> None:
        try:
            for run in self.runs.values():
                self._w.add_metadata(METADATA_NAME, run.metadata())
            self._w.finish()
        finally:
            for run in self.runs.values():
                if run.maker is not None:
                    run.maker.close()


async def record(source: Source, run_id: str | None, out_path: Path | str,
                 stop_event: trio.Event, *, counter: RejectionCounter | None = None,
                 info: Mapping[str, Any] | None = None, scene_hz: float | None = SCENE_HZ,
                 task_status: trio.TaskStatus[None] = trio.TASK_STATUS_IGNORED) -> RecordSummary:
    """Record ``qlap/<run_id>/**`` (every run when ``run_id`` is None) to ``out_path`` until
    ``stop_event`` is set; then write what has already arrived and finish the file.

    ``info``: the run's context (``RunContext.to_json()``) for the metadata record; without
    it, what the run's ``status`` messages say. ``scene_hz``: ``/qlap/scene`` updates per
    second (0: one per ``sense``; None: none). With ``nursery.start(record, ...)`` the call
    returns once the subscriber is declared, so nothing published afterwards is missed.
    """
    counter = counter if counter is not None else RejectionCounter("recorder")
    summary = RecordSummary(Path(out_path))
    before = counter.total
    if info is not None and run_id is not None and "run_id" not in info:
        info = {**info, "run_id": run_id}
    # Streamed to NAME.part, renamed to NAME once the file is whole (its footer written, even
    # when the recording ends with an error): NAME is never a torn recording.
    part = Path(out_path).with_name(Path(out_path).name + ".part")
    whole = False
    with ExitStack() as stack:
        stack.callback(lambda: whole and os.replace(part, out_path))
        session = _session(source, stack)
        f = open(part, "wb")  # noqa: ASYNC230 - a local file, streamed

        def close() -> None:
            """Closed before the rename: a write the buffer held fails here on a full disk."""
            nonlocal whole
            try:
                f.close()
            except OSError as exc:
                summary.error, whole = summary.error or one_line(exc), False

        stack.callback(close)
        sink = McapSink(f, info=info, scene_hz=scene_hz)
        try:
            sub = stack.enter_context(
                TrioSubscriber(session, keys.run_pattern(run_id), counter=counter))
            task_status.started()

            def write(batch: list[Received]) -> bool:
                """False once the file refuses a write (the recording stops there)."""
                try:
                    for r in batch:
                        sink.write(r)
                        summary.by_topic[r.key] = summary.by_topic.get(r.key, 0) + 1
                        summary.messages += 1
                except OSError as exc:         # its caller says so (the run goes on)
                    summary.error = one_line(exc)
                return not summary.error

            async with trio.open_nursery() as nursery:
                nursery.start_soon(cancel_when, stop_event, nursery.cancel_scope)
                async for batch in sub:  # a batch is taken whole: cancellation loses nothing
                    if not write(batch):
                        nursery.cancel_scope.cancel()     # the run goes on without it
                        break
            if not summary.error:
                write(sub.receive_nowait())
        finally:
            if not summary.error:
                try:
                    sink.finish()
                except OSError as exc:          # no room for the footer
                    summary.error = one_line(exc)
            whole = not summary.error
    summary.rejected = counter.total - before
    summary.scenes = sink.scenes
    summary.runs = tuple(sink.runs)
    return summary


def _session(source: Source, stack: ExitStack) -> zenoh.Session:
    if isinstance(source, zenoh.Session):
        return source
    cfg = source if isinstance(source, zenoh.Config) else client_config(source)
    return stack.enter_context(zenoh.open(cfg))


def read_mcap(path: Path | str) -> list[tuple[str, Any, int]]:
    """Every bus message of an MCAP file written by :func:`record` as (key expression, decoded
    message, log time ns), in log-time order; the scene is left out. Files written before the
    topics became ``/qlap/<topic>`` (topic = key expression) read the same."""
    from mcap.reader import make_reader

    out = []
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=True):
            if schema is None or not schema.name.startswith("qlap."):
                continue
            key = channel.metadata.get("key", channel.topic)
            out.append((key, decode(key, message.data), message.log_time))
    return out


def read_metadata(path: Path | str) -> list[dict[str, str]]:
    """The ``qlap.run`` metadata records of an MCAP file written by :func:`record`, one per
    run recorded (see :func:`run_metadata`)."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        return [dict(m.metadata) for m in make_reader(f).iter_metadata()
                if m.name == METADATA_NAME]


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
            nursery.start_soon(cancel_when, stop_event, nursery.cancel_scope)
            async for batch in sub:
                for r in batch:
                    text = as_json(r.msg, r.payload)[1].decode("utf-8", "backslashreplace")
                    out.write(f"{r.key} {text}\n")
                    n += 1
                    if limit is not None and n >= limit:
                        break
                out.flush()
                if limit is not None and n >= limit:
                    # Leave now: a batch already waiting is returned without a checkpoint,
                    # so a cancel alone could print it too (one more line than asked).
                    nursery.cancel_scope.cancel()
                    break
    return n
