"""Bus messages ↔ the algorithm's objects: the world's values as ``sense`` carries them,
``qstate`` ↔ :class:`Percept`, landmark deltas on perception, the world's view, the executor's
state a batch reads (``batchctx``, §6.2.1) and the agent a plan compilation reads (``planreq``,
Algorithm 2 line 15)."""

from __future__ import annotations

import base64
import json
import math
import sys
import tempfile
import threading
from pathlib import Path
from typing import Any

import numpy as np

from qlap_runtime.bus.qrecord import QRecord, encode_record, encode_rejected, names_blob
from qlap_runtime.bus.schema import BatchContext, PlanRequest, QState, Sense, WorldView
from qlap_runtime.qlap.agent import Agent
from qlap_runtime.qlap.checkpoint import learner_state, load_agent, restore_learner, save_agent
from qlap_runtime.qlap.delta import AddLandmark, Delta
from qlap_runtime.qlap.perception import MAX_ABS_VALUE, InvalidObservation, Percept, Perception
from qlap_runtime.qlap.plan_delta import PlanDelta
from qlap_runtime.qlap.quantity import Landmark
from qlap_runtime.qlap.variables import Event, VariableTable

REQUEST_FILES = ("agent.json", "agent.npz", "learner.json", "learner.npz")
"""The checkpoint files a ``planreq`` carries (``save_agent``'s, docs/checkpoint.md)."""
SCRATCH = "/dev/shm" if Path("/dev/shm").is_dir() else None
"""Where a request's files pass through (memory where the system has it)."""


def sense_values(values: dict, available_from: dict[str, int], t: int) -> tuple[dict, bool]:
    """``values`` as ``sense(t)`` can carry them, and whether the agent rejects them (a NaN,
    ±inf or |x| > ``MAX_ABS_VALUE`` of an available variable). A NaN is left out, ±inf becomes
    ±``sys.float_info.max``: the perception actor then sees what the synchronous agent sees."""
    bad = False
    out = values
    for k, v in values.items():
        try:
            if abs(v) <= MAX_ABS_VALUE:     # False on NaN: the fast path of every step
                continue
            fv = float(v)
        except (TypeError, ValueError):
            continue                        # not a number: the perception actor names it
        if out is values:
            out = dict(values)
        if math.isnan(fv):
            del out[k]
            bad = bad or t >= available_from.get(k, 0)
        else:
            if math.isinf(fv):
                out[k] = math.copysign(sys.float_info.max, fv)
            bad = True
    return out, bad


class SenseCodec:
    """``sense(t)`` messages of one world (:func:`sense_values`), counting those the agent
    rejects."""

    def __init__(self, variables: Any) -> None:
        self.available = {v.name: int(getattr(v, "available_from", 0) or 0) for v in variables}
        self.rejected = 0

    def message(self, t: int, obs: dict, applied: dict, discontinuity: bool) -> Sense:
        values, bad = sense_values({**obs, **applied}, self.available, t)
        self.rejected += bad
        return Sense(t, values, discontinuity)


def rejection_as_sent(per: Perception, t: int, msg: Any,
                      exc: InvalidObservation) -> InvalidObservation:
    """The reason the synchronous agent gives for rejecting ``sense(t)``: ±inf travels as ±float
    max (:func:`sense_values`), so the rejection is checked again with them restored (the state
    is unchanged by a rejected observation)."""
    try:
        x = per.vector(msg.values)
    except InvalidObservation:                  # an unknown name, a value not a number
        return exc
    huge = np.abs(x) == sys.float_info.max
    if not huge.any():
        return exc
    x[huge] = np.copysign(np.inf, x[huge])
    try:
        per.perceive(t, x, copy=False, discontinuity=msg.discontinuity)
    except InvalidObservation as again:
        return again
    return exc


def apply_landmark_ops(per: Perception, deltas: list) -> None:
    """Mirror the learner's landmark additions (the only ops that change perception)."""
    for delta in deltas:
        for op in delta.ops:
            if isinstance(op, AddLandmark):
                space = per.spaces[int(op.var)]
                if space.landmarks and space.interval_of_range(float(op.lb),
                                                               float(op.ub)) is None:
                    continue                     # the learner skips it too
                per.add_landmark(int(op.var), Landmark(float(op.lb), float(op.ub), int(op.step),
                                                       op.source))


def world_view(world: Any, name: str, t: int, obs: dict, applied: dict) -> WorldView:
    """The UI's world panel: the world drawn as text, its finite values and the motors."""
    return WorldView(t, str(getattr(world, "name", name)), world.render_text(44, 14),
                     {k: float(v) for k, v in obs.items() if math.isfinite(v)}, applied, {})


class QStateCodec:
    """``qstate`` messages of one variable table: names in table order, built once; the
    perception actor writes binary records (:meth:`record`, docs/decisions.md 98), a consumer
    takes those or JSON messages (:meth:`percept`)."""

    def __init__(self, table: VariableTable) -> None:
        self.names = tuple(v.name for v in sorted(table, key=lambda v: v.index))
        self.index = {name: i for i, name in enumerate(self.names)}
        self.blob = names_blob(self.names)

    def record(self, p: Percept) -> QRecord:
        """The perception actor's record of a percept: its arrays as they are."""
        return encode_record(p.step, self.blob, p.x, p.q, p.events, p.discontinuity)

    @staticmethod
    def rejected(t: int, reason: str) -> QRecord:
        """The record of a rejected step t."""
        return encode_rejected(t, reason)

    def message(self, p: Percept) -> QState:
        """The perception actor's message of a percept (a NaN: not yet known, left out)."""
        names = self.names
        x = {k: v for k, v in zip(names, p.x.tolist(), strict=True) if v == v}
        q = {k: v for k, v in zip(names, p.q.tolist(), strict=True) if v >= 0}
        events = tuple((names[e.var], int(e.value), int(e.direction)) for e in p.events)
        return QState(p.step, q, events, x, discontinuity=p.discontinuity)

    def percept(self, msg: QState | QRecord) -> Percept:
        """The perception actor's :class:`Percept`, rebuilt from its message: a record's arrays
        as they are (read-only; its names are the table's, ``qstate_rule`` checked them)."""
        if type(msg) is QRecord:
            events = tuple(Event(v, val, d) for v, val, d in msg.events.tolist())
            return Percept(msg.step, msg.x, msg.q, events, _NO_IDS, msg.discontinuity)
        index = self.index
        x = self._vector(msg.x, np.nan, float)
        q = self._vector(msg.values, -1, np.int64)
        events = tuple(Event(index[name], int(v), int(d)) for name, v, d in msg.events)
        return Percept(msg.step, x, q, events, np.zeros(0, dtype=np.int64), msg.discontinuity)

    def _vector(self, by_name: dict, missing: Any, dtype: Any) -> np.ndarray:
        """``by_name`` in table order; absent names get ``missing``. The common case (every
        variable, in table order, as :meth:`message` writes them) is one C-level conversion;
        otherwise each name is placed by index (an unknown name raises KeyError)."""
        names = self.names
        if len(by_name) == len(names) and tuple(by_name) == names:
            return np.fromiter(by_name.values(), dtype=dtype, count=len(names))
        out = np.full(len(names), missing, dtype=dtype)
        if by_name:
            out[[self.index[k] for k in by_name]] = list(by_name.values())
        return out


_NO_IDS = np.zeros(0, dtype=np.int64)


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


class ArrayPool:
    """Buffers, touched before the clock starts, for the large arrays a realtime request
    copies on the world's tick (docs/decisions.md 103). A fresh array of megabytes faults its
    pages in as the copy writes it, and on this VM that once took 48 ms for the perception's
    5.4 MB history at step 4,000 (four missed ticks at 100 Hz; 0.7–2.9 ms in the other runs).
    An array of at least ``MIN_BYTES`` is copied into a buffer of its shape taken from the
    pool (a fresh one if none is free); :meth:`give_back` returns the buffers once the
    planner's thread has rebuilt the learner, which copies every array it reads
    (:func:`~qlap_runtime.qlap.checkpoint.restore_learner`)."""

    MIN_BYTES = 1 << 18
    KEEP = 2
    """Free buffers kept per shape (a request is taken long before the next is made)."""

    def __init__(self) -> None:
        self.free: dict[tuple, list[np.ndarray]] = {}
        self.lock = threading.Lock()

    @staticmethod
    def _key(a: np.ndarray) -> tuple:
        return a.shape, a.dtype.str

    def prepare(self, arrays: dict[str, np.ndarray]) -> int:
        """Touch a buffer for every large array of ``arrays``; returns how many bytes."""
        touched = 0
        for a in arrays.values():
            if a.nbytes >= self.MIN_BYTES:
                buf = np.empty_like(a)
                np.copyto(buf, a)                   # every page written: resident now
                self.give_back([buf])
                touched += a.nbytes
        return touched

    def copy(self, a: np.ndarray) -> np.ndarray:
        """A copy of ``a``: in a pooled buffer when ``a`` is large."""
        if a.nbytes < self.MIN_BYTES:
            return a.copy()
        with self.lock:
            bufs = self.free.get(self._key(a))
            buf = bufs.pop() if bufs else None
        if buf is None:
            return a.copy()
        np.copyto(buf, a)
        return buf

    def give_back(self, arrays: Any) -> None:
        """Return the large arrays among ``arrays`` (no longer read by anyone) to the pool."""
        with self.lock:
            for a in arrays:
                if a.nbytes >= self.MIN_BYTES and a.base is None and a.flags.c_contiguous:
                    bufs = self.free.setdefault(self._key(a), [])
                    if len(bufs) < self.KEEP:
                        bufs.append(a)


class LocalRequests:
    """The embedded placement's ``planreq``: the executor and the planner share a process, so
    the request hands over a private copy of the agent (:meth:`Agent.planning_copy`, deep: the
    executor goes on while the planner compiles) instead of its files; the message only says
    so (``local``), and stays in the replay log like any other. ``light`` (the realtime
    clock): the learner goes as its checkpoint state, taken in a few ms on the world's tick
    (its large arrays copied into :class:`ArrayPool` buffers touched at start-up,
    :meth:`prepare`) and rebuilt by :meth:`take` in the planner's thread (docs/decisions.md
    82, 103). ``batch``: the learners' copy of the same state, handed to their batch in this
    process, which applies the batch's operations to it as it computes (what the synchronous
    loop's ``take_batch`` gives): the compilation runs on it once the batch's deltas are out,
    without a second copy on the step chain (docs/decisions.md 86)."""

    def __init__(self) -> None:
        self.agents: dict[tuple[str, int], tuple[Agent, Any]] = {}
        self.lock = threading.Lock()
        self.pool = ArrayPool()

    def prepare(self, learner: Any) -> int:
        """Before a realtime run's clock starts: buffers for the light requests' large arrays
        (:class:`ArrayPool`); returns the bytes touched."""
        return self.pool.prepare(learner_state(learner)[1])

    def put(self, run_id: str, agent: Agent, step: int, light: bool = False,
            batch: Any = None) -> PlanRequest:
        state: Any
        if light:
            meta, arrays = learner_state(agent.learner)
            state = (json.loads(json.dumps(meta)),
                     {k: self.pool.copy(v) for k, v in arrays.items()})
            copy = agent.planning_copy(agent.learner, deep=True)    # its learner: take's
        elif batch is not None:
            state, copy = BATCHED, agent.planning_copy(batch, deep=True)
        else:
            state, copy = None, agent.planning_copy(agent.learner.batch_copy(), deep=True)
        with self.lock:
            self.agents[(run_id, step)] = (copy, state)
        return PlanRequest(step, local=True)

    def take(self, run_id: str, step: int) -> tuple[Agent, bool]:
        """The request's agent, and whether its learner holds the batch's deltas already."""
        with self.lock:
            held = self.agents.pop((run_id, step), None)
        if held is None:
            raise BadRequest(f"no agent was handed over in this process for step {step}")
        copy, state = held
        if state is BATCHED:
            return copy, True
        if state is not None:
            copy.learner = restore_learner(*state)
            self.pool.give_back(state[1].values())      # the learner copied what it reads
        return copy, False


class BadRequest(ValueError):
    """A ``planreq`` that names no agent: files that are not base64 or not an agent's
    checkpoint, or a local request with nothing handed over (a forged or damaged message)."""


BATCHED = object()
"""A local request's mark: its learner is the learners' batch copy (:class:`LocalRequests`)."""


LOCAL = LocalRequests()


def plan_request(agent: Agent, step: int) -> PlanRequest:
    """``planreq(step)``: the executor's agent as a checkpoint (no pickle), for the planner."""
    with tempfile.TemporaryDirectory(prefix="qlap-planreq-", dir=SCRATCH) as tmp:
        save_agent(agent, tmp, fast=True)
        files = {name: base64.b64encode((Path(tmp) / name).read_bytes()).decode()
                 for name in REQUEST_FILES}
    return PlanRequest(step, files)


def compile_request(msg: PlanRequest, deltas: list[Delta], lag: int,
                    run_id: str = "") -> PlanDelta:
    """The planner's work: the request's agent, the batch's ``deltas`` applied to its learner,
    compiled (:meth:`~qlap_runtime.qlap.agent.Agent.compile_plans`). :class:`BadRequest` (before
    anything is compiled) when the request holds no agent."""
    applied = False
    if msg.local:
        agent, applied = LOCAL.take(run_id, msg.step)
    else:
        with tempfile.TemporaryDirectory(prefix="qlap-planreq-", dir=SCRATCH) as tmp:
            try:
                for name in REQUEST_FILES:
                    (Path(tmp) / name).write_bytes(base64.b64decode(msg.files[name],
                                                                    validate=True))
                agent = load_agent(tmp)
            except (ValueError, KeyError) as e:     # binascii.Error, CheckpointError
                raise BadRequest(f"planreq({msg.step}): {type(e).__name__}: {e}") from None
    for d in () if applied else deltas:
        agent.learner.apply_delta(d)
    return agent.compile_plans(msg.step, msg.step + lag)
