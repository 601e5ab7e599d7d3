"""What every actor shares: its run context, step-indexed inboxes and the delta inbox."""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import Awaitable, Callable, Iterator
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trio

from qlap_runtime.bus import keys
from qlap_runtime.bus.bridge import RejectionCounter, TrioSubscriber
from qlap_runtime.bus.replay import fetch_replay
from qlap_runtime.bus.schema import BatchContext, Control, DeltaMsg, QState
from qlap_runtime.qlap.params import Params
from qlap_runtime.qlap.perception import Percept
from qlap_runtime.qlap.variables import Event, VariableTable
from qlap_runtime.runtime import snapshot as snap
from qlap_runtime.runtime.lockstep import DeltaBook
from qlap_runtime.runtime.watchdog import Slot

log = logging.getLogger("qlap.actors")


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
    board: Any = field(default=None, repr=False, compare=False)
    """The run's progress board (:mod:`~qlap_runtime.runtime.watchdog`), set by the launcher
    in each process; not part of the JSON form."""

    @property
    def realtime(self) -> bool:
        """The realtime clock (``extra["clock"] == "realtime"``, rate ``extra["hz"]``)."""
        return self.extra.get("clock") == "realtime"

    @property
    def start(self) -> int:
        """The first step of the run (``extra["start_step"]``, 0 by default)."""
        return int(self.extra.get("start_step", 0))

    @property
    def snapshot_dir(self) -> Path | None:
        """Where actors write their snapshots (``extra["snapshot_dir"]``, set by the processes
        launcher); None: no snapshots (the embedded placement, or the realtime clock, whose
        state is not a function of the input stream)."""
        d = self.extra.get("snapshot_dir")
        return None if d is None or self.realtime else Path(d)

    @property
    def snapshot_every(self) -> int:
        return max(1, int(self.extra.get("snapshot_every", snap.DEFAULT_EVERY)))

    @property
    def replay_keep(self) -> int:
        """Steps a writer keeps in its replay logs: enough for a consumer whose snapshot is up
        to two periods old and that died just before a landmark batch was due."""
        if "replay_keep" in self.extra:
            return int(self.extra["replay_keep"])
        p = self.params
        return 2 * self.snapshot_every + max(p.landmark_period, p.dbn_period) \
            + 2 * p.batch_lag + 100

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


MAX_PENDING_BYTES = 64 * 2**20
"""Per inbox: the payload bytes of messages received for later steps that may wait there. A
run's own messages never come near it (a core2d ``qstate`` is ~0.5 kB and the window a few
thousand steps); a sender flooding valid far-future messages is rejected beyond it."""

REFILL_AFTER_S = 1.0
"""A restarted actor waiting this long for a step while later steps are buffered asks the
writer's replay log again (a message put while its subscription was still propagating)."""


class StepInbox:
    """Messages of one topic, indexed by step; ``await get(t)`` returns step t's message.

    Steps below the next one expected are dropped: a writer restarted from a snapshot publishes
    again the steps after its snapshot, which this consumer may already have consumed.
    ``refill(step)`` (a restarted actor's fetch from the writer's replay log) fills gaps.

    Rules (docs/runtime.md, "Rules on messages"): a live message more than ``window`` steps
    after the next step expected (or the last one fetched from a replay log) is outside the
    lockstep window; ``rule(msg)`` returns why a message cannot be one of the run's; the payload
    bytes waiting are bounded by ``MAX_PENDING_BYTES``. Such messages are counted and logged by
    ``counter`` on ``key`` and dropped.
    """

    def __init__(self, sub: TrioSubscriber, first: int = 0,
                 refill: Callable[[int], Awaitable[list]] | None = None,
                 end: Controls | None = None, slot: Slot | None = None,
                 topic: str = "", *, counter: RejectionCounter | None = None, key: str = "",
                 window: int | None = None,
                 rule: Callable[[Any], str | None] | None = None) -> None:
        self.sub = sub
        self.counter = counter if counter is not None else RejectionCounter()
        self.key = key or topic
        self.window = window
        self.rule = rule
        self.high = -1
        """The last step fetched from a replay log (a restarted actor's window starts there)."""
        self.sizes: dict[int, int] = {}
        self.pending_bytes = 0
        self.slot = slot if slot is not None else Slot()
        """Where a wait is reported for the watchdog (:mod:`~qlap_runtime.runtime.watchdog`)."""
        self.topic = topic
        self.buf: dict[int, Any] = {}
        self.next = first
        self.refill = refill
        self.end = end
        """The run's controls: :meth:`get` raises :class:`RunEnded` for a step after the last
        one the world announced (``quit``)."""
        self.duplicates = 0
        """Messages dropped because their step was already consumed."""

    def add(self, msg: Any, size: int = 0, live: bool = True) -> bool:
        """Keep ``msg`` for its step (``size``: its payload bytes; ``live``: from the
        subscription, not a replay log); False if it was dropped."""
        step = msg.step
        if self.rule is not None:                   # first: a forgery is always counted
            why = self.rule(msg)
            if why is not None:
                return self._reject(why)
        if step < self.next:
            self.duplicates += 1
            return False
        if live:
            if self.window is not None and step > max(self.next, self.high) + self.window:
                return self._reject(f"step {step} outside the lockstep window (next "
                                    f"{self.next}, window {self.window})")
            if self.pending_bytes + size - self.sizes.get(step, 0) > MAX_PENDING_BYTES:
                return self._reject(f"step {step}: more than {MAX_PENDING_BYTES} bytes of "
                                    "messages for later steps pending")
        self.pending_bytes += size - self.sizes.get(step, 0)
        self.sizes[step] = size
        self.buf[step] = msg
        if not live:
            self.high = max(self.high, step)
        return True

    def _reject(self, reason: str) -> bool:
        self.counter.reject(self.key, reason)
        return False

    def drop(self, step: int) -> None:
        """Forget the message of ``step`` (not to be consumed)."""
        self.buf.pop(step, None)
        self.pending_bytes -= self.sizes.pop(step, 0)

    async def get(self, step: int, at: int | None = None) -> Any:
        """Step ``step``'s message (waited for; the wait is on the board, before passing step
        ``at``, by default ``step``)."""
        if step not in self.buf:
            with self.slot.waiting(self.topic, step, at):
                await self._wait_for(step)
        self.next = max(self.next, step + 1)
        self.pending_bytes -= self.sizes.pop(step, 0)
        return self.buf.pop(step)

    async def _wait_for(self, step: int) -> None:
        while step not in self.buf:
            end = self.end
            if end is not None and end.ended(step):
                raise RunEnded(end.last_step)       # type: ignore[arg-type]
            batch: list = []
            with end.interruptible() if end is not None else nullcontext():
                if self.refill is None:
                    batch = await self.sub.receive_batch()
                else:
                    with trio.move_on_after(REFILL_AFTER_S):
                        batch = await self.sub.receive_batch()
            # A restarted actor idle for REFILL_AFTER_S asks the replay log again: a gap, or
            # a writer that was itself restarting when this actor first asked (chaos trials).
            if self.refill is not None and not batch and not (end and end.ended(step)):
                for msg in await self.refill(step):
                    self.add(msg, live=False)
            for r in batch:
                self.add(r.msg, len(r.payload))

    async def fill_from_replay(self, refill: Callable[[int], Awaitable[list]]) -> int:
        """Add the writer's logged messages from :attr:`next` on (a restarted consumer, after
        subscribing); keep ``refill`` for gaps; return how many were added."""
        self.refill = refill
        msgs = await refill(self.next)
        for msg in msgs:
            self.add(msg, live=False)
        return len(msgs)


class RunEnded(Exception):
    """The world ended the run early (``quit``): there is no step after :attr:`last_step`."""

    def __init__(self, last_step: int) -> None:
        super().__init__(f"the run ended after step {last_step}")
        self.last_step = last_step


class ControlError(ValueError):
    """A control command whose arguments are malformed (counted as a rejected message)."""


class Controls:
    """The run's ``control`` topic (``qlap/<run>/control``), delivered on the actor's trio loop.

    The Zenoh callback only schedules :meth:`_deliver` with ``run_sync_soon`` (thread-safe, in
    arrival order); decoding happens there, on the trio thread, where a malformed message is
    counted by the actor's :class:`RejectionCounter` and dropped. Controls of another run never
    arrive: the key carries the run id. Create inside trio.

    - ``pending`` / :meth:`take` / :meth:`wait`: the commands, for the actors that obey them
      (world, executor); ``keep=False`` keeps none (the other actors only need the end).
    - The world's end marker, ``quit {"last_step": T}``, sets :attr:`last_step` and interrupts
      every :meth:`interruptible` wait (a :class:`StepInbox` waiting for a step after T), so
      that every actor finishes its loop after step T and writes its outputs.
    """

    def __init__(self, session: Any, ctx: RunContext, counter: RejectionCounter,
                 keep: bool = True) -> None:
        self.key = keys.key(ctx.run_id, "control")
        self.counter = counter
        self.keep = keep
        self.pending: deque[Control] = deque()
        self.last_step: int | None = None
        self.received = 0
        self._event = trio.Event()
        self._scopes: set[trio.CancelScope] = set()
        self._token = trio.lowlevel.current_trio_token()
        self._sub = session.declare_subscriber(self.key, self._on_sample)

    def _on_sample(self, sample: Any) -> None:
        # A Zenoh thread (or the putting thread, same session): no actor state here.
        try:
            self._token.run_sync_soon(self._deliver, str(sample.key_expr),
                                      sample.payload.to_bytes())
        except trio.RunFinishedError:
            pass                                    # the actor's trio run is over
        except Exception:                           # pragma: no cover - never into Zenoh
            log.exception("control callback failed on %s", self.key)

    def _deliver(self, key_expr: str, payload: bytes) -> None:
        self.received += 1
        msg = self.counter.decode(key_expr, payload)
        if not isinstance(msg, Control):
            return
        if msg.command == "quit" and "last_step" in msg.args:
            last = msg.args["last_step"]
            if type(last) is not int:
                self.counter.reject(key_expr, f"quit: last_step must be an integer, got "
                                              f"{last!r}")
                return
            self.last_step = last if self.last_step is None else min(self.last_step, last)
            for scope in list(self._scopes):
                scope.cancel()
        if self.keep:
            self.pending.append(msg)
        self._event.set()
        self._event = trio.Event()

    def take(self) -> list[Control]:
        """The commands received since the last call, oldest first."""
        out = list(self.pending)
        self.pending.clear()
        return out

    async def wait(self) -> None:
        """Return when a command is pending (at once if one already is)."""
        if not self.pending:
            await self._event.wait()

    def ended(self, step: int) -> bool:
        """True when ``step`` lies after the run's announced last step."""
        return self.last_step is not None and step > self.last_step

    @contextmanager
    def interruptible(self) -> Iterator[trio.CancelScope]:
        """A cancel scope that the end marker cancels (wrap a wait for the next step)."""
        with trio.CancelScope() as scope:
            self._scopes.add(scope)
            try:
                yield scope
            finally:
                self._scopes.discard(scope)

    def close(self) -> None:
        try:
            self._sub.undeclare()
        except Exception:  # pragma: no cover - session already closed
            pass

    def __enter__(self) -> Controls:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


MIN_SPEED, MAX_SPEED = 0.01, 1e6
"""The range a positive ``speed`` is clamped to (steps/s)."""


@dataclass
class RunControl:
    """The clock commands — ``pause``, ``resume``, ``step``, ``speed``, ``quit`` — with the
    semantics of ``tui/driver.py``. The world obeys this state; the executor applies the same
    control stream to its own copy, so its status reports the world's pause and speed without
    asking it.

    ``default_speed`` is what ``speed 0`` means: 0 (as fast as possible) in lockstep, the
    configured tick rate under the realtime clock (where "as fast as possible" has no
    meaning: the world would never wait for a motor command).
    """

    paused: bool = False
    budget: int = 0
    """Steps still to take while paused (``step {"n": k}``)."""
    speed: float = 0.0
    """Steps/s: lockstep pace (0 = free) or realtime tick rate."""
    default_speed: float = 0.0
    quit: bool = False
    message: str = ""
    """The answer to the last command (``AgentStatus.message``)."""

    def apply(self, c: Control) -> bool:
        """Apply a clock command; False for the others (goal, save). Raises
        :class:`ControlError` for malformed arguments (the state is left as it was)."""
        a = c.args
        if c.command == "pause":
            self.paused, self.budget, self.message = True, 0, "paused"
        elif c.command == "resume":
            self.paused, self.budget, self.message = False, 0, "resumed"
        elif c.command == "step":
            n = max(1, _number(a, "n", 1, int))
            self.paused = True
            self.budget += n
            self.message = f"step {self.budget}"
        elif c.command == "speed":
            x = max(0.0, _number(a, "steps_per_s", 0.0, float))
            self.speed = min(max(x, MIN_SPEED), MAX_SPEED) if x > 0 else self.default_speed
            self.message = f"speed {self.speed:g} steps/s" if self.speed else "speed: free"
        elif c.command == "quit":
            self.quit = True
            last = a.get("last_step")
            self.message = "quit" if last is None else f"run ended after step {last}"
        else:
            return False
        return True

    @property
    def may_step(self) -> bool:
        """Whether the world may take its next step now."""
        return not self.quit and (not self.paused or self.budget > 0)

    def stepped(self) -> None:
        """One step was taken (uses up the single-step budget while paused)."""
        if self.budget > 0:
            self.budget -= 1


def _number(args: dict[str, Any], name: str, default: Any, kind: type) -> Any:
    """``args[name]`` as ``kind`` (int or float); bool, strings, lists... are malformed."""
    v = args.get(name, default)
    if type(v) not in (int, float) or (kind is int and v != int(v)):
        raise ControlError(f"{name} must be a{'n integer' if kind is int else ' number'}, "
                           f"got {v!r}")
    return kind(v)


class DeltaInbox:
    """Receives ``delta/*`` and hands out those due at a step, in apply order.

    A delta whose turn has passed (already applied here) is ignored: a learner restarted from a
    snapshot recomputes and publishes again the batches after its snapshot.
    """

    def __init__(self, session: Any, ctx: RunContext, counter: RejectionCounter,
                 slot: Slot | None = None, n_vars: int | None = None) -> None:
        from .rules import delta_rule

        self.book = DeltaBook(ctx.params)
        self.slot = slot if slot is not None else Slot()
        self.counter = counter
        self.keys = {k: keys.key(ctx.run_id, f"delta/{k}") for k in ("dbn", "landmarks")}
        self.rule = None if n_vars is None else delta_rule(ctx.params, n_vars, ctx.realtime)
        self.window = None if ctx.realtime else ctx.replay_keep
        self.start = ctx.start
        self.sizes: dict[tuple[int, str], int] = {}
        self.pending_bytes = 0
        self.sub = TrioSubscriber(session, f"{keys.ROOT}/{ctx.run_id}/delta/*", counter=counter)
        self.wait_s = 0.0
        self.realtime = ctx.realtime
        self.stale = 0
        self.refill: Callable[[], Awaitable[list]] | None = None
        """Set for a restarted actor (:meth:`catch_up`): fetch the delta logs again."""

    def add(self, msg: DeltaMsg, size: int = 0, live: bool = True) -> None:
        """Keep a delta until it is due (counted and dropped if it breaks a rule)."""
        if msg.kind not in ("dbn", "landmarks"):
            return
        if self.rule is not None:                   # first: a forgery is always counted
            why = self.rule(msg)
            if why is not None:
                self.counter.reject(self.keys[msg.kind], why)
                return
        at = msg.delta["computed_at"]
        lag = 0 if self.realtime else self.book.params.batch_lag
        done = at + lag                             # the step at whose boundary it applies
        if done <= self.book.last:
            self.stale += 1
            return
        key = (at, msg.kind)
        if live and self.window is not None \
                and at > max(self.book.last, self.start - 1) + self.window:
            self.counter.reject(self.keys[msg.kind],
                                f"delta/{msg.kind} computed at {at}: outside the "
                                f"lockstep window (last applied step "
                                f"{self.book.last}, window {self.window})")
            return
        if live and self.pending_bytes + size - self.sizes.get(key, 0) > MAX_PENDING_BYTES:
            self.counter.reject(self.keys[msg.kind],
                                f"delta/{msg.kind} computed at {at}: more than "
                                f"{MAX_PENDING_BYTES} bytes of deltas pending")
            return
        self.pending_bytes += size - self.sizes.get(key, 0)
        self.sizes[key] = size
        self.book.add(msg.kind, msg.to_delta())

    def _popped(self, deltas: list) -> list:
        for d in deltas:
            for kind in ("dbn", "landmarks"):
                self.pending_bytes -= self.sizes.pop((d.computed_at, kind), 0)
        return deltas

    def _take(self, batch) -> None:
        for r in batch:
            self.add(r.msg, len(r.payload))

    async def catch_up(self, session: Any, ctx: RunContext, counter: RejectionCounter) -> int:
        """A restarted actor: add every delta the learners' replay logs hold (after
        subscribing, so none published meanwhile is lost); return how many came back."""
        async def refill() -> list:
            return await fetch_replay(session, ctx.run_id, "delta/*", 0, counter=counter)

        self.refill = refill
        msgs = await refill()
        for msg in msgs:
            self.add(msg, live=False)
        return len(msgs)

    async def due(self, step: int) -> list:
        self._take(self.sub.receive_nowait())
        if not self.book.ready(step):
            self.book.waits += 1
            t0 = time.perf_counter()
            while not self.book.ready(step):
                computed, kind = self.book.missing(step)[0]
                with self.slot.waiting(f"delta/{kind}", computed, step):
                    if self.refill is None:
                        self._take(await self.sub.receive_batch())
                        continue
                    # Restarted: idle for REFILL_AFTER_S, ask the learners' replay logs
                    # again (a learner that was itself restarting when this actor asked).
                    batch: list = []
                    with trio.move_on_after(REFILL_AFTER_S):
                        batch = await self.sub.receive_batch()
                    self._take(batch)
                    if not batch:
                        for msg in await self.refill():
                            self.add(msg, live=False)
            self.wait_s += time.perf_counter() - t0
        return self._popped(self.book.pop_due(step))

    async def due_now(self, step: int, realtime: bool) -> list:
        """Lockstep: :meth:`due` (waits). Realtime: what has arrived, applied on arrival."""
        if not realtime:
            return await self.due(step)
        self._take(self.sub.receive_nowait())
        return self._popped(self.book.arrived_prefix(step))

    def close(self) -> None:
        self.sub.close()


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

    @classmethod
    def of(cls, ctx: RunContext, actor: str) -> Resume:
        if not ctx.extra.get("restarted"):
            return cls(ctx.start - 1)
        path = ctx.extra.get("resume_from")
        if not path:
            return cls(ctx.start - 1, restarted=True)
        step, state = snap.read_snapshot(Path(path), actor)
        log.info("%s: resuming from the snapshot at step %d", actor, step)
        return cls(step, Path(path), state, True)


async def resume_inputs(session: Any, ctx: RunContext, resume: Resume, inbox: StepInbox,
                        topic: str, deltas: DeltaInbox | None,
                        counter: RejectionCounter) -> None:
    """A restarted actor, once subscribed: restore its delta book and fetch what it missed
    (its input topic from the step after its snapshot, and the deltas in the logs)."""
    if not resume.restarted:
        return
    if deltas is not None and "book" in resume.state:
        snap.restore_book(deltas.book, resume.state["book"])

    async def refill(step: int) -> list:
        return await fetch_replay(session, ctx.run_id, topic, step, counter=counter)

    got = await inbox.fill_from_replay(refill)
    if deltas is not None:
        await deltas.catch_up(session, ctx, counter)
    first = resume.step + 1
    if got and first < ctx.start + ctx.steps and first not in inbox.buf:
        raise RuntimeError(f"cannot resume at step {first}: the {topic} replay log starts at "
                           f"step {min(inbox.buf)}")


def oldest_consumer_snapshot(ctx: RunContext, consumers: tuple[str, ...]) -> int:
    """The oldest latest-snapshot step among ``consumers`` (``ctx.start - 1`` if one has
    none): a writer's snapshot keeps its logged messages after it, so that a consumer
    restarted from that snapshot can fetch them even after the writer itself restarted."""
    assert ctx.snapshot_dir is not None
    steps = []
    for actor in consumers:
        latest = snap.latest_snapshot(ctx.snapshot_dir, actor)
        if latest is None:
            return ctx.start - 1
        steps.append(latest[0])
    return min(steps, default=ctx.start - 1)


def snapshot_due(ctx: RunContext, step: int) -> bool:
    """True when an actor writes a snapshot at the boundary of ``step``."""
    return ctx.snapshot_dir is not None and (step + 1 - ctx.start) % ctx.snapshot_every == 0 \
        and step + 1 < ctx.start + ctx.steps


def write_snapshot(ctx: RunContext, actor: str, step: int, deltas: DeltaInbox,
                   save: Callable[[Path], Any] | None, **state: Any) -> float:
    """Write the actor's snapshot at the boundary of ``step`` (synchronously: the state must
    be the one at ``step``); returns the seconds it took."""
    t0 = time.perf_counter()
    deltas._take(deltas.sub.receive_nowait())
    assert ctx.snapshot_dir is not None
    snap.write_snapshot(ctx.snapshot_dir, actor, step,
                        {"book": snap.book_state(deltas.book), **state}, save)
    return time.perf_counter() - t0


def snapshot_stats(times: list[float], resume: Resume) -> dict[str, Any]:
    """What an actor's result says about its snapshots and its restart."""
    out: dict[str, Any] = {"snapshots": len(times),
                           "snapshot_max_s": round(max(times, default=0.0), 4)}
    if resume.restarted:
        out["resumed_from_step"] = resume.step
    return out


def percept_from_qstate(msg: QState, table: VariableTable) -> Percept:
    """Rebuild the perception actor's :class:`Percept` from its message."""
    names, index = _names(table)
    x = _vector(msg.x, names, index, np.nan, float)
    q = _vector(msg.values, names, index, -1, np.int64)
    events = tuple(Event(index[name], int(v), int(d)) for name, v, d in msg.events)
    return Percept(msg.step, x, q, events, np.zeros(0, dtype=np.int64), msg.discontinuity)


def _vector(by_name: dict, names: tuple[str, ...], index: dict[str, int], missing: Any,
            dtype: Any) -> np.ndarray:
    """``by_name`` as a vector in table order; absent names get ``missing``.

    The common case (every variable present, in table order, as :func:`qstate_of` writes
    them) is one C-level conversion; otherwise each name is placed by index (an unknown name
    raises KeyError)."""
    if len(by_name) == len(names) and tuple(by_name) == names:
        return np.fromiter(by_name.values(), dtype=dtype, count=len(names))
    out = np.full(len(names), missing, dtype=dtype)
    if by_name:
        out[[index[k] for k in by_name]] = list(by_name.values())
    return out


def _names(table: VariableTable) -> tuple[tuple[str, ...], dict[str, int]]:
    """(names in table order, name -> index), kept on the table."""
    cached = getattr(table, "_names_cache", None)
    if cached is None or len(cached[0]) != len(table):
        names = tuple(v.name for v in sorted(table, key=lambda v: v.index))
        cached = (names, {name: i for i, name in enumerate(names)})
        table._names_cache = cached  # type: ignore[attr-defined]
    return cached


def batch_context(agent: Any, step: int) -> BatchContext:
    """What the batch after ``step`` reads of the executor's agent (§6.2.1): the sufficiently
    reliable actions and the DBNs that are plans."""
    learner = agent.learner
    return BatchContext(step, tuple(sorted((int(v), int(q))
                                           for v, q in learner.reliable_actions)),
                        tuple(sorted(int(i) for i, d in learner.dbns.items() if d.is_plan)))


def apply_batch_context(learner: Any, msg: BatchContext) -> None:
    """Give a batch actor's learner the executor's state that its next batch reads, as the
    synchronous loop's learner has it (the agent sets it there)."""
    learner.reliable_actions = {(v, q) for v, q in msg.reliable_actions}
    plans = set(msg.plan_dbns)
    for dbn_id, dbn in learner.dbns.items():
        dbn.is_plan = dbn_id in plans


def qstate_of(p: Percept, table: VariableTable) -> QState:
    names, _ = _names(table)
    xs = p.x.tolist()
    qs = p.q.tolist()
    x = {k: v for k, v in zip(names, xs, strict=True) if v == v}          # NaN: not yet known
    q = {k: v for k, v in zip(names, qs, strict=True) if v >= 0}
    events = tuple((names[e.var], int(e.value), int(e.direction)) for e in p.events)
    return QState(p.step, q, events, x, discontinuity=p.discontinuity)


async def checkpoint_async(fn, *args) -> None:
    """Run a (blocking) checkpoint write off the trio thread."""
    await trio.to_thread.run_sync(fn, *args)
