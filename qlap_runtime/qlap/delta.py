"""Knowledge deltas: what one batch changed, as an ordered list of operations
(docs/architecture.md §1).

A batch of Algorithm 2 (lines 6–13) is computed from the data up to step ``computed_at`` and
applied at a step boundary ``apply_at`` = computed_at + L. Replaying the operations in order on
any copy of the learner in the same state gives the same knowledge, so a delta is all that needs
to travel between actors. Each operation is a frozen dataclass; consumers dispatch on its class
(``match op: case AddLandmark(): ...``). On the wire, in checkpoints and in recorded runs an
operation is a JSON list led by its tag (``to_json``; the form is unchanged since the operations
were plain tuples, so older recordings and checkpoints read the same):

- :class:`Refresh` ``["refresh"]`` — refresh the sticky "sufficiently reliable" flags from the
  CPTs (§4.2.2); the first operation of every DBN batch, so every replica refreshes at the same
  point.
- :class:`SetK` ``["set_k", k]`` — the window k learned (Appendix C); pair statistics restart
  with it.
- :class:`AddDBN` ``["add_dbn", kind, [var, value, dir], [var, value, dir], [context vars]]`` — a
  new DBN; its id is the learner's next id when applied.
- :class:`SetContext` ``["set_context", dbn_id, [context vars]]`` — Algorithm 3's result.
- :class:`DeleteDBN` ``["delete_dbn", dbn_id]`` — §6.2.1 item 4 and §6.2.3.
- :class:`AddLandmark` ``["add_landmark", var, lb, ub, source, step, dbn_id | null,
  antecedent | null, context | null]`` — a landmark (Algorithms 4 and 5) and, for Algorithm 4,
  the improved DBN's new antecedent or context.

:func:`op_from_json` (and so :meth:`Delta.from_json`) checks every field strictly: a malformed
operation raises a ValueError naming the operation and the field. Whether the variables exist in
a given run is the runtime's rule (``qlap_runtime/runtime/rules.py``).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, Self

from .dbn import CHANGE, MAGNITUDE
from .variables import Event

if TYPE_CHECKING:
    from .params import Params

KINDS = ("dbn", "landmarks")
"""The parts of a batch of Algorithm 2, in apply order: lines 6–9, then lines 10–13."""


def delta_version(computed_at: int, kind: str) -> int:
    """The global, deterministic version of a batch's delta (apply order)."""
    return 2 * computed_at + KINDS.index(kind)


def batch_kinds(params: Params, step: int) -> tuple[str, ...]:
    """The deltas a batch at ``step`` produces (none if ``step`` is not a batch step)."""
    if step <= 0 or step % params.dbn_period:
        return ()
    if step % params.landmark_period == 0:
        return KINDS
    return ("dbn",)


# ---------------------------------------------------------------------------------------------
# Strict field checks of the JSON form (each error names the operation and the field)
# ---------------------------------------------------------------------------------------------
def _fail(op: str, field: str, what: str, value: Any) -> ValueError:
    return ValueError(f"delta operation {op}: {field} must be {what}, got {value!r}")


def op_items(op: str, item: Any, n: int) -> Sequence[Any]:
    """The JSON list of an operation, checked for its tag and its length."""
    if not isinstance(item, list | tuple) or not item or item[0] != op:
        raise ValueError(f"delta operation {op}: not a list led by {op!r}: {item!r}")
    if len(item) != n:
        raise ValueError(f"delta operation {op}: {n - 1} field(s) expected, got "
                         f"{len(item) - 1}: {list(item)!r}")
    return item


def int_field(op: str, field: str, v: Any, low: int = 0) -> int:
    if isinstance(v, bool) or not isinstance(v, numbers.Integral) or v < low:
        raise _fail(op, field, f"an integer ≥ {low}", v)
    return int(v)


def _finite(op: str, field: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v):
        raise _fail(op, field, "a finite number", v)
    return float(v)


def _choice(op: str, field: str, v: Any, allowed: tuple[str, ...]) -> str:
    if not isinstance(v, str) or v not in allowed:
        raise _fail(op, field, f"one of {', '.join(map(repr, allowed))}", v)
    return v


def _event(op: str, field: str, v: Any) -> Event:
    if not isinstance(v, list | tuple) or len(v) != 3:
        raise _fail(op, field, "an event [var, value, direction]", v)
    var = int_field(op, f"{field}.var", v[0])
    value = int_field(op, f"{field}.value", v[1])
    if isinstance(v[2], bool) or v[2] not in (-1, 0, 1):
        raise _fail(op, f"{field}.direction", "-1, 0 or 1", v[2])
    return Event(var, value, int(v[2]))


def vars_field(op: str, field: str, v: Any) -> tuple[int, ...]:
    if not isinstance(v, list | tuple):
        raise _fail(op, field, "a list of variable indexes", v)
    return tuple(int_field(op, f"{field}[{i}]", x) for i, x in enumerate(v))


# ---------------------------------------------------------------------------------------------
# The operations
# ---------------------------------------------------------------------------------------------


class OneIdOp:
    """An operation with one integer field, ``FIELD``: ``[NAME, id]`` on the wire (DBN and plan
    deltas alike)."""

    NAME: ClassVar[str]
    FIELD: ClassVar[str]

    def to_json(self) -> list[Any]:
        return [self.NAME, getattr(self, self.FIELD)]

    @classmethod
    def from_json(cls, item: Any) -> Self:
        _, v = op_items(cls.NAME, item, 2)
        return cls(int_field(cls.NAME, cls.FIELD, v))  # type: ignore[call-arg]
@dataclass(frozen=True)
class Refresh:
    """Refresh the sticky "sufficiently reliable" flags from the CPTs (§4.2.2)."""

    NAME: ClassVar[str] = "refresh"

    def to_json(self) -> list[Any]:
        return [self.NAME]

    @classmethod
    def from_json(cls, item: Any) -> Refresh:
        op_items(cls.NAME, item, 1)
        return cls()


@dataclass(frozen=True)
class SetK:
    """The window k learned (Appendix C); the pair statistics restart with it."""

    k: int
    NAME: ClassVar[str] = "set_k"

    def to_json(self) -> list[Any]:
        return [self.NAME, self.k]

    @classmethod
    def from_json(cls, item: Any) -> SetK:
        _, k = op_items(cls.NAME, item, 2)
        return cls(int_field(cls.NAME, "k", k, low=1))


@dataclass(frozen=True)
class AddDBN:
    """A new DBN (antecedent ⇒ consequent in the context); its id is the learner's next id
    when applied."""

    kind: str
    """``"change"`` or ``"magnitude"`` (:mod:`.dbn`)."""
    antecedent: Event
    consequent: Event
    context: tuple[int, ...] = ()
    NAME: ClassVar[str] = "add_dbn"

    def __post_init__(self) -> None:            # lists from callers: the hashable forms
        object.__setattr__(self, "antecedent", Event(*self.antecedent))
        object.__setattr__(self, "consequent", Event(*self.consequent))
        object.__setattr__(self, "context", tuple(self.context))

    def to_json(self) -> list[Any]:
        return [self.NAME, self.kind, list(self.antecedent), list(self.consequent),
                list(self.context)]

    @classmethod
    def from_json(cls, item: Any) -> AddDBN:
        n = cls.NAME
        _, kind, e1, e2, ctx = op_items(n, item, 5)
        return cls(_choice(n, "kind", kind, (CHANGE, MAGNITUDE)), _event(n, "antecedent", e1),
                   _event(n, "consequent", e2), vars_field(n, "context", ctx))


@dataclass(frozen=True)
class SetContext:
    """Algorithm 3's result: the DBN's new context."""

    dbn_id: int
    context: tuple[int, ...]
    NAME: ClassVar[str] = "set_context"

    def __post_init__(self) -> None:
        object.__setattr__(self, "context", tuple(self.context))

    def to_json(self) -> list[Any]:
        return [self.NAME, self.dbn_id, list(self.context)]

    @classmethod
    def from_json(cls, item: Any) -> SetContext:
        n = cls.NAME
        _, dbn_id, ctx = op_items(n, item, 3)
        return cls(int_field(n, "dbn_id", dbn_id), vars_field(n, "context", ctx))


@dataclass(frozen=True)
class DeleteDBN(OneIdOp):
    """Delete a DBN (§6.2.1 item 4, §6.2.3)."""

    dbn_id: int
    NAME: ClassVar[str] = "delete_dbn"
    FIELD: ClassVar[str] = "dbn_id"


@dataclass(frozen=True)
class AddLandmark:
    """A landmark [lb, ub] on variable ``var`` (Algorithm 5: ``source`` "event"; Algorithm 4:
    "dbn") and, for Algorithm 4, the improved DBN's new antecedent or context."""

    var: int
    lb: float
    ub: float
    source: str
    step: int
    """The batch step that found it."""
    dbn_id: int | None = None
    antecedent: Event | None = None
    context: tuple[int, ...] | None = None
    NAME: ClassVar[str] = "add_landmark"
    SOURCES: ClassVar[tuple[str, ...]] = ("event", "dbn")

    def __post_init__(self) -> None:
        if self.antecedent is not None:
            object.__setattr__(self, "antecedent", Event(*self.antecedent))
        if self.context is not None:
            object.__setattr__(self, "context", tuple(self.context))

    def to_json(self) -> list[Any]:
        return [self.NAME, self.var, self.lb, self.ub, self.source, self.step, self.dbn_id,
                None if self.antecedent is None else list(self.antecedent),
                None if self.context is None else list(self.context)]

    @classmethod
    def from_json(cls, item: Any) -> AddLandmark:
        n = cls.NAME
        _, var, lb, ub, source, step, dbn_id, ante, ctx = op_items(n, item, 9)
        return cls(int_field(n, "var", var), _finite(n, "lb", lb), _finite(n, "ub", ub),
                   _choice(n, "source", source, cls.SOURCES), int_field(n, "step", step),
                   None if dbn_id is None else int_field(n, "dbn_id", dbn_id),
                   None if ante is None else _event(n, "antecedent", ante),
                   None if ctx is None else vars_field(n, "context", ctx))


Op = Refresh | SetK | AddDBN | SetContext | DeleteDBN | AddLandmark
"""One operation of a delta."""

OP_TYPES: dict[str, type[Op]] = {t.NAME: t for t in (Refresh, SetK, AddDBN, SetContext,
                                                     DeleteDBN, AddLandmark)}
"""The operation classes by their JSON tag."""
OP_NAMES = tuple(OP_TYPES)


def op_from_json(item: Any) -> Op:
    """The operation of a JSON list (:meth:`to_json` of any operation class); a ValueError
    naming the operation and the field when it is malformed."""
    if not isinstance(item, list | tuple) or not item:
        raise ValueError(f"delta operation: not a non-empty list: {item!r}")
    cls = OP_TYPES.get(item[0]) if isinstance(item[0], str) else None
    if cls is None:
        raise ValueError(f"unknown delta operation {item[0]!r}; known: {', '.join(OP_NAMES)}")
    return cls.from_json(item)


@dataclass(frozen=True)
class Delta:
    """One batch's changes to the learned knowledge."""

    version: int
    """Sequence number of the batch (1, 2, ...); consumers apply deltas in this order."""
    computed_at: int
    """The step whose data the batch was computed from."""
    apply_at: int
    """The step at whose boundary it is applied (computed_at + L)."""
    ops: tuple[Op, ...] = ()
    """The operations, in order."""
    applied: bool = False
    """True when the operations were already applied to the learner that computed it (L = 0)."""

    def mark_applied(self) -> Delta:
        return dataclasses.replace(self, applied=True)

    def to_json(self) -> dict[str, Any]:
        return {"version": self.version, "computed_at": self.computed_at,
                "apply_at": self.apply_at, "ops": [op.to_json() for op in self.ops]}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Delta:
        """Inverse of :meth:`to_json`; every operation checked (:func:`op_from_json`)."""
        ops = tuple(op_from_json(op) for op in d["ops"])
        return cls(int(d["version"]), int(d["computed_at"]), int(d["apply_at"]), ops)
