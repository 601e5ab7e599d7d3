"""Plan deltas: what one plan compilation changed (Algorithm 2 line 15; §5.2–5.4, §6.2).

A compilation runs on a copy of the agent as it was at a batch step t, with that batch's
knowledge deltas applied (:meth:`~.agent.Agent.compile_plans`): it removes plans (§6.2.2), learns
the second-order contexts C_o (§5.4), converts DBNs to plans (line 15, §6.2.1–6.2.2, §6.3) and
rebuilds every plan's MDP, planning new states by value iteration (§5.2.2). It records what it
did as an ordered list of operations, applied by the executor at the boundary of t + L
(:meth:`~.agent.Agent.apply_plans`), right after the batch's own deltas. The decisions and the
values of value iteration are the compilation's; the Q-values the executor learned since t by
Sarsa and Dyna are kept (a rebuild carries them over, :func:`~.mdp.grow_q`), and the second-order
CPTs are counted again from the executor's own calls (docs/decisions.md 56).

Each operation is a frozen dataclass; on the wire an operation is a JSON list led by its tag, as
for :mod:`.delta`. A Q-table travels as its shape, the packed bits of its not-applicable pairs
and the other values as little-endian float64 bytes, both base64 (JSON has no infinity).
"""

from __future__ import annotations

import base64
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from .delta import OneIdOp, int_field, op_items, vars_field
from .mdp import NOT_APPLICABLE


def q_to_json(q: np.ndarray) -> dict[str, Any]:
    """A Q-table as JSON, byte-exact (see the module docstring)."""
    q = np.ascontiguousarray(q, dtype=np.float64)
    na = q == NOT_APPLICABLE
    values = np.ascontiguousarray(q[~na], dtype="<f8")
    return {"shape": list(q.shape),
            "na": base64.b64encode(np.packbits(na.ravel()).tobytes()).decode(),
            "values": base64.b64encode(values.tobytes()).decode()}


def q_from_json(op: str, d: Any) -> np.ndarray:
    """Inverse of :func:`q_to_json`; a ValueError naming ``op`` when it is malformed."""
    if not isinstance(d, dict) or set(d) != {"shape", "na", "values"}:
        raise ValueError(f"plan delta operation {op}: q must be an object of shape, na and "
                         f"values, got {d!r}")
    shape = tuple(int_field(op, "q.shape", n) for n in d["shape"])
    if len(shape) != 2:
        raise ValueError(f"plan delta operation {op}: q.shape must have 2 sizes, got {shape}")
    try:
        na_bits = np.frombuffer(base64.b64decode(d["na"], validate=True), dtype=np.uint8)
        values = np.frombuffer(base64.b64decode(d["values"], validate=True), dtype="<f8")
    except (TypeError, ValueError) as e:
        raise ValueError(f"plan delta operation {op}: q is not base64: {e}") from None
    n = shape[0] * shape[1]
    if len(na_bits) != (n + 7) // 8:
        raise ValueError(f"plan delta operation {op}: q.na has {len(na_bits)} bytes for "
                         f"{n} entries")
    na = np.unpackbits(na_bits, count=n).astype(bool).reshape(shape)
    if int((~na).sum()) != len(values) or not np.isfinite(values).all():
        raise ValueError(f"plan delta operation {op}: q.values must be {int((~na).sum())} "
                         f"finite numbers")
    q = np.full(shape, NOT_APPLICABLE, dtype=np.float64)
    q[~na] = values
    return q


def _q_or_none(op: str, d: Any) -> np.ndarray | None:
    return None if d is None else q_from_json(op, d)


@dataclass(frozen=True)
class RemovePlan(OneIdOp):
    """Remove plan ``plan_id`` (its DBN is gone, rel(o) fell too low, or another plan takes
    its slot: §6.2.2); a frame running it ends."""

    plan_id: int
    NAME: ClassVar[str] = "remove_plan"
    FIELD: ClassVar[str] = "plan_id"


@dataclass(frozen=True)
class PlanContexts:
    """The second-order contexts learned (§5.4.2): each changed plan's new C_o. Applied, every
    plan's second-order CPT is counted again from its stored calls and its sticky "sufficiently
    reliable" flag refreshed (§5.4.1)."""

    changes: tuple[tuple[int, tuple[int, ...]], ...] = ()
    """(plan id, new C_o) of each plan whose C_o changed, by plan id."""
    NAME: ClassVar[str] = "plan_contexts"

    def to_json(self) -> list[Any]:
        return [self.NAME, [[pid, list(ctx)] for pid, ctx in self.changes]]

    @classmethod
    def from_json(cls, item: Any) -> PlanContexts:
        n = cls.NAME
        _, changes = op_items(n, item, 2)
        if not isinstance(changes, list | tuple) or not all(
                isinstance(c, list | tuple) and len(c) == 2 for c in changes):
            raise ValueError(f"plan delta operation {n}: changes must be [plan_id, [vars]] "
                             f"pairs, got {changes!r}")
        return cls(tuple((int_field(n, "plan_id", pid), vars_field(n, "context_o", ctx))
                         for pid, ctx in changes))


@dataclass(frozen=True, eq=False)
class AddPlan:
    """A new plan ``plan_id`` for DBN ``dbn_id`` (line 15), planned by value iteration
    (§5.2.2): ``q`` is Q* of its model at the compilation."""

    plan_id: int
    dbn_id: int
    q: np.ndarray = field(repr=False)
    NAME: ClassVar[str] = "add_plan"

    def to_json(self) -> list[Any]:
        return [self.NAME, self.plan_id, self.dbn_id, q_to_json(self.q)]

    @classmethod
    def from_json(cls, item: Any) -> AddPlan:
        n = cls.NAME
        _, pid, dbn_id, q = op_items(n, item, 4)
        return cls(int_field(n, "plan_id", pid), int_field(n, "dbn_id", dbn_id), q_from_json(n, q))


@dataclass(frozen=True)
class SkipPlan(OneIdOp):
    """DBN ``dbn_id`` qualified for a plan whose Q-table would exceed
    ``Params.max_plan_entries`` (counted as ``plans_too_large``, docs/decisions.md 23)."""

    dbn_id: int
    NAME: ClassVar[str] = "skip_plan"
    FIELD: ClassVar[str] = "dbn_id"


@dataclass(frozen=True)
class DropContext(OneIdOp):
    """Plan ``plan_id`` outgrew ``Params.max_plan_entries``: it gives up C_o (§5.4.2,
    docs/decisions.md 23)."""

    plan_id: int
    NAME: ClassVar[str] = "drop_context"
    FIELD: ClassVar[str] = "plan_id"


@dataclass(frozen=True, eq=False)
class Rebuild:
    """Rebuild plan ``plan_id``'s MDP from its DBN's structure (§5.2.1); its learned Q-values
    are carried over to a changed space (:func:`~.mdp.grow_q`). ``q``: Q* of the new model
    at the compilation, for the pairs with no ancestor (None when the compilation needed
    none)."""

    plan_id: int
    q: np.ndarray | None = field(default=None, repr=False)
    NAME: ClassVar[str] = "rebuild"

    def to_json(self) -> list[Any]:
        return [self.NAME, self.plan_id, None if self.q is None else q_to_json(self.q)]

    @classmethod
    def from_json(cls, item: Any) -> Rebuild:
        n = cls.NAME
        _, pid, q = op_items(n, item, 3)
        return cls(int_field(n, "plan_id", pid), _q_or_none(n, q))


PlanOp = RemovePlan | PlanContexts | AddPlan | SkipPlan | DropContext | Rebuild
"""One operation of a plan delta."""

PLAN_OP_TYPES: dict[str, type[PlanOp]] = {t.NAME: t for t in (
    RemovePlan, PlanContexts, AddPlan, SkipPlan, DropContext, Rebuild)}
"""The operation classes by their JSON tag."""


def plan_op_from_json(item: Any) -> PlanOp:
    """The operation of a JSON list; a ValueError naming the operation and the field."""
    if not isinstance(item, list | tuple) or not item:
        raise ValueError(f"plan delta operation: not a non-empty list: {item!r}")
    cls = PLAN_OP_TYPES.get(item[0]) if isinstance(item[0], str) else None
    if cls is None:
        raise ValueError(f"unknown plan delta operation {item[0]!r}; known: "
                         f"{', '.join(PLAN_OP_TYPES)}")
    return cls.from_json(item)


@dataclass(frozen=True)
class PlanDelta:
    """One compilation's changes to the plans, applied at ``apply_at`` after the deltas of the
    batch at ``computed_at`` (docs/runtime.md, Lockstep)."""

    computed_at: int
    """The batch step whose snapshot the compilation read."""
    apply_at: int
    """The step at whose boundary it is applied (computed_at + L)."""
    ops: tuple[PlanOp, ...] = ()
    """The operations, in order."""

    def to_json(self) -> dict[str, Any]:
        return {"computed_at": self.computed_at, "apply_at": self.apply_at,
                "ops": [op.to_json() for op in self.ops]}

    @classmethod
    def from_json(cls, d: Any) -> PlanDelta:
        """Inverse of :meth:`to_json`; every operation checked."""
        if not isinstance(d, dict) or set(d) != {"computed_at", "apply_at", "ops"} \
                or not isinstance(d["ops"], list):
            raise ValueError("plan delta must hold exactly computed_at, apply_at and a list "
                             f"ops, got {sorted(d) if isinstance(d, dict) else d!r}")
        return cls(int_field("plan_delta", "computed_at", d["computed_at"]),
                   int_field("plan_delta", "apply_at", d["apply_at"]),
                   tuple(plan_op_from_json(op) for op in d["ops"]))
