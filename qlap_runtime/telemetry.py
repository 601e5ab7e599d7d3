"""Telemetry: what a running agent publishes for viewers (the TUI, ``qlap echo``, recorders).

Pure functions from an :class:`~qlap_runtime.qlap.agent.Agent` (and its world) to bus messages
(:mod:`qlap_runtime.bus.schema`), plus :class:`Cadence`, which says when each is due. Nothing
here touches Zenoh; the local driver (``tui/driver.py``) and, later, the actor runtime's
executor publish what these return. Every message is NaN-free (undefined numbers are −1).

- :func:`knowledge_msg` — :class:`~.schema.Knowledge`: actions with plans or calls, their
  plans in the reference's notation, landmarks, counters.
- :func:`call_list_msg` — :class:`~.schema.CallList`.
- :func:`iac_msgs` — :class:`~.schema.IACChoice` for the log entries newer than a step.
- :func:`world_msg` — :class:`~.schema.WorldView`.
- :func:`status_msg` — :class:`~.schema.AgentStatus`; :func:`stats_msg` — :class:`~.schema.Stats`.
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .bus.schema import (
    ActionInfo,
    AgentStatus,
    CallList,
    IACChoice,
    Knowledge,
    KnowledgeCounters,
    LandmarkInfo,
    PlanInfo,
    Stats,
    WorldView,
)
from .qlap.curiosity import fallback_weight, iac_weight
from .qlap.dbn import model_stats
from .qlap.variables import Kind

log = logging.getLogger("qlap.telemetry")

HISTORY = 32
"""rel(a) values per action carried in a snapshot (the sparkline's width)."""

_DOT = re.compile(r"\b(\w)(\w*)\.dot\b")
_NEG_ZERO = re.compile(r"(?<![\w.])-(0(?:\.0*)?)(?![\w.])")
_MINUS = re.compile(r"(?<![\w.])-(?=\.?\d)")


def pretty(text: str) -> str:
    """The reference's notation: ``h_x.dot`` → ``ḣ_x``, ``+inf`` → ``+∞``, ``-inf`` → ``−∞``
    (as ``qlap show``), a negative number's sign the same minus as −∞'s (``-2.5`` → ``−2.5``;
    a goal given so is read back, :meth:`~.qlap.agent.Agent.set_goal`), and a zero is ``0``,
    never ``-0`` (a motor's initial landmark)."""
    text = _DOT.sub(lambda m: m.group(1) + "\u0307" + m.group(2), text)
    text = _NEG_ZERO.sub(r"\1", text)
    text = _MINUS.sub("\u2212", text)
    return text.replace("+inf", "+∞").replace("-inf", "−∞")


def _finite(x: float | None, default: float = -1.0) -> float:
    if x is None:
        return default
    x = float(x)
    return x if math.isfinite(x) else default


def _action_label(agent: Any, key: tuple[int, int]) -> str:
    return pretty(agent.action_label(key))


def knowledge_msg(agent: Any) -> Knowledge:
    """A complete snapshot of the agent's knowledge (cheap: model statistics are computed only
    for the DBNs that are plans)."""
    learner, table, params = agent.learner, agent.table, agent.params
    by_action: dict[tuple[int, int], list[Any]] = {}
    for plan in agent.plans.values():
        by_action.setdefault(plan.action, []).append(plan)
    actions = []
    for key, st in agent.actions.items():
        plans = sorted(by_action.get(key, []), key=lambda p: p.id)
        if st.calls == 0 and not plans:
            continue
        infos = []
        best_rel_o = None
        for pl in plans:
            dbn = learner.dbns.get(pl.dbn_id)
            if dbn is None:
                continue
            ms = model_stats(dbn.cpt_s, dbn.cpt_f, len(dbn.context), params)
            rel_o = _finite(pl.rel(), 0.0)
            best_rel_o = rel_o if best_rel_o is None else max(best_rel_o, rel_o)
            infos.append(PlanInfo(
                pl.id, pl.dbn_id, pretty(learner.dbn_label(dbn)), str(pl.kind),
                _finite(ms.brel), _finite(ms.entropy, 0.0),
                tuple(pretty(table[v].name) for v in pl.context_o), rel_o, int(pl.calls),
                int(pl.space.n_states) if pl.space is not None else 0))
        rel = _finite(st.rel(params.prior), 0.5)
        if not infos:
            weight = -1.0
        else:
            w = iac_weight(st.history, params)
            weight = w if w is not None else fallback_weight(rel, best_rel_o or 0.0)
        actions.append(ActionInfo(
            _action_label(agent, key), table[key[0]].name, learner.value_label(*key), key[1],
            rel, int(st.calls), int(st.successes), bool(st.reliable), _finite(weight),
            tuple(_finite(x, 0.0) for x in list(st.history)[-HISTORY:]), tuple(infos)))

    landmarks: dict[str, tuple[LandmarkInfo, ...]] = {}
    n_landmarks = 0
    for v in table.of_kind(Kind.MOTOR, Kind.MAGNITUDE):
        space = learner.perception.spaces[v.index]
        rows = []
        for m, lm in zip(space.to_json(), space.landmarks, strict=True):
            source = str(m.get("source", ""))
            rows.append(LandmarkInfo(lm.label(), int(m.get("step") or 0), source))
            n_landmarks += source != "initial"
        landmarks[v.name] = tuple(rows)

    values: dict[str, tuple[str, ...]] = {}
    sizes = learner.perception.events.sizes
    for v in table:
        if v.kind is Kind.MOTOR:
            continue
        values[v.name] = tuple(learner.value_label(v.index, q) for q in range(int(sizes[v.index])))

    c = agent.counters
    reliable_actions = sum(1 for key, st in agent.actions.items()
                           if st.reliable and table[key[0]].kind is not Kind.MOTOR)
    counters = KnowledgeCounters(
        dbns=len(learner.dbns), reliable_dbns=sum(1 for d in learner.dbns.values()
                                                  if d.ever_reliable),
        plans=len(agent.plans), landmarks=n_landmarks, reliable_actions=reliable_actions,
        practice_calls=c.practice_calls, babble_commands=c.babble_commands,
        successes=c.successes, failures=c.failures)
    return Knowledge(max(agent.step_count, 0), int(learner.k), tuple(actions), landmarks,
                     counters, values, tuple(sorted(table[v].name for v in agent.self_vars)))


def knowledge_signature(agent: Any) -> tuple[int, ...]:
    """Cheap fingerprint of the knowledge: when it changes, a snapshot is due."""
    learner = agent.learner
    return (learner.applied_count, len(learner.dbns), len(agent.plans), agent.next_plan_id,
            agent.counters.successes + agent.counters.failures)


def call_list_msg(agent: Any) -> CallList:
    """The call list, outermost first, in the reference's notation."""
    return CallList(max(agent.step_count, 0), tuple(pretty(x) for x in agent.call_list_labels()))


def iac_msgs(agent: Any, after_step: int) -> list[IACChoice]:
    """IAC log entries of ``agent.iac_log`` made after ``after_step``, oldest first.

    The agent's log keeps only the probabilities of the applicable actions, in order, not their
    names, so ``weights`` is keyed ``#0, #1, ...`` in that order.
    """
    new = []
    for c in reversed(agent.iac_log):   # the steps only grow: stop at the first one seen
        if c.step <= after_step:
            break
        new.append(c)
    out = []
    for c in reversed(new):
        label = _action_label(agent, c.action) if c.action is not None else ""
        out.append(IACChoice(int(c.step), label, _finite(c.weight, 0.0), int(c.n_applicable),
                             bool(c.babbling),
                             {f"#{i}": _finite(w, 0.0) for i, w in enumerate(c.weights)}))
    return out


def world_msg(agent: Any, world: Any, width: int = 44, height: int = 14) -> WorldView:
    """The world as it is now, every row from the same step: the drawing, the raw values, the
    motor command that produced them (the agent's latest), and their qualitative values under
    the agent's current landmarks (what its next percept will be; a derivative is the change
    since the agent's latest percept, none across a discontinuity).

    The message's ``step`` is the agent's latest step t; the world is then at its own
    ``t + 1`` (the step the agent will sense next), which is what the UI calls step t + 1.
    """
    try:
        text = world.render_text(width, height)
    except Exception as e:  # a drawing must never stop the run
        text = f"(no drawing: {type(e).__name__})"
    obs = dict(world.observation)
    values = {k: _finite(v, 0.0) for k, v in obs.items()}
    motor = {k: _finite(v, 0.0) for k, v in agent.motor.items()}
    qualitative: dict[str, str] = {}
    if agent.last_percept is not None:
        try:
            qualitative = _qualitative_now(agent, {**obs, **agent.motor},
                                           bool(getattr(world, "discontinuity", False)))
        except (ValueError, KeyError, IndexError) as exc:  # a display never stops the run
            log.debug("world view without qualitative values: %s", exc)
            qualitative = {}
    return WorldView(agent.step_count, str(getattr(world, "name", "")), text, values,
                     motor, qualitative)


def _qualitative_now(agent: Any, full: dict[str, float], discontinuity: bool) -> dict[str, str]:
    """Labels of the qualitative values of ``full`` (world values and motor command) as the
    agent's perception would classify them, without changing it."""
    learner = agent.learner
    perception = learner.perception
    x = perception.vector(full)
    dt = perception.params.step_seconds
    for v in agent.table:
        if v.kind is Kind.CHANGE:
            x[v.index] = (np.nan if discontinuity
                          else (x[v.source] - perception.prev_x[v.source]) / dt)
    q = perception.quantize(x)
    return {v.name: learner.value_label(v.index, int(q[v.index]))
            for v in agent.table if q[v.index] >= 0}


def status_msg(agent: Any, *, steps_per_s: float, paused: bool, finished: bool = False,
               speed: float = 0.0, clock: str = "free", placement: str = "embedded",
               world: str = "", seed: int = 0, late_ticks: int = 0, missed_ticks: int = 0,
               wall_s: float = 0.0, message: str = "") -> AgentStatus:
    """The agent's runtime state; ``step`` is the agent's latest step t (−1 before the first),
    so t + 1 steps are done (the UI shows t + 1)."""
    goal = _action_label(agent, agent.goal) if agent.goal is not None else ""
    pending = len(getattr(agent.learner, "pending_deltas", ()) or ())
    return AgentStatus(agent.step_count, round(_finite(steps_per_s, 0.0), 1),
                       str(agent.mode), paused, finished, float(speed), clock, placement, world,
                       int(seed), goal, bool(agent.learning), int(pending), int(late_ticks),
                       int(missed_ticks), round(_finite(wall_s, 0.0), 3), message)


def stats_msg(status: AgentStatus, actor: str = "agent") -> Stats:
    """The generic :class:`~.schema.Stats` every actor publishes, from a status."""
    return Stats(status.step, actor, status.steps_per_s, late_ticks=status.late_ticks,
                 missed_ticks=status.missed_ticks)


@dataclass
class Cadence:
    """When each telemetry message is due (wall-clock seconds and agent steps).

    Display topics go out at most ``display_hz`` times a second; the knowledge snapshot every
    ``knowledge_every`` steps, as soon as :func:`knowledge_signature` changes, and at least every
    ``knowledge_max_s`` (for late viewers of a paused run), but never more often than
    ``knowledge_min_s``; stats every ``stats_s``. The knowledge snapshot of a grown agent is
    large (core after 30,000 steps: ~1,600 DBNs, 100 KB, ~35 ms to build and encode), so it
    goes out at most once a second: more would cost the agent several percent of its time.
    """

    display_hz: float = 10.0
    knowledge_every: int = 250
    knowledge_min_s: float = 1.0
    knowledge_max_s: float = 2.0
    stats_s: float = 1.0
    last_display: float = -math.inf
    last_knowledge: float = -math.inf
    last_knowledge_step: int = -(10**9)
    last_signature: tuple[int, ...] = ()
    last_stats: float = -math.inf
    last_iac_step: int = -1
    rate: list[tuple[float, int]] = field(default_factory=list)

    def display_due(self, now: float) -> bool:
        if now - self.last_display >= 1.0 / self.display_hz:
            self.last_display = now
            return True
        return False

    def knowledge_due(self, now: float, step: int, signature: tuple[int, ...]) -> bool:
        if now - self.last_knowledge < self.knowledge_min_s:
            return False
        if (signature != self.last_signature or step - self.last_knowledge_step
                >= self.knowledge_every or now - self.last_knowledge >= self.knowledge_max_s):
            self.last_knowledge, self.last_knowledge_step = now, step
            self.last_signature = signature
            return True
        return False

    def stats_due(self, now: float) -> bool:
        if now - self.last_stats >= self.stats_s:
            self.last_stats = now
            return True
        return False

    def steps_per_s(self, now: float, step: int, window: float = 1.0) -> float:
        """Step rate over about the last ``window`` seconds (call once per display tick)."""
        self.rate.append((now, step))
        while len(self.rate) > 2 and now - self.rate[1][0] >= window:
            self.rate.pop(0)
        (t0, s0), (t1, s1) = self.rate[0], self.rate[-1]
        return (s1 - s0) / (t1 - t0) if t1 > t0 else 0.0


def goal_key(agent: Any, var: str, value: Any) -> tuple[int, int]:
    """The action key (variable index, value index) that ``goal {"var", "value"}`` names: the
    value is an index or a label of the variable's quantity space (as the UI shows it)."""
    vi = agent.table.index(var)
    if type(value) is int:
        return vi, value
    labels = [agent.learner.value_label(vi, q)
              for q in range(int(agent.learner.perception.events.sizes[vi]))]
    for q, label in enumerate(labels):
        if str(value) in (label, pretty(label)):
            return vi, q
    raise ValueError(f"{value!r} is not a value of {var} ({', '.join(labels)})")
