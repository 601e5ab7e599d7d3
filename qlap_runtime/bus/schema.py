"""Every message that crosses the bus, in one module (docs/architecture.md §1 rule 5; docs/bus.md).

A message is a frozen dataclass with a docstring under each field and a ``version`` field (the
schema version of its type, checked on decode). The topic of the key expression says which type
a payload must be (:data:`TOPIC_TYPES`), so no type tag travels.

Wire format: compact UTF-8 JSON object, one key per field, no NaN or infinity (orjson, strict
JSON). Sequences are JSON arrays and decode to tuples; ``float`` fields accept JSON integers.
:func:`decode` validates everything (JSON syntax, object shape, required and unknown fields,
every field's type, finite numbers, the version, per-type rules) and raises
:class:`MessageError` carrying the key expression. :func:`json_schema` gives the JSON Schema
(draft 2020-12) of each type, used as the MCAP schema by the recorder. No pickle. One
exception: ``qstate`` may also be a binary record of arrays (:mod:`.qrecord`, the perception
actor's, docs/decisions.md 98), which the recorder and ``echo`` write as its JSON message.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import itertools
import json
import math
import textwrap
import types
import typing
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cache, lru_cache
from typing import Any, Literal

import orjson

from ..qlap.delta import Delta
from ..qlap.plan_delta import PlanDelta
from . import keys
from .qrecord import QRecord, RecordError, decode_record, is_record

JSON = Any
"""A JSON value (null, bool, number, string, array, object) with finite numbers."""


class MessageError(ValueError):
    """A payload that is not a valid message for its key expression."""

    def __init__(self, key_expr: str, reason: str) -> None:
        super().__init__(f"{key_expr}: {reason}")
        self.key_expr = key_expr
        self.reason = reason


# --------------------------------------------------------------------------- messages


@dataclass(frozen=True)
class Sense:
    """``sense(t)``: the world's raw observation at step t (topic ``sense``)."""

    step: int
    """Agent step t (0, 1, ...)."""
    values: dict[str, float]
    """Raw real value of every observed variable, by variable name."""
    discontinuity: bool = False
    """The world jumped since step t − 1 (``World.discontinuity``: a replaced block, a new
    trial); no derivative or event spans it."""
    version: int = 1
    """Schema version of this message type."""


@dataclass(frozen=True)
class QState:
    """``qstate(t)``: the qualitative state and events at step t (topic ``qstate``)."""

    step: int
    """Agent step t."""
    values: dict[str, int]
    """Qualitative value (index into the variable's quantity space) by variable name."""
    events: tuple[tuple[str, int, int], ...] = ()
    """Events X → x at t as (variable name, qualitative value, direction); direction is +1
    for ↑, −1 for ↓ on magnitudes, else 0 (§3.2)."""
    x: dict[str, float] = dataclasses.field(default_factory=dict)
    """Real values at t by variable name, the directions of change (``<name>.dot``) included;
    variables not yet available are absent. The learners keep their statistics from these."""
    rejected: str = ""
    """Non-empty when ``sense(t)`` was rejected (e.g. a NaN): the reason. Every actor then
    skips step t, as the synchronous loop does (the executor repeats its last motor values)."""
    discontinuity: bool = False
    """``sense(t)`` marked a discontinuity: the learners break their histories at t."""
    version: int = 1
    """Schema version of this message type."""


def qstate_of(rec: QRecord) -> QState:
    """The JSON :class:`QState` of a binary ``qstate`` record's step (what the perception
    actor's ``QStateCodec.message`` writes: NaN values and unavailable qualitative values
    left out): what recordings and ``echo`` show (docs/decisions.md 98)."""
    if rec.rejected:
        return QState(rec.step, {}, (), {}, rejected=rec.rejected)
    names = rec.names
    x = {k: v for k, v in zip(names, rec.x.tolist(), strict=True) if v == v}
    q = {k: v for k, v in zip(names, rec.q.tolist(), strict=True) if v >= 0}
    events = tuple((names[v], val, d) for v, val, d in rec.events.tolist())
    return QState(rec.step, q, events, x, discontinuity=rec.discontinuity)


@dataclass(frozen=True)
class Motor:
    """``motor(t)``: the motor values the executor chose at step t (topic ``motor``)."""

    step: int
    """Agent step t whose ``qstate`` these motor values answer."""
    values: dict[str, float]
    """Motor value by motor variable name."""
    version: int = 1
    """Schema version of this message type."""


@dataclass(frozen=True)
class BatchContext:
    """What a batch reads of the executor's state, as it was after step t (topic
    ``batchctx``), published for the step before each batch step.

    Algorithm 2's batches consult the agent (§6.2.1): no new DBN predicts, no event landmark
    is learned for, and DBNs are deleted when their consequent is a sufficiently reliable
    action; DBNs that are plans are never deleted as old. The batch actors hold no actions or
    plans, so the executor tells them; the synchronous loop reads the same state directly."""

    step: int
    """The step t after whose decision the state was taken (the batch is at t + 1)."""
    reliable_actions: tuple[tuple[int, int], ...] = ()
    """Sufficiently reliable actions a(v, q) as (variable index, value index), sorted."""
    plan_dbns: tuple[int, ...] = ()
    """Ids of the DBNs that are plans, sorted."""
    version: int = 1
    """Schema version of this message type."""


DeltaKind = Literal["dbn", "landmarks"]


@dataclass(frozen=True)
class DeltaMsg:
    """A knowledge delta (docs/architecture.md §1) on ``delta/dbn`` or ``delta/landmarks``;
    the kind must match the topic."""

    kind: DeltaKind
    """Which knowledge changed: ``dbn`` or ``landmarks``."""
    delta: dict[str, JSON]
    """The payload of :meth:`qlap_runtime.qlap.delta.Delta.to_json` (version, computed_at,
    apply_at, ops); decoding checks that :meth:`Delta.from_json` accepts it."""
    version: int = 1
    """Schema version of this message type."""

    @classmethod
    def of(cls, kind: DeltaKind, delta: Delta) -> DeltaMsg:
        """Wrap a :class:`Delta`."""
        return cls(kind, delta.to_json())

    def to_delta(self) -> Delta:
        """The :class:`Delta` carried (its operations typed, each field checked)."""
        return Delta.from_json(self.delta)


@dataclass(frozen=True)
class PlanRequest:
    """What a plan compilation reads (topic ``planreq``; Algorithm 2 line 15, §5.2–5.4): the
    executor's agent at batch step t, after observing ``qstate(t)`` and before applying the
    deltas due at t — the state the batch at t copies — published by the executor for every
    batch step. The planner applies the batch's deltas to it and compiles."""

    step: int
    """The batch step t."""
    files: dict[str, str] = field(default_factory=dict)
    """The agent as a checkpoint (``save_agent``): file name -> base64 of its bytes."""
    rejected: bool = False
    """``qstate(t)`` was rejected: no batch at t, and no compilation (``files`` empty)."""
    last: bool = False
    """The executor's last step t (not a batch step it asks about; ``files`` empty): the
    planner ends."""
    local: bool = False
    """The agent was handed over in this process (the embedded placement: a copy, no files;
    ``actors.convert.LocalRequests``)."""
    version: int = 1
    """Schema version of this message type."""


@dataclass(frozen=True)
class PlanDeltaMsg:
    """A plan compilation's result (topic ``delta/plans``): the payload of
    :meth:`qlap_runtime.qlap.plan_delta.PlanDelta.to_json`, applied by the executor at
    ``apply_at`` right after the batch's deltas; decoding checks every operation."""

    step: int
    """The batch step t whose request it answers (its ``computed_at``)."""
    delta: dict[str, JSON]
    """computed_at, apply_at and the list of operations."""
    kind: Literal["plans"] = "plans"
    """Always ``plans`` (a delta inbox of the batches' kinds ignores it)."""
    version: int = 1
    """Schema version of this message type."""

    @classmethod
    def of(cls, delta: PlanDelta) -> PlanDeltaMsg:
        return cls(delta.computed_at, delta.to_json())

    def to_delta(self) -> PlanDelta:
        return PlanDelta.from_json(self.delta)


@dataclass(frozen=True)
class CallList:
    """The executor's call list at step t (topic ``calllist``; §5.5, Appendix F)."""

    step: int
    """Agent step t."""
    actions: tuple[str, ...]
    """Names of the actions on the call list, outermost first."""
    version: int = 1
    """Schema version of this message type."""


@dataclass(frozen=True)
class IACChoice:
    """One IAC choice of an action to practise (topic ``iac``; §6.1, Appendix E)."""

    step: int
    """Agent step at which the choice was made."""
    action: str
    """Name of the chosen action (empty when babbling)."""
    weight: float
    """The chosen action's weight."""
    n_applicable: int
    """How many actions were applicable (could be chosen)."""
    babbling: bool
    """True when the agent babbled instead of practising an action."""
    weights: dict[str, float] = field(default_factory=dict)
    """Weight of every applicable action, by name."""
    version: int = 1
    """Schema version of this message type."""


@dataclass(frozen=True)
class Rejected:
    """Counts of messages rejected by one actor's decoder (malformed, wrongly typed, unknown
    version, unknown key)."""

    total: int = 0
    """Messages rejected since the actor started."""
    by_key: dict[str, int] = field(default_factory=dict)
    """Rejections by key expression."""
    last_error: str = ""
    """The most recent rejection's reason, with its key expression."""


@dataclass(frozen=True)
class Stats:
    """An actor's runtime counters (topic ``stats``), published every few seconds."""

    step: int
    """Latest step the actor has processed."""
    actor: str = ""
    """Name of the reporting actor."""
    steps_per_s: float = 0.0
    """Steps per second over the last reporting interval."""
    waits: int = 0
    """Lockstep: times the world waited for a delta that was late (docs/architecture.md §2)."""
    late_ticks: int = 0
    """Realtime: ticks that started later than their deadline."""
    missed_ticks: int = 0
    """Realtime: ticks skipped altogether."""
    lateness_p50_ms: float = 0.0
    """Realtime: median tick lateness in milliseconds."""
    lateness_p99_ms: float = 0.0
    """Realtime: 99th percentile of tick lateness in milliseconds."""
    restarts: int = 0
    """Supervisor: actor restarts so far."""
    rejected: Rejected = field(default_factory=Rejected)
    """This actor's rejected messages."""
    version: int = 1
    """Schema version of this message type."""


ControlCommand = Literal["pause", "resume", "step", "goal", "save", "speed", "quit"]


@dataclass(frozen=True)
class Control:
    """A command to the running agent (topic ``control``)."""

    command: ControlCommand
    """``pause``, ``resume``, ``step`` (advance n steps while paused), ``goal`` (set a goal
    ``{"var": name, "value": q}``; ``{"clear": true}`` ends goal mode), ``save`` (write a
    checkpoint), ``speed`` (``{"steps_per_s": x}``, 0 = as fast as possible) or ``quit`` (stop
    the agent)."""
    args: dict[str, JSON] = field(default_factory=dict)
    """Arguments of the command, e.g. ``{"n": 10}`` for step, ``{"path": ...}`` for save."""
    version: int = 1
    """Schema version of this message type."""


# --------------------------------------------------------------------------- display (TUI)
# Snapshots for viewers (docs/tui.md): published with DROP, each one complete in itself, so a
# late or slow viewer only needs the latest of each topic.


@dataclass(frozen=True)
class PlanInfo:
    """One plan of an action, as in Tables 8.2–8.6 (inside :class:`Knowledge`)."""

    id: int
    """Plan id."""
    dbn_id: int
    """Id of the DBN the plan was made from."""
    label: str
    """The DBN in the reference's notation, e.g. ``⟨{h_x}: u_x→(331.27, +∞) ⇒ ḣ_x→[+]⟩``."""
    kind: str
    """``change`` or ``magnitude`` (the DBN's kind)."""
    brel: float
    """Best reliability of the DBN; −1 when undefined (⊥: no context cell has enough data)."""
    entropy: float
    """Entropy H of the DBN's context, in bits."""
    context_o: tuple[str, ...]
    """The plan's extra context C_o (variable names)."""
    rel_o: float
    """rel(o): the plan's own reliability over its calls."""
    calls: int
    """Times the plan was called."""
    states: int
    """Number of states of the plan's MDP."""


@dataclass(frozen=True)
class ActionInfo:
    """One action a(v, q) that has a plan or was practised (inside :class:`Knowledge`)."""

    label: str
    """The action in the reference's notation, e.g. ``a(ḣ_x, [+])``."""
    variable: str
    """Variable name v (ASCII, e.g. ``h_x.dot``)."""
    value: str
    """Label of the qualitative value q, e.g. ``[+]`` or ``(0.5, +inf)``."""
    index: int
    """Index of q in the variable's quantity space."""
    rel: float
    """rel(a): reliability of the action (prior 1)."""
    calls: int
    """Times the action was called."""
    successes: int
    """Calls that succeeded."""
    reliable: bool
    """Sufficiently reliable (§6.2.1; sticky)."""
    weight: float
    """Current IAC weight w_a (eq. 6.1 once 2θ calls are recorded, else eq. 6.2 with the best
    plan's rel(o)); −1 when the action has no plan."""
    history: tuple[float, ...]
    """Recent rel(a) after each call, oldest first (at most 32 values, for a sparkline)."""
    plans: tuple[PlanInfo, ...]
    """The action's plans, by id."""


@dataclass(frozen=True)
class LandmarkInfo:
    """One landmark of a magnitude or motor variable (inside :class:`Knowledge`)."""

    label: str
    """The landmark's value as printed, e.g. ``331.27``."""
    step: int
    """Agent step at which it was adopted (0 for initial landmarks)."""
    source: str
    """How it came: ``initial``, ``event``, ``context`` or ``motor`` (as the learner says)."""


@dataclass(frozen=True)
class KnowledgeCounters:
    """Counts of what has been learned (inside :class:`Knowledge`)."""

    dbns: int = 0
    """DBNs."""
    reliable_dbns: int = 0
    """Sufficiently reliable DBNs."""
    plans: int = 0
    """Plans."""
    landmarks: int = 0
    """Learned (non-initial) landmarks."""
    reliable_actions: int = 0
    """Sufficiently reliable non-motor actions."""
    practice_calls: int = 0
    """Actions chosen by IAC so far."""
    babble_commands: int = 0
    """Babbling commands chosen instead of an action."""
    successes: int = 0
    """Practised (or goal) actions that succeeded."""
    failures: int = 0
    """Practised (or goal) actions that failed."""


@dataclass(frozen=True)
class Knowledge:
    """A snapshot of what the agent has learned (topic ``knowledge``), published every few
    hundred steps and when it changes; complete in itself."""

    step: int
    """Agent step of the snapshot."""
    k: int
    """The window k of the learner (steps)."""
    actions: tuple[ActionInfo, ...]
    """Actions that have a plan or were practised."""
    landmarks: dict[str, tuple[LandmarkInfo, ...]]
    """Landmarks of each magnitude and motor variable, in order of value."""
    counters: KnowledgeCounters
    """Counts of DBNs, plans, landmarks, reliable actions, practice."""
    values: dict[str, tuple[str, ...]] = field(default_factory=dict)
    """Labels of the qualitative values of each non-motor variable (goals a viewer may set)."""
    self_vars: tuple[str, ...] = ()
    """Variables the agent has found to be part of itself (§6.4)."""
    version: int = 1
    """Schema version of this message type."""


@dataclass(frozen=True)
class WorldView:
    """What the world looks like now (topic ``world``), a few times a second."""

    step: int
    """Agent step."""
    world: str
    """World name, e.g. ``core2d``."""
    text: str
    """A top-down text drawing of the world (``world.render_text``), lines joined by ``\\n``."""
    values: dict[str, float]
    """Raw value of every sensed variable."""
    motor: dict[str, float] = field(default_factory=dict)
    """Motor values currently applied."""
    qualitative: dict[str, str] = field(default_factory=dict)
    """Qualitative value label of each variable, as the agent perceives it."""
    version: int = 1
    """Schema version of this message type."""


@dataclass(frozen=True)
class AgentStatus:
    """The running agent's state (topic ``status``), a few times a second and after every
    control command."""

    step: int
    """Latest agent step."""
    steps_per_s: float
    """Steps per second over the last second or so."""
    mode: str
    """The agent's mode: babble, command, practice, hold, goal, idle."""
    paused: bool = False
    """True while paused."""
    finished: bool = False
    """True once the run reached its last step (the driver then waits for ``quit``)."""
    speed: float = 0.0
    """Step-rate limit in steps/s; 0 = as fast as possible."""
    clock: str = "free"
    """``free`` (as fast as possible), ``realtime`` (paced at ``speed``) or ``lockstep``."""
    placement: str = "embedded"
    """``embedded`` (one process), ``local`` (processes on one host) or ``distributed``."""
    world: str = ""
    """World name."""
    seed: int = 0
    """Random seed of the run."""
    goal: str = ""
    """The goal action's label in goal mode, else empty."""
    learning: bool = True
    """Whether the agent learns."""
    pending_deltas: int = 0
    """Knowledge deltas computed but not yet applied (batch lag, docs/architecture.md §2)."""
    late_ticks: int = 0
    """Realtime: ticks that started later than their deadline."""
    missed_ticks: int = 0
    """Realtime: ticks skipped altogether."""
    wall_s: float = 0.0
    """Seconds since the run started."""
    message: str = ""
    """The answer to the last control command, e.g. ``saved /tmp/ck/step-0004000``."""
    version: int = 1
    """Schema version of this message type."""


Message = (Sense | QState | Motor | DeltaMsg | CallList | IACChoice | Stats | Control
           | Knowledge | WorldView | AgentStatus | BatchContext | PlanRequest | PlanDeltaMsg
           | QRecord)

TOPIC_TYPES: dict[str, type] = {
    "sense": Sense, "qstate": QState, "motor": Motor, "delta/dbn": DeltaMsg,
    "delta/landmarks": DeltaMsg, "delta/plans": PlanDeltaMsg, "calllist": CallList,
    "iac": IACChoice, "stats": Stats, "control": Control,
    "knowledge": Knowledge, "world": WorldView, "status": AgentStatus,
    "batchctx": BatchContext, "planreq": PlanRequest}
"""The message type each topic carries."""

MESSAGE_TYPES: tuple[type, ...] = (Sense, QState, Motor, DeltaMsg, CallList, IACChoice, Stats,
                                   Control, Knowledge, WorldView, AgentStatus, BatchContext,
                                   PlanRequest, PlanDeltaMsg)

WIRE_TYPES: dict[str, tuple[type, ...]] = {t: (c,) for t, c in TOPIC_TYPES.items()}
WIRE_TYPES["qstate"] = (QState, QRecord)
"""The Python types a topic's payloads may be: ``qstate`` is a JSON :class:`QState` or the
perception actor's binary :class:`~.qrecord.QRecord` (docs/decisions.md 98)."""

SUPPORTED_VERSIONS: dict[type, frozenset[int]] = {t: frozenset({1}) for t in MESSAGE_TYPES}
"""Versions :func:`decode` accepts, per type."""

assert set(TOPIC_TYPES) == set(keys.TOPICS)


# --------------------------------------------------------------------------- encoding


def encode(msg: Message) -> bytes:
    """Compact UTF-8 JSON of ``msg``. A NaN or infinity raises :class:`MessageError`.

    orjson does the work (several times faster than :mod:`json` on the step chain's messages).
    It writes a NaN or infinity as ``null``, so a payload holding ``null`` is re-encoded by the
    standard library with ``allow_nan=False``, which raises on them; so is anything orjson does
    not take (float subclasses such as ``numpy.float64``, non-string keys). A
    :class:`~.qrecord.QRecord` is its own payload."""
    if type(msg) is QRecord:
        return msg.payload
    obj = _to_obj(msg)
    try:
        out = orjson.dumps(obj)
        if b"null" not in out:
            return out
    except orjson.JSONEncodeError:
        pass
    try:
        return _ENCODER.encode(obj).encode()
    except (ValueError, TypeError) as e:
        raise MessageError(f"<{type(msg).__name__}>", f"cannot encode: {e}") from None


_ENCODER = json.JSONEncoder(separators=(",", ":"), ensure_ascii=False, allow_nan=False)


def _to_obj(msg: Any) -> dict[str, Any]:
    out = dict(msg.__dict__)  # fields in declaration order
    for name in _nested(type(msg)):
        out[name] = _to_obj(out[name])
    for name in _deep(type(msg)):
        out[name] = _jsonable(out[name])
    return out


@cache
def _deep(cls: type) -> tuple[str, ...]:
    """Fields holding dataclasses inside tuples or dicts (the display messages)."""
    hints = typing.get_type_hints(cls, globalns=globals())
    return tuple(f.name for f in dataclasses.fields(cls)
                 if not dataclasses.is_dataclass(hints[f.name]) and _holds_dataclass(hints[f.name]))


def _holds_dataclass(tp: Any) -> bool:
    return any(dataclasses.is_dataclass(a) or _holds_dataclass(a) for a in typing.get_args(tp))


def _jsonable(v: Any) -> Any:
    if dataclasses.is_dataclass(v):
        return _to_obj(v)
    if isinstance(v, tuple | list):
        return [_jsonable(x) for x in v]
    if isinstance(v, dict):
        return {k: _jsonable(x) for k, x in v.items()}
    return v


@cache
def _nested(cls: type) -> tuple[str, ...]:
    hints = typing.get_type_hints(cls, globalns=globals())
    return tuple(f.name for f in dataclasses.fields(cls) if dataclasses.is_dataclass(hints[f.name]))


def decode(key_expr: str, payload: bytes | bytearray | memoryview | str) -> Message:
    """The message that ``payload`` holds, validated against the type of ``key_expr``'s topic.

    Raises :class:`MessageError` (with the key expression) for an unknown key, bad UTF-8 or
    JSON, NaN/infinity, a missing, unknown or wrongly typed field, or an unknown version. On
    ``qstate`` a payload that starts as a binary record (:mod:`.qrecord`) is one.
    """
    key_expr = str(key_expr)
    topic, cls, problem = _topic_type(key_expr)
    if cls is None:
        raise MessageError(key_expr, problem)
    if cls is QState and is_record(payload):
        try:
            return decode_record(payload)
        except RecordError as e:
            raise MessageError(key_expr, f"invalid qstate record: {e}") from None
    try:
        obj = orjson.loads(payload)     # strict JSON: NaN, Infinity and bad UTF-8 raise
    except (orjson.JSONDecodeError, TypeError) as e:
        raise MessageError(key_expr, f"not UTF-8 JSON: {_json_problem(payload, e)}") from None
    try:
        msg = _build(cls, obj)
        _check_rules(msg, topic)
    except _Invalid as e:
        raise MessageError(key_expr, f"invalid {cls.__name__}: {e}") from None
    return msg


def _json_problem(payload: Any, error: Exception) -> str:
    """What is wrong with a payload orjson refused, in the standard library's words where it
    has them ("NaN is not allowed" names the token); the error path only."""
    try:
        text = payload if isinstance(payload, str) else bytes(payload).decode("utf-8")
        json.loads(text, parse_constant=_reject_constant)
    except (UnicodeDecodeError, ValueError, TypeError) as e:
        return str(e)
    return f"numbers must be finite: {error}" if "infinity" in str(error) else str(error)


def _reject_constant(name: str) -> float:
    raise ValueError(f"{name} is not allowed")


@lru_cache(maxsize=4096)
def _topic_type(key_expr: str) -> tuple[str, type | None, str]:
    try:
        topic = keys.topic_of(key_expr)
    except keys.BusKeyError as e:
        return "", None, str(e)
    cls = TOPIC_TYPES.get(topic)
    return topic, cls, "" if cls else f"topic {topic!r} carries no messages"


class _Invalid(Exception):
    """A validation failure; ``where`` collects the path innermost first, only on failure, so
    that valid messages pay nothing for error reporting."""

    def __init__(self, what: str, *where: str) -> None:
        super().__init__(what)
        self.what = what
        self.where = list(where)

    def at(self, part: str) -> _Invalid:
        self.where.append(part)
        return self

    def __str__(self) -> str:
        path = "".join(reversed(self.where)).lstrip(".")
        return f"{path} {self.what}" if path else self.what


def _build(cls: type, obj: Any) -> Any:
    if type(obj) is not dict:
        raise _Invalid(f"must be a JSON object, got {_tname(obj)}")
    fields = _fields(cls)
    if "version" in fields:
        if "version" not in obj:
            raise _Invalid("missing field 'version'")
        v = obj["version"]
        if type(v) is not int:
            raise _Invalid(f"must be an integer, got {v!r}", ".version")
        if v not in SUPPORTED_VERSIONS[cls]:
            raise _Invalid(f"unknown version {v} (supported: {sorted(SUPPORTED_VERSIONS[cls])})")
    if len(obj) > len(fields) or not fields.keys() >= obj.keys():
        raise _Invalid(f"unknown field(s) {sorted(set(obj) - set(fields))}")
    kwargs = {}
    for name, (check, required) in fields.items():
        if name in obj:
            try:
                kwargs[name] = check(obj[name])
            except _Invalid as e:
                raise e.at("." + name) from None
        elif required:
            raise _Invalid(f"missing field {name!r}")
    return cls(**kwargs)


def _check_rules(msg: Any, topic: str) -> None:
    if isinstance(msg, PlanDeltaMsg):
        try:
            d = PlanDelta.from_json(msg.delta)
        except (KeyError, TypeError, ValueError) as e:
            raise _Invalid(f"delta: {type(e).__name__}: {e}") from None
        if d.computed_at != msg.step:
            raise _Invalid(f"delta computed at {d.computed_at} on step {msg.step}")
    if isinstance(msg, DeltaMsg):
        expected = topic.removeprefix("delta/")
        if msg.kind != expected:
            raise _Invalid(f"kind {msg.kind!r} on topic {topic!r} (expected {expected!r})")
        try:
            d = Delta.from_json(msg.delta)
        except (KeyError, TypeError, ValueError) as e:
            raise _Invalid(f"delta: {type(e).__name__}: {e}") from None
        if set(msg.delta) != {"version", "computed_at", "apply_at", "ops"} or any(
                type(msg.delta[k]) is not int for k in ("version", "computed_at", "apply_at")):
            raise _Invalid("delta must hold exactly integer version, computed_at, apply_at "
                           "and a list ops")
        if not isinstance(msg.delta["ops"], list) or len(d.ops) != len(msg.delta["ops"]):
            raise _Invalid("delta.ops must be a list of operations")


# --------------------------------------------------------------------------- type checkers
# A checker takes a JSON value and returns it converted (tuples for arrays, float for integer
# numbers in float fields), or raises _Invalid. Object keys from orjson.loads are always strings.

Checker = Callable[[Any], Any]


def _tname(v: Any) -> str:
    return {dict: "object", list: "array", str: "string", bool: "boolean", int: "integer",
            float: "number", type(None): "null"}.get(type(v), type(v).__name__)


def _check_int(v: Any) -> int:
    if type(v) is not int:
        raise _Invalid(f"must be an integer, got {_tname(v)} {v!r}")
    return v


def _check_float(v: Any) -> float:
    t = type(v)
    if t is float:
        if v - v != 0.0:  # inf or nan
            raise _Invalid(f"must be finite, got {v!r}")
        return v
    if t is int:
        return float(v)
    raise _Invalid(f"must be a number, got {_tname(v)} {v!r}")


def _check_str(v: Any) -> str:
    if type(v) is not str:
        raise _Invalid(f"must be a string, got {_tname(v)} {v!r}")
    return v


def _check_bool(v: Any) -> bool:
    if type(v) is not bool:
        raise _Invalid(f"must be true or false, got {_tname(v)} {v!r}")
    return v


def _check_json(v: Any) -> Any:
    # orjson.loads already rejected NaN/Infinity literals and out-of-range numbers (1e999).
    t = type(v)
    if t is float and not math.isfinite(v):
        raise _Invalid(f"must be finite, got {v!r}")
    if t is list:
        for i, x in enumerate(v):
            try:
                _check_json(x)
            except _Invalid as e:
                raise e.at(f"[{i}]") from None
    elif t is dict:
        for k, x in v.items():
            try:
                _check_json(x)
            except _Invalid as e:
                raise e.at(f"[{k!r}]") from None
    return v


def _dict_of_float(v: Any) -> dict[str, float]:
    # The hot path (sense, motor, qstate.x): all floats and a finite sum is checked in C;
    # otherwise one pass converts integers and finds the offending entry.
    if type(v) is not dict:
        raise _Invalid(f"must be an object, got {_tname(v)}")
    vals = v.values()
    if set(map(type, vals)) <= _FLOAT_ONLY and math.isfinite(sum(vals)):
        return v
    out = v
    for k, x in v.items():
        if type(x) is float and x - x == 0.0:
            continue
        if type(x) is int:
            if out is v:
                out = dict(v)
            out[k] = float(x)
            continue
        try:
            _check_float(x)
        except _Invalid as e:
            raise e.at(f"[{k!r}]") from None
    return out


_FLOAT_ONLY = frozenset({float})
_INT_ONLY = frozenset({int})


def _dict_of_int(v: Any) -> dict[str, int]:
    if type(v) is not dict:
        raise _Invalid(f"must be an object, got {_tname(v)}")
    if set(map(type, v.values())) <= _INT_ONLY:
        return v
    for k, x in v.items():
        if type(x) is not int:
            raise _Invalid(f"must be an integer, got {_tname(x)} {x!r}", f"[{k!r}]")
    return v


@cache
def _checker(tp: Any) -> Checker:
    if tp is int:
        return _check_int
    if tp is float:
        return _check_float
    if tp is str:
        return _check_str
    if tp is bool:
        return _check_bool
    if tp is Any:
        return _check_json
    if tp == dict[str, float]:
        return _dict_of_float
    if tp == dict[str, int]:
        return _dict_of_int
    if dataclasses.is_dataclass(tp):
        return lambda v: _build(tp, v)  # type: ignore[arg-type]
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is Literal:
        allowed = args

        def check_literal(v: Any) -> Any:
            if type(v) is not str or v not in allowed:
                raise _Invalid(f"must be one of {list(allowed)}, got {v!r}")
            return v
        return check_literal
    if origin is dict:
        vc = _checker(args[1])

        def check_dict(v: Any) -> dict:
            if type(v) is not dict:
                raise _Invalid(f"must be an object, got {_tname(v)}")
            out = {}
            for k, x in v.items():
                try:
                    out[k] = vc(x)
                except _Invalid as e:
                    raise e.at(f"[{k!r}]") from None
            return out
        return check_dict
    if origin is tuple and len(args) == 2 and args[1] is Ellipsis:
        ic = _checker(args[0])

        def check_seq(v: Any) -> tuple:
            if type(v) is not list:
                raise _Invalid(f"must be an array, got {_tname(v)}")
            out = []
            for i, x in enumerate(v):
                try:
                    out.append(ic(x))
                except _Invalid as e:
                    raise e.at(f"[{i}]") from None
            return tuple(out)
        return check_seq
    if origin is tuple:
        ics = [_checker(a) for a in args]

        def check_tuple(v: Any) -> tuple:
            if type(v) is not list or len(v) != len(ics):
                raise _Invalid(f"must be an array of {len(ics)} items, got {v!r}")
            out = []
            for i, (c, x) in enumerate(zip(ics, v, strict=True)):
                try:
                    out.append(c(x))
                except _Invalid as e:
                    raise e.at(f"[{i}]") from None
            return tuple(out)
        return check_tuple
    raise TypeError(f"no checker for {tp!r}")


@cache
def _fields(cls: type) -> dict[str, tuple[Checker, bool]]:
    hints = typing.get_type_hints(cls, globalns=globals())
    out = {}
    for f in dataclasses.fields(cls):
        required = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        out[f.name] = (_checker(hints[f.name]), required)
    return out


# --------------------------------------------------------------------------- JSON schema


def json_schema(cls: type) -> dict[str, Any]:
    """The JSON Schema (draft 2020-12) of a message type, with each field's docstring as its
    description."""
    schema = _object_schema(cls)
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["$id"] = f"qlap/{cls.__name__}/v{max(SUPPORTED_VERSIONS.get(cls, {1}))}"
    return schema


def _object_schema(cls: type) -> dict[str, Any]:
    hints = typing.get_type_hints(cls, globalns=globals())
    docs = _field_docs(cls)
    props: dict[str, Any] = {}
    required = []
    for f in dataclasses.fields(cls):
        s = _type_schema(hints[f.name])
        if f.name in docs:
            s["description"] = docs[f.name]
        if f.name == "version" and cls in SUPPORTED_VERSIONS:
            s["enum"] = sorted(SUPPORTED_VERSIONS[cls])
        props[f.name] = s
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            required.append(f.name)
    return {"title": cls.__name__, "description": inspect.cleandoc(cls.__doc__ or ""),
            "type": "object", "properties": props, "required": required,
            "additionalProperties": False}


def _type_schema(tp: Any) -> dict[str, Any]:
    simple = {int: "integer", float: "number", str: "string", bool: "boolean"}
    if tp in simple:
        return {"type": simple[tp]}
    if tp is Any:
        return {}
    if dataclasses.is_dataclass(tp):
        return _object_schema(tp)  # type: ignore[arg-type]
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is Literal:
        return {"type": "string", "enum": list(args)}
    if origin is dict:
        return {"type": "object", "additionalProperties": _type_schema(args[1])}
    if origin is tuple and len(args) == 2 and args[1] is Ellipsis:
        return {"type": "array", "items": _type_schema(args[0])}
    if origin is tuple:
        return {"type": "array", "prefixItems": [_type_schema(a) for a in args],
                "minItems": len(args), "maxItems": len(args)}
    if isinstance(tp, types.UnionType):  # pragma: no cover - no unions in messages yet
        return {"anyOf": [_type_schema(a) for a in typing.get_args(tp)]}
    raise TypeError(f"no schema for {tp!r}")


@cache
def _field_docs(cls: type) -> dict[str, str]:
    """The docstring under each field (``x: int`` followed by a string literal)."""
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    except (OSError, TypeError):  # pragma: no cover - source not available
        return {}
    body = tree.body[0].body  # type: ignore[attr-defined]
    docs = {}
    for a, b in itertools.pairwise(body):
        if (isinstance(a, ast.AnnAssign) and isinstance(a.target, ast.Name)
                and isinstance(b, ast.Expr) and isinstance(b.value, ast.Constant)
                and isinstance(b.value.value, str)):
            docs[a.target.id] = inspect.cleandoc(b.value.value)
    return docs


def schema_name(cls: type) -> str:
    """The MCAP schema name of a message type, e.g. ``qlap.Sense``."""
    return f"qlap.{cls.__name__}"
