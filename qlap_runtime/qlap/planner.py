"""Plans: DBNs turned into small MDPs and options (§5.2–5.4, §6.2.2).

A :class:`Plan` is the option o = ⟨I, π, β⟩ made from one change or magnitude DBN: its state
space Q(C_o) × Q(C) × Q(X) × Q(Y), its action set and transition model (:mod:`.mdp`), a Q-table
learned by value iteration and then refined by Sarsa(λ) and Dyna, and the statistics of the
second-order DBN r_o² = ⟨C_o : call(t, o) ⇒ succeeds(t, o)⟩ that give rel(o), rel(o, s) and the
extra context C_o.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from .actions import PlanStats
from .context import StoredActivations, update_context
from .dbn import (
    CHANGE,
    DBN,
    ModelStats,
    cell_reliabilities,
    context_cells,
    counts_by_cell,
    model_stats,
)
from .mdp import (
    MDPAction,
    PlanSpec,
    PlanStateSpace,
    SarsaLambda,
    TransitionModel,
    build_actions,
    dyna_sweep,
    grow_q,
    value_iteration,
)
from .params import Params
from .ring import ring_push, ring_rows
from .variables import Event, Kind, VariableTable

RelAction = Callable[[int, int], float]
"""rel(a) of the action a(var, value)."""
Usable = Callable[[int, int], bool]
"""Whether the action a(var, value) can be performed at all (a motor value in range, §5.5)."""


class PlanTooLarge(ValueError):
    """The plan's Q-table would exceed ``Params.max_plan_entries``."""


def plan_entries(context_o, dbn: DBN, sizes) -> int:
    """(states × an upper bound of actions) of the plan a DBN would give with extra context
    ``context_o``: the size check before anything is built."""
    vars_ = set(context_o) | set(dbn.context) | {dbn.antecedent.var, dbn.consequent.var}
    n_states = int(np.prod([int(sizes[v]) for v in vars_]))
    n_actions = sum(int(sizes[v]) for v in vars_) + 1
    return n_states * n_actions


class ModelMemo:
    """The transition models a compilation built, by what each is a function of (a plan's
    structure and the reliabilities it read), so that the executor's rebuild of the same plan
    with the same inputs takes the model instead of building it again (docs/decisions.md 109).
    Shared by an agent and its planning copies; a deep copy (a checkpoint's) starts empty."""

    def __init__(self) -> None:
        self._models: dict[tuple, TransitionModel] = {}
        self.hits = 0
        """How many builds took a model from here (for tests and benchmarks)."""

    def get(self, key: tuple) -> TransitionModel | None:
        model = self._models.get(key)
        self.hits += model is not None
        return model

    def put(self, key: tuple, model: TransitionModel) -> None:
        self._models[key] = model

    def clear(self) -> None:
        self._models.clear()

    def __len__(self) -> int:
        return len(self._models)

    def __deepcopy__(self, memo: dict[int, Any]) -> ModelMemo:
        return ModelMemo()


class Plan:
    """One option for the action a(Y, y), built from DBN ``dbn_id`` (§5.2, §5.3)."""

    def __init__(self, plan_id: int, dbn: DBN, table: VariableTable, params: Params,
                 created: int, n_vars: int) -> None:
        self.id = plan_id
        self.dbn_id = dbn.id
        self.kind = dbn.kind
        self.created = created
        self.params = params
        g = dbn.consequent
        self.goal = Event(g.var, g.value, g.direction if dbn.kind != CHANGE else 0)
        self.action = (g.var, g.value)
        self.context_o: tuple[int, ...] = ()
        # Second-order DBN statistics (§5.4.1): calls with the state at the call, and outcome.
        cap = params.stored_activations
        self.call_x = np.full((cap, n_vars), np.nan)
        self.call_ok = np.zeros(cap, dtype=bool)
        self.call_n = 0
        self.call_head = 0
        self.calls = 0
        self.successes = 0
        self.cpt_s = np.zeros(1)
        self.cpt_f = np.zeros(1)
        self.q = np.zeros((1, 1))
        self.sarsa: SarsaLambda | None = None
        self.model: TransitionModel | None = None
        self._model_cache: tuple[tuple, tuple, TransitionModel] | None = None
        """(structure, reliabilities, model) of the last :meth:`_model`, reused while they
        hold."""
        self.space: PlanStateSpace | None = None
        self.actions: list[MDPAction] = []
        self.spec: PlanSpec | None = None
        self._usable_flags: tuple[bool, ...] | None = None
        """Each action's usability at the last build or refresh (see :meth:`_flags`)."""
        self.ever_reliable = False
        """Sticky: brel(o) > θ_SR at some time (§5.4.1); see :meth:`refresh_reliable`."""
        self.last_planned: np.ndarray | None = None
        """Q* computed by value iteration in the last :meth:`build` (None: none needed)."""
        self._context_unchanged: tuple | None = None
        """The inputs of the last C_o search that found no change (see update_context)."""
        self._recounted: tuple | None = None
        """The inputs of the last :meth:`recount` (a pure cache, never saved)."""
        self._magnitudes = frozenset(v.index for v in table if v.kind is Kind.MAGNITUDE)
        self._nominals = frozenset(v.index for v in table if v.kind is Kind.NOMINAL)
        self._dot_of = {v.source: v.index for v in table if v.kind is Kind.CHANGE}

    # -- structure ------------------------------------------------------------------------------
    def follow_dbn(self, dbn: DBN) -> None:
        """The goal and the action from the DBN's consequent, which a landmark may have
        renumbered (§4.4): until the plan is rebuilt, what it is a plan of is read from them
        (§5.3's one plan from each side, §6.2.2's criterion 1)."""
        g = dbn.consequent
        goal = Event(g.var, g.value, g.direction if self.kind != CHANGE else 0)
        if goal != self.goal:
            self.goal = goal                     # equal: kept (the same object)
        self.action = (g.var, g.value)

    def build(self, dbn: DBN, sizes: Mapping[int, int] | list[int], rel_action: RelAction,
              rel_model: Callable[[PlanStateSpace], np.ndarray], fresh: bool = False,
              value_maps: Mapping[int, np.ndarray] | None = None,
              usable: Usable | None = None, planned: np.ndarray | None = None,
              memo: ModelMemo | None = None) -> bool:
        """(Re)build the MDP from the DBN's current structure; keep Q if the space is unchanged.

        A fresh plan is planned by value iteration (§5.2.2). When the state space or the action
        list changed (new landmarks, contexts), the learned Q-values are carried over to the
        new space (:func:`~.mdp.grow_q`: each old state's values go to its descendants, via the
        ``new_to_old`` ``value_maps`` of the variables that gained landmarks); only pairs with
        no ancestor take the values of value iteration on the new model, and Dyna refines the
        rest as the model improves. ``usable(var, value)`` False removes a(var, value) from the
        plan (a motor value out of the motor's range, §5.5). Returns True when the structure
        changed (state and action indices of the old space are void).

        ``planned``: Q* of the new model computed elsewhere (a plan compilation, §5.2.2), used
        instead of value iteration here when it has the model's shape; :attr:`last_planned`
        is the Q* this build computed itself (None when it needed none). ``memo``: models
        built elsewhere from the same inputs (:class:`ModelMemo`), and where this one goes.
        """
        self.last_planned = None
        self.follow_dbn(dbn)                     # landmarks may have renumbered it
        ante = dbn.antecedent
        spec = PlanSpec(goal=self.goal, antecedent=ante, magnitude_plan=self.kind != CHANGE,
                        magnitude_vars=self._magnitudes)
        groups = [self.context_o, dbn.context, [ante.var], [self.goal.var]]
        space = PlanStateSpace.from_groups(groups, {v: int(sizes[v]) for g in groups for v in g})
        if self.space is not None and space == self.space:
            space = self.space                   # equal: keep the one with its cached arrays
        actions = build_actions(space, spec)
        # Equal ones are kept (as the space): the model cache then compares identical objects.
        if spec == self.spec:
            spec = self.spec
        if actions == self.actions:
            actions = self.actions
        if space.n_states * len(actions) > self.params.max_plan_entries:
            raise PlanTooLarge(f"plan for DBN {self.dbn_id}: {space.n_states} states × "
                               f"{len(actions)} actions > {self.params.max_plan_entries}")
        same = (not fresh and self.space is not None and space == self.space
                and actions == self.actions and spec == self.spec)
        old_space, old_actions, old_q = self.space, self.actions, self.q
        self.spec, self.space, self.actions = spec, space, actions
        cached = getattr(self, "_model_cache", None)
        if same and self.model is not None and cached is not None \
                and cached[2] is self.model and cached[0] == self._structure(self._flags(usable)):
            # Only rel(a) and rel(r, s) may have changed, and the model's probabilities are
            # read by Dyna and value iteration alone, which get the model anew with the
            # reliabilities of their time (refresh; a structure change): left until then.
            return False
        self.model = self._model(rel_action, rel_model, usable, memo)
        if not same:
            model, params = self.model, self.params

            def plan() -> np.ndarray:
                if planned is not None and planned.shape == model.applicable.shape:
                    return np.array(planned, dtype=float, copy=True)
                self.last_planned = value_iteration(model, params)
                return self.last_planned.copy()

            grown = None
            if not fresh and old_space is not None:
                grown = grow_q(old_q, old_space, old_actions, space, actions,
                               value_maps or {}, plan, model.applicable)
            self.q = plan() if grown is None else grown
            self.sarsa = SarsaLambda(self.q, self.params)
        return not same

    def _model(self, rel_action: RelAction, rel_model, usable: Usable | None,
               memo: ModelMemo | None = None) -> TransitionModel:
        assert self.space is not None
        assert self.spec is not None
        space = self.space
        structure = self._structure(self._flags(usable))
        usable_j = structure[3]
        rel_a = [rel_action(a.var, a.value) if a.var >= 0 else 1.0 for a in self.actions]
        rel_r = rel_model(space)
        # The model is a function of these alone (the regress mask below follows from the
        # space, actions, spec and usability): reuse it when none changed, and when only the
        # reliabilities did (Dyna refreshes) recompute just its probabilities.
        rels = (tuple(rel_a), np.asarray(rel_r, dtype=float).tobytes())
        cached = getattr(self, "_model_cache", None)
        if cached is not None and cached[0] == structure:
            if cached[1] == rels:
                return cached[2]
            model = cached[2].with_reliabilities(rel_a, rel_r)
            self._model_cache = (structure, rels, model)
            return model
        known = memo.get((structure, rels)) if memo is not None else None
        if known is not None:                    # built from these very inputs (decision 109)
            self._model_cache = (structure, rels, known)
            return known
        vals = space.all_values()
        # §5.2.1 rule 2 as a mask: reaching a(v, q) on a magnitude would need the very change
        # this plan is for (e.g. ⟨{Y}: X→x ⇒ Ẏ→[+]⟩ with Y below q needs Ẏ = [+]).
        regress = np.zeros((space.n_states, len(self.actions)), dtype=bool)
        gvar, gval = self.action
        for j, a in enumerate(self.actions):
            if a.var in self._magnitudes and self._dot_of.get(a.var) == gvar and a.var in space:
                now = vals[:, space.position(a.var)]
                need = np.where(now < a.value, 2, 0)
                regress[:, j] = (now != a.value) & (need == gval)
            elif (a.var in self._nominals and a.var in space
                  and a.var != self.spec.antecedent.var):
                # Appendix A item 1: actions on nominal variables already achieved in s.
                regress[:, j] = vals[:, space.position(a.var)] == a.value
            if not usable_j[j]:
                regress[:, j] = True             # e.g. a motor value out of the motor's range
        model = TransitionModel.build(space, self.actions, self.spec, rel_a, rel_r, regress)
        self._model_cache = (structure, rels, model)
        if memo is not None:
            memo.put((structure, rels), model)
        return model

    def _flags(self, usable: Usable | None) -> tuple[bool, ...]:
        """Each action's usability, asked of ``usable`` now and kept as flags, never the
        callable (the agent's bound method in a plan made every planning copy of the agent
        cyclic garbage, docs/decisions.md 104); without ``usable``, the flags last found."""
        if usable is None and self._usable_flags is not None \
                and len(self._usable_flags) == len(self.actions):
            return self._usable_flags
        self._usable_flags = tuple(a.var < 0 or usable is None or bool(usable(a.var, a.value))
                                   for a in self.actions)
        return self._usable_flags

    def _structure(self, flags: tuple[bool, ...]) -> tuple:
        """What the model is, besides rel(a) and rel(r, s), a function of: the space, the
        actions, the spec and each action's usability (:meth:`_flags`)."""
        return (self.space, tuple(self.actions), self.spec, flags)

    def refresh(self, rel_action: RelAction, rel_model, dyna: bool,
                usable: Usable | None = None) -> None:
        """New statistics: rebuild T_i and, unless ablated, one Dyna sweep (§5.2.2, eq. 5.10).
        ``usable`` as for :meth:`build`; None keeps the usability the last build found."""
        self.model = self._model(rel_action, rel_model, usable)
        if dyna:
            dyna_sweep(self.q, self.model, self.params)

    def snapshot(self, traces: bool = False) -> Plan:
        """A copy that stays as this plan is now while this one goes on learning: the arrays
        written in place (Q by Sarsa and Dyna, the stored calls and the second-order counts by
        :meth:`record_call`) are its own; everything else is replaced, never written, by the
        plan's methods, so it is shared. Its Sarsa traces are the executor's (none), unless
        ``traces``: a copy of them (a checkpoint saves them)."""
        c = copy.copy(self)
        c.q, c.call_x, c.call_ok = self.q.copy(), self.call_x.copy(), self.call_ok.copy()
        c.cpt_s, c.cpt_f = self.cpt_s.copy(), self.cpt_f.copy()
        c.sarsa = None if not traces or self.sarsa is None \
            else SarsaLambda(c.q, self.params, self.sarsa.e.copy())
        return c

    # -- second-order statistics (§5.4) ------------------------------------------------------
    def record_call(self, x: np.ndarray, success: bool, cell: int) -> None:
        self.call_head, self.call_n = ring_push(self.call_x, self.call_ok, self.call_head,
                                                self.call_n, x, success)
        self.calls += 1
        self.successes += int(success)
        if 0 <= cell < len(self.cpt_s):
            if success:
                self.cpt_s[cell] += 1
            else:
                self.cpt_f[cell] += 1

    def stored_calls(self) -> tuple[np.ndarray, np.ndarray]:
        return ring_rows(self.call_x, self.call_ok, self.call_head, self.call_n)

    @property
    def failures(self) -> int:
        return self.calls - self.successes

    def plan_stats(self, t: int | None = None) -> PlanStats:
        """Counts as :class:`~.actions.PlanStats` (for the plan limits of §6.2.2), with the
        sticky reliability flag and the age at step ``t``."""
        age = 0 if t is None else max(0, t - self.created)
        return PlanStats(self.calls, self.successes, self.calls - self.successes,
                         self.ever_reliable, age)

    def stats_removed(self, params: Params) -> bool:
        """rel(o) fell below 0.05 after enough calls (§6.2.2)."""
        return self.plan_stats().should_remove(params)

    def refresh_reliable(self) -> bool:
        """Set the sticky flag if brel(o) of r_o² is now > θ_SR (§5.4.1: "a plan can also be
        sufficiently reliable if at any time brel(o) > θ_SR"; the same test as for DBNs)."""
        if not self.ever_reliable and self.stats().reliable:
            self.ever_reliable = True
        return self.ever_reliable

    def rel(self, prior: float | None = None) -> float:
        """rel(o): overall reliability of the option (prior α = β = 1 unless given)."""
        p = self.params.prior if prior is None else prior
        total = self.calls + 2 * p
        return (self.successes + p) / total if total > 0 else 0.0

    def stats(self) -> ModelStats:
        return model_stats(self.cpt_s, self.cpt_f, len(self.context_o), self.params)

    def recount(self, quantize_columns: Callable[[np.ndarray, np.ndarray], np.ndarray],
                sizes: Mapping[int, int] | list[int], version: object = None) -> None:
        """The second-order CPT from the stored calls under the current C_o and landmarks.

        ``version`` names the quantity spaces (as for :meth:`update_context`): the CPT is left
        as it is when the last recount had the same calls, C_o, sizes and ``version`` (only
        :meth:`record_call` changes the CPT in between, and it counts a call)."""
        ctx = self.context_o
        key = (self.calls, ctx, tuple(int(sizes[v]) for v in ctx), version)
        if version is not None and self._recounted == key:
            return
        X, ok = self.stored_calls()
        n_cells = int(np.prod([sizes[v] for v in ctx])) if ctx else 1
        cells = context_cells(list(quantize_columns(X, ctx).T), [sizes[v] for v in ctx]) \
            if ctx else np.zeros(len(ok), dtype=np.int64)
        self.cpt_s, self.cpt_f = counts_by_cell(cells, ok, n_cells)
        self._recounted = key

    def update_context(self, candidates: list[int], quantize_columns, sizes,
                       version: object = None) -> bool:
        """Algorithm 3 on the second-order DBN; True if C_o changed (§5.4.2).

        ``version`` names the quantity spaces (their landmarks): a search that gave "no change"
        is not repeated while the stored calls, C_o, the candidates and ``version`` stay the
        same (Algorithm 3 is a function of them alone)."""
        search = self.context_search(candidates, version)
        if search is None:
            return False
        X, ok = search[1], search[2]
        acts = StoredActivations.quantized(X, ok, quantize_columns,
                                           (*candidates, *self.context_o), sizes, self.params)
        new = update_context(self.context_o, candidates, acts.evaluate, self.params,
                             acts.choose, reliable_once=self.ever_reliable)
        return self.context_found(search[0], new, quantize_columns, sizes, version)

    def context_search(self, candidates: list[int], version: object = None
                       ) -> tuple[tuple, np.ndarray, np.ndarray] | None:
        """What :meth:`update_context` searches: None when it would answer "no change"
        without a search (the inputs of the last such answer, or no calls), else the inputs'
        key and the stored calls (real states, outcomes)."""
        key = (self.calls, self.context_o, version, tuple(candidates), self.ever_reliable)
        if version is not None and self._context_unchanged == key:
            return None
        X, ok = self.stored_calls()
        if not len(ok):
            return None
        return key, X, ok

    def context_found(self, key: tuple, new: tuple[int, ...] | None, quantize_columns, sizes,
                      version: object = None) -> bool:
        """The end of :meth:`update_context` once Algorithm 3 answered ``new`` (None: no
        change) for the search of :meth:`context_search` with ``key``."""
        if new is None:
            self._context_unchanged = key
            return False
        self.context_o = new
        self.recount(quantize_columns, sizes, version)
        return True

    def rel_state(self, x_cell: int) -> float:
        """rel(o, s) from the second-order CPT cell of the state (prior 1)."""
        if not 0 <= x_cell < len(self.cpt_s):
            return self.rel()
        # (s + α) / (s + f + 2α) of the cell, from the per-cell values kept until the CPT
        # changes (record_call counts every in-place change in ``calls``).
        return cell_reliabilities(self, self.cpt_s, self.cpt_f, self.calls,
                                  self.params.prior)[x_cell]


class PlanGroups:
    """The plans grouped by their action a(v, q) (keys in order, each group's plans by id),
    with a vectorised test of which plans know their state in a qualitative vector.

    The IAC scan (§6.1.1) looks at every plan at every exploration choice; the groups change
    only when a plan, its action, goal or space does, so they are kept while :meth:`key_of`
    of the plans is unchanged (a pure cache, see :meth:`for_plans`).
    """

    def __init__(self, plans: Mapping[int, Plan]) -> None:
        by_action: dict[tuple[int, int], list[Plan]] = {}
        for plan in plans.values():
            by_action.setdefault(plan.action, []).append(plan)
        self.keys = sorted(by_action)
        """The actions with plans, in order."""
        self.groups = [sorted(by_action[k], key=lambda pl: pl.id) for k in self.keys]
        """The plans of each action, by id."""
        self._index = {k: i for i, k in enumerate(self.keys)}
        flat = [pl for group in self.groups for pl in group]
        self.rows: list[list[int]] = []
        """Row of each group's plans in :meth:`known`'s answer."""
        i = 0
        for group in self.groups:
            self.rows.append(list(range(i, i + len(group))))
            i += len(group)
        width = max([len(pl.space.vars) for pl in flat if pl.space is not None] + [0])
        self._vars = np.zeros((len(flat), width), dtype=np.int64)
        # Padding columns accept any value: lower bound −∞, upper bound +∞ (as int64).
        self._low = np.full((len(flat), width), np.iinfo(np.int64).min, dtype=np.int64)
        self._sizes = np.full((len(flat), width), np.iinfo(np.int64).max, dtype=np.int64)
        self._max_var = np.full(len(flat), -1, dtype=np.int64)
        self._has_space = np.zeros(len(flat), dtype=bool)
        for r, pl in enumerate(flat):
            if pl.space is None:
                continue
            n = len(pl.space.vars)
            self._vars[r, :n] = pl.space.vars
            self._low[r, :n] = 0
            self._sizes[r, :n] = pl.space.sizes
            self._max_var[r] = max(pl.space.vars, default=-1)
            self._has_space[r] = True

    def plans_of(self, action: tuple[int, int]) -> list[Plan]:
        """The plans of ``action`` by id (none: an empty list)."""
        i = self._index.get(action)
        return [] if i is None else list(self.groups[i])

    @staticmethod
    def key_of(plans: Mapping[int, Plan]) -> tuple:
        """What the groups are a function of: each plan with its action, goal and space."""
        return tuple((pl, pl.action, pl.goal, pl.space) for pl in plans.values())

    @classmethod
    def for_plans(cls, plans: Mapping[int, Plan], cached: tuple | None
                  ) -> tuple[PlanGroups, tuple]:
        """The groups of ``plans``, reusing ``cached`` (a previous answer) when its key holds;
        returns the groups and the ``(key, groups)`` pair to keep for the next call."""
        key = cls.key_of(plans)
        if cached is not None and cached[0] == key:
            # Keep the new key: its objects are the plans' own, so the next comparison
            # meets identical objects (a rebuilt plan's equal goal is a new Event).
            return cached[1], (key, cached[1])
        groups = cls(plans)
        return groups, (key, groups)

    def _by_group(self, magnitudes: frozenset[int]) -> tuple[np.ndarray, ...]:
        """Per group its action's variable and value and whether the variable is one of
        ``magnitudes``; per row its group and its plan's goal direction (cached)."""
        cached = self.__dict__.get("_group_arrays")
        if cached is not None and cached[0] == magnitudes:
            return cached[1]
        out = (np.array([k[0] for k in self.keys], dtype=np.int64),
               np.array([k[1] for k in self.keys], dtype=np.int64),
               np.array([k[0] in magnitudes for k in self.keys], dtype=bool),
               np.array([g for g, group in enumerate(self.groups) for _ in group],
                        dtype=np.int64),
               np.array([pl.goal.direction for group in self.groups for pl in group],
                        dtype=np.int64))
        self._group_arrays = (magnitudes, out)
        return out

    def usable(self, q: np.ndarray, magnitudes: frozenset[int]) -> tuple[list[int], list[bool]]:
        """The groups whose action is not achieved in ``q`` (v ≠ q) and that have a usable
        plan there: its state known (:meth:`known`) and, for an action on one of the
        ``magnitudes``, its goal direction the side q is reached from (1 from below, −1 from
        above; §5.3). Returns those groups' indices in order and the per-row usability, the
        tests of the agent's IAC scan done at once for all plans."""
        row_ok = np.asarray(self.known(q), dtype=bool)
        if not self.keys:
            return [], []
        var, val, is_mag, row_group, row_dir = self._by_group(magnitudes)
        qv = np.asarray(q)[var]
        side = np.where(qv < val, 1, -1)
        row_ok &= ~is_mag[row_group] | (row_dir == side[row_group])
        has = np.bincount(row_group[row_ok], minlength=len(self.keys)) > 0
        return np.flatnonzero(has & (qv != val)).tolist(), row_ok.tolist()

    def known(self, q: np.ndarray) -> list[bool]:
        """Per row: the plan has a space and :meth:`~.mdp.PlanStateSpace.index_from_full` of
        ``q`` is not None (every plan variable in ``q`` with a value in 0..size − 1)."""
        n_full = len(q)
        ok = self._has_space & (self._max_var < n_full)
        if n_full and self._vars.shape[1]:
            vals = np.asarray(q)[np.minimum(self._vars, n_full - 1)]
            ok &= ((vals >= self._low) & (vals < self._sizes)).all(axis=1)
        return ok.tolist()


def dbn_rel_state(dbn: DBN, sizes, prior: float) -> Callable[[PlanStateSpace], np.ndarray]:
    """rel(r, s) for every state of a plan's space: the DBN's CPT cell of the state's context
    values (prior α = β = 1). Returns a function of the space (vectorised)."""
    ctx = dbn.context
    rel_cells = (dbn.cpt_s + prior) / (dbn.cpt_s + dbn.cpt_f + 2 * prior)

    def rel(space: PlanStateSpace) -> np.ndarray:
        cell = space.cells(ctx, [int(sizes[v]) for v in ctx])
        out = np.full(space.n_states, 0.5)
        ok = cell < len(rel_cells)
        out[ok] = rel_cells[cell[ok]]
        return out

    return rel


def closes_cycle(adj: Mapping[tuple[int, int], list[tuple[int, int]]],
                 new: tuple[tuple[int, int], tuple[int, int]]) -> bool:
    """Would adding the edge ``new`` = (consequent, antecedent) close a cycle in the action
    graph (§6.2.2 criterion 2)? ``adj``: the graph's edges as adjacency lists (node ->
    successors), for a caller that tests many edges on one graph."""
    src, dst = new
    if src == dst:
        return True
    stack, seen = [dst], {dst}
    while stack:
        node = stack.pop()
        if node == src:
            return True
        for nxt in adj.get(node, ()):
            if nxt not in seen:
                seen.add(nxt)
                stack.append(nxt)
    return False
