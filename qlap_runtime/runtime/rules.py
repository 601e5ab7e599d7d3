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

import numpy as np

from ..bus.qrecord import QRecord, names_blob
from ..qlap.delta import AddDBN, AddLandmark, SetContext, SetK, op_from_json
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
    values and directions are small integers. A binary record (docs/decisions.md 98) names the
    table's variables in the table's order (one comparison of its names' bytes); its
    structure was checked by the decoder."""
    known = frozenset(names)
    blob = names_blob(tuple(names))

    def check(msg: Any) -> str | None:
        if msg.rejected:
            return None
        if type(msg) is QRecord:
            if msg.names_blob != blob:
                return _record_names(msg, names, known)
            if msg.n and (top := int(np.maximum.reduce(msg.q))) >= 10_000:
                return f"qstate({msg.step}): qualitative value {top} out of range"
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


def _record_names(msg: QRecord, names: Sequence[str], known: frozenset[str]) -> str:
    bad = sorted(set(msg.names) - known)[:3]
    if bad:
        return f"qstate({msg.step}): unknown variable(s) {bad} in the record"
    return f"qstate({msg.step}): the record's {len(msg.names)} variables are not the " \
           f"table's {len(names)} in the table's order"


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


def op_problem(op: Sequence[Any], n_vars: int) -> str | None:
    """What is wrong with one delta operation in its JSON form (None: nothing): malformed
    (:func:`~qlap_runtime.qlap.delta.op_from_json` names the field), a variable that is not in
    the run's table, or a window k above 1000."""
    try:
        parsed = op_from_json(op)
    except ValueError as exc:
        return str(exc)[:200]
    match parsed:
        case SetK(k=k) if k > 1000:
            return f"set_k {k}: outside 1–1000"
        case AddDBN(antecedent=a, consequent=c, context=ctx):
            used: tuple[int, ...] = (a.var, c.var, *ctx)
        case SetContext(context=ctx):
            used = ctx
        case AddLandmark(var=var, antecedent=a, context=ctx):
            used = (var, *(() if a is None else (a.var,)), *(ctx or ()))
        case _:
            used = ()
    unknown = [v for v in used if v >= n_vars]
    if unknown:
        return f"{parsed.NAME} names an unknown variable {unknown[0]} (the table has " \
               f"{n_vars}): {list(op)!r}"[:200]
    return None


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


def planreq_rule(files: tuple[str, ...], local: bool) -> Rule:
    """``planreq``: the checkpoint files of an agent and nothing else (a rejected step: none);
    ``local``: the planner shares the executor's process, whose requests hand the agent over
    in memory (no files), and only then."""

    def check(msg: Any) -> str | None:
        if msg.local != local and not (msg.rejected or msg.last):
            return (f"planreq({msg.step}): local {msg.local}, but this planner "
                    f"{'shares' if local else 'does not share'} the executor's process")
        want = set() if msg.rejected or msg.last or msg.local else set(files)
        if set(msg.files) != want:
            return f"planreq({msg.step}): files {sorted(msg.files)} (expected {sorted(want)})"
        return None

    return check


def plan_delta_rule(params: Params, realtime: bool = False) -> Rule:
    """``delta/plans``: computed at a batch step, applied at computed_at + L (lockstep)."""

    def check(msg: Any) -> str | None:
        d = msg.delta
        at = d["computed_at"]
        if not batch_kinds(params, at):
            return f"delta/plans computed at {at}: not a batch step"
        if not realtime and d["apply_at"] != at + params.batch_lag:
            return f"delta/plans computed at {at}: apply_at {d['apply_at']} is not " \
                   f"{at} + lag {params.batch_lag}"
        return None

    return check
