"""Rules on well-formed messages (docs/runtime.md, "Rules on messages").

Decoding (``qlap_runtime/bus/schema.py``) rejects what is not a message of the topic; these
rules reject what is a message but cannot be one the run's own actors sent: a motor that names
no motor of the world or is outside its range, a ``qstate`` or ``batchctx`` naming variables the
world does not have, a delta at a step that is no batch step of its kind or whose operations
name unknown variables or are malformed. Each rule returns the reason (a string) or None; the
consumer counts and logs a rejected message (``RejectionCounter.reject``) and drops it, so it
never reaches the physics or the algorithm. The step window and the bound on pending messages
are the inboxes' (:mod:`.inbox`).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Sequence
from typing import Any

from ..qlap.params import Params
from .lockstep import batch_kinds

Rule = Callable[[Any], str | None]


def motor_rule(specs: Sequence[Any]) -> Rule:
    """``motor(t)``: every name a motor of the world, every value finite within its range."""
    ranges: dict[str, tuple[float, float]] = {}
    for v in specs:
        if str(getattr(v.kind, "value", v.kind)) == "motor":
            lo = -math.inf if v.low is None else float(v.low)
            hi = math.inf if v.high is None else float(v.high)
            ranges[v.name] = (lo, hi)

    def check(msg: Any) -> str | None:
        for name, value in msg.values.items():
            r = ranges.get(name)
            if r is None:
                return f"motor({msg.step}): unknown motor {name!r}; motors: " \
                       f"{', '.join(sorted(ranges))}"
            if not r[0] <= value <= r[1]:             # False for NaN too
                return f"motor({msg.step}): {name} = {value!r} outside [{r[0]}, {r[1]}]"
        return None

    return check


def qstate_rule(names: Sequence[str]) -> Rule:
    """``qstate(t)``: values, real values and events name variables of the table; qualitative
    values and directions are small integers."""
    known = frozenset(names)

    def check(msg: Any) -> str | None:
        if msg.rejected:
            return None
        for field, d in (("values", msg.values), ("x", msg.x)):
            if not d.keys() <= known:
                bad = sorted(set(d) - known)[:3]
                return f"qstate({msg.step}): unknown variable(s) {bad} in {field}"
        for v in msg.values.values():
            if not 0 <= v < 10_000:
                return f"qstate({msg.step}): qualitative value {v} out of range"
        for e in msg.events:
            if len(e) != 3 or e[0] not in known or not _int(e[1]) \
                    or e[2] not in (-1, 0, 1):
                return f"qstate({msg.step}): malformed event {e!r}"
        return None

    return check


def batchctx_rule(n_vars: int) -> Rule:
    def check(msg: Any) -> str | None:
        for a in msg.reliable_actions:
            if len(a) != 2 or not _var(a[0], n_vars) or not _int(a[1]):
                return f"batchctx({msg.step}): malformed action {a!r}"
        if any(not _int(i) or i < 0 for i in msg.plan_dbns):
            return f"batchctx({msg.step}): malformed DBN id"
        return None

    return check


def _int(v: Any) -> bool:
    return isinstance(v, numbers.Integral) and not isinstance(v, bool)


def _var(v: Any, n_vars: int) -> bool:
    return _int(v) and 0 <= v < n_vars


def _event(e: Any, n_vars: int) -> bool:
    return isinstance(e, list | tuple) and len(e) == 3 and _var(e[0], n_vars) \
        and all(_int(x) for x in e[1:])


def _vars(c: Any, n_vars: int) -> bool:
    return isinstance(c, list | tuple) and all(_var(v, n_vars) for v in c)


def op_problem(op: Sequence[Any], n_vars: int) -> str | None:
    """What is wrong with one delta operation (None: nothing)."""
    name = op[0]
    if name == "refresh":
        return None if len(op) == 1 else "refresh takes no argument"
    if name == "set_k":
        return None if len(op) == 2 and _int(op[1]) and 1 <= op[1] <= 1000 \
            else f"set_k {op[1:]!r}"
    if name == "add_dbn":
        if len(op) != 5 or not _event(op[2], n_vars) or not _event(op[3], n_vars) \
                or not _vars(op[4], n_vars):
            return f"add_dbn names an unknown variable or is malformed: {list(op)!r}"[:200]
        return None
    if name == "set_context":
        if len(op) != 3 or not _int(op[1]) or not _vars(op[2], n_vars):
            return f"set_context names an unknown variable or is malformed: {list(op)!r}"[:200]
        return None
    if name == "delete_dbn":
        return None if len(op) == 2 and _int(op[1]) else f"delete_dbn {op[1:]!r}"
    if name == "add_landmark":
        if len(op) != 9 or not _var(op[1], n_vars) or not all(
                isinstance(x, numbers.Real) and math.isfinite(x) for x in op[2:4]) \
                or not _int(op[5]) \
                or not (op[6] is None or _int(op[6])) \
                or not (op[7] is None or _event(op[7], n_vars)) \
                or not (op[8] is None or _vars(op[8], n_vars)):
            return f"add_landmark names an unknown variable or is malformed: " \
                   f"{list(op)!r}"[:200]
        return None
    return f"unknown operation {name!r}"


def delta_rule(params: Params, n_vars: int, realtime: bool = False) -> Rule:
    """``delta/<kind>``: computed at a batch step of its kind, applied at computed_at + L
    (lockstep), every operation well-formed and naming variables of the table."""

    def check(msg: Any) -> str | None:
        d = msg.delta
        at = d["computed_at"]
        if msg.kind not in batch_kinds(params, at):
            return f"delta/{msg.kind} computed at {at}: not a batch step of {msg.kind}"
        if not realtime and d["apply_at"] != at + params.batch_lag:
            return f"delta/{msg.kind} computed at {at}: apply_at {d['apply_at']} is not " \
                   f"{at} + lag {params.batch_lag}"
        for op in d["ops"]:
            why = op_problem(op, n_vars)
            if why is not None:
                return f"delta/{msg.kind} computed at {at}: {why}"
        return None

    return check
