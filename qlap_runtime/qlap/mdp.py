"""The small MDPs behind QLAP's plans: state spaces, transitions, value iteration, Sarsa(λ), Dyna.

A plan made from a DBN r = ⟨C : X → x ⇒ Y → y⟩ is an MDP ⟨S, A, T, R⟩ (§5.2.1); a magnitude
plan made from r± = ⟨C : Ẏ → [±] ⇒ Y → y⟩ differs only in its actions and transitions (§5.3).
This module knows nothing about DBNs: the planner describes the plan with a :class:`PlanSpec`
(goal and antecedent events, which variables are magnitudes), lists the actions (or lets
:func:`build_actions` do it per eq. 5.3), supplies rel(a) and rel(r, s), and gets back a
:class:`TransitionModel` to plan with.

Conventions
-----------
* A Q-table is a float array of shape ``(n_states, n_actions)``; pairs whose action is not
  applicable in the state hold :data:`NOT_APPLICABLE` (−inf), so the table alone tells which
  actions may be chosen (:func:`greedy_action`).
* Goal states (Y = y) are terminal: no action is applicable there and their value is 0. A
  non-goal state with no applicable action is a dead end where the plan fails (§5.5.2): its
  value is also 0 (the episode ends without further reward).
* State indices are mixed radix over the plan's variables, the first variable most significant.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .kernels import kernels
from .params import Params
from .variables import Event

NOT_APPLICABLE = -np.inf
"""Q-value sentinel of a (state, action) pair whose action is not applicable."""


# ---------------------------------------------------------------------------------------------
# State space (§5.2.1 eq. 5.1, §5.4.2 eq. 5.14)
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PlanStateSpace:
    """S = Q(C_o) × Q(C) × Q(X) × Q(Y), each variable once (eq. 5.1, eq. 5.14).

    ``vars`` are agent variable indices in state-space order, ``sizes`` their |Q(v)|.
    """

    vars: tuple[int, ...]
    sizes: tuple[int, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "vars", tuple(int(v) for v in self.vars))
        object.__setattr__(self, "sizes", tuple(int(n) for n in self.sizes))
        if len(self.vars) != len(self.sizes):
            raise ValueError(f"{len(self.vars)} variables but {len(self.sizes)} sizes")
        if len(set(self.vars)) != len(self.vars):
            raise ValueError(f"a variable appears twice in the state space: {self.vars}")
        if any(n < 1 for n in self.sizes):
            raise ValueError(f"every variable needs at least one value, got sizes {self.sizes}")
        # (variable, size) pairs for :meth:`index_from_full`, called for every plan at every
        # IAC choice (not a field: equality and hashing stay those of vars and sizes).
        object.__setattr__(self, "_var_sizes", tuple(zip(self.vars, self.sizes, strict=True)))

    @classmethod
    def from_groups(cls, groups: Iterable[Iterable[int]],
                    sizes: Mapping[int, int]) -> PlanStateSpace:
        """Build from the groups (C_o, C, {X}, {Y}) in order, keeping each variable once."""
        order: list[int] = []
        for group in groups:
            for v in group:
                if v not in order:
                    order.append(int(v))
        return cls(tuple(order), tuple(sizes[v] for v in order))

    @property
    def n_states(self) -> int:
        """|S| = Π |Q(v)|."""
        cached = self.__dict__.get("_n_states")
        if cached is None:
            cached = int(np.prod(self.sizes, dtype=np.int64))
            object.__setattr__(self, "_n_states", cached)
        return cached

    @property
    def strides(self) -> tuple[int, ...]:
        """Mixed-radix place value of each variable (the last variable has stride 1)."""
        cached = self.__dict__.get("_strides")
        if cached is not None:
            return cached
        out = [1] * len(self.sizes)
        for i in range(len(self.sizes) - 2, -1, -1):
            out[i] = out[i + 1] * self.sizes[i + 1]
        out_t = tuple(out)
        object.__setattr__(self, "_strides", out_t)
        return out_t

    def __contains__(self, var: object) -> bool:
        return var in self.vars

    def position(self, var: int) -> int:
        """Position of agent variable ``var`` in the state tuple."""
        try:
            return self.vars.index(var)
        except ValueError:
            raise KeyError(f"variable {var} is not in the plan's state space {self.vars}") from None

    def size_of(self, var: int) -> int:
        """|Q(var)|."""
        return self.sizes[self.position(var)]

    def index(self, values: Sequence[int]) -> int:
        """Mixed-radix index of the state with these values (in ``vars`` order)."""
        if len(values) != len(self.sizes):
            raise ValueError(f"expected {len(self.sizes)} values, got {len(values)}")
        idx = 0
        for q, n in zip(values, self.sizes, strict=True):
            if not 0 <= q < n:
                raise ValueError(f"value {q} outside 0..{n - 1} in state {tuple(values)}")
            idx = idx * n + int(q)
        return idx

    def values(self, index: int) -> tuple[int, ...]:
        """Inverse of :meth:`index`."""
        if not 0 <= index < self.n_states:
            raise ValueError(f"state index {index} outside 0..{self.n_states - 1}")
        out = []
        for n in reversed(self.sizes):
            index, q = divmod(index, n)
            out.append(q)
        return tuple(reversed(out))

    def all_values(self) -> np.ndarray:
        """Array ``(n_states, n_vars)`` whose row s is ``values(s)``.

        Computed once per space and shared: the array is read-only (copy it to modify).
        """
        cached = self.__dict__.get("_all_values")
        if cached is not None:
            return cached
        if not self.sizes:
            out = np.zeros((1, 0), dtype=np.int64)
        else:
            grids = np.unravel_index(np.arange(self.n_states), self.sizes)
            out = np.stack(grids, axis=1).astype(np.int64)
        out.flags.writeable = False
        object.__setattr__(self, "_all_values", out)
        return out

    def cells(self, ctx: Sequence[int], radices: Sequence[int]) -> np.ndarray:
        """Per state, the mixed-radix cell of its values of the variables ``ctx`` (each a
        variable of the space) with radices ``radices`` (e.g. a DBN's CPT cell of the state).

        Computed once per space and arguments and shared: the array is read-only.
        """
        key = (tuple(int(v) for v in ctx), tuple(int(n) for n in radices))
        cache = self.__dict__.get("_cells")
        if cache is None:
            cache = {}
            object.__setattr__(self, "_cells", cache)
        out = cache.get(key)
        if out is None:
            vals = self.all_values()
            out = np.zeros(self.n_states, dtype=np.int64)
            for v, n in zip(*key, strict=True):
                out = out * n + vals[:, self.position(v)]
            out.flags.writeable = False
            cache[key] = out
        return out

    def index_from_full(self, full: Sequence[int] | np.ndarray) -> int | None:
        """Plan state of the agent's full qualitative vector (indexed by variable number).

        None if a plan variable has no valid value there (e.g. −1, not yet available, §7.5).
        A plain list is fastest (callers looking up many plans convert the vector once).
        """
        if isinstance(full, np.ndarray):
            full = full.tolist()
        n_full = len(full)
        idx = 0
        for v, n in self.__dict__["_var_sizes"]:
            if v >= n_full:
                return None
            q = full[v]
            if not 0 <= q < n:
                return None
            idx = idx * n + int(q)
        return idx

    def with_variable(self, var: int, size: int) -> tuple[PlanStateSpace, np.ndarray]:
        """Append ``var`` (§5.4.2): the new space and ``state_map`` (new state → old state).

        ``q_new = q_old[state_map]`` copies each Q-value to every value of the new variable.
        """
        if var in self.vars:
            raise ValueError(f"variable {var} is already in the state space")
        new = PlanStateSpace((*self.vars, int(var)), (*self.sizes, int(size)))
        return new, np.arange(new.n_states, dtype=np.int64) // int(size)

    def resized(self, var: int, new_size: int,
                old_to_new: Sequence[int | Sequence[int]]) -> tuple[PlanStateSpace, np.ndarray]:
        """``var`` gained landmarks: the new space and ``state_map`` (new state → old state).

        ``old_to_new[q]`` is the new value, or the new values, of old value q; a split value
        maps to several new values, which all get copies of its Q-values. Every new value must
        come from exactly one old value (see :func:`split_value_map`).
        """
        pos = self.position(var)
        new_to_old = invert_value_map(self.sizes[pos], new_size, old_to_new)
        sizes = list(self.sizes)
        sizes[pos] = int(new_size)
        new = PlanStateSpace(self.vars, tuple(sizes))
        vals = new.all_values().copy()
        vals[:, pos] = new_to_old[vals[:, pos]]
        return new, _ravel(vals, self.sizes)

    def to_state(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {"vars": list(self.vars), "sizes": list(self.sizes)}

    @classmethod
    def from_state(cls, data: Mapping[str, Any]) -> PlanStateSpace:
        """Inverse of :meth:`to_state`."""
        return cls(tuple(int(v) for v in data["vars"]), tuple(int(n) for n in data["sizes"]))


def _ravel(vals: np.ndarray, sizes: Sequence[int]) -> np.ndarray:
    if not len(sizes):
        return np.zeros(vals.shape[0], dtype=np.int64)
    return np.ravel_multi_index(tuple(vals.T), tuple(sizes)).astype(np.int64)


def invert_value_map(old_size: int, new_size: int,
                     old_to_new: Sequence[int | Sequence[int]]) -> np.ndarray:
    """``new_to_old`` (length ``new_size``) from a one-to-many ``old_to_new`` value map."""
    if len(old_to_new) != old_size:
        raise ValueError(f"old_to_new has {len(old_to_new)} entries for {old_size} old values")
    new_to_old = np.full(int(new_size), -1, dtype=np.int64)
    for old, targets in enumerate(old_to_new):
        for q in (targets,) if isinstance(targets, int | np.integer) else targets:
            if not 0 <= q < new_size:
                raise ValueError(f"new value {q} outside 0..{new_size - 1}")
            if new_to_old[q] >= 0:
                raise ValueError(f"new value {q} comes from two old values")
            new_to_old[q] = old
    missing = np.flatnonzero(new_to_old < 0)
    if missing.size:
        raise ValueError(f"new values {missing.tolist()} come from no old value")
    return new_to_old


def split_value_map(old_size: int, split: int) -> list[int | tuple[int, ...]]:
    """``old_to_new`` after a landmark split the interval ``split`` (QuantitySpace.insert).

    The interval becomes (split, split + 1, split + 2): below, the landmark, above; every
    value above it shifts by 2 (cf. ``quantity.remap_after_insert``).
    """
    if not 0 <= split < old_size or split % 2:
        raise ValueError(f"split must be an interval value in 0..{old_size - 1}, got {split}")
    return [q if q < split else (q, q + 1, q + 2) if q == split else q + 2
            for q in range(old_size)]


# ---------------------------------------------------------------------------------------------
# Actions (§5.2.1 eq. 5.2–5.3, §5.3.1)
# ---------------------------------------------------------------------------------------------


class Role(enum.StrEnum):
    """What an MDP action does in its plan."""

    CONTEXT = "context"
    """a(v, q) moving within the state space; also a(X, q), q ≠ x, on a magnitude X (eq. 5.3)."""
    ANTECEDENT = "antecedent"
    """a(X, x), the action that brings about the antecedent event."""
    WAIT = "wait"
    """Magnitude plans only: hold the motors while the antecedent holds (§5.3.1)."""


@dataclass(frozen=True)
class MDPAction:
    """One action of a plan's MDP: the QLAP action a(var, value) in a role (wait: var = −1)."""

    var: int
    value: int
    role: Role = Role.CONTEXT

    def __post_init__(self) -> None:
        object.__setattr__(self, "role", Role(self.role))
        if self.role is Role.WAIT:
            if (self.var, self.value) != (-1, -1):
                raise ValueError("the wait action has var = value = -1")
        elif self.var < 0 or self.value < 0:
            raise ValueError(f"a(v, q) needs v, q >= 0, got a({self.var}, {self.value})")

    # Frozen, of ints and an enum: a copy (the executor's periodic checkpoint copies the
    # agent, hundreds of these) is the action itself (docs/decisions.md 101).
    def __copy__(self) -> MDPAction:
        return self

    def __deepcopy__(self, memo: dict) -> MDPAction:
        return self

    @classmethod
    def wait(cls) -> MDPAction:
        """The wait action of magnitude plans (§5.3.1)."""
        return cls(-1, -1, Role.WAIT)

    def to_state(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {"var": self.var, "value": self.value, "role": self.role.value}

    @classmethod
    def from_state(cls, data: Mapping[str, Any]) -> MDPAction:
        """Inverse of :meth:`to_state`."""
        return cls(int(data["var"]), int(data["value"]), Role(data["role"]))


@dataclass(frozen=True)
class PlanSpec:
    """What the MDP needs to know about the DBN r = ⟨C : X → x ⇒ Y → y⟩ (§5.2, §5.3).

    ``goal`` is the event Y → y; its ``direction`` is used only by magnitude plans (+1: reach
    y from below, the plan of r⁺; −1: from above, r⁻). ``antecedent`` is X → x, whose
    ``direction`` (+1 ↑, −1 ↓) is required when X is a magnitude variable of a change plan.
    ``magnitude_vars`` are the variables that count as magnitudes for applicability rules 1
    and 3 of §5.2.1 (the planner decides, e.g. whether motors are included).
    """

    goal: Event
    antecedent: Event
    magnitude_plan: bool = False
    magnitude_vars: frozenset[int] = field(default_factory=frozenset)

    def __post_init__(self) -> None:
        object.__setattr__(self, "goal", Event(*(int(x) for x in self.goal)))
        object.__setattr__(self, "antecedent", Event(*(int(x) for x in self.antecedent)))
        object.__setattr__(self, "magnitude_vars", frozenset(int(v) for v in self.magnitude_vars))
        if self.goal.var == self.antecedent.var:
            raise ValueError("the antecedent and the goal are on the same variable")
        if self.magnitude_plan:
            if self.goal.direction not in (1, -1):
                raise ValueError("a magnitude plan needs goal.direction +1 or -1 (§5.3)")
        elif self.antecedent_on_magnitude and self.antecedent.direction not in (1, -1):
            raise ValueError("a magnitude antecedent needs direction +1 (↑) or -1 (↓) (§5.2.1)")

    @property
    def antecedent_on_magnitude(self) -> bool:
        """X is a magnitude variable (rule 3 and the wrong-side rule apply, §5.2.1)."""
        return self.antecedent.var in self.magnitude_vars


def build_actions(space: PlanStateSpace, spec: PlanSpec) -> list[MDPAction]:
    """A_i of eq. 5.3 (plus wait for magnitude plans, §5.3.1), in a deterministic order.

    Context actions a(v, q) for every state variable other than X and Y (C and C_o, §5.4.2),
    then a(X, q) for q ≠ x if X is a magnitude of a change plan, then a(X, x), then wait.
    """
    x_var, y_var = spec.antecedent.var, spec.goal.var
    for v in (x_var, y_var):
        space.position(v)
    out = [MDPAction(v, q) for v, n in zip(space.vars, space.sizes, strict=True)
           if v not in (x_var, y_var) for q in range(n)]
    if spec.antecedent_on_magnitude and not spec.magnitude_plan:
        out += [MDPAction(x_var, q) for q in range(space.size_of(x_var))
                if q != spec.antecedent.value]
    out.append(MDPAction(x_var, spec.antecedent.value, Role.ANTECEDENT))
    if spec.magnitude_plan:
        out.append(MDPAction.wait())
    return out


def action_map(old: Sequence[MDPAction], new: Sequence[MDPAction],
               value_maps: Mapping[int, Sequence[int]] | None = None) -> np.ndarray:
    """For each new action, the index of the old action it continues, or −1 (a new action).

    ``value_maps[var]`` is a ``new_to_old`` value map of a resized variable (see
    :func:`invert_value_map`): a(var, q) then continues a(var, new_to_old[q]).
    """
    value_maps = value_maps or {}
    where = {a: i for i, a in enumerate(old)}
    out = np.full(len(new), -1, dtype=np.int64)
    for j, a in enumerate(new):
        if a.var in value_maps:
            a = MDPAction(a.var, int(value_maps[a.var][a.value]), a.role)
        out[j] = where.get(a, -1)
    return out


# ---------------------------------------------------------------------------------------------
# Transition model (§5.2.1, §5.3.2) and rewards (eq. 5.5)
# ---------------------------------------------------------------------------------------------


RelAction = Sequence[float] | np.ndarray | Callable[[MDPAction], float]
RelModel = Sequence[float] | np.ndarray | Callable[[Mapping[int, int]], float]
Regress = np.ndarray | Callable[[Mapping[int, int], MDPAction], bool]


@dataclass(frozen=True, eq=False)
class TransitionModel:
    """P(s' | s, a) with at most two next states (§5.2.1): ``next1`` with probability ``p1``,
    else ``next2``; plus the applicability mask A_i^s and the goal mask.

    Inapplicable pairs have ``next1 = next2 = s`` and ``p1 = 0``. Build with :meth:`build`
    (the arrays are read-only; rebuild when rel(a) or rel(r, s) change, then run Dyna).
    """

    space: PlanStateSpace
    actions: tuple[MDPAction, ...]
    spec: PlanSpec
    next1: np.ndarray
    p1: np.ndarray
    next2: np.ndarray
    applicable: np.ndarray
    goal: np.ndarray
    """``goal[s]``: Y = y in s (terminal)."""

    @property
    def n_states(self) -> int:
        return self.space.n_states

    @property
    def n_actions(self) -> int:
        return len(self.actions)

    @classmethod
    def build(cls, space: PlanStateSpace, actions: Sequence[MDPAction], spec: PlanSpec,
              rel_action: RelAction, rel_model: RelModel,
              regress: Regress | None = None) -> TransitionModel:
        """Build T_i and A_i^s from rel(a) and rel(r, s).

        ``rel_action``: rel(a) per action (array of length n_actions, or a function of the
        action); used by context actions and, in magnitude plans, by the antecedent action.
        ``rel_model``: rel(r, s) per state (array of length n_states, or a function of the
        state as a ``{var: value}`` mapping); used by the antecedent action of change plans
        and by wait. ``regress``: rule 2 of §5.2.1, the pairs whose action would call a(Y, y)
        again — a bool ``(n_states, n_actions)`` mask (True = excluded) or a predicate.

        Applicability (A_i^s), §5.2.1 and §5.3.1:
        * nothing is applicable in goal states (Y = y), nor, in a magnitude plan, on the wrong
          side of y (Y > y for r⁺, Y < y for r⁻);
        * rule 1: a(v, q) with v a magnitude and v = q already;
        * rule 2: the ``regress`` pairs;
        * rule 3: for a change plan with a magnitude antecedent ↑X → x, a(X, q) (q ≠ x) is
          applicable only if q < x and X ≥ x (↓: q > x and X ≤ x). The text says X > x; we
          include X = x because rule 1 removes a(X, x) there and the event needs X_{t−1} < x,
          so the literal reading would leave X = x with no action on X at all;
        * magnitude plans: wait only where X = x (antecedent holds), a(X, x) only where not.

        Transitions: context a(v, q) → s with v = q (rel(a)), else s. Change-plan antecedent
        → s with X = x and Y = y (rel(r, s); 0 on the wrong side: X > x for ↑, X < x for ↓),
        else s with X = x. Magnitude-plan antecedent is a context move (§5.3.2). Wait → s
        with Y = y (rel(r, s)), else s.
        """
        actions = tuple(actions)
        n_s, n_a = space.n_states, len(actions)
        vals = space.all_values()
        strides = np.asarray(space.strides, dtype=np.int64)
        states = np.arange(n_s, dtype=np.int64)
        x_ev, y_ev = spec.antecedent, spec.goal
        x_pos, y_pos = space.position(x_ev.var), space.position(y_ev.var)
        for ev, pos in ((x_ev, x_pos), (y_ev, y_pos)):
            if not 0 <= ev.value < space.sizes[pos]:
                raise ValueError(f"event value {ev.value} outside Q({ev.var})")
        x_now, y_now = vals[:, x_pos], vals[:, y_pos]

        rel_a = _rel_actions(rel_action, actions)
        rel_r = _rel_states(rel_model, space, vals)
        excluded = _regress_mask(regress, space, vals, actions)

        goal = y_now == y_ev.value
        alive = ~goal
        if spec.magnitude_plan:
            wrong = y_now > y_ev.value if y_ev.direction > 0 else y_now < y_ev.value
            alive &= ~wrong
        x_holds = x_now == x_ev.value

        next1 = np.tile(states[:, None], (1, n_a))
        next2 = next1.copy()
        p1 = np.zeros((n_s, n_a))
        applicable = np.zeros((n_s, n_a), dtype=bool)
        recipe: list[tuple[bool, np.ndarray | None]] = []  # per column: from rel(r, s)?, zeroed
        n_ante = 0
        for j, a in enumerate(actions):
            ok = alive.copy()
            if a.role is Role.WAIT:
                if not spec.magnitude_plan:
                    raise ValueError("wait is an action of magnitude plans only (§5.3.1)")
                ok &= x_holds
                next1[:, j] = states + (y_ev.value - y_now) * strides[y_pos]
                p1[:, j] = rel_r
                recipe.append((True, None))
            else:
                pos = space.position(a.var)
                if not 0 <= a.value < space.sizes[pos]:
                    raise ValueError(f"action a({a.var}, {a.value}) outside Q({a.var})")
                now = vals[:, pos]
                moved = states + (a.value - now) * strides[pos]
                if a.var in spec.magnitude_vars:
                    ok &= now != a.value  # rule 1
                if a.role is Role.ANTECEDENT:
                    n_ante += 1
                    if (a.var, a.value) != (x_ev.var, x_ev.value):
                        raise ValueError(f"antecedent action a({a.var}, {a.value}) is not "
                                         f"a({x_ev.var}, {x_ev.value})")
                    if spec.magnitude_plan:
                        ok &= ~x_holds  # §5.3.1 rule 2
                        next1[:, j], p1[:, j] = moved, rel_a[j]
                        recipe.append((False, None))
                    else:
                        next1[:, j] = moved + (y_ev.value - y_now) * strides[y_pos]
                        next2[:, j] = moved
                        p1[:, j] = rel_r
                        wrong_x = None
                        if spec.antecedent_on_magnitude:  # the wrong side
                            d = x_ev.direction
                            wrong_x = now > x_ev.value if d > 0 else now < x_ev.value
                            p1[wrong_x, j] = 0.0
                        recipe.append((True, wrong_x))
                else:
                    if (a.var == x_ev.var and spec.antecedent_on_magnitude
                            and not spec.magnitude_plan):  # rule 3
                        if x_ev.direction > 0:
                            ok &= (a.value < x_ev.value) & (now >= x_ev.value)
                        else:
                            ok &= (a.value > x_ev.value) & (now <= x_ev.value)
                    next1[:, j], p1[:, j] = moved, rel_a[j]
                    recipe.append((False, None))
            applicable[:, j] = ok & ~excluded[:, j]
        if n_ante > 1:
            raise ValueError("a plan has one antecedent action")
        next1[~applicable] = np.broadcast_to(states[:, None], (n_s, n_a))[~applicable]
        next2[~applicable] = next1[~applicable]
        p1[~applicable] = 0.0
        for arr in (next1, p1, next2, applicable, goal):
            arr.flags.writeable = False
        model = cls(space, actions, spec, next1, p1, next2, applicable, goal)
        object.__setattr__(model, "_p1_recipe", tuple(recipe))
        return model

    def with_reliabilities(self, rel_action: RelAction, rel_model: RelModel) -> TransitionModel:
        """The model :meth:`build` would give with new rel(a) and rel(r, s) and the same space,
        actions, spec and ``regress``: only ``p1`` changes (the other arrays are shared).

        The model must come from :meth:`build` (it records where each column of ``p1`` comes
        from); ``p1`` gets the very values :meth:`build` would assign.
        """
        recipe = self.__dict__.get("_p1_recipe")
        if recipe is None:
            raise ValueError("with_reliabilities needs a model made by TransitionModel.build")
        space = self.space
        rel_a = _rel_actions(rel_action, self.actions)
        rel_r = _rel_states(rel_model, space, space.all_values())
        source, pair_source = self._p1_sources()
        # Every entry of p1 is a copy of rel(r, s), of its action's rel(a) or 0.0, as in
        # build: gathered at once from the three.
        values = np.concatenate((rel_r, rel_a, _ZERO))
        # p1 is gathered when first read (:meth:`__getattr__`): a Dyna refresh reads only the
        # applicable pairs' values below, and a large plan's table has ~10⁵ pairs.
        model = TransitionModel(space, self.actions, self.spec, self.next1, None,  # type: ignore[arg-type]
                                self.next2, self.applicable, self.goal)
        object.__delattr__(model, "p1")
        object.__setattr__(model, "_p1_lazy", (values, source))
        object.__setattr__(model, "_p1_recipe", recipe)
        object.__setattr__(model, "_p1_src", self.__dict__["_p1_src"])
        rewards = self.__dict__.get("_rewards")     # R does not depend on p1
        if rewards is not None:
            object.__setattr__(model, "_rewards", rewards)
        pairs = self.__dict__.get("_applicable_pairs")
        if pairs is not None:
            # The applicable pairs, rewards and next states do not depend on p1 either.
            key, (flat, _, _, r1, r2, n1, n2) = pairs
            a1 = values.take(pair_source)
            object.__setattr__(model, "_applicable_pairs",
                               (key, (flat, a1, 1.0 - a1, r1, r2, n1, n2)))
        return model

    def __getattr__(self, name: str) -> Any:
        # Only for attributes not set: ``p1`` of a model from with_reliabilities, gathered
        # once from its values and sources (the very values an eager gather gives).
        if name == "p1":
            lazy = self.__dict__.get("_p1_lazy")
            if lazy is not None:
                p1 = lazy[0].take(lazy[1])
                p1.flags.writeable = False
                object.__setattr__(self, "p1", p1)
                return p1
        raise AttributeError(f"{type(self).__name__!s} has no attribute {name!r}")

    def _p1_sources(self) -> tuple[np.ndarray, np.ndarray]:
        """Where each entry of ``p1`` comes from (cached), as indices into rel(r, s) (one per
        state), then rel(a) (one per action), then a 0.0: per pair, and per applicable pair
        (in the order of :func:`_applicable_pairs`). From the recipe :meth:`build` records:
        columns from rel(r, s) or from rel(a), wrong-side rows zeroed, inapplicable pairs 0."""
        cached = self.__dict__.get("_p1_src")
        if cached is None:
            recipe = self.__dict__["_p1_recipe"]
            n_s, n_a = self.applicable.shape
            source = np.empty((n_s, n_a), dtype=np.int64)
            states = np.arange(n_s, dtype=np.int64)
            for j, (from_model, wrong) in enumerate(recipe):
                source[:, j] = states if from_model else n_s + j
                if wrong is not None:
                    source[wrong, j] = n_s + n_a
            source[~self.applicable] = n_s + n_a
            cached = (source, source.ravel()[np.flatnonzero(self.applicable)])
            object.__setattr__(self, "_p1_src", cached)
        return cached

    def rewards(self, params: Params) -> tuple[np.ndarray, np.ndarray]:
        """R(s, a, s') of eq. 5.5 for the two next states: (R to next1, R to next2).

        Cached per model and reward constants (read-only arrays)."""
        key = (params.goal_reward, params.step_reward)
        cached = self.__dict__.get("_rewards")
        if cached is not None and cached[0] == key:
            return cached[1]
        out = (reward(self.goal[self.next1], params), reward(self.goal[self.next2], params))
        for arr in out:
            arr.flags.writeable = False
        object.__setattr__(self, "_rewards", (key, out))
        return out

    def backup(self, q: np.ndarray, params: Params) -> np.ndarray:
        """Σ_s' P(s'|s,a) [R(s,a,s') + γ max_a' Q(s',a')] for all pairs (eq. 5.6, 5.10);
        −inf where not applicable."""
        v = state_values(q)
        r1, r2 = self.rewards(params)
        g = params.gamma
        out = self.p1 * (r1 + g * v[self.next1]) + (1.0 - self.p1) * (r2 + g * v[self.next2])
        return np.where(self.applicable, out, NOT_APPLICABLE)

    def initial_q(self, fill: float = 0.0) -> np.ndarray:
        """A Q-table of ``fill`` on applicable pairs and the sentinel elsewhere."""
        return np.where(self.applicable, float(fill), NOT_APPLICABLE)


_ZERO = np.zeros(1)
"""The 0.0 of :meth:`TransitionModel._p1_sources`."""


def _rel_actions(rel: RelAction, actions: Sequence[MDPAction]) -> np.ndarray:
    out = (np.array([float(rel(a)) for a in actions]) if callable(rel)
           else np.asarray(rel, dtype=float))
    if out.shape != (len(actions),):
        raise ValueError(f"rel(a) needs shape ({len(actions)},), got {out.shape}")
    return _check_probs(out, "rel(a)")


def _rel_states(rel: RelModel, space: PlanStateSpace, vals: np.ndarray) -> np.ndarray:
    if callable(rel):
        out = np.array([float(rel(dict(zip(space.vars, map(int, row), strict=True))))
                        for row in vals])
    else:
        out = np.asarray(rel, dtype=float)
    if out.shape != (space.n_states,):
        raise ValueError(f"rel(r, s) needs shape ({space.n_states},), got {out.shape}")
    return _check_probs(out, "rel(r, s)")


def _check_probs(p: np.ndarray, name: str) -> np.ndarray:
    # All in [0, 1] (NaN fails: min and max propagate it), in two reductions.
    if p.size and not (p.min() >= 0.0 and p.max() <= 1.0):
        raise ValueError(f"{name} must lie in [0, 1]")
    return p


def _regress_mask(regress: Regress | None, space: PlanStateSpace, vals: np.ndarray,
                  actions: Sequence[MDPAction]) -> np.ndarray:
    shape = (space.n_states, len(actions))
    if regress is None:
        return np.zeros(shape, dtype=bool)
    if callable(regress):
        out = np.zeros(shape, dtype=bool)
        for s, row in enumerate(vals):
            state = dict(zip(space.vars, map(int, row), strict=True))
            for j, a in enumerate(actions):
                out[s, j] = bool(regress(state, a))
        return out
    out = np.asarray(regress, dtype=bool)
    if out.shape != shape:
        raise ValueError(f"regress mask needs shape {shape}, got {out.shape}")
    return out


def reward(goal_reached: bool | np.ndarray, params: Params) -> np.ndarray:
    """R(s, a, s') of eq. 5.5: 10 − 2 if Y = y in s', else −2 (Params.goal/step_reward)."""
    return np.where(goal_reached, params.goal_reward + params.step_reward, params.step_reward)


# ---------------------------------------------------------------------------------------------
# Policies (§5.2.2, §6.1.3)
# ---------------------------------------------------------------------------------------------


def state_values(q: np.ndarray) -> np.ndarray:
    """V(s) = max over applicable a of Q(s, a); 0 where nothing is applicable (goal, dead end)."""
    q = np.asarray(q, dtype=float)
    if q.shape[1] == 0:
        return np.zeros(q.shape[0])
    v = q.max(axis=1)
    return np.where(np.isfinite(v), v, 0.0)


def value_iteration(model: TransitionModel, params: Params) -> np.ndarray:
    """Q* of eq. 5.6 (γ = Params.gamma) by synchronous sweeps from Q = 0.

    Stops when no Q-value moves more than ``value_iteration_tol`` or after
    ``value_iteration_max_sweeps`` sweeps. Inapplicable pairs hold :data:`NOT_APPLICABLE`.

    The sweeps run on the quotient of the model by exact bisimilarity (:func:`_bisimilar`):
    states of one class get bit for bit the same Q-values at every sweep, so each class is
    computed once and copied back — the same result as sweeping every state, ~15× fewer states
    in grown plans (variables of C and C_o that the transitions do not distinguish).
    """
    k = kernels()
    if k is not None and model.n_actions:      # all of the below, compiled (the same numbers)
        return k.value_iteration(
            np.ascontiguousarray(model.p1, dtype=float), np.ascontiguousarray(model.next1),
            np.ascontiguousarray(model.next2), np.ascontiguousarray(model.applicable),
            np.ascontiguousarray(model.goal), float(params.goal_reward + params.step_reward),
            float(params.step_reward), float(params.gamma), float(params.value_iteration_tol),
            int(params.value_iteration_max_sweeps))
    # eq. 5.6 with the constant parts of :meth:`TransitionModel.backup` taken out of the loop.
    r1, r2 = model.rewards(params)
    p1 = model.p1
    p2 = 1.0 - p1
    expected_r = p1 * r1 + p2 * r2
    app = model.applicable
    cls, reps = _bisimilar(app, expected_r, p1, model.next1, model.next2)
    if reps.size == cls.size:                       # nothing to merge
        return _sweeps(model.initial_q(), expected_r, p1, p2, model.next1, model.next2, app,
                       params)
    q = np.where(app[reps], 0.0, NOT_APPLICABLE)
    q = _sweeps(q, expected_r[reps], p1[reps], p2[reps], cls[model.next1[reps]],
                cls[model.next2[reps]], app[reps], params)
    return q[cls]


def _sweeps(q: np.ndarray, expected_r: np.ndarray, p1: np.ndarray, p2: np.ndarray,
            next1: np.ndarray, next2: np.ndarray, applicable: np.ndarray,
            params: Params) -> np.ndarray:
    """The sweeps of :func:`value_iteration` on a Q-table ``q`` (fresh, contiguous; 0 on the
    applicable pairs), in place; ``next1``/``next2`` index rows of ``q``."""
    g = params.gamma
    # Only the applicable pairs are computed (the others stay NOT_APPLICABLE): the same
    # element-wise operations on the same values as over the whole table, on fewer elements.
    flat = np.flatnonzero(applicable)
    er = expected_r.ravel()[flat]
    a1, a2 = p1.ravel()[flat], p2.ravel()[flat]
    n1, n2 = next1.ravel()[flat], next2.ravel()[flat]
    q_flat = q.reshape(-1)                   # a view: q is a fresh contiguous array
    q_app = q_flat[flat]
    # V(s) (:func:`state_values`) from the applicable pairs alone: they come row by row, so a
    # segmented max over each row's run gives max_a Q(s, a); rows with none keep V = 0.
    n_a = q.shape[1]
    rows = flat // n_a if n_a else flat
    starts = np.flatnonzero(np.r_[True, rows[1:] != rows[:-1]]) if flat.size else flat
    live = rows[starts]
    k = kernels()
    if k is not None:                       # the same sweeps, compiled (kernels.vi_sweeps)
        q_flat[flat] = k.vi_sweeps(q_app, er, a1, a2, n1, n2, starts, live, q.shape[0],
                                   float(g), float(params.value_iteration_tol),
                                   int(params.value_iteration_max_sweeps))
        return q
    v = np.zeros(q.shape[0])
    t1, t2 = np.empty_like(er), np.empty_like(er)
    for _ in range(params.value_iteration_max_sweeps):
        if flat.size:
            v[live] = np.maximum.reduceat(q_app, starts)
        # new = er + g * (a1 * v[n1] + a2 * v[n2]), in preallocated buffers
        np.multiply(a1, np.take(v, n1, out=t1, mode="clip"), out=t1)  # indices are valid
        np.multiply(a2, np.take(v, n2, out=t2, mode="clip"), out=t2)
        np.add(t1, t2, out=t1)
        np.multiply(t1, g, out=t1)
        new = np.add(er, t1)
        np.subtract(new, q_app, out=t2)
        delta = float(np.abs(t2, out=t2).max(initial=0.0))
        q_app = new
        if delta < params.value_iteration_tol:
            break
    q_flat[flat] = q_app
    return q


def _bisimilar(applicable: np.ndarray, expected_r: np.ndarray, p1: np.ndarray,
               next1: np.ndarray, next2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The coarsest partition of the states in which two states of a class have, for every
    action, the same applicability, the same bits of E[R] and of p1, and next states in the
    same class; returns (class of each state, the first state of each class, in state order).

    By induction over the sweeps of :func:`value_iteration` (Q = 0 at the start, each backup a
    function of exactly these), states of one class have bit-identical Q rows at every sweep.
    Found by partition refinement: classes are split by their next states' classes until every
    state agrees with its class's first state (grown plans: usually at once).
    """
    n_s, n_a = applicable.shape
    sig = np.empty((n_s, 2 * n_a + 1), dtype=np.int64)
    # NaN marks an inapplicable pair (E[R] of an applicable one is finite).
    sig[:, 1:n_a + 1] = np.where(applicable, expected_r, np.nan).view(np.int64)
    sig[:, n_a + 1:] = np.where(applicable, p1, 0.0).view(np.int64)
    k = kernels()
    if k is not None:                        # the same partition, compiled (kernels.bisimilar)
        return k.bisimilar(np.ascontiguousarray(sig[:, 1:]), np.ascontiguousarray(next1),
                           np.ascontiguousarray(next2))
    cls, reps = _row_classes(sig[:, 1:])
    while True:
        # An inapplicable pair leads to its own state (TransitionModel.build), whose class all
        # states of the class share: no mask is needed.
        sig[:, 0] = cls
        np.take(cls, next1, out=sig[:, 1:n_a + 1])
        np.take(cls, next2, out=sig[:, n_a + 1:])
        if np.array_equal(sig, sig[reps[cls]]):     # stable: no class splits
            return cls, reps
        cls, reps = _row_classes(sig)


_ROW_HASH: dict[int, np.ndarray] = {}


def _row_classes(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Classes of equal rows of an int64 matrix: (class of each row, first row of each class),
    classes numbered in the order of their first rows.

    Rows are grouped by a 64-bit hash and each group is checked against its first row; only if
    a hash collided are the rows compared whole (exact either way).
    """
    w = rows.shape[1]
    mult = _ROW_HASH.get(w)
    if mult is None:       # odd 64-bit multipliers, fixed per width
        drawn = np.random.default_rng(w).integers(1, 2**63, size=w, dtype=np.uint64)
        mult = _ROW_HASH[w] = np.bitwise_or(drawn, np.uint64(1))
    _, first, inv = np.unique(rows.view(np.uint64) @ mult, return_index=True,
                              return_inverse=True)
    inv = inv.reshape(-1)
    if not np.array_equal(rows, rows[first[inv]]):
        whole = np.ascontiguousarray(rows).view(np.dtype((np.void, 8 * w))).reshape(-1)
        _, first, inv = np.unique(whole, return_index=True, return_inverse=True)
        inv = inv.reshape(-1)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    return rank[inv], first[order]


def dyna_sweep(q: np.ndarray, model: TransitionModel, params: Params) -> np.ndarray:
    """One Dyna sweep (eq. 5.10, α = Params.dyna_alpha) over all applicable pairs, in place.

    Synchronous: every backup uses the Q-table from before the sweep. Returns ``q``.
    """
    _check_shape(q, model)
    a = params.dyna_alpha
    if not q.flags.c_contiguous:
        target = model.backup(q, params)
        m = model.applicable
        q[m] = (1.0 - a) * q[m] + a * target[m]
        return q
    # :meth:`TransitionModel.backup` on the applicable pairs only (the others are not used):
    # the same element-wise operations on the same values, about half the elements.
    flat, p1, p2, r1, r2, n1, n2 = _applicable_pairs(model, params)
    k = kernels()
    if k is not None and q.dtype == np.float64:   # the same sweep, compiled (kernels.dyna)
        k.dyna(q, flat, p1, p2, r1, r2, n1, n2, float(params.gamma), float(a))
        return q
    v = state_values(q)
    g = params.gamma
    target = p1 * (r1 + g * v[n1]) + p2 * (r2 + g * v[n2])
    q_flat = q.reshape(-1)                                  # a view (contiguous)
    q_flat[flat] = (1.0 - a) * q_flat[flat] + a * target
    return q


def _applicable_pairs(model: TransitionModel, params: Params) -> tuple[np.ndarray, ...]:
    """The applicable pairs' flat indices, p1, 1 − p1, rewards and next states (in
    :meth:`TransitionModel.backup`'s terms), cached on the model per reward constants."""
    key = (params.goal_reward, params.step_reward)
    cached = model.__dict__.get("_applicable_pairs")
    if cached is not None and cached[0] == key:
        return cached[1]
    r1, r2 = model.rewards(params)
    flat = np.flatnonzero(model.applicable)
    out = (flat, model.p1.ravel()[flat], (1.0 - model.p1).ravel()[flat], r1.ravel()[flat],
           r2.ravel()[flat], model.next1.ravel()[flat], model.next2.ravel()[flat])
    object.__setattr__(model, "_applicable_pairs", (key, out))
    return out


def greedy_policy(q: np.ndarray) -> np.ndarray:
    """argmax_a Q(s, a) per state (lowest index on ties), −1 where nothing is applicable."""
    q = np.asarray(q, dtype=float)
    if q.shape[1] == 0:
        return np.full(q.shape[0], -1, dtype=np.int64)
    best = np.argmax(q, axis=1).astype(np.int64)
    return np.where(np.isfinite(q.max(axis=1)), best, -1)


def greedy_action(q: np.ndarray, s: int, rng: np.random.Generator,
                  epsilon: float) -> int | None:
    """ε-greedy choice in state s among applicable actions (§6.1.3); None if none applies.

    With probability ε a uniformly random applicable action, else a maximiser of Q(s, ·)
    (ties broken uniformly at random). Draws from ``rng`` only.
    """
    # Plain Python on the row's floats: a plan has a few actions, and this runs at every
    # sub-action choice, where numpy's per-call overhead dominated (the same comparisons).
    row = np.asarray(q[s], dtype=float).tolist()
    ok = [j for j, x in enumerate(row) if math.isfinite(x)]
    if not ok:
        return None
    if rng.random() < epsilon:
        return ok[int(rng.integers(len(ok)))]
    top = max(row[j] for j in ok)
    best = [j for j in ok if row[j] == top]
    return best[0] if len(best) == 1 else best[int(rng.integers(len(best)))]


# ---------------------------------------------------------------------------------------------
# Sarsa(λ) (§5.2.2, eq. 5.7–5.9)
# ---------------------------------------------------------------------------------------------


def sarsa_reward(goal_reached: bool, option_steps: int, params: Params) -> float:
    """r' = R(s) − 0.01·t (eq. 5.8): R(s) = 10 if Y = y in the reached state, else 0."""
    base = params.goal_reward if goal_reached else 0.0
    return base - params.sarsa_time_cost * option_steps


class SarsaLambda:
    """Sarsa(λ) with replacing traces on a plan's Q-table (eq. 5.7–5.9).

    ``q`` is shared, not copied: updates write into it (as :func:`dyna_sweep` does), so one
    table serves value iteration, Dyna and Sarsa. Every MDP transition is one time step: the
    trace decays by λγ per update and a visited pair's trace is set to 1 (not incremented).
    """

    def __init__(self, q: np.ndarray, params: Params, traces: np.ndarray | None = None) -> None:
        self.q = q
        self.params = params
        self.e = np.zeros_like(q, dtype=float) if traces is None else np.asarray(traces, float)
        if self.e.shape != q.shape:
            raise ValueError(f"traces {self.e.shape} do not match Q {q.shape}")

    def reset(self) -> None:
        """Clear the traces (a new episode)."""
        self.e[...] = 0.0

    def start(self, s: int, a: int) -> None:
        """Begin an episode (the plan called action a in state s): e = 0, then e(s, a) = 1."""
        self._check(s, a)
        self.reset()
        self.e[s, a] = 1.0

    def update(self, s: int, a: int, r_prime: float, s2: int, a2: int | None) -> float:
        """The update of eq. 5.7 after a ended in s2 and the plan chose a2; returns δ.

        δ = r' + γQ(s2, a2) − Q(s, a) (r' − Q(s, a) when ``a2`` is None: s2 is terminal or
        the plan ends), e(s, a) = 1, Q += αeδ for all pairs, then e ← λγe (eq. 5.9). A
        terminal update clears the traces.
        """
        p = self.params
        self._check(s, a)
        target = float(r_prime)
        if a2 is not None:
            self._check(s2, a2)
            target += p.gamma * float(self.q[s2, a2])
        delta = target - float(self.q[s, a])
        k = kernels()
        if k is not None and self.q.flags.c_contiguous and self.e.flags.c_contiguous \
                and self.q.dtype == np.float64 and self.e.dtype == np.float64:
            # The same update, compiled (kernels.sarsa): αδ and λγ as below.
            k.sarsa(self.q, self.e, s, a, p.sarsa_alpha * delta, p.sarsa_lambda * p.gamma,
                    a2 is None)
            return delta
        self.e[s, a] = 1.0
        live = self.e > 0.0
        self.q[live] += p.sarsa_alpha * delta * self.e[live]
        if a2 is None:
            self.reset()
        else:
            self.e *= p.sarsa_lambda * p.gamma
        return delta

    def _check(self, s: int, a: int) -> None:
        if not np.isfinite(self.q[s, a]):
            raise ValueError(f"action {a} is not applicable in state {s}")

    def to_state(self) -> dict[str, Any]:
        """JSON-ready form of Q and the traces (see :func:`q_to_state`)."""
        return {**q_to_state(self.q), "traces": self.e.tolist()}

    @classmethod
    def from_state(cls, data: Mapping[str, Any], params: Params) -> SarsaLambda:
        """Inverse of :meth:`to_state`."""
        q = q_from_state(data)
        return cls(q, params, np.asarray(data["traces"], dtype=float).reshape(q.shape))


# ---------------------------------------------------------------------------------------------
# Growing Q-tables and serialisation (§5.4.2)
# ---------------------------------------------------------------------------------------------


def remap_q(q: np.ndarray, state_map: np.ndarray | None = None,
            actions: np.ndarray | None = None, applicable: np.ndarray | None = None,
            fill: float = 0.0) -> np.ndarray:
    """A new Q-table for a grown state space and/or action list.

    ``state_map[s_new]`` is the old state (from :meth:`PlanStateSpace.with_variable` or
    :meth:`PlanStateSpace.resized`); ``actions[a_new]`` the old action or −1
    (:func:`action_map`). Copied values stay; new actions, and old inapplicable pairs that
    became applicable, get ``fill``; pairs not ``applicable`` get the sentinel.
    """
    q = np.asarray(q, dtype=float)
    n_s, n_a = q.shape
    rows = np.arange(n_s) if state_map is None else np.asarray(state_map, dtype=np.int64)
    cols = np.arange(n_a) if actions is None else np.asarray(actions, dtype=np.int64)
    out = np.full((rows.size, cols.size), float(fill))
    known = cols >= 0
    out[:, known] = q[np.ix_(rows, cols[known])]
    if applicable is not None:
        applicable = np.asarray(applicable, dtype=bool)
        if applicable.shape != out.shape:
            raise ValueError(f"applicable {applicable.shape} does not match {out.shape}")
        out = np.where(applicable & ~np.isfinite(out), float(fill), out)
        out[~applicable] = NOT_APPLICABLE
    return out


def compose_split_maps(splits: Iterable[tuple[int, int]],
                       sizes: Mapping[int, int] | Sequence[int]) -> dict[int, np.ndarray]:
    """``new_to_old`` value maps after landmarks split intervals, in order (§4.4).

    ``splits`` are (var, split) pairs as the learner reports them (each in the numbering left
    by the previous ones, :func:`split_value_map`); ``sizes[var]`` is |Q(var)| after all of them.
    ``maps[var][q_new]`` is the value q_new came from before the first split; the old size is
    ``maps[var].max() + 1`` (every old value has a descendant). A variable whose size the
    splits do not explain gets no map (its plans are then re-planned, :func:`grow_q`).
    """
    order: dict[int, list[int]] = {}
    for var, split in splits:
        order.setdefault(int(var), []).append(int(split))
    maps: dict[int, np.ndarray] = {}
    for var, seq in order.items():
        m = np.arange(max(0, int(sizes[var]) - 2 * len(seq)), dtype=np.int64)
        for split in seq:
            if not 0 <= split < m.size:
                break
            q = np.arange(m.size + 2, dtype=np.int64)
            m = m[np.where(q < split, q, np.where(q <= split + 2, split, q - 2))]
        else:
            maps[var] = m
    return maps


def space_value_maps(old: PlanStateSpace, new: PlanStateSpace,
                     value_maps: Mapping[int, np.ndarray]) -> dict[int, np.ndarray] | None:
    """The value maps that lead from ``old`` to ``new`` for the variables of both.

    A variable of the same size in both is unchanged (no entry); one that grew needs a map of
    matching sizes in ``value_maps``. None when a variable's values cannot be followed.
    """
    out: dict[int, np.ndarray] = {}
    for v in old.vars:
        if v not in new:
            continue
        n_old, n_new = old.size_of(v), new.size_of(v)
        if n_old == n_new:
            continue
        m = value_maps.get(v)
        if m is None or m.size != n_new or int(m.max()) + 1 != n_old:
            return None
        out[v] = np.asarray(m, dtype=np.int64)
    return out


def grow_q(q_old: np.ndarray, old: PlanStateSpace, old_actions: Sequence[MDPAction],
           new: PlanStateSpace, new_actions: Sequence[MDPAction],
           value_maps: Mapping[int, np.ndarray],
           base: np.ndarray | Callable[[], np.ndarray],
           applicable: np.ndarray | None = None) -> np.ndarray | None:
    """Carry a plan's learned Q-values over a change of its state space (§5.2.2, §5.4.2).

    Each new state inherits the values of the old state it descends from: a value split by a
    landmark passes its values to the three new values, a variable added (C_o, a DBN context)
    copies them to each of its values, and a variable dropped averages the old states that
    merge. Actions follow :func:`action_map`. Pairs with no ancestor (new actions, pairs that
    became applicable) take ``base`` (e.g. Q* of the new model by value iteration); pairs not
    applicable in ``base`` (−inf) stay so. None when a variable's values cannot be followed
    (:func:`space_value_maps`). ``base`` may be a function computing it, with the new model's
    ``applicable`` mask: it is then called only if some applicable pair has no ancestor (value
    iteration is the expensive part of a rebuild, and most growths leave none).
    """
    maps = space_value_maps(old, new, value_maps)
    if maps is None:
        return None
    q_old = np.asarray(q_old, dtype=float)
    vals = new.all_values()
    old_vals = np.zeros((new.n_states, len(old.vars)), dtype=np.int64)
    dropped = []
    for i, v in enumerate(old.vars):
        if v in new:
            col = vals[:, new.position(v)]
            old_vals[:, i] = maps[v][col] if v in maps else col
        else:
            dropped.append(i)
    cols = action_map(old_actions, new_actions, maps)
    known = np.flatnonzero(cols >= 0)
    if dropped:
        acc, cnt = _merged_ancestors(q_old, old, old_vals, dropped, cols[known])
        has = cnt > 0
    else:
        # One ancestor per state (the usual growth): its values, as the mean of one value
        # would give them (0.0 + x / 1.0, i.e. x with −0.0 made +0.0).
        block = q_old[np.ix_(_ravel(old_vals, old.sizes), cols[known])]
        has = np.isfinite(block)
    if callable(base):
        if applicable is None:
            raise ValueError("grow_q: a callable base needs the applicable mask")
        inherited = np.zeros(applicable.shape, dtype=bool)
        inherited[:, known] = has
        if (applicable & ~inherited).any():
            base = base()
        else:
            base = np.where(applicable, 0.0, NOT_APPLICABLE)
    out = np.array(base, dtype=float, copy=True)
    sub = out[:, known]
    ok = has & np.isfinite(sub)
    sub[ok] = acc[ok] / cnt[ok] if dropped else block[ok] + 0.0
    out[:, known] = sub
    return out


def _merged_ancestors(q_old: np.ndarray, old: PlanStateSpace, old_vals: np.ndarray,
                      dropped: Sequence[int], cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sum and count of the finite Q-values of the old states that merge into each new state
    when the old variables at positions ``dropped`` leave the space (:func:`grow_q`), for the
    old action columns ``cols``.

    ``old_vals`` holds each new state's values of the kept old variables (the dropped columns
    are ignored). The merge is a function of those values alone, so it is computed once per
    combination of kept values (the old table with the dropped variables' axes first) and
    then read for each new state. Each sum is accumulated in the order of ``np.ndindex`` over
    the dropped values, from 0.0, so it is bit for bit the one of adding the combinations one
    after another.
    """
    dropped = list(dropped)
    kept = [i for i in range(len(old.vars)) if i not in dropped]
    grid = np.asarray(q_old, dtype=float)[:, cols].reshape(*old.sizes, len(cols))
    grid = np.moveaxis(grid, dropped, list(range(len(dropped))))  # C order: np.ndindex's
    n_combos = int(np.prod([old.sizes[i] for i in dropped], dtype=np.int64))
    n_kept = int(np.prod([old.sizes[i] for i in kept], dtype=np.int64))
    grid = grid.reshape(n_combos, n_kept, len(cols))    # also with no column (no -1)
    finite = np.isfinite(grid)
    values = np.where(finite, grid, 0.0)
    acc = np.zeros(values.shape[1:])
    for block in values:
        acc += block
    cnt = finite.sum(axis=0).astype(float)
    rows = _ravel(old_vals[:, kept], [old.sizes[i] for i in kept])
    return acc[rows], cnt[rows]


def descendant_state(old: PlanStateSpace, new: PlanStateSpace,
                     value_maps: Mapping[int, np.ndarray], old_state: int,
                     prefer: Sequence[int]) -> int | None:
    """The state of ``new`` that old state ``old_state`` became, choosing among its
    descendants the values in ``prefer`` (the agent's current qualitative values, by variable)
    where there is a choice; None when the values cannot be followed."""
    maps = space_value_maps(old, new, value_maps)
    if maps is None:
        return None
    before = dict(zip(old.vars, old.values(old_state), strict=True))
    out = []
    for v, n in zip(new.vars, new.sizes, strict=True):
        if v in before:
            cand = np.flatnonzero(maps[v] == before[v]) if v in maps else np.array([before[v]])
        else:
            cand = np.arange(n)
        want = int(prefer[v]) if v < len(prefer) else -1
        out.append(want if want in cand else int(cand[0]))
    return new.index(out)


def q_to_state(q: np.ndarray) -> dict[str, Any]:
    """JSON-ready (and npz-ready via ``np.asarray``) form: finite values and a bool mask."""
    q = np.asarray(q, dtype=float)
    ok = np.isfinite(q)
    return {"q": np.where(ok, q, 0.0).tolist(), "applicable": ok.tolist(),
            "shape": list(q.shape)}


def q_from_state(data: Mapping[str, Any]) -> np.ndarray:
    """Inverse of :func:`q_to_state`."""
    shape = tuple(int(n) for n in data["shape"])
    vals = np.asarray(data["q"], dtype=float).reshape(shape)
    ok = np.asarray(data["applicable"], dtype=bool).reshape(shape)
    return np.where(ok, vals, NOT_APPLICABLE)


def actions_to_state(actions: Iterable[MDPAction]) -> list[dict[str, Any]]:
    """JSON-ready form of an action list (the Q-table's columns)."""
    return [a.to_state() for a in actions]


def actions_from_state(data: Iterable[Mapping[str, Any]]) -> list[MDPAction]:
    """Inverse of :func:`actions_to_state`."""
    return [MDPAction.from_state(d) for d in data]


def _check_shape(q: np.ndarray, model: TransitionModel) -> None:
    if q.shape != (model.n_states, model.n_actions):
        raise ValueError(f"Q {q.shape} does not match the model "
                         f"({model.n_states}, {model.n_actions})")
