"""The key-expression scheme: ``qlap/<run-id>/<topic>`` (docs/bus.md).

Topics and their writers:

========================  ============  =====================================================
topic                     writer        message (:mod:`qlap_runtime.bus.schema`)
========================  ============  =====================================================
``sense``                 world         :class:`~.schema.Sense`
``qstate``                perception    :class:`~.schema.QState`
``motor``                 executor      :class:`~.schema.Motor`
``delta/dbn``             contingency   :class:`~.schema.DeltaMsg` (kind ``dbn``)
``delta/landmarks``       landmarks     :class:`~.schema.DeltaMsg` (kind ``landmarks``)
``delta/plans``           planner       :class:`~.schema.PlanDeltaMsg`
``planreq``               executor      :class:`~.schema.PlanRequest`
``batchctx``              executor      :class:`~.schema.BatchContext`
``calllist``              executor      :class:`~.schema.CallList`
``iac``                   executor      :class:`~.schema.IACChoice`
``stats``                 any actor     :class:`~.schema.Stats`
``control``               TUI / user    :class:`~.schema.Control`
``knowledge``             agent         :class:`~.schema.Knowledge` (display snapshot)
``world``                 agent         :class:`~.schema.WorldView` (display)
``status``                agent         :class:`~.schema.AgentStatus` (display)
``alive/<actor>``         each actor    liveliness token (no payload)
``replay/<topic>``        its writer    queryable: the writer's recent messages of a lockstep
                                        topic (``?from=STEP``), for a restarted consumer
========================  ============  =====================================================
"""

from __future__ import annotations

import os
import re
import time

ROOT = "qlap"

TOPICS = ("sense", "qstate", "motor", "delta/dbn", "delta/landmarks", "delta/plans",
          "calllist", "iac", "stats", "control", "knowledge", "world", "status", "batchctx",
          "planreq")
"""Every data topic under ``qlap/<run-id>/``."""

ALIVE = "alive"

REPLAY = "replay"
REPLAY_TOPICS = ("sense", "qstate", "motor", "delta/dbn", "delta/landmarks", "batchctx",
                 "planreq", "delta/plans")
"""The lockstep topics whose writers keep a replay log (docs/runtime.md, Faults)."""

_FORBIDDEN = set("*$/#?") | {" ", "\t", "\n", "\r"}
_NAME = re.compile(r"^[A-Za-z0-9_.\-]+$")


class BusKeyError(ValueError):
    """A run id, actor name, topic or key expression outside the scheme."""


def validate_run_id(run_id: str) -> str:
    """Return ``run_id`` if it is one non-empty key chunk: no ``* $ / # ?`` nor whitespace."""
    return _chunk(run_id, "run id")


def validate_actor(actor: str) -> str:
    """Return ``actor`` if it is a valid single key chunk (same rule as run ids)."""
    return _chunk(actor, "actor name")


def _chunk(text: str, what: str) -> str:
    if not isinstance(text, str) or not text:
        raise BusKeyError(f"{what} must be a non-empty string, got {text!r}")
    bad = sorted(set(text) & _FORBIDDEN)
    if bad:
        raise BusKeyError(f"{what} {text!r} contains forbidden characters {bad}")
    if not _NAME.match(text):
        raise BusKeyError(f"{what} {text!r}: use letters, digits, '_', '-', '.'")
    return text


def key(run_id: str, topic: str) -> str:
    """``qlap/<run-id>/<topic>`` for one of :data:`TOPICS`."""
    if topic not in TOPICS:
        raise BusKeyError(f"unknown topic {topic!r}; known: {', '.join(TOPICS)}")
    return f"{ROOT}/{validate_run_id(run_id)}/{topic}"


def alive_key(run_id: str, actor: str) -> str:
    """``qlap/<run-id>/alive/<actor>``: the actor's liveliness token."""
    return f"{ROOT}/{validate_run_id(run_id)}/{ALIVE}/{validate_actor(actor)}"


def replay_key(run_id: str, topic: str) -> str:
    """``qlap/<run-id>/replay/<topic>``: the queryable answering with a writer's recent
    messages of one of :data:`REPLAY_TOPICS`."""
    if topic not in REPLAY_TOPICS:
        raise BusKeyError(f"topic {topic!r} has no replay log; those with one: "
                          f"{', '.join(REPLAY_TOPICS)}")
    return f"{ROOT}/{validate_run_id(run_id)}/{REPLAY}/{topic}"


def alive_pattern(run_id: str) -> str:
    """``qlap/<run-id>/alive/*``: every actor's liveliness token."""
    return f"{ROOT}/{validate_run_id(run_id)}/{ALIVE}/*"


def run_pattern(run_id: str | None) -> str:
    """``qlap/<run-id>/**`` (or ``qlap/**`` for every run when ``run_id`` is None)."""
    return f"{ROOT}/**" if run_id is None else f"{ROOT}/{validate_run_id(run_id)}/**"


def parse(key_expr: str) -> tuple[str, str]:
    """Split a concrete key into (run id, topic); topic may be ``alive/<actor>``."""
    parts = str(key_expr).split("/", 2)
    if len(parts) != 3 or parts[0] != ROOT:
        raise BusKeyError(f"{key_expr!r} is not under {ROOT}/<run-id>/")
    _, run_id, topic = parts
    validate_run_id(run_id)
    if topic not in TOPICS:
        head, _, actor = topic.partition("/")
        if head != ALIVE or not actor:
            raise BusKeyError(f"{key_expr!r}: unknown topic {topic!r}")
        validate_actor(actor)
    return run_id, topic


def topic_of(key_expr: str) -> str:
    """The topic part of a concrete key expression (see :func:`parse`)."""
    return parse(key_expr)[1]


def new_run_id() -> str:
    """A fresh run id: UTC time and 4 random hex digits, e.g. ``20260122T101500-3fa2``."""
    return time.strftime("%Y%m%dT%H%M%S", time.gmtime()) + "-" + os.urandom(2).hex()


WRITERS: dict[str, tuple[str, ...]] = {
    "world": ("sense", "world", "control"),       # control: the end marker of a quit
    "perception": ("qstate",),
    "contingency": ("delta/dbn",),
    "landmarks": ("delta/landmarks",),
    "planner": ("delta/plans",),
    "executor": ("motor", "calllist", "iac", "status", "knowledge", "batchctx", "planreq"),
    "tui": ("control",),
    "supervisor": ("control",),
    "recorder": (),
}
"""The topics each actor publishes (every actor also publishes ``stats`` and its liveliness
token). The ACL of :func:`~.config.acl_own_keys` is built from this."""


def actor_put_keys(actor: str, run_id: str = "*") -> list[str]:
    """Key expressions ``actor`` may put (or reply) on: its topics, the replay logs of its
    lockstep topics, ``stats`` and its liveliness token (``run_id='*'``: in any run)."""
    run = run_id if run_id == "*" else validate_run_id(run_id)
    topics = WRITERS.get(validate_actor(actor), ())
    own = [f"{ROOT}/{run}/{t}" for t in topics]
    replay = [f"{ROOT}/{run}/{REPLAY}/{t}" for t in topics if t in REPLAY_TOPICS]
    return [*own, *replay, f"{ROOT}/{run}/stats", f"{ROOT}/{run}/{ALIVE}/{actor}"]
