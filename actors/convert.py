"""Bus messages ↔ the algorithm's objects: ``qstate`` ↔ :class:`Percept`, the executor's
state a batch reads (``batchctx``, §6.2.1) and the agent a plan compilation reads
(``planreq``, Algorithm 2 line 15)."""

from __future__ import annotations

import base64
import tempfile
import threading
from pathlib import Path
from typing import Any

import numpy as np

from qlap_runtime.bus.schema import BatchContext, PlanRequest, QState
from qlap_runtime.qlap.agent import Agent
from qlap_runtime.qlap.checkpoint import load_agent, save_agent
from qlap_runtime.qlap.delta import Delta
from qlap_runtime.qlap.perception import Percept
from qlap_runtime.qlap.plan_delta import PlanDelta
from qlap_runtime.qlap.variables import Event, VariableTable

REQUEST_FILES = ("agent.json", "agent.npz", "learner.json", "learner.npz")
"""The checkpoint files a ``planreq`` carries (``save_agent``'s, docs/checkpoint.md)."""
SCRATCH = "/dev/shm" if Path("/dev/shm").is_dir() else None
"""Where a request's files pass through (memory where the system has it)."""


class QStateCodec:
    """``qstate`` messages of one variable table: names in table order, built once."""

    def __init__(self, table: VariableTable) -> None:
        self.names = tuple(v.name for v in sorted(table, key=lambda v: v.index))
        self.index = {name: i for i, name in enumerate(self.names)}

    def message(self, p: Percept) -> QState:
        """The perception actor's message of a percept (a NaN: not yet known, left out)."""
        names = self.names
        x = {k: v for k, v in zip(names, p.x.tolist(), strict=True) if v == v}
        q = {k: v for k, v in zip(names, p.q.tolist(), strict=True) if v >= 0}
        events = tuple((names[e.var], int(e.value), int(e.direction)) for e in p.events)
        return QState(p.step, q, events, x, discontinuity=p.discontinuity)

    def percept(self, msg: QState) -> Percept:
        """The perception actor's :class:`Percept`, rebuilt from its message."""
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


class LocalRequests:
    """The embedded placement's ``planreq``: the executor and the planner share a process, so
    the request hands over a private copy of the agent (:meth:`Agent.planning_copy`, deep: the
    executor goes on while the planner compiles) instead of its files; the message only says
    so (``local``), and stays in the replay log like any other."""

    def __init__(self) -> None:
        self.agents: dict[tuple[str, int], Agent] = {}
        self.lock = threading.Lock()

    def put(self, run_id: str, agent: Agent, step: int) -> PlanRequest:
        copy = agent.planning_copy(agent.learner.batch_copy(), deep=True)
        with self.lock:
            self.agents[(run_id, step)] = copy
        return PlanRequest(step, local=True)

    def take(self, run_id: str, step: int) -> Agent:
        with self.lock:
            return self.agents.pop((run_id, step))


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
    compiled (:meth:`~qlap_runtime.qlap.agent.Agent.compile_plans`)."""
    if msg.local:
        agent = LOCAL.take(run_id, msg.step)
    else:
        with tempfile.TemporaryDirectory(prefix="qlap-planreq-", dir=SCRATCH) as tmp:
            for name in REQUEST_FILES:
                (Path(tmp) / name).write_bytes(base64.b64decode(msg.files[name],
                                                                validate=True))
            agent = load_agent(tmp)
    for d in deltas:
        agent.learner.apply_delta(d)
    return agent.compile_plans(msg.step, msg.step + lag)
