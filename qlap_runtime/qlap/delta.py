"""Knowledge deltas: what one batch changed, as an ordered list of operations
(docs/architecture.md §1).

A batch of Algorithm 2 (lines 6–13) is computed from the data up to step ``computed_at`` and
applied at a step boundary ``apply_at`` = computed_at + L. Replaying the operations in order on
any copy of the learner in the same state gives the same knowledge, so a delta is all that needs
to travel between actors. Operations are JSON-ready tuples:

- ``("refresh",)`` — refresh the sticky "sufficiently reliable" flags from the CPTs (§4.2.2);
  the first operation of every DBN batch, so every replica refreshes at the same point.
- ``("set_k", k)`` — the window k learned (Appendix C); pair statistics restart with it.
- ``("add_dbn", kind, [var, value, dir], [var, value, dir], [context vars])`` — a new DBN; its id
  is the learner's next id when applied.
- ``("set_context", dbn_id, [context vars])`` — Algorithm 3's result.
- ``("delete_dbn", dbn_id)`` — §6.2.1 item 4 and §6.2.3.
- ``("add_landmark", var, lb, ub, source, step, dbn_id | None, antecedent | None,
  context | None)`` — a landmark (Algorithms 4 and 5) and, for Algorithm 4, the improved DBN's
  new antecedent or context.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .params import Params

Op = tuple[Any, ...]

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


OP_NAMES = ("refresh", "set_k", "add_dbn", "set_context", "delete_dbn", "add_landmark")


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
                "apply_at": self.apply_at, "ops": [list(op) for op in self.ops]}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Delta:
        ops = []
        for op in d["ops"]:
            if not op or op[0] not in OP_NAMES:
                raise ValueError(f"unknown delta operation {op!r}")
            ops.append(tuple(op))
        return cls(int(d["version"]), int(d["computed_at"]), int(d["apply_at"]), tuple(ops))
