"""The trio <-> Zenoh bridge (docs/architecture.md §3; docs/bus.md).

Zenoh callbacks run on Zenoh's threads — with zenoh-python 1.x also for a put in the same peer
session (measured: none delivered during ``put``) — so a :class:`Publisher` hands its messages to
the :class:`TrioSubscriber` s of its own session itself (:class:`LocalRoutes`). Callbacks never
touch actor state: they append ``(key, payload, receive time)`` to a
locked deque and, only when the deque was empty, schedule ``event.set`` on the trio loop with
``trio_token.run_sync_soon`` (``Event.set`` cannot raise). The trio task drains the whole deque
per wake-up and decodes at the edge, where a :class:`RejectionCounter` counts and logs malformed
messages with their key expression and never raises into the actor.

- :class:`TrioSubscriber` — ``async for batch in sub`` / ``await sub.receive_batch()``.
- :class:`Publisher` — encodes messages; ``CongestionControl.BLOCK`` on topics that must not
  lose data, ``DROP`` on display topics.
- :func:`declare_alive` / :class:`AliveWatcher` — liveliness tokens of actors.
- :class:`StateQueryable` / :func:`fetch` — current state for late joiners.

Every object here is a context manager; undeclare (or leave the ``with``) before closing the
session.
"""

from __future__ import annotations

import logging
import queue
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any, ClassVar, Generic, TypeVar

import trio
import zenoh

from . import keys
from .faults import Faults
from .qrecord import MAGIC
from .schema import TOPIC_TYPES, WIRE_TYPES, Message, MessageError, Rejected, decode, encode

log = logging.getLogger("qlap.bus")

RELIABLE_TOPICS = frozenset({"sense", "qstate", "motor", "delta/dbn", "delta/landmarks",
                             "delta/plans", "control", "batchctx", "planreq"})
"""Topics that must not lose data: published with ``CongestionControl.BLOCK``."""
DISPLAY_TOPICS = frozenset({"calllist", "iac", "stats", "knowledge", "world", "status"})
"""Display topics: published with ``CongestionControl.DROP`` (a slow viewer loses frames, the
agent never waits for it)."""

assert RELIABLE_TOPICS | DISPLAY_TOPICS == set(keys.TOPICS)

LOCKSTEP_TOPICS = frozenset({"sense", "qstate", "motor", "delta/dbn", "delta/landmarks",
                             "batchctx", "planreq", "delta/plans"})
"""Topics on the lockstep chain, published ``express`` (sent at once, not batched)."""

QUIET_S = 0.05
"""How long a lockstep topic's publisher trusts zenoh's answer that no other session listens
before asking again (:meth:`Publisher.wanted`; zenoh's matching listener reports a new
subscriber in any case; docs/decisions.md 84)."""

BUNDLE = b"qlap-bundle"
"""The attachment of a Zenoh sample that carries several messages of its key, their payloads
joined by newlines (compact JSON has none): :meth:`Publisher.hold` and :meth:`Publisher.flush`
send them, :class:`TrioSubscriber` hands them out one by one (docs/decisions.md 91)."""

FRAMED = b"qlap-bundle-framed"
"""The attachment of a bundle whose messages may be binary (``qstate`` records, which may hold
newlines): their count and lengths, then the payloads (:func:`frame`, :func:`unframe`;
docs/decisions.md 98)."""

T = TypeVar("T")
_DONE: Any = object()


def congestion_control(topic: str) -> zenoh.CongestionControl:
    """BLOCK for :data:`RELIABLE_TOPICS`, DROP for :data:`DISPLAY_TOPICS`."""
    if topic in RELIABLE_TOPICS:
        return zenoh.CongestionControl.BLOCK
    if topic in DISPLAY_TOPICS:
        return zenoh.CongestionControl.DROP
    raise keys.BusKeyError(f"unknown topic {topic!r}")


def frame(payloads: list[bytes]) -> bytes:
    """``payloads`` as one :data:`FRAMED` bundle: their count and lengths (uint32,
    little-endian), then the payloads one after the other (two C calls on the step chain)."""
    n = len(payloads)
    return struct.pack(f"<{n + 1}I", n, *map(len, payloads)) + b"".join(payloads)


def unframe(data: bytes) -> list[bytes]:
    """The payloads of a :data:`FRAMED` bundle. A forged or cut bundle gives what it can — a
    cut payload, or the whole sample as one when its count does not fit — which the decoder
    rejects (so it is counted), never an exception."""
    n = int.from_bytes(data[:4], "little")
    if len(data) < 4 * (n + 1):
        return [data]
    at, out = 4 * (n + 1), []
    for size in struct.unpack_from(f"<{n}I", data, 4):
        out.append(data[at:at + size])
        at += size
    if at < len(data):
        out.append(data[at:])               # bytes left over: one more (invalid) payload
    return out


# --------------------------------------------------------------------------- inbox


class TrioInbox(Generic[T]):
    """A thread-safe inbox feeding one trio task: :meth:`push` from any thread,
    ``await`` :meth:`get_batch` in trio. Create it inside the trio run that consumes it.

    Invariant: the trio task is woken (one ``run_sync_soon``) at most once per transition of the
    deque from empty to non-empty, so a burst costs one wake-up, not one per item.
    """

    def __init__(self) -> None:
        self._token = trio.lowlevel.current_trio_token()
        self._thread = threading.get_ident()
        self._lock = threading.Lock()
        self._items: deque[T] = deque()
        self._event = trio.Event()
        self._closed = False
        self.pushed = 0
        """Items pushed so far (for tests and stats)."""

    def push(self, item: T) -> None:
        """Append ``item``; safe from any thread, never raises, never blocks for long."""
        with self._lock:
            was_empty = not self._items
            self._items.append(item)
            self.pushed += 1
            event = self._event
        if was_empty:
            self._wake_consumer(event)

    def push_many(self, items: list[T]) -> None:
        """:meth:`push` each of ``items``, with at most one wake-up."""
        if not items:
            return
        with self._lock:
            was_empty = not self._items
            self._items.extend(items)
            self.pushed += len(items)
            event = self._event
        if was_empty:
            self._wake_consumer(event)

    def _wake_consumer(self, event: trio.Event) -> None:
        """Wake the consumer that waits on ``event``: at once on its own thread, else through
        trio's wake-up socket."""
        if threading.get_ident() == self._thread:
            self._set_here(event)
        else:
            self._wake(event)

    def _set_here(self, event: trio.Event) -> None:
        """On the consuming trio run's own thread (a put from one of its tasks): set the event
        at once instead of a ``run_sync_soon`` round trip through trio's wake-up socket."""
        try:
            event.set()
        except RuntimeError:                # not inside the run (it has ended): as from afar
            self._wake(event)

    def close(self) -> None:
        """No more items: a waiting :meth:`get_batch` returns what is left, then ``[]``."""
        with self._lock:
            self._closed = True
            event = self._event
        self._wake(event)

    def _wake(self, event: trio.Event) -> None:
        try:
            self._token.run_sync_soon(event.set)
        except trio.RunFinishedError:
            pass  # the consuming trio run is over; nobody to wake

    @property
    def closed(self) -> bool:
        return self._closed

    def pending(self) -> int:
        with self._lock:
            return len(self._items)

    def take_nowait(self) -> list[T]:
        """Everything queued now (possibly nothing), without waiting."""
        with self._lock:
            items = list(self._items)
            self._items.clear()
        return items

    async def get_batch(self) -> list[T]:
        """Wait until at least one item is queued (or the inbox is closed) and return all
        queued items, oldest first; ``[]`` only once closed and empty."""
        while True:
            with self._lock:
                if self._items or self._closed:
                    items = list(self._items)
                    self._items.clear()
                    return items
                # Invariant: a new event is made only while the deque is empty, under the lock,
                # so a push after this point sees was_empty and sets this very event.
                self._event = event = trio.Event()
            await event.wait()


# --------------------------------------------------------------------------- rejections


class RejectionCounter:
    """Counts and logs rejected messages by key expression; never raises.

    The first ``log_first`` rejections on a key are logged at WARNING, then every
    ``log_every``-th, so a flood of garbage cannot flood the log.
    """

    def __init__(self, actor: str = "", *, logger: logging.Logger | None = None,
                 log_first: int = 5, log_every: int = 1000) -> None:
        self.actor = actor
        self.total = 0
        self.by_key: dict[str, int] = {}
        self.last_error = ""
        self._log = logger or log
        self._log_first = log_first
        self._log_every = log_every

    def reject(self, key_expr: str, reason: str) -> None:
        """Count one rejected message on ``key_expr``."""
        n = self.by_key.get(key_expr, 0) + 1
        self.by_key[key_expr] = n
        self.total += 1
        self.last_error = f"{key_expr}: {reason}"
        if n <= self._log_first or n % self._log_every == 0:
            self._log.warning("%srejected message #%d on %s: %s",
                              f"[{self.actor}] " if self.actor else "", n, key_expr, reason)

    def decode(self, key_expr: str, payload: bytes) -> Message | None:
        """The decoded message, or None (counted and logged) if it is invalid."""
        try:
            return decode(key_expr, payload)
        except MessageError as e:
            self.reject(key_expr, e.reason)
        except Exception as e:
            self.reject(key_expr, f"decoder error {type(e).__name__}: {e}")
        return None

    def snapshot(self) -> Rejected:
        """The counts as a :class:`~.schema.Rejected` (for :class:`~.schema.Stats`)."""
        return Rejected(self.total, dict(self.by_key), self.last_error)


# --------------------------------------------------------------------------- subscriber


@dataclass(frozen=True, slots=True)
class Received:
    """One decoded message."""

    key: str
    """The key expression it was published on."""
    msg: Message | None
    """The message (None when the subscriber does not decode)."""
    payload: bytes
    """The raw payload (compact JSON), e.g. for recording without re-encoding."""
    recv_ns: int
    """Wall-clock receive time (``time.time_ns()``) in the Zenoh callback."""


async def cancel_when(event: trio.Event, scope: trio.CancelScope) -> None:
    """Cancel ``scope`` once ``event`` is set: how a loop over a subscription (or signals) in a
    nursery is ended from outside: ``nursery.start_soon(cancel_when, stop, nursery.cancel_scope)``.
    """
    await event.wait()
    scope.cancel()


class TrioSubscriber:
    """A Zenoh subscriber feeding a trio task, decoding at the edge.

    Create inside trio (it captures the current trio token)::

        with TrioSubscriber(session, keys.run_pattern(run_id), counter=counter) as sub:
            async for batch in sub:          # list[Received], oldest first
                for r in batch: ...

    Malformed messages are counted in ``counter`` and left out of the batches. With
    ``decode=False`` batches hold undecoded :class:`Received` items whose ``msg`` is None.
    ``local=False``: the messages of this session's :class:`Publisher` s are not handed to it
    (an actor of the hosted step chain takes them in memory, docs/decisions.md 84); raw puts
    and other sessions' messages still come.
    """

    def __init__(self, session: zenoh.Session, key_expr: str, *,
                 counter: RejectionCounter | None = None, decode: bool = True,
                 local: bool = True) -> None:
        self.key_expr = key_expr
        self.counter = counter if counter is not None else RejectionCounter()
        self._decode = decode
        self.local = local
        self._inbox: TrioInbox[tuple[str, bytes, int, Message | None]] = TrioInbox()
        self._routes = LocalRoutes.of(session)
        self._sub = session.declare_subscriber(
            key_expr, zenoh.handlers.Callback(self._on_sample, indirect=False))
        self._since = self._routes.add(self)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        # Runs on a Zenoh thread: no actor state here.
        try:
            att = sample.attachment
            if att is not None:
                tag = att.to_bytes()
                if tag == BUNDLE or tag == FRAMED:      # several messages (Publisher.flush)
                    key, now, data = str(sample.key_expr), time.time_ns(), \
                        sample.payload.to_bytes()
                    parts = data.split(b"\n") if tag == BUNDLE else unframe(data)
                    self._inbox.push_many([(key, part, now, None) for part in parts])
                    return
                if self._routes.delivered(tag, self._since):
                    return                   # a Publisher of this session handed it over
            self._inbox.push((str(sample.key_expr), sample.payload.to_bytes(), time.time_ns(),
                              None))
        except Exception:
            log.exception("subscriber callback failed on %s", self.key_expr)

    def deliver(self, key: str, payload: bytes, msg: Message | None = None) -> None:
        """A message published on this subscriber's session (:class:`LocalRoutes`): its
        payload and, from a :class:`Publisher`'s ``put``, the typed message itself, which this
        subscriber then hands out without decoding it again (it never left the process)."""
        self._inbox.push((key, payload, time.time_ns(), msg))

    def pending(self) -> int:
        """Messages that arrived and were not taken yet (not decoded yet)."""
        return self._inbox.pending()

    @property
    def received(self) -> int:
        """Samples that reached the callback (valid or not)."""
        return self._inbox.pushed

    async def receive_batch(self) -> list[Received]:
        """Wait for messages and return all that arrived, oldest first (malformed ones are
        counted and skipped; the list may then be empty). Raises ``trio.EndOfChannel`` once
        closed and drained."""
        raw = await self._inbox.get_batch()
        if not raw and self._inbox.closed:
            raise trio.EndOfChannel
        return self._convert(raw)

    def receive_nowait(self) -> list[Received]:
        """Whatever has arrived, without waiting."""
        return self._convert(self._inbox.take_nowait())

    def _convert(self, raw: list[tuple[str, bytes, int, Message | None]]) -> list[Received]:
        if not self._decode:
            return [Received(k, None, p, t) for k, p, t, _ in raw]
        out = []
        for k, p, t, msg in raw:
            if msg is None:
                msg = self.counter.decode(k, p)
            if msg is not None:
                out.append(Received(k, msg, p, t))
        return out

    def __aiter__(self) -> TrioSubscriber:
        return self

    async def __anext__(self) -> list[Received]:
        try:
            return await self.receive_batch()
        except trio.EndOfChannel:
            raise StopAsyncIteration from None

    def close(self) -> None:
        """Undeclare the subscriber; iteration ends after the queued messages."""
        self._routes.remove(self)
        try:
            self._sub.undeclare()
        except zenoh.ZError:  # pragma: no cover - session already closed
            pass
        self._inbox.close()

    def __enter__(self) -> TrioSubscriber:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# --------------------------------------------------------------------------- local routes


class LocalRoutes:
    """The :class:`TrioSubscriber` s declared on one session, so that a :class:`Publisher` of the
    same session hands them its messages directly, on the publishing thread.

    Zenoh runs a Python callback on its own thread even for a put in the same session, so an
    in-process hop would cost a thread hand-over (the GIL) and a trio wake-up through a socket;
    in the embedded placement every step crosses three such hops. The message still goes out on
    Zenoh for every other subscriber (other processes, raw subscribers such as the terminal
    UI's), with an attachment naming this session and the routes' version; a subscriber of this
    session registered by that version drops that second copy (:meth:`delivered`). A message of
    a lockstep topic goes out on Zenoh only to other sessions, and only while one of them
    subscribes (:class:`Publisher`, docs/decisions.md 73). Messages put without a
    :class:`Publisher` (raw puts, other processes) reach every subscriber through Zenoh as
    before.
    """

    _by_session: ClassVar[dict[str, LocalRoutes]] = {}
    _lock: ClassVar[threading.Lock] = threading.Lock()

    def __init__(self, zid: str) -> None:
        self.zid = zid
        self.prefix = f"qlap-local/{zid}/".encode()
        self.version = 0
        self._subs: list[TrioSubscriber] = []

    @classmethod
    def of(cls, session: zenoh.Session) -> LocalRoutes:
        zid = str(session.info.zid())
        with cls._lock:
            routes = cls._by_session.get(zid)
            if routes is None:
                routes = cls._by_session[zid] = cls(zid)
            return routes

    def add(self, sub: TrioSubscriber) -> int:
        """Register ``sub``; the version from which it receives local messages directly."""
        with self._lock:
            self._subs.append(sub)
            self.version += 1
            return self.version

    def remove(self, sub: TrioSubscriber) -> None:
        with self._lock:
            if sub in self._subs:
                self._subs.remove(sub)
                self.version += 1

    def matching(self, key: str) -> tuple[int, list[TrioSubscriber]]:
        """The version and the subscribers whose key expression intersects ``key``."""
        with self._lock:
            ke = zenoh.KeyExpr(key)
            return self.version, [s for s in self._subs
                                  if s.local and zenoh.KeyExpr(s.key_expr).intersects(ke)]

    def tag(self, version: int) -> bytes:
        return self.prefix + str(version).encode()

    def delivered(self, attachment: bytes, since: int) -> bool:
        """True when ``attachment`` says a publisher of this session already handed the
        message to the subscribers registered by then, one of them registered at ``since``."""
        if not attachment.startswith(self.prefix):
            return False
        try:
            return int(attachment[len(self.prefix):]) >= since
        except ValueError:
            return False


# --------------------------------------------------------------------------- publisher


class Publisher:
    """Publishes one topic's messages on ``qlap/<run-id>/<topic>``.

    Congestion control follows the topic (:func:`congestion_control`) unless given. With BLOCK,
    :meth:`put` may block while the network or a slow subscriber catches up: that is the point.

    A lockstep topic's message (:data:`LOCKSTEP_TOPICS`; :attr:`remote_only`) reaches this
    session's :class:`TrioSubscriber` s by :class:`LocalRoutes` alone and goes out on Zenoh
    only towards other sessions (``Locality.REMOTE``), and only while one of them has a
    matching subscriber (zenoh's matching listener, and its matching status when the listener
    says no: a recorder or a UI that subscribes mid-run gets the messages from then on).
    Zenoh's matching status counts this session's own subscribers too, whichever origin they
    allow (measured on zenoh 1.10), so a put for everyone could not tell that nobody else
    listens; a raw subscriber of a lockstep topic on this very session gets nothing (use a
    :class:`TrioSubscriber`, as the recorder does; docs/decisions.md 73). Display and control
    topics go to every subscriber as before.
    """

    def __init__(self, session: zenoh.Session, run_id: str, topic: str, *,
                 congestion: zenoh.CongestionControl | None = None,
                 priority: zenoh.Priority | None = None, express: bool | None = None,
                 faults: Faults | None = None, tag: str = "") -> None:
        self.key = keys.key(run_id, topic)
        self.topic = topic
        self.msg_type = TOPIC_TYPES[topic]
        self.msg_types = WIRE_TYPES[topic]
        """The message types it takes (``qstate``: JSON or a binary record)."""
        self.congestion = congestion if congestion is not None else congestion_control(topic)
        if express is None and topic in LOCKSTEP_TOPICS:
            express = True           # the step chain waits for these: no batching delay
        self.remote_only = topic in LOCKSTEP_TOPICS
        """Zenoh carries it to other sessions only, while one listens (see the class)."""
        where = {"allowed_destination": zenoh.Locality.REMOTE} if self.remote_only else {}
        self._pub = session.declare_publisher(
            self.key, encoding=zenoh.Encoding.APPLICATION_JSON, congestion_control=self.congestion,
            priority=priority, express=express, **where)
        self.remote = True
        """Whether another session has a matching subscriber (kept by zenoh's listener)."""
        self._matching: Any = None
        if self.remote_only:
            self._matching = self._pub.declare_matching_listener(self._on_matching)
            self.remote = bool(self._pub.matching_status.matching)
        self._quiet_until = 0.0
        self.skipped = 0
        """Zenoh puts left out: nobody outside the session listened."""
        self._routes = LocalRoutes.of(session)
        self._local: tuple[int, list[TrioSubscriber], bytes] = (-1, [], b"")
        """The routes' version, this key's local subscribers then, and their tag."""
        self.sent = 0
        self.payload = b""
        """The encoding of the last message :meth:`put` (a replay log keeps it)."""
        self.faults = faults.injector(topic, tag) if faults is not None else None
        """Injected drops and delays (tests and the chaos harness only; :mod:`.faults`)."""
        self._held: list[bytes] = []
        """Payloads :meth:`hold` kept for other sessions until :meth:`flush`."""
        self.held_bytes = 0
        """Their size (a bundle over Zenoh's 64 KiB batch is fragmented, which costs)."""
        self.bundles = 0
        """Zenoh puts of several held messages (:meth:`flush`)."""
        self._sender: Sender | None = None
        """The thread that puts what ``flush(wait=False)`` hands it, started at the first."""

    def put(self, msg: Message) -> bool:
        """Encode and publish ``msg``; a message of the wrong type or with a NaN raises
        (:class:`TypeError` / :class:`~.schema.MessageError`): that is a bug in the caller.
        False only when an injected fault dropped it (:mod:`.faults`)."""
        if type(msg) not in self.msg_types:
            raise TypeError(f"{self.key} carries {self.msg_type.__name__}, "
                            f"not {type(msg).__name__}")
        self.sent += 1
        self.payload = payload = encode(msg)
        if self.faults is None:
            self._send(payload, msg)
            return True
        return self.faults.put(partial(self._send, msg=msg), payload)   # lost or late

    def hold(self, msg: Message) -> bool:
        """:meth:`put` for a reader in another session that may take ``msg`` a little later:
        this session's subscribers get it now, other sessions with the next :meth:`flush`,
        several messages in one Zenoh sample (:data:`BUNDLE`): a put to the router is a
        syscall and a wake-up of the router and of the reader, which a step chain paid for
        every ``qstate`` (docs/decisions.md 91). The writer flushes before anything could
        wait for what it holds. With injected faults, or for a topic that is not a lockstep
        topic, it is :meth:`put`. Same answer as :meth:`put`."""
        if self.faults is not None or not self.remote_only:
            return self.put(msg)
        if type(msg) not in self.msg_types:
            raise TypeError(f"{self.key} carries {self.msg_type.__name__}, "
                            f"not {type(msg).__name__}")
        self.sent += 1
        self.payload = payload = encode(msg)
        for sub in self._local_subs():
            sub.deliver(self.key, payload, msg)
        self._held.append(payload)
        self.held_bytes += len(payload)
        return True

    @property
    def held(self) -> int:
        """Messages :meth:`hold` kept for the next :meth:`flush`."""
        return len(self._held)

    def flush(self, wait: bool = True) -> None:
        """Put what :meth:`hold` kept, as one Zenoh sample, while another session listens
        (else they count as :attr:`skipped`, as :meth:`put` would have). ``wait=False``: the
        put goes to this publisher's sender thread, after the ones before it, and the writer
        goes on while Zenoh blocks (congestion control BLOCK towards a reader that is behind;
        the put releases the GIL; docs/decisions.md 96); ``wait=True`` returns once every
        sample held or handed to the thread is on Zenoh."""
        held = self._held
        if held:
            self._held, self.held_bytes = [], 0
            binary = any(p[:3] == MAGIC for p in held)   # a record: FRAMED, not newlines
            if not self._remote_now():
                self.skipped += len(held)
            else:
                sample = (held[0], None) if len(held) == 1 \
                    else (frame(held), FRAMED) if binary else (b"\n".join(held), BUNDLE)
                self.bundles += len(held) > 1
                if not wait:
                    if self._sender is None:
                        self._sender = Sender(self._put_sample, self.key)
                    self._sender.send(sample)
                    return
                if self._sender is not None:
                    self._sender.drain()
                self._put_sample(sample)
                return
        if wait and self._sender is not None:
            self._sender.drain()

    def _put_sample(self, sample: tuple[bytes, bytes | None]) -> None:
        payload, attachment = sample
        if attachment is None:
            self._pub.put(payload)
        else:
            self._pub.put(payload, attachment=attachment)

    @property
    def wanted(self) -> bool:
        """Whether a :meth:`put` now would reach anyone: a :class:`TrioSubscriber` of this
        session, another session's subscriber (a lockstep topic: while one listens; any other
        topic: always), or an injected fault. False lets a writer skip the encoding, and even
        the message (docs/decisions.md 84)."""
        if self.faults is not None or not self.remote_only or self._local_subs():
            return True
        return self._remote_now()

    def _remote_now(self) -> bool:
        """Whether another session listens: the listener's answer, else zenoh's matching
        status (the listener's False may lag zenoh's routing: a subscription just declared),
        whose no is trusted for :data:`QUIET_S` (a query is 1.1 µs, and the step chain asks
        for three topics a step)."""
        if self.remote:
            return True
        now = time.monotonic()
        if now < self._quiet_until:
            return False
        if self._pub.matching_status.matching:
            # The listener's False lagged (or never changed: a subscription declared before
            # this publisher); it sets False again when the last one goes. Without this the
            # step chain asked zenoh at every put of qstate (1.3% of its samples, py-spy).
            self.remote = True
            return True
        self._quiet_until = now + QUIET_S
        return False

    def _local_subs(self) -> list[TrioSubscriber]:
        version, local, tag = self._local
        if version != self._routes.version:
            version, local = self._routes.matching(self.key)
            tag = self._routes.tag(version)
            self._local = (version, local, tag)
        return local

    def _send(self, payload: bytes, msg: Message | None = None) -> None:
        """Hand ``payload`` (and ``msg``, the message it encodes, if known) to the subscribers
        of this session, then put it on Zenoh for every other subscriber, tagged so that this
        session's own drop their second copy."""
        if self._sender is not None:
            self._sender.drain()                # after what the sender thread still holds
        local = self._local_subs()
        tag = self._local[2]
        for sub in local:
            sub.deliver(self.key, payload, msg)
        if self.remote_only:
            # Other sessions only (no second local copy), while one listens.
            if self._remote_now():
                self._pub.put(payload)
            else:
                self.skipped += 1
        elif local:
            self._pub.put(payload, attachment=tag)
        else:
            self._pub.put(payload)

    def _on_matching(self, status: Any) -> None:
        # A Zenoh thread: one store (read by the next put).
        self.remote = bool(status.matching)

    @property
    def matched(self) -> bool:
        """True when some subscriber matches this key: one of this session's
        :class:`TrioSubscriber` s, or any (zenoh's matching status)."""
        if self.remote_only and self._routes.matching(self.key)[1]:
            return True
        status = self._pub.matching_status
        return bool(getattr(status, "matching", status))

    async def wait_matched(self, poll: float = 0.005) -> None:
        """Wait until a subscriber matches (e.g. the world before its first ``sense`` in
        lockstep, so that step 0 is not published into the void). Wrap in ``trio.fail_after``."""
        while not self.matched:  # noqa: ASYNC110 - zenoh reports matching by polling or callback
            await trio.sleep(poll)

    def put_raw(self, payload: bytes) -> None:
        """Publish bytes as they are (tests of the decoder's defences), in order with
        :meth:`put`."""
        self._send(payload)

    def close(self) -> None:
        if self.faults is not None:
            self.faults.close()
        try:
            self.flush()
            if self._sender is not None:
                self._sender.close()
            if self._matching is not None:
                self._matching.undeclare()
            self._pub.undeclare()
        except zenoh.ZError:  # pragma: no cover
            pass

    def __enter__(self) -> Publisher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class Sender:
    """A thread that puts samples on Zenoh in the order given (:meth:`Publisher.flush` with
    ``wait=False``). A put that fails (the session closing) is logged and dropped, as a lost
    message, and the thread goes on; :meth:`drain` waits until every sample given is out."""

    def __init__(self, put: Callable[[Any], None], name: str) -> None:
        self.put = put
        self.queue: queue.Queue[Any] = queue.Queue()
        self.thread = threading.Thread(target=self._run, name=f"sender {name}", daemon=True)
        self.thread.start()

    def send(self, sample: Any) -> None:
        self.queue.put(sample)

    def drain(self) -> None:
        self.queue.join()

    def close(self) -> None:
        """Every sample out, then the thread ends."""
        self.queue.put(None)
        self.thread.join()

    def _run(self) -> None:
        while True:
            sample = self.queue.get()
            try:
                if sample is None:
                    return
                self.put(sample)
            except Exception as exc:            # the thread goes on: drain waits on it
                log.warning("a held sample was not sent: %s", exc)
            finally:
                self.queue.task_done()


# --------------------------------------------------------------------------- liveliness


def declare_alive(session: zenoh.Session, run_id: str, actor: str) -> zenoh.LivelinessToken:
    """Declare ``qlap/<run-id>/alive/<actor>``; the token lives until undeclared or the session
    closes (or the process dies). Use as ``with declare_alive(...):``."""
    return session.liveliness().declare_token(keys.alive_key(run_id, actor))


@dataclass(frozen=True, slots=True)
class AliveChange:
    """An actor appearing or disappearing."""

    actor: str
    """The actor's name (last chunk of its liveliness key)."""
    alive: bool
    """True when its token appeared, False when it went away."""
    key: str
    """The token's key expression."""


class AliveWatcher:
    """Watches the liveliness tokens of a run from trio.

    ``alive`` is the set of actors currently alive (updated as batches are received);
    ``await watcher.changes()`` returns the next changes. Tokens that already exist are reported
    on declaration (``history=True``).
    """

    def __init__(self, session: zenoh.Session, run_id: str) -> None:
        self.alive: set[str] = set()
        self._inbox: TrioInbox[AliveChange] = TrioInbox()
        self._sub = session.liveliness().declare_subscriber(
            keys.alive_pattern(run_id), self._on_sample, history=True)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        try:
            key = str(sample.key_expr)
            self._inbox.push(AliveChange(key.rsplit("/", 1)[-1],
                                         sample.kind == zenoh.SampleKind.PUT, key))
        except Exception:
            log.exception("liveliness callback failed")

    async def changes(self) -> list[AliveChange]:
        """The next changes, oldest first (waits for at least one)."""
        batch = await self._inbox.get_batch()
        for c in batch:
            (self.alive.add if c.alive else self.alive.discard)(c.actor)
        return batch

    async def wait_until(self, predicate: Callable[[set[str]], bool]) -> set[str]:
        """Wait until ``predicate(alive)`` holds; return the alive set."""
        while not predicate(self.alive):
            await self.changes()
        return set(self.alive)

    def close(self) -> None:
        try:
            self._sub.undeclare()
        except zenoh.ZError:  # pragma: no cover
            pass
        self._inbox.close()

    def __enter__(self) -> AliveWatcher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


async def alive_actors(session: zenoh.Session, run_id: str, *,
                       query_timeout: float = 2.0) -> set[str]:
    """The actors of a run whose liveliness token exists now (a query, not a subscription:
    no race with a token that goes while a subscriber's history is being answered)."""
    inbox: TrioInbox[Any] = TrioInbox()

    def on_reply(reply: zenoh.Reply) -> None:
        try:
            ok = reply.ok
            if ok is not None:
                inbox.push(str(ok.key_expr).rsplit("/", 1)[-1])
        except Exception:
            log.exception("liveliness reply callback failed")

    session.liveliness().get(keys.alive_pattern(run_id),
                             zenoh.handlers.Callback(on_reply, lambda: inbox.push(_DONE)),
                             timeout=query_timeout)
    out: set[str] = set()
    with trio.move_on_after(query_timeout + 1.0):
        while True:
            for item in await inbox.get_batch():
                if item is _DONE:
                    return out
                out.add(item)
    return out


# --------------------------------------------------------------------------- late joiners


class StateQueryable:
    """Answers queries on ``key_expr`` with an actor's current state, for late joiners.

    The actor calls :meth:`set` (replace the state under a key) or :meth:`append` (add to a
    log, e.g. every delta so far) from its own task; the Zenoh query callback only reads an
    immutable snapshot of pre-encoded payloads, so no actor state is touched from Zenoh's
    threads.
    """

    def __init__(self, session: zenoh.Session, key_expr: str) -> None:
        self.key_expr = key_expr
        self._entries: tuple[tuple[str, bytes], ...] = ()  # replaced atomically, never mutated
        self._q = session.declare_queryable(key_expr, self._on_query)

    def set(self, key: str, msg: Message) -> None:
        """Replace every entry under ``key`` by ``msg``."""
        payload = encode(msg)
        self._entries = (*[(k, p) for k, p in self._entries if k != key], (key, payload))

    def append(self, key: str, msg: Message) -> None:
        """Add ``msg`` under ``key`` after the existing entries."""
        self._entries = (*self._entries, (key, encode(msg)))

    def clear(self) -> None:
        self._entries = ()

    def _on_query(self, query: zenoh.Query) -> None:
        entries = self._entries
        try:
            selector = zenoh.KeyExpr(str(query.key_expr))
            for k, p in entries:
                if selector.intersects(zenoh.KeyExpr(k)):
                    query.reply(k, p, encoding=zenoh.Encoding.APPLICATION_JSON)
        except Exception:
            log.exception("state query on %s failed", self.key_expr)

    def close(self) -> None:
        try:
            self._q.undeclare()
        except zenoh.ZError:  # pragma: no cover
            pass

    def __enter__(self) -> StateQueryable:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


async def fetch(session: zenoh.Session, selector: str, *, query_timeout: float = 2.0,
                counter: RejectionCounter | None = None) -> list[Received]:
    """Query ``selector`` (e.g. ``qlap/<run>/delta/**``) and return every decoded reply in
    arrival order (no consolidation, so a log of deltas arrives whole). Invalid replies are
    counted in ``counter``; error replies are logged."""
    counter = counter if counter is not None else RejectionCounter()
    inbox: TrioInbox[Any] = TrioInbox()

    def on_reply(reply: zenoh.Reply) -> None:
        try:
            ok = reply.ok
            if ok is not None:
                inbox.push((str(ok.key_expr), ok.payload.to_bytes(), time.time_ns()))
            else:
                inbox.push((selector, None, 0))
        except Exception:
            log.exception("reply callback failed")

    session.get(selector, zenoh.handlers.Callback(on_reply, lambda: inbox.push(_DONE)),
                consolidation=zenoh.ConsolidationMode.NONE, timeout=query_timeout)
    out: list[Received] = []
    with trio.move_on_after(query_timeout + 1.0):
        while True:
            for item in await inbox.get_batch():
                if item is _DONE:
                    return out
                k, p, t = item
                if p is None:
                    log.warning("error reply to query %s", selector)
                    continue
                msg = counter.decode(k, p)
                if msg is not None:
                    out.append(Received(k, msg, p, t))
    return out
