"""The actor skeleton: what every actor of a run shares, so that an actor reads
receive → algorithm → publish (docs/runtime.md).

An :class:`Actor` owns, for one actor of one run:

- **liveness**: its token ``qlap/<run>/alive/<name>``, declared once every subscription of the
  actor exists (:meth:`Actor.start`), and its line on the watchdog's board (:attr:`slot`);
- **inputs**: step inboxes of its input topics (:meth:`Actor.input`), the delta inbox
  (:meth:`Actor.deltas`) and the run's controls with the world's end marker (:attr:`controls`);
- **outputs**: publishers that keep a replay log for consumers restarted later
  (:meth:`Actor.output`);
- **resume and snapshots**: where it starts (:class:`Resume`, from the supervisor's restart
  fields of the run context), the replay of what it missed (:meth:`Actor.start`), and its
  snapshots at the boundaries the run schedules (:meth:`Actor.snapshot_due`,
  :meth:`Actor.snapshot`), with their statistics in :meth:`Actor.result`;
- **the end**: :meth:`Actor.linger` withdraws the token when the loop is done and keeps the
  replay logs open until the actor's consumers are done too.

Use as ``with Actor(session, ctx, name) as actor:``; everything is closed on exit.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Self

import trio

from ..bus import keys
from ..bus.bridge import (
    Publisher,
    RejectionCounter,
    TrioSubscriber,
    alive_actors,
    declare_alive,
)
from ..bus.faults import Faults
from ..bus.qrecord import payload_bytes, payload_text
from ..bus.replay import ReplayLog, fetch_replay
from ..bus.schema import Message, decode
from . import snapshot as snap
from .context import RunContext
from .controls import Controls
from .inbox import DeltaInbox, RunEnded, StepInbox
from .lockstep import batch_kinds
from .rules import Rule
from .watchdog import Slot, slot_of

log = logging.getLogger("qlap.actors")

LINGER_S = 30.0
"""How long a writer keeps its replay logs open after its last step for consumers that lag
(:meth:`Actor.linger`)."""
LINGER_POLL_S = 0.05
LAZY_S = 0.005
"""How long an actor off the step chain lets the chain run when it has caught up
(:meth:`Actor.receive` ``lazy``), so that one wake-up takes several steps."""
BUNDLE_BYTES = 32 * 1024
BUNDLE_S = 0.02
"""A ``bundled`` output (:class:`Output`) sends what it holds once it holds this many bytes
(32 steps of core's ``qstate``: the cheapest size per message, measured; over Zenoh's 64 KiB
batch a sample is fragmented), once its oldest message is this old, and at every batch step
(a batch at t reads every step up to t, and its delta may be waited for from t on;
docs/decisions.md 91)."""


@dataclass
class Resume:
    """Where an actor starts: fresh, or restarted by the supervisor (from a snapshot or, when
    it died before its first one, from the start, with its inputs replayed)."""

    step: int
    """The last step whose input the state has consumed (``ctx.start - 1`` when fresh)."""
    path: Path | None = None
    """The snapshot directory, if any."""
    state: dict[str, Any] = field(default_factory=dict)
    """The actor-specific values of the snapshot (see :mod:`~qlap_runtime.runtime.snapshot`)."""
    restarted: bool = False
    checkpoint: Path | None = None
    """The resumed run's checkpoint the actor starts from when it has no snapshot of its own
    (``ctx.resume_checkpoint``; docs/decisions.md 50)."""

    @classmethod
    def of(cls, ctx: RunContext, actor: str) -> Resume:
        if not ctx.restarted:
            return cls(ctx.start - 1, checkpoint=ctx.resume_checkpoint)
        if ctx.resume_from is None:
            return cls(ctx.start - 1, restarted=True, checkpoint=ctx.resume_checkpoint)
        step, state = snap.read_snapshot(ctx.resume_from, actor)
        log.info("%s: resuming from the snapshot at step %d", actor, step)
        return cls(step, ctx.resume_from, state, True)


class Output:
    """One output topic: published, and kept in a replay log for restarted consumers.

    ``logged=False``: no replay log (every consumer takes the messages in memory, the hosted
    step chain's ``sense`` and ``motor``); a message then is encoded and put only while
    somebody listens (:attr:`wanted`, docs/decisions.md 84). ``bundled``: other sessions get
    the messages in bundles (:meth:`~qlap_runtime.bus.bridge.Publisher.hold`), each sent when
    :data:`BUNDLE_BYTES` or :data:`BUNDLE_S` says, at a batch step, or by :meth:`flush`
    (docs/decisions.md 91)."""

    def __init__(self, session: Any, ctx: RunContext, topic: str, actor: str = "",
                 logged: bool = True, bundled: bool = False) -> None:
        self.pub = Publisher(session, ctx.run_id, topic, faults=Faults.of(ctx.faults),
                             tag=actor)
        self._send = self.pub.hold if bundled else self.pub.put
        self.bundled, self.params, self._held_since = bundled, ctx.params, 0.0
        self._log = ReplayLog(session, ctx.run_id, topic, ctx.replay_keep) if logged else None
        self.key = keys.key(ctx.run_id, topic)
        self.unsent = 0
        """Messages neither logged nor put: nobody listened."""

    @property
    def log(self) -> ReplayLog:
        """The replay log (an output made with ``logged``)."""
        assert self._log is not None, f"{self.key} keeps no replay log"
        return self._log

    @property
    def wanted(self) -> bool:
        """Whether :meth:`put` would do anything (a log, or a listener): a writer may skip
        building a message nobody reads."""
        return self._log is not None or self.pub.wanted

    def put(self, step: int, msg: Message) -> None:
        """Publish ``msg`` and log it under ``step`` (not logged only when an injected fault
        loses it for good, :class:`~qlap_runtime.bus.faults.Faults` ``lost``)."""
        if self._log is None:
            if self.pub.wanted:
                self._send(msg)
            else:
                self.unsent += 1
        elif self._send(msg) or self.pub.faults is None or not self.pub.faults.lost:
            self._log.append(step, msg, self.pub.payload)
        if self.bundled and (held := self.pub.held):
            if held == 1:
                self._held_since = time.perf_counter()
            if self.pub.held_bytes >= BUNDLE_BYTES or batch_kinds(self.params, step) \
                    or time.perf_counter() - self._held_since >= BUNDLE_S:
                self.pub.flush(wait=False)      # the chain goes on (decision 96)

    @property
    def held(self) -> int:
        """Messages of a ``bundled`` output not yet sent to other sessions."""
        return self.pub.held

    def flush(self) -> None:
        """Send what a ``bundled`` output holds (one Zenoh sample)."""
        self.pub.flush()

    def skip(self) -> None:
        """A message not built: nobody wanted it (:attr:`wanted`)."""
        self.unsent += 1

    def saved(self, since: int | None = None) -> list[list]:
        """The logged ``[step, payload]`` entries from step ``since`` on, for a snapshot
        (:meth:`Actor.restore_log` serves them again; a binary record as base64)."""
        return [] if self._log is None \
            else [[s, payload_text(p)] for s, p in self._log.payloads(since)]

    def close(self) -> None:
        if self._log is not None:
            self._log.close()
        self.pub.close()


class Actor:
    """One actor's runtime (see the module docstring). ``obey`` keeps the control commands
    for the actor (world, executor); the others only see the end marker."""

    def __init__(self, session: Any, ctx: RunContext, name: str, *, obey: bool = False) -> None:
        self.session, self.ctx, self.name = session, ctx, name
        self.counter = RejectionCounter(name)
        self.slot: Slot = slot_of(ctx, name)
        self.resume = Resume.of(ctx, name)
        self._stack = ExitStack()
        self.controls = self._stack.enter_context(Controls(session, ctx, self.counter,
                                                           keep=obey))
        self.inbox: StepInbox | None = None
        """The primary input (the first :meth:`input`)."""
        self._inputs: list[tuple[StepInbox, str]] = []
        self._deltas: DeltaInbox | None = None
        self._outputs: list[Output] = []
        self._token: Any = None
        self.snapshot_times: list[float] = []

    # ------------------------------------------------------------------------- set-up
    def input(self, topic: str, *, window: int | None, rule: Rule | None = None,
              first: int | None = None, end: bool = True, hosted: bool = False) -> StepInbox:
        """A step inbox of ``topic`` from step ``first`` (default: the step after the resume
        point); ``window``: the lockstep window (ignored under the realtime clock); ``end``:
        the world's end marker ends a wait for a later step (not for the world itself);
        ``hosted``: the actor takes the topic's messages in memory from the actor before it
        on the hosted step chain, so this session's own messages are not handed to the inbox,
        which only keeps the rules on what else comes (:meth:`StepInbox.discard`)."""
        sub = self._stack.enter_context(
            TrioSubscriber(self.session, keys.key(self.ctx.run_id, topic), counter=self.counter,
                           local=not hosted))
        # In lockstep a step that does not come in time is asked for again from the writer's
        # replay log (a lost message; a restarted writer or consumer).
        refill = None if self.ctx.realtime else self._refill(topic)
        inbox = StepInbox(sub, first=self.resume.step + 1 if first is None else first,
                          refill=refill, end=self.controls if end else None, slot=self.slot,
                          topic=topic,
                          counter=self.counter, key=keys.key(self.ctx.run_id, topic),
                          window=None if self.ctx.realtime else window, rule=rule)
        self._inputs.append((inbox, topic))
        if self.inbox is None:
            self.inbox = inbox
        return inbox

    def deltas(self, n_vars: int) -> DeltaInbox:
        """The delta inbox (rules for a world of ``n_vars`` variables)."""
        self._deltas = DeltaInbox(self.session, self.ctx, self.counter, self.slot, n_vars)
        self._stack.callback(self._deltas.close)
        return self._deltas

    def output(self, topic: str, *, logged: bool = True, bundled: bool = False) -> Output:
        """A published topic with its replay log (``logged``) and bundles (``bundled``,
        :class:`Output`)."""
        out = Output(self.session, self.ctx, topic, self.name, logged, bundled)
        self._stack.callback(out.close)
        self._outputs.append(out)
        return out

    def publisher(self, topic: str) -> Publisher:
        """A published topic without a replay log (display, the end marker)."""
        pub = Publisher(self.session, self.ctx.run_id, topic)
        self._stack.callback(pub.close)
        return pub

    def restore_log(self, output: Output, entries: list) -> None:
        """Serve again the ``[step, payload]`` entries a snapshot kept of ``output``'s log."""
        for step, text in entries:
            payload = payload_bytes(text)
            output.log.append(int(step), decode(output.key, payload), payload)

    async def start(self) -> None:
        """Declare the actor alive (every subscription exists) and, when restarted, restore
        its delta book and fetch what it missed from the writers' replay logs."""
        self._token = declare_alive(self.session, self.ctx.run_id, self.name)
        self._stack.callback(self._undeclare)
        resume = self.resume
        if not resume.restarted:
            return
        if self._deltas is not None and "book" in resume.state:
            snap.restore_book(self._deltas.book, resume.state["book"])
        for i, (inbox, topic) in enumerate(self._inputs):
            got = await inbox.fill_from_replay(self._refill(topic))
            if i == 0 and self._deltas is not None:
                await self._deltas.catch_up(self.session, self.ctx, self.counter)
            first = resume.step + 1
            if i == 0 and got and first < self.ctx.end and first not in inbox.buf:
                raise RuntimeError(f"cannot resume at step {first}: the {topic} replay log "
                                   f"starts at step {min(inbox.buf)}")

    def _refill(self, topic: str) -> Callable[[int], Any]:
        async def refill(step: int) -> list:
            return await fetch_replay(self.session, self.ctx.run_id, topic, step,
                                      counter=self.counter)
        return refill

    def _undeclare(self) -> None:
        token, self._token = self._token, None
        if token is not None:
            try:
                token.undeclare()
            except Exception:                       # pragma: no cover - session closed
                pass

    async def linger(self, consumers: tuple[str, ...], limit_s: float = LINGER_S) -> None:
        """After the last step: no longer alive as a consumer (the token goes), but the replay
        logs stay open until every actor of ``consumers`` has ended its loop too (its token
        gone), at most ``limit_s``: a consumer that lags (a learner behind the step chain)
        can still ask again for a message it lost near the end of the run."""
        self._undeclare()
        wanted = set(consumers) - {self.name}
        if self.ctx.realtime or not self._outputs or not wanted:
            return
        with trio.move_on_after(limit_s):
            # Polled: the tokens are another process's; a subscription's history can miss
            # a token that goes while it is answered.
            while await alive_actors(self.session, self.ctx.run_id) & wanted:  # noqa: ASYNC110
                await trio.sleep(LINGER_POLL_S)

    async def finish(self, consumers: tuple[str, ...], **values: Any) -> dict[str, Any]:
        """After the last step: off the board, :meth:`linger` for ``consumers``, and the
        actor's :meth:`result` with ``values``."""
        self.slot.finished()
        await self.linger(consumers)
        return self.result(**values)

    async def others_ended(self, limit_s: float) -> None:
        """Wait (at most ``limit_s``) until every other actor of the run has withdrawn its
        token: their outputs are written."""
        with trio.move_on_after(limit_s):
            # Polled (a subscription's history can miss a token that goes while it answers).
            others = {self.name}
            while (await alive_actors(self.session, self.ctx.run_id)) - others:  # noqa: ASYNC110
                await trio.sleep(LINGER_POLL_S)

    # ------------------------------------------------------------------------- the loop
    def steps(self) -> range:
        """The steps this actor still has to take."""
        return range(self.resume.step + 1, self.ctx.end)

    async def receive(self, t: int, *, lazy: bool = False) -> Any | None:
        """The primary input's message of step ``t``; None when the run ended before it.

        ``lazy``: the actor is off the step chain (a learner: nothing on the chain waits for
        it before step t + L). When step t has not arrived yet it first sleeps
        :data:`LAZY_S`, so that the chain runs on and the actor then takes every step that
        came meanwhile in one wake-up, instead of one trio wake-up (a cancel scope, an
        event, the board) per step."""
        assert self.inbox is not None
        if lazy and not self.inbox.ready(t):
            await trio.sleep(LAZY_S)
        try:
            return await self.inbox.get(t)
        except RunEnded:                            # quit: the world took no step t
            return None

    def snapshot_due(self, step: int) -> bool:
        """True when the actor writes a snapshot at the boundary of ``step``."""
        ctx = self.ctx
        return ctx.snapshots is not None \
            and (step + 1 - ctx.start) % max(1, ctx.snapshot_every) == 0 \
            and step + 1 < ctx.end

    def snapshot(self, step: int, save: Callable[[Path], Any] | None, **state: Any) -> None:
        """Write the actor's snapshot at the boundary of ``step`` (synchronously: the state
        must be the one at ``step``); the delta book goes with it."""
        t0 = time.perf_counter()
        book: dict[str, Any] = {}
        if self._deltas is not None:
            self._deltas.drain()
            book = {"book": snap.book_state(self._deltas.book)}
        assert self.ctx.snapshots is not None
        snap.write_snapshot(self.ctx.snapshots, self.name, step, {**book, **state}, save)
        self.snapshot_times.append(time.perf_counter() - t0)

    def oldest_snapshot(self, consumers: tuple[str, ...]) -> int:
        """The oldest latest-snapshot step among ``consumers`` (``ctx.start - 1`` if one has
        none): a writer's snapshot keeps its logged messages after it, so that a consumer
        restarted from that snapshot can fetch them even after the writer itself restarted."""
        assert self.ctx.snapshots is not None
        steps = []
        for actor in consumers:
            latest = snap.latest_snapshot(self.ctx.snapshots, actor)
            if latest is None:
                return self.ctx.start - 1
            steps.append(latest[0])
        return min(steps, default=self.ctx.start - 1)

    def result(self, **values: Any) -> dict[str, Any]:
        """The actor's result: ``values`` with its rejected messages, waits, snapshots."""
        times = self.snapshot_times
        out: dict[str, Any] = {"rejected": self.counter.snapshot().total,
                               "waits": 0 if self._deltas is None else self._deltas.book.waits,
                               **values, "snapshots": len(times),
                               "snapshot_max_s": round(max(times, default=0.0), 4)}
        if self.resume.restarted:
            out["resumed_from_step"] = self.resume.step
        refills = sum(i.refills for i, _ in self._inputs) \
            + (self._deltas.refills if self._deltas is not None else 0)
        if refills:
            out["refills"] = refills
        injected = [o.pub.faults.counts() for o in self._outputs if o.pub.faults is not None]
        if injected:
            out["injected"] = {k: sum(c[k] for c in injected) for k in ("dropped", "delayed")}
        return out

    # ------------------------------------------------------------------------- lifecycle
    def close(self) -> None:
        self._stack.close()

    def __enter__(self) -> Actor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class ActorBase:
    """Base of an actor's class (``actors/*``): it owns an :class:`Actor` and closes it when it
    is closed itself, also as a context manager. A subclass gives :meth:`step` (receive →
    algorithm → publish) and :meth:`finish`; :meth:`run` is its loop as a task of its own."""

    actor: Actor
    result: dict[str, Any] | None = None
    """The actor's result, once :meth:`finish` has run."""
    nursery: trio.Nursery
    """Where the actor's background work (a batch in a worker thread) runs during :meth:`run`;
    the loop ends when that work is done."""

    async def start(self) -> None:
        """Alive (every subscription exists); a restarted actor fetches what it missed."""
        await self.actor.start()

    async def step(self, t: int) -> bool:
        """One step of the loop; False when the run ended before step ``t``."""
        raise NotImplementedError

    async def finish(self) -> dict[str, Any]:
        """After the last step: the actor's result."""
        raise NotImplementedError

    async def run(self) -> dict[str, Any]:
        """The actor as a task of its own: :meth:`start`, every step, :meth:`finish`."""
        await self.start()
        async with trio.open_nursery() as self.nursery:
            for t in self.actor.steps():
                if not await self.step(t):
                    break
        return await self.finish()

    def close(self) -> None:
        self.actor.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


async def to_thread(fn: Callable[..., Any], *args: Any) -> Any:
    """Run a blocking call (a batch, a checkpoint) off the trio thread."""
    return await trio.to_thread.run_sync(fn, *args)
