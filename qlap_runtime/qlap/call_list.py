"""The call list: how a called action runs (Algorithms 6 and 7, Appendix F; §5.5).

:class:`CallList` is the part of :class:`~.agent.Agent` that executes actions: choosing the
plan that performs a called action (§6.1.2, eq. 6.3, ε-greedy), its policy's sub-actions
(§6.1.3), termination (§5.2.3: success, 300 steps, 5 calls, stuck 10 steps; §5.5.2), the wait
of k steps after a change plan's antecedent (Algorithm 7), Sarsa(λ) within an option and Dyna
after it (§5.2.2), and the statistics rel(a) and rel(o) recorded when an action ends (§6.1.1,
§5.4.1). It works on the agent's fields (``call_list``, ``plans``, ``actions``, ``learner``,
``params``, ``rng``, ``learning``); :class:`~.agent.Agent` composes it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from .actions import ActionKey, ActionStats, motor_value_for
from .curiosity import choose_plan, iac_weight, plan_weight
from .dbn import CHANGE
from .mdp import Role, greedy_action, sarsa_reward
from .perception import Percept
from .planner import Plan
from .variables import Kind

if TYPE_CHECKING:
    from .actions import ActionTable
    from .agent import AgentCounters
    from .learner import ModelLearner
    from .params import Params
    from .planner import PlanGroups
    from .variables import VariableTable

RUN, SUCCESS, FAIL = "run", "success", "fail"
CHANGE_ZERO = 1
"""The value [0] of a direction-of-change variable (Q = {[−], [0], [+]} = 0, 1, 2)."""


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


class CallList:
    """Algorithms 6 and 7 on the agent's call list (a mixin of :class:`~.agent.Agent`)."""

    if TYPE_CHECKING:   # the agent's fields and methods this part uses (Agent's __init__)
        actions: ActionTable
        call_list: list[Frame]
        counters: AgentCounters
        learner: ModelLearner
        learning: bool
        motor: dict[str, float]
        params: Params
        plans: dict[int, Plan]
        rng: np.random.Generator
        self_vars: set[int]
        table: VariableTable
        _trial_saved: dict[int, tuple[np.ndarray, np.ndarray]]

        def _plan_groups(self) -> PlanGroups: ...
        def _refresh(self, plan: Plan) -> None: ...
        def _usable(self, var: int, value: int) -> bool: ...

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
        # The stuck rule counts from the call (§5.2.3: nothing "change[s] in 10 timesteps"):
        # the state at the call is the one to compare with.
        frame = Frame(key, t, plan_id=plan.id, last_change=t, call_x=p.x.copy(),
                      practised=practised, last_sig=self._stuck_signature(plan, p))
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
        sig = self._stuck_signature(plan, p)
        if sig != f.last_sig:
            f.last_sig, f.last_change = sig, t
            return False
        return t - f.last_change >= self.params.stuck_steps

    def _stuck_signature(self, plan: Plan, p: Percept) -> tuple:
        """What the stuck rule watches (§5.2.3): the plan's state and the self variables."""
        q = self._q_list(p)
        return (self._plan_state(plan, p), *[q[v] for v in self._self_sorted()])

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
