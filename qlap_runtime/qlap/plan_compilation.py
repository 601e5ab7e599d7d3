"""Plan compilation: what the plans do when the knowledge changes (Algorithm 2 line 15).

:class:`PlanCompilation` is the part of :class:`~.agent.Agent` that follows a batch: plans
whose DBN disappeared are removed, the others follow their DBN's structure and new landmarks
(§4.4), second-order contexts are found (§5.4), DBNs become plans under the developmental
restrictions (§6.2: sufficiently reliable, NRP, the plan slots of §6.2.2) and targeted
learning (§6.3), every plan's MDP is rebuilt with value iteration where it has no learned
values (§5.2–5.3), and self is updated (§6.4). A compilation runs on a planning copy
(:meth:`PlanCompilation.planning_copy`) and returns a :class:`~.plan_delta.PlanDelta` applied
at t + L (:meth:`PlanCompilation.apply_plans`; the planner actor computes the same,
docs/decisions.md 56). It works on the agent's fields (``plans``, ``actions``, ``learner``,
``params``, ``call_list``, ``goal``).
"""

from __future__ import annotations

import copy
from collections import deque
from collections.abc import Mapping
from dataclasses import replace
from typing import TYPE_CHECKING, cast

import numpy as np

from .actions import ActionKey, PlanStats, motor_reachable, plan_slots, targeted
from .context import update_contexts_many
from .dbn import CHANGE, DBN, model_stats
from .learner import ModelLearner
from .mdp import (
    MDPAction,
    PlanStateSpace,
    Role,
    action_map,
    compose_split_maps,
    descendant_state,
    space_value_maps,
)
from .perception import Percept
from .plan_delta import AddPlan, DropContext, PlanContexts, PlanDelta, Rebuild, RemovePlan, SkipPlan
from .planner import Plan, PlanTooLarge, closes_cycle, dbn_rel_state, plan_entries
from .probability import prob_above, success_probability
from .variables import Kind

if TYPE_CHECKING:
    from .actions import ActionKey, ActionTable
    from .agent import Agent, AgentCounters
    from .call_list import Frame
    from .params import Params
    from .plan_delta import PlanOp
    from .planner import ModelMemo
    from .variables import VariableTable


class PlanCompilation:
    """Line 15 of Algorithm 2 on the agent's plans (a mixin of :class:`~.agent.Agent`)."""

    if TYPE_CHECKING:   # the agent's fields and methods this part uses (Agent's __init__)
        actions: ActionTable
        call_list: list[Frame]
        counters: AgentCounters
        goal: ActionKey | None
        goal_dropped: tuple[int, str] | None
        step_count: int
        learner: ModelLearner
        mode: str
        model_memo: ModelMemo | None
        next_plan_id: int
        motor: dict[str, float]
        params: Params
        pending_plans: deque[PlanDelta]
        plans: dict[int, Plan]
        table: VariableTable
        _compiling: list[PlanOp] | None

        def _plans_changed(self) -> None: ...

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
        cut = self._renumber_frames(splits)
        for var, split in splits:
            self.actions.on_landmark(var, split)
            if self.goal is not None and self.goal[0] == var:
                if self.goal[1] > split:
                    self.goal = (var, self.goal[1] + 2)
                elif self.goal[1] == split:
                    self._drop_split_goal(var, split)
        self.actions.sync(sizes)
        if splits:
            # The plans' goals and actions renumbered as their DBNs' consequents were, before
            # anything reads them: a compilation converts DBNs (one plan from each side,
            # §5.3; criterion 1, §6.2.2) before it rebuilds the plans. With the old numbers
            # the plans of a split value's neighbours stood for the new values, whose
            # magnitude DBNs then got no plan until the next batch, and criterion 1 read the
            # wrong plan (docs/decisions.md 120).
            for plan in self.plans.values():
                dbn = self.learner.dbns.get(plan.dbn_id)
                if dbn is not None:
                    plan.follow_dbn(dbn)
            self._plans_changed()
        if cut is not None:
            self._end_frames(cut)
        return value_maps

    def _drop_split_goal(self, var: int, split: int) -> None:
        """A landmark split the goal's value into three (§4.4): no one of them is the value
        the user asked for, so the goal is dropped rather than silently narrowed to the lower
        part, and :attr:`goal_dropped` says why (the UI shows it; docs/decisions.md 121)."""
        v = self.table[var]
        label = self.learner.value_label
        parts = ", ".join(label(var, q) for q in range(split, split + 3))
        self.goal_dropped = (self.step_count, f"goal on {v.name} dropped at step "
                             f"{self.step_count + 1}: a new landmark split its value into "
                             f"{parts}; give the goal again")
        self.goal = None
        self.mode = "idle"

    def planning_copy(self, learner: ModelLearner, deep: bool = False) -> Agent:
        """A private copy of the agent's plans and actions as they are now, on ``learner``
        (the batch's learner, :meth:`~.learner.ModelLearner.take_batch`), for
        :meth:`compile_plans`. A compilation replaces a plan's arrays rather than writing into
        them, so the copies share them, unless ``deep`` (a compilation while this agent goes
        on, in another thread); the call list stays the executor's."""
        c = cast("Agent", copy.copy(self))
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
        for op in delta.ops:
            match op:
                case RemovePlan(plan_id=pid):
                    if pid in self.plans:
                        self._remove_plan(pid)
                case PlanContexts(changes=changes):
                    for pid, context_o in changes:
                        if pid in self.plans:
                            self.plans[pid].context_o = context_o
                    self._recount_plans(refresh_reliable=True)
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
        # The second-order CPTs in the new numbering of their C_o, as a plan delta's
        # PlanContexts recounts them (rel(o, s) and the calls read and write their cells).
        self._recount_plans()
        self._update_self()

    def _recount_plans(self, refresh_reliable: bool = False) -> None:
        """Every plan's second-order CPT recounted over its C_o in the current values (§5.4),
        and with ``refresh_reliable`` its sticky reliability flag set if it is now earned."""
        quantize, sizes = self.learner.perception.quantize_columns, self._sizes()
        signature = self.learner.perception.landmark_signature
        for pid in sorted(self.plans):
            plan = self.plans[pid]
            plan.recount(quantize, sizes, signature(sorted(plan.context_o)))
            if refresh_reliable:
                plan.refresh_reliable()

    def _drop_context(self, plan: Plan) -> None:
        plan.context_o = ()
        plan.recount(self.learner.perception.quantize_columns, self._sizes())

    def _renumber_frames(self, splits: list[tuple[int, int]]) -> int | None:
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
        # A sub-action whose state was lost by an earlier rebuild has none to follow.
        s_old = descendant_state(old_space, plan.space, value_maps, f.sub_state, p.q) \
            if f.sub_state >= 0 else None
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
                       update_contexts_many(problems, [sizes[v] for v in cols], self.params,
                                            [plan.ever_reliable for plan, *_ in searches])]
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

