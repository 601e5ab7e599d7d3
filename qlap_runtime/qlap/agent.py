"""The whole QLAP agent: Algorithm 2 as one synchronous, deterministic loop (ch. 5–6).

:class:`Agent` composes the model learner (ch. 4), the plans (§5.2–5.4) and the executor: the
call list of Algorithms 6 and 7 (Appendix F), termination (§5.2.3, §5.5.2), Sarsa(λ) and Dyna
(§5.2.2), exploration by motor babbling and IAC (§6.1, App. E), the developmental restrictions
(§6.2), targeted learning (§6.3), self (§6.4) and goal mode (§7.2.1).

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
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .actions import (
    ActionKey,
    ActionStats,
    ActionTable,
    PlanStats,
    motor_reachable,
    motor_value_for,
    plan_slots,
    rest_value,
    targeted,
)
from .babble import Babbler
from .context import update_contexts_many
from .curiosity import (
    IACChoice,
    action_weight,
    choose_action,
    choose_plan,
    iac_weight,
    plan_weight,
)
from .dbn import CHANGE, DBN, model_stats
from .learner import ModelLearner
from .mdp import (
    MDPAction,
    PlanStateSpace,
    Role,
    action_map,
    compose_split_maps,
    descendant_state,
    greedy_action,
    sarsa_reward,
    space_value_maps,
)
from .params import Params
from .perception import Percept
from .plan_delta import (
    AddPlan,
    DropContext,
    PlanContexts,
    PlanDelta,
    PlanOp,
    Rebuild,
    RemovePlan,
    SkipPlan,
)
from .planner import (
    ModelMemo,
    Plan,
    PlanGroups,
    PlanTooLarge,
    closes_cycle,
    dbn_rel_state,
    plan_entries,
)
from .probability import prob_above, success_probability
from .variables import Kind, VariableTable

RUN, SUCCESS, FAIL = "run", "success", "fail"
CHANGE_MINUS, CHANGE_ZERO, CHANGE_PLUS = 0, 1, 2


@dataclass
class Frame:
    """One action in the call list (§5.5.1); frame i + 1 is the sub-action of frame i."""

    key: ActionKey
    """The action a(v, q)."""
    started: int
    """Step at which it was called."""
    is_motor: bool = False
    plan_id: int = -1
    """The plan chosen to perform it (non-motor actions)."""
    sub: int = -1
    """Index of the plan's current MDP action; −1 none."""
    sub_state: int = -1
    """Plan state in which the current sub-action was called (for Sarsa)."""
    sub_started: int = 0
    calls: int = 0
    """Action calls made by the plan so far (≤ 5, §5.2.3)."""
    wait_until: int = -1
    """After the antecedent of a change plan succeeded: wait until this step (Alg. 7)."""
    last_change: int = 0
    """Last step at which the plan's state or a self variable changed (stuck rule)."""
    last_sig: tuple = ()
    call_x: np.ndarray | None = None
    """The real state at the call (second-order DBN statistics, §5.4.1)."""
    practised: bool = False
    """The top-level action chosen for practice (IAC) or as the goal."""

    def to_json(self) -> dict[str, Any]:
        return {"key": list(self.key), "started": self.started, "is_motor": self.is_motor,
                "plan_id": self.plan_id, "sub": self.sub, "sub_state": self.sub_state,
                "sub_started": self.sub_started, "calls": self.calls,
                "wait_until": self.wait_until, "last_change": self.last_change,
                "last_sig": list(self.last_sig), "practised": self.practised,
                "call_x": None if self.call_x is None else
                [None if np.isnan(v) else float(v) for v in self.call_x]}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Frame:
        cx = d["call_x"]
        return cls(tuple(d["key"]), d["started"], d["is_motor"], d["plan_id"], d["sub"],
                   d["sub_state"], d["sub_started"], d["calls"], d["wait_until"],
                   d["last_change"], tuple(d["last_sig"]),
                   None if cx is None else np.array([np.nan if v is None else v for v in cx]),
                   d["practised"])


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


class Agent:
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
    # knowledge changes: line 15 of Algorithm 2 and the consequences of new landmarks
    # ------------------------------------------------------------------------------------------
    def _sizes(self) -> list[int]:
        return list(self.learner.perception.events.sizes)

    def _follow_landmarks(self) -> dict[int, np.ndarray]:
        """New landmarks renumbered qualitative values (§4.4): the call list, the actions and
        the goal follow them. Returns the value maps (new value -> old) of the split
        variables, which the plans' rebuilds read."""
        splits, self.learner.splits = self.learner.splits, []
        sizes = self._sizes()
        value_maps = compose_split_maps(splits, sizes) if splits else {}
        cut = self._renumber_frames(splits, sizes)
        for var, split in splits:
            self.actions.on_landmark(var, split)
            if self.goal is not None and self.goal[0] == var and self.goal[1] > split:
                self.goal = (var, self.goal[1] + 2)
        self.actions.sync(sizes)
        if cut is not None:
            self._end_frames(cut)
        return value_maps

    def planning_copy(self, learner: ModelLearner, deep: bool = False) -> Agent:
        """A private copy of the agent's plans and actions as they are now, on ``learner``
        (the batch's learner, :meth:`~.learner.ModelLearner.take_batch`), for
        :meth:`compile_plans`. A compilation replaces a plan's arrays rather than writing into
        them, so the copies share them, unless ``deep`` (a compilation while this agent goes
        on, in another thread); the call list stays the executor's."""
        c = copy.copy(self)
        c.learner = learner
        memo = {id(self.params): self.params, id(self.table): self.table, id(self): c,
                id(self.learner): learner}
        c.actions = copy.deepcopy(self.actions, memo)
        c.plans = {pid: plan.snapshot() if deep else copy.copy(plan)
                   for pid, plan in self.plans.items()}
        c.call_list = []
        c.counters = copy.deepcopy(self.counters)
        c.pending_plans = deque()
        return c

    def compile_plans(self, t: int, apply_at: int) -> PlanDelta:
        """Plans follow a batch's knowledge (Algorithm 2 line 15, §5.2–5.4, §6.2), computed on
        a private copy (:meth:`planning_copy`, or the planner actor's agent) whose learner holds
        the batch at ``t`` with its deltas applied: removals (§6.2.2), second-order contexts
        (§5.4), DBNs converted to plans, and every plan's MDP rebuilt with value iteration for
        what has no learned values. Returns what it did, for :meth:`apply_plans` at
        ``apply_at``."""
        value_maps = self._follow_landmarks()
        if self.model_memo is not None:
            self.model_memo.clear()             # this compilation's models only
        self._compiling = ops = []
        try:
            # Plans whose DBN disappeared are removed; the others follow their DBN's structure.
            for pid in sorted(self.plans):
                plan = self.plans[pid]
                if self.learner.dbns.get(plan.dbn_id) is None \
                        or plan.stats_removed(self.params):
                    self._remove_plan(pid)
            ops.append(PlanContexts(self._update_plan_contexts()))
            self._convert_dbns_to_plans(t, apply_at)
            for pid in sorted(self.plans):
                plan = self.plans[pid]
                try:
                    self._rebuild(plan, value_maps=value_maps)
                except PlanTooLarge:
                    # Outgrew Params.max_plan_entries: first give up the variables of C_o
                    # (§5.4.2, the plan keeps its DBN's own space), and only if that is still
                    # too large remove the plan (docs/decisions.md 23).
                    if not plan.context_o:
                        self._remove_plan(pid)
                        continue
                    ops.append(DropContext(pid))
                    self._drop_context(plan)
                    try:
                        self._rebuild(plan, value_maps=value_maps)
                    except PlanTooLarge:
                        self._remove_plan(pid)
                        continue
                ops.append(Rebuild(pid, plan.last_planned))
        finally:
            self._compiling = None
        return PlanDelta(t, apply_at, tuple(ops))

    def apply_plans(self, delta: PlanDelta, p: Percept,
                    value_maps: Mapping[int, np.ndarray]) -> None:
        """Apply a compilation's operations (:meth:`compile_plans`) at a step boundary, after
        the batch's deltas and :meth:`_follow_landmarks`: its decisions and values of value
        iteration, on the executor's own statistics and Q-values (learned since the batch by
        Sarsa and Dyna, carried over by every rebuild). The call list keeps running unless a
        plan in it was removed or an action in it lost its meaning (docs/decisions.md)."""
        quantize = self.learner.perception.quantize_columns
        for op in delta.ops:
            match op:
                case RemovePlan(plan_id=pid):
                    if pid in self.plans:
                        self._remove_plan(pid)
                case PlanContexts(changes=changes):
                    for pid, context_o in changes:
                        if pid in self.plans:
                            self.plans[pid].context_o = context_o
                    sizes = self._sizes()
                    signature = self.learner.perception.landmark_signature
                    for pid in sorted(self.plans):
                        plan = self.plans[pid]
                        plan.recount(quantize, sizes, signature(sorted(plan.context_o)))
                        plan.refresh_reliable()
                case AddPlan(plan_id=pid, dbn_id=dbn_id, q=q):
                    dbn = self.learner.dbns.get(dbn_id)
                    if dbn is not None:
                        self._add_plan(dbn, delta.apply_at, plan_id=pid, planned=q)
                case SkipPlan():
                    self._count_too_large()
                case DropContext(plan_id=pid):
                    if pid in self.plans:
                        self._drop_context(self.plans[pid])
                case Rebuild(plan_id=pid, q=q):
                    plan = self.plans.get(pid)
                    if plan is not None:
                        old_space, old_actions = plan.space, plan.actions
                        if self._rebuild(plan, value_maps=value_maps, planned=q) \
                                and old_space is not None:
                            self._follow_structure(plan, old_space, old_actions, value_maps, p)
        self._update_self()

    def _follow_knowledge(self, p: Percept, value_maps: Mapping[int, np.ndarray]) -> None:
        """Knowledge changed without a compilation: plans whose DBN is gone are removed, the
        others rebuilt (value iteration here), as a compilation would (realtime clock)."""
        for pid in sorted(self.plans):
            plan = self.plans[pid]
            if self.learner.dbns.get(plan.dbn_id) is None:
                self._remove_plan(pid)
                continue
            old_space, old_actions = plan.space, plan.actions
            try:
                changed = self._rebuild(plan, value_maps=value_maps)
            except PlanTooLarge:
                self._remove_plan(pid)
                continue
            if changed and old_space is not None:
                self._follow_structure(plan, old_space, old_actions, value_maps, p)
        self._update_self()

    def _drop_context(self, plan: Plan) -> None:
        plan.context_o = ()
        plan.recount(self.learner.perception.quantize_columns, self._sizes())

    def _renumber_frames(self, splits: list[tuple[int, int]], sizes: list[int]) -> int | None:
        """Landmarks renumbered values (§4.4): shift the values the frames hold. A motor frame
        whose interval was split takes the part holding its commanded value; a frame whose goal
        interval was split has lost its meaning: the index of the first such frame, else None.
        """
        cut: int | None = None
        split_vars = set()
        for var, split in splits:
            split_vars.add(var)
            for i, f in enumerate(self.call_list):
                v, q = f.key
                if v != var:
                    continue
                if q > split:
                    f.key = (v, q + 2)
                elif q == split and not f.is_motor:
                    cut = i if cut is None else min(cut, i)
        for f in self.call_list:
            if f.is_motor and f.key[0] in split_vars:
                name = self.table[f.key[0]].name
                f.key = (f.key[0], self.learner.perception.spaces[f.key[0]].value_of(
                    self.motor[name]))
        return cut

    def _follow_structure(self, plan: Plan, old_space: PlanStateSpace,
                          old_actions: list[MDPAction], value_maps: dict[int, np.ndarray],
                          p: Percept) -> None:
        """The plan's space or actions changed under its running frame: carry the frame's
        current sub-action and its state to the new indices (:func:`~.mdp.descendant_state`).
        When that cannot be done the pending Sarsa update is dropped, and a running sub-action
        that is no longer an action of the plan ends (the plan then chooses again)."""
        i = next((j for j, f in enumerate(self.call_list) if f.plan_id == plan.id), None)
        if i is None:
            return
        f = self.call_list[i]
        assert plan.space is not None
        s_now = plan.space.index_from_full(p.q)
        f.last_sig = (s_now, *(int(p.q[v]) for v in sorted(self.self_vars)))
        if f.sub < 0:
            return
        child = self.call_list[i + 1] if i + 1 < len(self.call_list) else None
        maps = space_value_maps(old_space, plan.space, value_maps)
        new_sub: int | None = None
        if maps is not None:
            old_act = old_actions[f.sub]
            cands = np.flatnonzero(action_map(old_actions, plan.actions, maps) == f.sub)
            if old_act.role is Role.WAIT or child is None:
                new_sub = int(cands[0]) if cands.size == 1 else None
            else:
                match = [int(j) for j in cands
                         if (plan.actions[j].var, plan.actions[j].value) == child.key]
                new_sub = match[0] if match else None
        if new_sub is None:
            f.sub = -1
            if child is not None and (child.key[0], child.key[1]) not in \
                    {(a.var, a.value) for a in plan.actions}:
                self._end_frames(i + 1)
            return
        s_old = descendant_state(old_space, plan.space, value_maps, f.sub_state, p.q)
        f.sub = new_sub
        if s_old is None or not np.isfinite(plan.q[s_old, new_sub]):
            f.sub_state = -1                            # no Sarsa update for this one
        else:
            f.sub_state = s_old

    def _end_frames(self, i: int) -> None:
        """End frames i, i + 1, … without recording (knowledge changed under them); the frame
        above chooses its next action, without a Sarsa update for the ended one."""
        if i <= 0:
            self._interrupt()
            return
        del self.call_list[i:]
        parent = self.call_list[i - 1]
        parent.sub = -1
        self.counters.call_list_interrupts += 1

    def _interrupt(self) -> None:
        """Knowledge changed under the running call list: end it without recording."""
        self.call_list.clear()
        self.counters.call_list_interrupts += 1
        if self.mode in ("practice", "goal"):
            self.mode = "idle"

    def _rel_action(self, var: int, value: int) -> float:
        if self.table[var].kind is Kind.MOTOR:
            return 1.0                                   # primitive: always achieved (§5.5)
        key = (var, value)
        return self.actions[key].rel(self.params.prior) if key in self.actions else 0.5

    def _usable(self, var: int, value: int) -> bool:
        """a(var, value) can be performed at all: a motor value must meet the motor's range
        (§5.5); an action that cannot is not applicable in any plan."""
        v = self.table[var]
        if v.kind is not Kind.MOTOR:
            return True
        return motor_reachable(self.learner.perception.spaces[var], value, v.low, v.high)

    def _rebuild(self, plan: Plan, fresh: bool = False,
                 value_maps: Mapping[int, np.ndarray] | None = None,
                 planned: np.ndarray | None = None) -> bool:
        self._plans_changed()
        dbn = self.learner.dbns[plan.dbn_id]
        sizes = self._sizes()
        return plan.build(dbn, sizes, self._rel_action,
                          dbn_rel_state(dbn, sizes, self.params.prior), fresh=fresh,
                          value_maps=value_maps, usable=self._usable, planned=planned,
                          memo=self.model_memo)

    def _refresh(self, plan: Plan) -> None:
        dbn = self.learner.dbns.get(plan.dbn_id)
        if dbn is None:
            return
        sizes = self._sizes()
        plan.refresh(self._rel_action, dbn_rel_state(dbn, sizes, self.params.prior),
                     dyna=not self.params.ablations.no_dyna, usable=self._usable)

    def _update_plan_contexts(self) -> tuple[tuple[int, tuple[int, ...]], ...]:
        """Second-order DBNs learn C_o like other DBNs; C_o joins the plan's space (§5.4).

        The plans' searches (Algorithm 3, :meth:`Plan.update_context`) are independent: they
        are made together (:func:`~.context.update_contexts_many`, the same answers), then
        each plan follows its answer in order of id. Returns (plan id, new C_o) of each plan
        whose C_o changed."""
        sizes = self._sizes()
        perception = self.learner.perception
        quantize = perception.quantize_columns
        searches: list[tuple[Plan, list[int], object, tuple, np.ndarray, np.ndarray]] = []
        todo: list[tuple[Plan, list[int], object, int]] = []
        for pid in sorted(self.plans):
            plan = self.plans[pid]
            dbn = self.learner.dbns[plan.dbn_id]
            cands = [v for v in self.learner.context_candidates(dbn) if v not in dbn.context]
            # The quantity spaces the second-order DBN's counts and its C_o search read: those
            # of the candidates and of C_o (landmarks of other variables leave them unchanged).
            version = perception.landmark_signature(sorted({*cands, *plan.context_o}))
            plan.recount(quantize, sizes, version)
            search = plan.context_search(cands, version)
            todo.append((plan, cands, version, len(searches) if search is not None else -1))
            if search is not None:
                searches.append((plan, cands, version, *search))
        answers: list[tuple[int, ...] | None] = []
        if searches:
            # As StoredActivations.quantized for each: the variables searched, quantized at
            # once as columns 0, 1, … in order of index (an increasing renumbering).
            cols = sorted({v for _, cands, *_ in searches for v in cands}
                          | {v for plan, *_ in searches for v in plan.context_o})
            at = {v: i for i, v in enumerate(cols)}
            Q_all = perception.quantize_values(
                np.concatenate([X[:, cols] for *_, X, _ in searches]), cols)
            problems = []
            row = 0
            for plan, cands, _, _, X, ok in searches:
                problems.append((tuple(at[v] for v in plan.context_o), [at[v] for v in cands],
                                 Q_all[row:row + len(X)], ok))
                row += len(X)
            answers = [None if a is None else tuple(cols[i] for i in a) for a in
                       update_contexts_many(problems, [sizes[v] for v in cols], self.params)]
        changes = []
        for plan, _, version, j in todo:
            dbn = self.learner.dbns[plan.dbn_id]
            before = plan.context_o
            if j >= 0 and plan.context_found(searches[j][3], answers[j], quantize, sizes,
                                             version) and \
                    plan_entries(plan.context_o, dbn, sizes) > self.params.max_plan_entries:
                plan.context_o = before                 # too large a state space: keep C_o
                plan.recount(quantize, sizes, version)
            plan.refresh_reliable()
            if plan.context_o != before:
                changes.append((plan.id, plan.context_o))
        return tuple(changes)

    def _plan_edges(self) -> set[tuple[ActionKey, ActionKey]]:
        edges = set()
        for plan in self.plans.values():
            dbn = self.learner.dbns[plan.dbn_id]
            edges.add(((dbn.consequent.var, dbn.consequent.value),
                       (dbn.antecedent.var, dbn.antecedent.value)))
        return edges

    def _antecedent_achievable(self, dbn: DBN, targeted: bool = False) -> bool:
        """§6.2.2 criterion 1 (NRP): "there is a sufficiently reliable plan to achieve the
        antecedent event", i.e. a plan of a(X, x) whose second-order model had brel(o) > θ_SR
        (§5.4.1, :meth:`Plan.refresh_reliable`); for ↑X → x (↓X → x) the plan reaching x from
        below (above). A motor antecedent is always achievable (§5.5). The text states the rule
        for change DBNs; a magnitude DBN ⟨Ẏ → [±] ⇒ Y → y⟩ needs a plan of a(Ẏ, [±]) (the
        applicability of magnitude actions, §6.1.1), reliable or not (docs/decisions.md).
        With ``Params.nrp_targeted`` a DBN whose consequent is ``targeted`` (§6.3) also takes
        a plan whose brel(o) is above θ_SR = 0.25 now (docs/decisions.md 75, 89)."""
        if self.params.ablations.nrp:
            return True
        a = dbn.antecedent
        if self.table[a.var].kind is Kind.MOTOR:
            return True
        on_magnitude = self.table[a.var].kind is Kind.MAGNITUDE
        for plan in self.plans.values():
            if plan.action != (a.var, a.value):
                continue
            if on_magnitude and plan.goal.direction != a.direction:
                continue
            if dbn.kind != CHANGE or self._plan_reliable(plan):
                return True
            if targeted and self.params.nrp_targeted and self._reliable_cells(
                    plan.cpt_s, plan.cpt_f, self.params.theta_sr_targeted):
                return True
        return False

    def _convert_dbns_to_plans(self, t: int, created: int | None = None) -> None:
        """Line 15 of Algorithm 2 with the restrictions of §6.2.1–6.2.2 and §6.3, at step
        ``t``; a new plan exists from step ``created`` (default ``t``).

        The DBNs that qualify compete for the plan slots best first: highest overall
        reliability rel(r) (Table 5.1; how often it works from the states the agent is in, as
        §6.2.2 judges plans by rel(o)), then highest brel, lowest entropy H(r), the older DBN.
        """
        p = self.params
        targeted_mask = targeted(self.learner.perception.satisfied_fraction(), p)
        index = self.learner.perception.events
        dbn_of_plan = {plan.dbn_id for plan in self.plans.values()}
        with_plans = {plan.action for plan in self.plans.values()}
        ranked: list[tuple[tuple[bool, float, float, int], DBN, bool]] = []
        for dbn_id in sorted(self.learner.dbns):
            dbn = self.learner.dbns[dbn_id]
            if dbn_id in dbn_of_plan:
                continue
            key = (dbn.consequent.var, dbn.consequent.value)
            if key not in self.actions or (self.actions[key].sufficiently_reliable(p)
                                           and key in with_plans):
                continue                                              # §6.2.1 item 2
            tgt = False
            if dbn.kind == CHANGE:
                cons_id = index.cons_of_event[index.encode(dbn.consequent)]
                tgt = bool(targeted_mask[cons_id]) if cons_id >= 0 else False
                if not (dbn.ever_reliable or (tgt and self._reliable_at(dbn, p.theta_sr_targeted))):
                    continue                                          # §5.2, §6.3
            st = model_stats(dbn.cpt_s, dbn.cpt_f, len(dbn.context), p)
            overall = success_probability(float(dbn.cpt_s.sum()), float(dbn.cpt_f.sum()),
                                          p.prior)
            ranked.append(((-overall, st.brel is None, -(st.brel or 0.0), st.entropy, dbn_id),
                           dbn, tgt))
        ranked.sort(key=lambda r: r[0])
        adj: dict[ActionKey, list[ActionKey]] = {}              # the edges of _plan_edges
        for a, b in self._plan_edges():
            adj.setdefault(a, []).append(b)
        for _, dbn, tgt in ranked:
            key = (dbn.consequent.var, dbn.consequent.value)
            if not self._antecedent_achievable(dbn, tgt):
                continue
            edge = (key, (dbn.antecedent.var, dbn.antecedent.value))
            if closes_cycle(adj, edge):
                continue                                              # §6.2.2 criterion 2
            mine = [pl for pl in self.plans.values() if pl.action == key]
            if dbn.kind != CHANGE:
                # Magnitude actions have their two plans, one from each side (§5.3).
                if any(pl.goal.direction == dbn.consequent.direction for pl in mine):
                    continue
            else:
                change_plans = sorted((pl for pl in mine if pl.kind == CHANGE), key=lambda x: x.id)
                slots = plan_slots([self._slot_stats(pl, t) for pl in change_plans], p,
                                   self.actions[key] if mine else None)   # decision 36
                for i in slots.remove:
                    self._remove_plan(change_plans[i].id)
                if not slots.accepts_new:
                    continue
                if slots.free <= 0 and slots.replaceable is not None:
                    self._remove_plan(change_plans[slots.replaceable].id)
            if self._add_plan(dbn, t if created is None else created) is not None \
                    and edge[1] not in adj.get(edge[0], ()):
                adj.setdefault(edge[0], []).append(edge[1])

    def _plan_reliable(self, plan: Plan) -> bool:
        """A sufficiently reliable plan (§5.4.1, §6.2.2): brel(o) > θ_SR at some time, or,
        with ``Params.plan_reliable == "dbn"``, its DBN sufficiently reliable (decision 105)."""
        if plan.ever_reliable:
            return True
        if self.params.plan_reliable != "dbn":
            return False
        dbn = self.learner.dbns.get(plan.dbn_id)
        return dbn is not None and dbn.ever_reliable

    def _slot_stats(self, plan: Plan, t: int) -> PlanStats:
        """The plan's slot counts (§6.2.2), "sufficiently reliable" by :meth:`_plan_reliable`."""
        st = plan.plan_stats(t)
        if not st.reliable and self._plan_reliable(plan):
            st = replace(st, reliable=True)
        return st

    def _reliable_at(self, dbn: DBN, theta: float) -> bool:
        return self._reliable_cells(dbn.cpt_s, dbn.cpt_f, theta, len(dbn.context))

    def _reliable_cells(self, cpt_s: np.ndarray, cpt_f: np.ndarray, theta: float,
                        n_context: int = 0) -> bool:
        """App. B's test at ``theta`` in the best cell of a CPT (brel > theta)."""
        st = model_stats(cpt_s, cpt_f, n_context, self.params)
        if st.brel is None:
            return False
        i = int(np.argmax((cpt_s + 1) / (cpt_s + cpt_f + 2) * (cpt_s >= 5)))
        return prob_above(theta, float(cpt_s[i]), float(cpt_f[i]), self.params.prior,
                          self.params.beta_confidence)

    def _add_plan(self, dbn: DBN, created: int, plan_id: int | None = None,
                  planned: np.ndarray | None = None) -> Plan | None:
        """A new plan of ``dbn`` (id ``plan_id``, default the next one), planned by value
        iteration unless ``planned`` gives Q* (§5.2.2)."""
        if plan_entries((), dbn, self._sizes()) > self.params.max_plan_entries:
            self._count_too_large()
            if self._compiling is not None:
                self._compiling.append(SkipPlan(dbn.id))
            return None
        pid = self.next_plan_id if plan_id is None else plan_id
        plan = Plan(pid, dbn, self.table, self.params, created, len(self.table))
        self.next_plan_id = max(self.next_plan_id, pid + 1)
        self.plans[plan.id] = plan
        dbn.is_plan = True
        self._rebuild(plan, fresh=True, planned=planned)  # plan_entries bounds its size
        self.counters.plans_created += 1
        if self._compiling is not None:
            self._compiling.append(AddPlan(pid, dbn.id, plan.q.copy()))
        return plan

    def _count_too_large(self) -> None:
        self.counters.extra["plans_too_large"] = \
            self.counters.extra.get("plans_too_large", 0) + 1

    def _remove_plan(self, pid: int) -> None:
        if self._compiling is not None:
            self._compiling.append(RemovePlan(pid))
        plan = self.plans.pop(pid)
        self._plans_changed()
        dbn = self.learner.dbns.get(plan.dbn_id)
        if dbn is not None:
            dbn.is_plan = False
        i = next((j for j, f in enumerate(self.call_list) if f.plan_id == pid), None)
        if i is not None:
            self._end_frames(i)
        self.counters.plans_removed += 1

    def _update_self(self) -> None:
        """§6.4: change (and nominal) variables the agent controls reliably and quickly."""
        k = self.learner.k
        self.self_vars = {v.index for v in self.table if v.kind in (Kind.CHANGE, Kind.NOMINAL)
                          and self.actions.is_self(v.index, v.kind, k)}
        # §6.2.1 restricts learning for a sufficiently reliable action so long as it has a plan
        # to be performed with: an action that lost its plans (their DBNs deleted or merged by
        # a landmark) learns again, or it could never be performed (docs/decisions.md).
        with_plans = {plan.action for plan in self.plans.values()}
        reliable = {key for key, st in self.actions.items()
                    if self.table[key[0]].kind is not Kind.MOTOR and st.reliable
                    and key in with_plans}
        self.learner.reliable_actions = reliable                    # §6.2.1

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
    # the call list (Algorithms 6 and 7)
    # ------------------------------------------------------------------------------------------
    def _achieved(self, key: ActionKey, p: Percept) -> bool:
        return self._q_list(p)[key[0]] == key[1]

    def _q_list(self, p: Percept) -> list[int]:
        """``p.q.tolist()`` (Python ints), kept for the percept of the step (the executor
        reads single values of it many times per step)."""
        cached = self.__dict__.get("_q_cache")
        if cached is not None and cached[0] is p:
            return cached[1]
        q = p.q.tolist()
        self._q_cache = (p, q)
        return q

    def _self_sorted(self) -> tuple[int, ...]:
        """``sorted(self.self_vars)``, kept while ``self_vars`` is the same set of the same
        size (:meth:`_update_self` assigns a new one)."""
        cached = self.__dict__.get("_self_cache")
        sv = self.self_vars
        if cached is not None and cached[0] is sv and cached[1] == len(sv):
            return cached[2]
        out = tuple(sorted(sv))
        self._self_cache = (sv, len(sv), out)
        return out

    def _iac_weight(self, stats: ActionStats) -> float | None:
        """:func:`~.curiosity.iac_weight` of an action, cached until its next record (the
        history changes only in :meth:`ActionStats.record`, which counts a call)."""
        cache = self.__dict__.setdefault("_iac_cache", {})
        key = id(stats)
        hit = cache.get(key)
        if hit is not None and hit[0] is stats and hit[1] is stats.history \
                and hit[2] == stats.calls and hit[3] == len(stats.history):
            return hit[4]
        w = iac_weight(stats.history, self.params)
        cache[key] = (stats, stats.history, stats.calls, len(stats.history), w)
        return w

    def _usable_plans(self, key: ActionKey, p: Percept, plans: list[Plan]) -> list[Plan]:
        """Plans of a(v, q) usable in this state: none on a discontinuity step (the agent's
        state is not fully known: no direction of change has a value, so the plans a call
        leads to cannot run; docs/decisions.md 39), else those whose state is known (no plan
        variable without a value) and magnitude plans from the current side."""
        if p.discontinuity:
            return []        # the state is not fully known (no direction of change is defined)
        full = self._q_list(p)
        known = sorted((pl for pl in plans
                        if pl.space is not None and pl.space.index_from_full(full) is not None),
                       key=lambda pl: pl.id)
        return self._from_side(key, known, full)

    def _from_side(self, key: ActionKey, plans: list[Plan], q_list: list[int]) -> list[Plan]:
        """The plans of a(v, q) that reach q from the current side of v (magnitude actions
        have a plan from each side, §5.3); all of them for other variables."""
        var, q = key
        if self.table[var].kind is not Kind.MAGNITUDE:
            return plans
        side = 1 if q_list[var] < q else -1
        return [pl for pl in plans if pl.goal.direction == side]

    def _o_cell(self, plan: Plan, x: np.ndarray) -> int:
        cell = 0
        sizes = self.learner.perception.events.sizes
        for v in plan.context_o:
            q = self.learner.value_of(v, x[v])
            if q < 0:
                return -1
            cell = cell * sizes[v] + q
        return cell

    def _pick_plan(self, plans: list[Plan], p: Percept,
                   q_list: list[int] | None = None) -> int | None:
        """§6.1.2: ε-greedy on w = rel(r, s)·rel(o, s); plans whose antecedent action is in
        the call list are excluded. ``q_list`` is ``p.q.tolist()`` when the caller has it."""
        w, excluded, _ = self._plan_weights(plans, p.q.tolist() if q_list is None else q_list)
        return choose_plan(w, excluded, self.rng, self.params.plan_epsilon)

    def _plan_weights(self, plans: list[Plan], q: list[int]
                      ) -> tuple[list[float], list[bool], list[float]]:
        """Per plan (§6.1.2): w = rel(r, s)·rel(o, s) (eq. 6.3), whether its antecedent action
        is in the call list, and rel(o, s), in the state ``q`` (``p.q.tolist()``)."""
        in_list = {f.key for f in self.call_list}
        w, excluded, rel_os = [], [], []
        prior = self.params.prior
        dbns = self.learner.dbns
        sizes = self.learner.perception.events.sizes
        for plan in plans:
            dbn = dbns[plan.dbn_id]
            ante = dbn.antecedent
            excluded.append((ante.var, ante.value) in in_list)
            cell = _cell_of(dbn.context, q, sizes) if dbn.context else 0
            # rel(r, s) of the one cell (eq. B.1); a cell without counts (−1) has none
            sc, fc = (float(dbn.cpt_s[cell]), float(dbn.cpt_f[cell])) \
                if 0 <= cell < len(dbn.cpt_s) else (0.0, 0.0)
            rel_rs = (sc + prior) / (sc + fc + 2 * prior)
            rel_o = plan.rel_state(_cell_of(plan.context_o, q, sizes) if plan.context_o else 0)
            rel_os.append(rel_o)
            w.append(plan_weight(rel_rs, rel_o))
        return w, excluded, rel_os

    def _call(self, key: ActionKey, p: Percept, practised: bool = False) -> str:
        """Algorithm 6: push a(v, q) on the call list; RUN or FAIL (the frame is then gone)."""
        var, q = key
        t = p.step
        v = self.table[var]
        if v.kind is Kind.MOTOR:
            if not self._usable(var, q):
                return FAIL                                  # out of the motor's range (§5.5)
            value = motor_value_for(self.learner.perception.spaces[var], q, v.low, v.high,
                                    self.rng)
            self.motor[v.name] = value
            self.call_list.append(Frame(key, t, is_motor=True, practised=practised))
            return RUN
        plans = self._usable_plans(key, p, self._plan_groups().plans_of(key))
        idx = self._pick_plan(plans, p) if plans else None
        if idx is None:
            if self.learning:
                self.actions.record(key, False, None, practised)  # §5.5.2: no usable plan
            return FAIL
        plan = plans[idx]
        # §5.5 footnote 5: called by a plan while already achieved, a direction-of-change
        # action's plan acts as if it were not, to give the motor command that keeps it.
        as_if = None
        if (self.params.achieved_call == "support" and self.call_list
                and v.kind is Kind.CHANGE and q != CHANGE_ZERO and self._achieved(key, p)):
            as_if = (var, CHANGE_ZERO)
        frame = Frame(key, t, plan_id=plan.id, last_change=t, call_x=p.x.copy(),
                      practised=practised)
        self.call_list.append(frame)
        depth = len(self.call_list) - 1
        assert plan.sarsa is not None
        if self._sarsa_on():
            self._keep_for_trial(plan)
            plan.sarsa.reset()
        status = self._next_sub(depth, p, first=True, as_if=as_if)
        if status == FAIL:
            self._terminate(depth, FAIL, p)
        return status

    def _plan_state(self, plan: Plan, p: Percept,
                    as_if: tuple[int, int] | None = None) -> int | None:
        """The plan's state in ``p``; ``as_if`` (var, value): with that variable at that value."""
        assert plan.space is not None
        full = self._q_list(p)
        if as_if is not None:
            full = list(full)
            full[as_if[0]] = as_if[1]
        return plan.space.index_from_full(full)

    def _next_sub(self, i: int, p: Percept, first: bool = False,
                  as_if: tuple[int, int] | None = None) -> str:
        """Choose and call the plan's next action by its policy (ε-greedy, §6.1.3);
        ``as_if`` (var, value): from the state with that variable at that value."""
        f = self.call_list[i]
        plan = self.plans[f.plan_id]
        s2 = self._plan_state(plan, p, as_if)
        if s2 is None:
            return FAIL
        goal = bool(plan.model is not None and plan.model.goal[s2])
        if f.calls >= self.params.option_max_calls:
            self._sarsa(plan, f, p, s2, goal, None)
            return FAIL                                          # §5.2.3 resource limit
        a2 = greedy_action(plan.q, s2, self.rng, self.params.policy_epsilon)
        if not first:
            self._sarsa(plan, f, p, s2, goal, a2)
        if a2 is None:
            return FAIL                                          # §5.5.2 plan rule 2
        f.sub, f.sub_state, f.sub_started = a2, s2, p.step
        if first and plan.sarsa is not None and self._sarsa_on():
            self._keep_for_trial(plan)
            plan.sarsa.start(s2, a2)
        act = plan.actions[a2]
        if act.role is Role.WAIT:
            return RUN                                           # hold the motors (§5.3.1)
        key2 = (act.var, act.value)
        if any(fr.key == key2 for fr in self.call_list):
            return FAIL                                          # §5.5.2 plan rule 3
        f.calls += 1
        status = self._call(key2, p)
        if status == FAIL:
            # Rule 4: the sub-action failed as it was called, and the plan fails with it. It
            # has terminated, so Sarsa updates its pair as terminal (§5.2.2), or the policy
            # would choose it from this state again and again (docs/decisions.md 40).
            self._sarsa(plan, f, p, s2, False, None)
        return status

    def _sarsa_on(self) -> bool:
        """Sarsa learns while the agent learns, unless ablated (§5.2.2, §7.11); with learning
        off it still learns within a trial when ``Params.sarsa_in_trials`` (undone by
        :meth:`end_trial`)."""
        return (self.learning or self.params.sarsa_in_trials) \
            and not self.params.ablations.no_sarsa

    def _keep_for_trial(self, plan: Plan) -> None:
        """With learning off, keep the plan's Q-table and traces as they were before this
        trial's first Sarsa step on it, for :meth:`end_trial`."""
        if not self.learning and plan.id not in self._trial_saved:
            assert plan.sarsa is not None
            self._trial_saved[plan.id] = (plan.q.copy(), plan.sarsa.e.copy())

    def end_trial(self) -> None:
        """Undo what Sarsa learned during a trial with learning off (``sarsa_in_trials``):
        every Q-table and trace is back to its value before the trial, bit for bit."""
        for pid, (q, e) in self._trial_saved.items():
            plan = self.plans[pid]
            assert plan.sarsa is not None
            plan.q[...] = q                          # in place: Sarsa shares the array
            plan.sarsa.e[...] = e
        self._trial_saved = {}

    def _sarsa(self, plan: Plan, f: Frame, p: Percept, s2: int, goal: bool,
               a2: int | None) -> None:
        """Eq. 5.7 for the sub-action f.sub called in f.sub_state, ended in s2; a2 the next."""
        if not self._sarsa_on() or plan.sarsa is None or f.sub < 0 or f.sub_state < 0:
            return
        if not np.isfinite(plan.q[f.sub_state, f.sub]):
            return                                       # no longer a pair of this plan
        r = sarsa_reward(goal, p.step - f.sub_started, self.params)
        if a2 is not None and not plan.model.applicable[s2, a2]:  # type: ignore[union-attr]
            a2 = None
        self._keep_for_trial(plan)
        plan.sarsa.update(f.sub_state, f.sub, r, s2, a2)

    def _process(self, i: int, p: Percept) -> str:
        """Algorithm 7 for frame i (and, recursively, those below it)."""
        f = self.call_list[i]
        t = p.step
        if f.is_motor:
            return SUCCESS if (t > f.started and self._achieved(f.key, p)) else RUN
        plan = self.plans.get(f.plan_id)
        if plan is None:
            return FAIL
        if self._stuck_or_out_of_time(f, plan, p):     # Alg. 7 line 3 before line 5
            self._end_sub(i, p, goal=False)
            return FAIL
        if t > f.started and self._achieved(f.key, p):
            self._end_sub(i, p, goal=True)
            return SUCCESS
        if f.wait_until >= 0:                           # waiting k steps after the antecedent
            if t < f.wait_until:
                return RUN
            f.wait_until = -1
            return self._next_sub(i, p)
        act = plan.actions[f.sub] if f.sub >= 0 else None
        if act is not None and act.role is Role.WAIT:
            dbn = self.learner.dbns[plan.dbn_id]
            if self._achieved((dbn.antecedent.var, dbn.antecedent.value), p):
                return RUN                              # still moving the right way
            return self._next_sub(i, p)
        if i + 1 >= len(self.call_list):
            return self._next_sub(i, p)
        status = self._process(i + 1, p)
        if status == RUN:
            return RUN
        sub = self.call_list[i + 1]
        self._terminate(i + 1, status, p)
        dbn = self.learner.dbns[plan.dbn_id]
        if (status == SUCCESS and plan.kind == CHANGE
                and sub.key == (dbn.antecedent.var, dbn.antecedent.value)):
            f.wait_until = t + self.learner.k           # Alg. 7 lines 18–20
            return RUN
        return self._next_sub(i, p)

    def _stuck_or_out_of_time(self, f: Frame, plan: Plan, p: Percept) -> bool:
        t = p.step
        if t - f.started >= self.params.option_max_steps:
            return True
        s = self._plan_state(plan, p)
        q = self._q_list(p)
        sig = (s, *[q[v] for v in self._self_sorted()])
        if sig != f.last_sig:
            f.last_sig, f.last_change = sig, t
            return False
        return t - f.last_change >= self.params.stuck_steps

    def _end_sub(self, i: int, p: Percept, goal: bool) -> None:
        """The plan of frame i ends: terminal Sarsa update for its running sub-action."""
        f = self.call_list[i]
        plan = self.plans.get(f.plan_id)
        if plan is not None and f.sub >= 0:
            s2 = self._plan_state(plan, p)
            if s2 is not None:
                self._sarsa(plan, f, p, s2, goal, None)

    def _terminate(self, i: int, status: str, p: Percept) -> Frame:
        """Frame i terminated: the frames below end with it (a list, not a stack, §5.5.1);
        record rel(a), rel(o) and refresh the plan's model (Dyna)."""
        f = self.call_list[i]
        del self.call_list[i:]
        success = status == SUCCESS
        if not f.is_motor and self.learning:
            self.actions.record(f.key, success, p.step - f.started if success else None,
                                f.practised)
            plan = self.plans.get(f.plan_id)
            if plan is not None and f.call_x is not None:
                plan.record_call(f.call_x, success, self._o_cell(plan, f.call_x))
                plan.refresh_reliable()
                self._refresh(plan)
        return f

    def _finish_top(self, status: str, p: Percept) -> Frame:
        top = self._terminate(0, status, p)
        if status == SUCCESS:
            self.counters.successes += 1
        else:
            self.counters.failures += 1
        return top

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
    def to_state(self) -> dict[str, Any]:
        """As JSON, ``seen_applied``: the learner's ``applied_count`` when the plans last
        followed a batch (:meth:`decide`), and the plan deltas not yet applied. Every other
        part of the agent's state is in public fields (``qlap_runtime/qlap/checkpoint.py``
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

    @property
    def last_percept(self) -> Percept | None:
        """The percept of the latest step (:meth:`decide`), None before the first."""
        return self._last_percept


def _cell_of(ctx: tuple[int, ...], q: np.ndarray | list[int], sizes) -> int:
    """Mixed-radix cell of the values ``q[v]`` of the variables ``ctx`` with radices
    ``sizes[v]`` (−1 if one is unavailable): a DBN's or plan's CPT cell of a state."""
    cell = 0
    for v in ctx:
        qv = int(q[v])
        if qv < 0:
            return -1
        cell = cell * sizes[v] + qv
    return cell
