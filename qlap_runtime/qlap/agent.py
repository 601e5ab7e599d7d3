"""The whole QLAP agent: Algorithm 2 as one synchronous, deterministic loop (ch. 5–6).

:class:`Agent` composes the model learner (ch. 4), the plans (§5.2–5.4) and the executor. This
module holds the step, exploration by motor babbling and IAC (§6.1, App. E), goal mode
(§7.2.1) and the agent's state; two parts live beside it: :mod:`.plan_compilation` (Algorithm 2
line 15: plans follow the knowledge, the developmental restrictions of §6.2, targeted learning
§6.3, self §6.4) and :mod:`.call_list` (Algorithms 6 and 7: executing a called action,
termination §5.2.3, Sarsa(λ) and Dyna §5.2.2).

One step (:meth:`Agent.step`): the percept of step t is the world's sensed values plus the motor
values currently applied (those commanded at t − 1); the learner observes it (and runs or
applies batches on schedule); a batch is followed by a plan compilation (line 15) on a copy
(:meth:`Agent.compile_plans`), whose plan delta is applied with the batch's deltas at t + L
(:meth:`Agent.apply_plans`; the planner actor computes the same, docs/decisions.md 56); then the
executor returns the motor command of step t.
"""

from __future__ import annotations

import copy
import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .actions import ActionKey, ActionTable, rest_value
from .babble import Babbler
from .call_list import FAIL, RUN, SUCCESS, CallList, Frame
from .curiosity import IACChoice, action_weight, choose_action, choose_plan
from .learner import ModelLearner
from .mdp import Role
from .params import Params
from .perception import Percept
from .plan_compilation import PlanCompilation
from .plan_delta import PlanDelta, PlanOp
from .planner import ModelMemo, Plan, PlanGroups
from .variables import Kind, VariableTable

__all__ = ["FAIL", "RUN", "SUCCESS", "Agent", "AgentCounters", "Frame"]


@dataclass
class AgentCounters:
    """Counts for the summary and the UI."""

    practice_calls: int = 0
    babble_commands: int = 0
    successes: int = 0
    failures: int = 0
    plans_created: int = 0
    plans_removed: int = 0
    call_list_interrupts: int = 0
    rejected_observations: int = 0
    extra: dict[str, int] = field(default_factory=dict)


class Agent(PlanCompilation, CallList):
    """QLAP: learner + plans + executor, stepping in lockstep with a world (Algorithm 2)."""

    def __init__(self, variables: VariableTable | Any, params: Params | None = None,
                 seed: int = 0) -> None:
        self.params = params or Params()
        self.learner = ModelLearner(variables, self.params)
        self.table = self.learner.table
        self.seed: int | None = seed
        """The seed the agent was made with (a checkpoint's agent: its run's; None if the
        checkpoint predates it)."""
        self.rng = np.random.default_rng(seed)
        self.babbler = Babbler(self.table, self.params, self.rng)
        self.actions = ActionTable(self.params)
        self.actions.sync(self._sizes())
        self.plans: dict[int, Plan] = {}
        self.next_plan_id = 0
        self.call_list: list[Frame] = []
        self.motors = self.table.of_kind(Kind.MOTOR)
        self.rest = {m.name: rest_value(m.low, m.high) for m in self.motors}
        """Rest posture: each motor at 0, or the value of its range nearest to 0."""
        self.motor = dict(self.rest)
        self.mode = "babble"          # babble | command | practice | hold | goal | idle
        self.hold_until = -1
        self.goal: ActionKey | None = None
        self.goal_idle = "babble"      # what goal mode does with no plan: babble | zero
        self.goal_dropped: tuple[int, str] | None = None
        """(step, why) of the last goal a new landmark split and so dropped (decision 121)."""
        self.learning = True
        """False: evaluation (§7.2). Nothing learned changes: no statistics of actions and
        plans, no Dyna, no model learning (the learner only perceives); Sarsa only within a
        trial, undone by :meth:`end_trial` (``Params.sarsa_in_trials``)."""
        self._trial_saved: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.iac_log: deque[IACChoice] = deque(maxlen=200)
        self.counters = AgentCounters()
        self.self_vars: set[int] = set()
        self.step_count = -1
        self._seen_applied = 0
        self._last_percept: Percept | None = None
        self.pending_plans: deque[PlanDelta] = deque()
        """Plan deltas computed at a batch step t, applied at t + L (:meth:`compile_plans`)."""
        self.model_memo: ModelMemo | None = ModelMemo()
        """The models of the last compilation, shared with its planning copy (decision 109);
        None: every build makes its own."""
        self._compiling: list[PlanOp] | None = None
        """While :meth:`compile_plans` runs: the operations recorded so far."""

    # ------------------------------------------------------------------------------------------
    # Algorithm 2, one step
    # ------------------------------------------------------------------------------------------
    def step(self, t: int, obs: Mapping[str, float],
             discontinuity: bool = False) -> dict[str, float]:
        """Sense step t (the world's values), learn, and return the motor command of step t.

        ``discontinuity``: the world jumped since step t − 1 (a replaced block, a new trial);
        no derivative, event or learning window spans it (the learner's business), and the
        running call list ends unrecorded (:meth:`decide`).
        """
        full = dict(obs)
        full.update(self.motor)
        if self.learning:
            p = self.learner.observe(t, full, discontinuity=discontinuity)
            work = self.learner.take_batch()
            if work is not None:
                # Line 15 on the batch's snapshot, applied at t + L with the batch's deltas
                # (what the planner actor computes, docs/decisions.md 56).
                self.pending_plans.append(self.planning_copy(work).compile_plans(
                    t, t + self.params.batch_lag))
        else:
            x = self.learner.perception.vector(full)
            p = self.learner.perception.perceive(t, x, copy=False, discontinuity=discontinuity,
                                                 remember=False)
        return self.decide(p)

    def decide(self, p: Percept) -> dict[str, float]:
        """After the learner observed ``p`` (and applied the deltas due): the call list follows
        new landmarks, the plan deltas due are applied (Algorithm 2 line 15), then the executor
        chooses the motor command."""
        self.step_count = p.step
        self._last_percept = p
        if p.discontinuity and self.call_list:
            self._interrupt()                   # the world moved, not the agent's actions
        value_maps: dict[int, np.ndarray] | None = None
        if self.learner.applied_count != self._seen_applied:
            self._seen_applied = self.learner.applied_count
            value_maps = self._follow_landmarks()
        if self.pending_plans and self.pending_plans[0].apply_at <= p.step:
            while self.pending_plans and self.pending_plans[0].apply_at <= p.step:
                self.apply_plans(self.pending_plans.popleft(), p, value_maps or {})
                value_maps = {}
        elif value_maps is not None:
            # Knowledge without its plan delta (the realtime clock applies what has arrived):
            # the plans follow it here, so that no plan outlives its DBN or its space.
            self._follow_knowledge(p, value_maps)
        self._act(p)
        return dict(self.motor)

    # ------------------------------------------------------------------------------------------
    # choosing what to do (§6.1)
    # ------------------------------------------------------------------------------------------
    def set_goal(self, var: int | str, value: int | str, idle: str = "babble") -> ActionKey:
        """Goal mode (§7.2.1): call a(var, value) and execute; ``idle`` when it has no plan."""
        if isinstance(var, str):
            var = self.table.index(var)
        v = self.table[var]
        if isinstance(value, str):
            value = self._value_named(v, value)
        size = self._sizes()[var]
        if not 0 <= int(value) < size:
            raise ValueError(f"value {value} outside Q({v.name}) (0..{size - 1})")
        if idle not in ("babble", "zero"):
            raise ValueError(f"idle must be 'babble' or 'zero', got {idle!r}")
        self.goal = (var, int(value))
        self.goal_idle = idle
        self.call_list.clear()
        self.mode = "idle"
        return self.goal

    def _value_named(self, v: Any, text: str) -> int:
        """The qualitative value of ``v`` that ``text`` names: ``+``/``[+]``, ``-``, ``0`` of
        a change variable; a nominal value's name; for a magnitude or motor variable a label as
        :meth:`ModelLearner.value_label` writes it (``(-inf, -2.5)``, ``[0.5, 0.6]``; ASCII
        ``-inf``/``inf`` accepted), a number (the value holding it), or ``#N`` (index N)."""
        if v.kind is Kind.CHANGE:
            names = {"-": 0, "[-]": 0, "0": 1, "[0]": 1, "+": 2, "[+]": 2}
        elif v.kind is Kind.NOMINAL:
            names = {name: i for i, name in enumerate(v.values)}
        else:
            space = self.learner.perception.spaces[v.index]

            def norm(label: str) -> str:
                return "".join(label.split()).replace("−", "-").replace("∞", "inf") \
                    .replace("+inf", "inf")

            names = {norm(space.label(q)): q for q in range(space.size)}
            names.update({f"[{name}]": q for name, q in list(names.items())
                          if q % 2 == 1 and not name.startswith("[")})   # a point landmark
            t = norm(text)
            if t in names:
                return names[t]
            if t.startswith("#") and t[1:].isdigit():
                return int(t[1:])
            try:
                x = float(t)
            except ValueError:
                x = math.nan
            if math.isfinite(x):
                return space.value_of(x)
            raise ValueError(f"{v.name} has no value {text!r}: give a number (the value "
                             f"holding it), #INDEX (0..{space.size - 1}) or one of "
                             f"{', '.join(space.label(q) for q in range(space.size))}")
        if text in names:
            return names[text]
        raise ValueError(f"{v.name} ({v.kind.value}) has no value {text!r}: one of "
                         f"{', '.join(dict.fromkeys(names))}")

    def new_episode(self) -> None:
        """A new trial (§7.2.1): forget the goal and the running call list, break the
        learner's histories (no derivative, event or window spans the jump), put the motors at
        rest and restart the babbler's hold counters, so nothing commanded in the previous
        episode (a babbled u_x = 803) is held into this one."""
        self.goal = None
        self.call_list.clear()
        self.mode = "idle"
        self.hold_until = -1
        self.end_trial()
        self.learner.break_history()
        self.motor = dict(self.rest)
        self.babbler.restart()

    def clear_goal(self) -> None:
        self.goal = None
        self.call_list.clear()
        self.mode = "idle"

    def _act(self, p: Percept) -> None:
        t = p.step
        if self.goal is not None:
            self._act_goal(p)
            return
        if t < self.params.babble_steps:
            self.mode = "babble"
            self.motor, _ = self.babbler.step()
            return
        if self.mode == "command":
            self.motor, done = self.babbler.step()
            if done:
                self.mode = "idle"
            return
        if self.mode == "hold":
            if t < self.hold_until:
                return
            self.mode = "idle"
        if self.mode == "practice" and self.call_list:
            status = self._process(0, p)
            if status == RUN:
                return
            top = self._finish_top(status, p)
            if status == SUCCESS and self.table[top.key[0]].kind is Kind.CHANGE:
                self.mode = "hold"                     # keep the last motor value k steps
                self.hold_until = t + self.learner.k
                return
            self.mode = "idle"
        self._choose_exploration(p)

    def _act_goal(self, p: Percept) -> None:
        assert self.goal is not None
        if self.call_list:
            status = self._process(0, p)
            if status == RUN:
                return
            self._finish_top(status, p)
        if self._achieved(self.goal, p):
            return                                      # the trial's success test ends it
        status = self._call(self.goal, p, practised=True)
        if status == FAIL:
            self.call_list.clear()
            if self.goal_idle == "zero":
                self.motor = dict(self.rest)
            else:
                self.motor, _ = self.babbler.step()
            self.mode = "idle"
        else:
            self.mode = "goal"

    def _choose_exploration(self, p: Percept) -> None:
        t = p.step
        if self.rng.random() < self.params.babble_probability:
            self._start_command(t, 0)
            return
        applicable, weights = self._applicable(p)
        if not applicable:
            self._start_command(t, 0)
            return
        key, probs = choose_action(applicable, weights, self.rng,
                                   no_iac=self.params.ablations.no_iac)
        assert key is not None
        i = applicable.index(key)
        self.iac_log.append(IACChoice(t, key, float(probs[i]), len(applicable), False,
                                      tuple(float(x) for x in probs)))
        self.motor = dict(self.rest)                    # rest posture for a new practice
        self.counters.practice_calls += 1
        status = self._call(key, p, practised=True)
        if status == FAIL:
            self.call_list.clear()
            self.mode = "idle"
        else:
            self.mode = "practice"

    def _start_command(self, t: int, n_applicable: int) -> None:
        self.iac_log.append(IACChoice(t, None, 0.0, n_applicable, True))
        self.counters.babble_commands += 1
        self.mode = "command"
        self.motor, done = self.babbler.step()
        if done:
            self.mode = "idle"

    def _applicable(self, p: Percept) -> tuple[list[ActionKey], list[float]]:
        """§6.1.1: actions not achieved now that could be performed, with their IAC weights
        (none on a discontinuity step, as :meth:`_usable_plans`)."""
        out, weights = [], []
        if p.discontinuity:
            return out, weights
        groups = self._plan_groups()
        q_list = self._q_list(p)
        # Actions not achieved now (:meth:`_achieved`) with a usable plan (known state, from
        # the current side: :meth:`_usable_plans`), tested for all plans at once.
        found, usable = groups.usable(p.q, self._magnitude_vars())
        for g in found:
            key = groups.keys[g]
            stats = self.actions[key]
            w = self._iac_weight(stats)
            if w is None:                 # fewer than 50 calls: eq. 6.2 with the chosen plan
                plans = [pl for pl, r in zip(groups.groups[g], groups.rows[g], strict=True)
                         if usable[r]]
                w_plans, excluded, rel_os = self._plan_weights(plans, q_list)
                idx = choose_plan(w_plans, excluded, self.rng, self.params.plan_epsilon)
                w = action_weight(stats, None if idx is None else rel_os[idx], self.params)
            out.append(key)
            weights.append(w)
        return out, weights

    def _magnitude_vars(self) -> frozenset[int]:
        """The magnitude variables (their actions have a plan from each side, §5.3)."""
        cached = self.__dict__.get("_magnitudes")
        if cached is None:
            cached = self._magnitudes = frozenset(
                v.index for v in self.table if v.kind is Kind.MAGNITUDE)
        return cached

    def _plan_groups(self) -> PlanGroups:
        """The plans by action (:class:`~.planner.PlanGroups`), kept until a plan is added,
        removed or rebuilt (:meth:`_rebuild`, :meth:`_remove_plan`: the only changes of the
        plans' actions, goals and spaces), or ``self.plans`` is another dict or size."""
        stamp = (self.__dict__.get("_plans_version", 0), id(self.plans), len(self.plans))
        cached = self.__dict__.get("_groups_cache")
        if cached is not None and cached[0] == stamp:
            return cached[1]
        groups = PlanGroups(self.plans)
        self._groups_cache = (stamp, groups)
        return groups

    def _plans_changed(self) -> None:
        """A plan was added, removed or rebuilt: the plan groups are void."""
        self._plans_version = self.__dict__.get("_plans_version", 0) + 1

    # ------------------------------------------------------------------------------------------
    # reading
    # ------------------------------------------------------------------------------------------
    def action_label(self, key: ActionKey) -> str:
        return f"a({self.table[key[0]].name}, {self.learner.value_label(*key)})"

    def call_list_labels(self) -> list[str]:
        return [self.action_label(f.key) for f in self.call_list]

    def waiting(self) -> bool:
        """Whether the deepest running plan waits with the motors held: a magnitude plan's wait
        action (§5.3.1, "maintaining its current motor value") or a change plan's k steps after
        its antecedent (Alg. 7 lines 18–20)."""
        if not self.call_list or self.call_list[-1].is_motor:
            return False
        f = self.call_list[-1]
        if f.wait_until >= 0:
            return True
        plan = self.plans.get(f.plan_id)
        return (plan is not None and 0 <= f.sub < len(plan.actions)
                and plan.actions[f.sub].role is Role.WAIT)

    def knowledge(self) -> dict[str, Any]:
        """Landmarks, DBNs (with plan flags), actions with their plans (knowledge.json)."""
        k = self.learner.knowledge()
        by_action: dict[ActionKey, list[Plan]] = {}
        for plan in self.plans.values():
            by_action.setdefault(plan.action, []).append(plan)
        acts = []
        for key, st in self.actions.items():
            plans = sorted(by_action.get(key, []), key=lambda x: x.id)
            if st.calls == 0 and not plans:
                continue
            acts.append({
                "variable": self.table[key[0]].name, "value": self.learner.value_label(*key),
                "index": key[1], "label": self.action_label(key),
                "reliability": round(st.rel(self.params.prior), 12), "calls": st.calls,
                "successes": st.successes, "sufficiently_reliable": st.reliable,
                "plans": [{"id": pl.id, "dbn": pl.dbn_id,
                           "dbn_label": self.learner.dbn_label(self.learner.dbns[pl.dbn_id]),
                           "kind": pl.kind, "rel_o": round(pl.rel(), 12), "calls": pl.calls,
                           "sufficiently_reliable": pl.ever_reliable,
                           "context_o": [self.table[v].name for v in pl.context_o],
                           "states": pl.space.n_states if pl.space else 0}
                          for pl in plans]})
        k["actions"] = acts
        k["self"] = sorted(self.table[v].name for v in self.self_vars)
        return k


    # ------------------------------------------------------------------------------------------
    # state (checkpoints): the bookkeeping that no public field holds
    # ------------------------------------------------------------------------------------------
    def checkpoint_copy(self) -> Agent:
        """A copy holding what a checkpoint saves (``checkpoint.save_agent``), to be written in
        another thread while this agent goes on (docs/decisions.md 125): a deep copy, except
        that each plan is its :meth:`~.planner.Plan.snapshot` with a copy of its Sarsa traces
        (what a plan does not write in place it replaces, so the snapshot may share it) and
        that the last compilation's model memo, which no checkpoint holds, is left out. The
        files written from it are those of a deep copy, byte for byte, in a third of its time
        at 250,000 core steps."""
        memo: dict[int, Any] = {id(self.params): self.params, id(self.table): self.table}
        if self.model_memo is not None:
            memo[id(self.model_memo)] = None
        for plan in self.plans.values():
            memo[id(plan)] = plan.snapshot(traces=True)
        return copy.deepcopy(self, memo)

    def to_state(self) -> dict[str, Any]:
        """As JSON, ``seen_applied``: the learner's ``applied_count`` when the plans last
        followed a batch (:meth:`decide`), and the plan deltas not yet applied. Every other
        part of the agent's state is in public fields (``qlap_runtime/qlap/checkpoint/``
        writes them); :meth:`load_state` is the inverse."""
        return {"seen_applied": self._seen_applied,
                "pending_plans": [d.to_json() for d in self.pending_plans]}

    def load_state(self, state: Mapping[str, Any]) -> None:
        """Restore :meth:`to_state`'s fields."""
        self._seen_applied = int(state["seen_applied"])
        self.pending_plans = deque(PlanDelta.from_json(d)
                                   for d in state.get("pending_plans", []))

    def restore_plan(self, plan: Plan, q: np.ndarray | None = None) -> None:
        """Add a plan read from a checkpoint (its DBN in the learner): its state space is built
        from the DBN as for a new plan, with its saved Q-table ``q`` (else value iteration);
        the caller then puts back its Q-table and traces."""
        self.plans[plan.id] = plan
        self._rebuild(plan, fresh=True, planned=q)

    def goal_held(self) -> bool:
        """The goal holds in the latest step's percept (goal mode: nothing to do)."""
        p = self._last_percept
        return self.goal is not None and p is not None and self._achieved(self.goal, p)

    @property
    def last_percept(self) -> Percept | None:
        """The percept of the latest step (:meth:`decide`), None before the first."""
        return self._last_percept
