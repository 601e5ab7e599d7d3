"""QLAP actions a(v, q), plan bookkeeping, self and targeted learning (§5.1, §5.5, §6.2–6.4).

Pure bookkeeping: counts and decisions, no planning and no world access.

* :class:`ActionStats` — calls, successes, failures, rel(a), mean steps to success, the
  sticky "sufficiently reliable" flag (§6.2.1, prior α = β = 2 of App. B) and the history of
  rel(a) at each termination that IAC reads (§6.1.1).
* :class:`PlanStats` — the same for one plan (option) o: rel(o) (prior 1), the replacement
  reliability (prior 0, App. B) and the §6.2.2 tests.
* :func:`plan_slots` — the §6.2.2 rule: at most three plans, replacement and removal.
* :class:`ActionTable` — one :class:`ActionStats` per qualitative value of every variable
  (§5.1), re-keyed when a variable gains a landmark.
* :func:`motor_value` / :func:`motor_value_for` — a random motor value within a value (§5.5);
  :func:`motor_reachable` — whether the value meets the motor's range at all; :func:`rest_value`.
* :func:`is_self` — §6.4 and Appendix A; :func:`targeted`, :func:`theta_pen_for`,
  :func:`theta_sr_for` — targeted learning (§6.3).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np

from .params import Params
from .probability import prob_above, success_probability
from .quantity import QuantitySpace
from .variables import Kind

ActionKey = tuple[int, int]
"""(variable index, qualitative value) of an action a(v, q) (§5.1)."""

REL_HISTORY_LEN = 200
"""rel(a) values kept per action for the UI's sparkline. Not a QLAP parameter (not in Params):
IAC itself needs only the last 2·θ = 50 (eq. 6.1); the deque keeps max(this, 2·iac_window)."""

CHANGE_MINUS, CHANGE_PLUS = 0, 2
"""Values [−] and [+] of a direction-of-change variable (landmark 0 at value 1, §3.1)."""

_DEFAULT_PARAMS = Params()


# ---------------------------------------------------------------------------------------------
# Actions (§5.1, Table 5.1, §6.2.1)
# ---------------------------------------------------------------------------------------------


@dataclass
class ActionStats:
    """Statistics of one action a(v, q) (Table 5.1)."""

    calls: int = 0
    """Times the action was called (each call ends in exactly one success or failure)."""
    successes: int = 0
    """Terminations with v = q."""
    failures: int = 0
    """Terminations with v ≠ q."""
    success_steps: int = 0
    """Sum over successes of the steps from call to success (for self, §6.4)."""
    timed_successes: int = 0
    """Successes whose step count was recorded."""
    reliable: bool = False
    """Sticky: rel(a) was sufficiently reliable at some termination (§6.2.1 "at any time")."""
    history_len: int = REL_HISTORY_LEN
    """Bound of :attr:`history`."""
    history: deque[float] = field(default_factory=deque)
    """rel(a) (prior ``Params.prior``) recorded at each termination, oldest first (§6.1.1)."""

    def __post_init__(self) -> None:
        self.history = deque(self.history, maxlen=self.history_len)

    def rel(self, prior: float = 1.0) -> float:
        """rel(a) = (#success + α) / (#success + #fail + 2α), α = β = ``prior`` (eq. B.1)."""
        return success_probability(self.successes, self.failures, prior)

    def check_reliable(self, params: Params) -> bool:
        """Beta test of rel(a) > θ_SR with prior α = β = 2 (App. B, §6.2.1), now, not sticky."""
        return prob_above(params.theta_sr, self.successes, self.failures,
                          prior=params.prior_action_reliable,
                          confidence=params.beta_confidence)

    def sufficiently_reliable(self, params: Params) -> bool:
        """True once rel(a) has been > θ_SR at any time (§6.2.1); the flag then stays set."""
        if not self.reliable and self.check_reliable(params):
            self.reliable = True
        return self.reliable

    def record(self, success: bool, steps: int | None = None,
               params: Params | None = None, practised: bool = True) -> None:
        """Count one termination; ``steps`` is the time from call to termination.

        Appends rel(a) (prior ``params.prior``) to the history (with ``params.iac_records``
        "practice", only for a ``practised`` call) and updates the sticky flag.
        """
        p = params if params is not None else _DEFAULT_PARAMS
        self.calls += 1
        if success:
            self.successes += 1
            if steps is not None:
                if steps < 0:
                    raise ValueError(f"steps must be >= 0, got {steps}")
                self.success_steps += int(steps)
                self.timed_successes += 1
        else:
            self.failures += 1
        if practised or p.iac_records == "all":
            self.history.append(self.rel(p.prior) if p.iac_progress == "cumulative"
                                else float(success))
        self.sufficiently_reliable(p)

    def mean_steps_to_success(self) -> float | None:
        """Average steps from call to success, or None with no timed success (§6.4)."""
        if self.timed_successes == 0:
            return None
        return self.success_steps / self.timed_successes

    def to_json(self) -> dict:
        """JSON-ready dict (checkpoints)."""
        return {"calls": self.calls, "successes": self.successes, "failures": self.failures,
                "success_steps": self.success_steps, "timed_successes": self.timed_successes,
                "reliable": self.reliable, "history_len": self.history_len,
                "history": list(self.history)}

    @classmethod
    def from_json(cls, data: dict) -> ActionStats:
        """Inverse of :meth:`to_json`."""
        return cls(int(data["calls"]), int(data["successes"]), int(data["failures"]),
                   int(data["success_steps"]), int(data["timed_successes"]),
                   bool(data["reliable"]), int(data["history_len"]),
                   deque(float(x) for x in data["history"]))


# ---------------------------------------------------------------------------------------------
# Plans (§5.4.1, §6.2.2)
# ---------------------------------------------------------------------------------------------


@dataclass
class PlanStats:
    """Overall statistics of one plan (option) o of an action (§5.4.1, Table 5.1)."""

    calls: int = 0
    successes: int = 0
    failures: int = 0
    reliable: bool = False
    """Sticky: brel(o) of the plan's second-order model r_o² was > θ_SR at some time (§5.4.1,
    "a plan can also be sufficiently reliable if at any time brel(o) > θ_SR")."""
    age: int = 0
    """Steps since the plan was created."""

    def record(self, success: bool) -> None:
        """Count one termination of the plan."""
        self.calls += 1
        if success:
            self.successes += 1
        else:
            self.failures += 1

    def rel(self, prior: float = 1.0) -> float:
        """rel(o) with α = β = ``prior`` (eq. B.1)."""
        return success_probability(self.successes, self.failures, prior)

    def replace_reliability(self, params: Params | None = None) -> float:
        """rel(o) with prior α = β = 0, used to rank plans for replacement (App. B, §6.2.2).

        0.0 when the plan was never called.
        """
        p = params if params is not None else _DEFAULT_PARAMS
        return success_probability(self.successes, self.failures, p.prior_plan_replace)

    def sufficiently_reliable(self, params: Params | None = None) -> bool:
        """The sticky brel(o) > θ_SR flag (§5.4.1); set by the planner from r_o²."""
        return self.reliable

    def eligible_for_replacement(self, params: Params) -> bool:
        """Not sufficiently reliable, and called more than 30 times (§6.2.2) — or, with fewer
        calls, created at least ``Params.dbn_max_age`` steps ago (our reading: a plan that is
        almost never called must not hold its slot for ever; the age of §6.2.3, see
        docs/decisions.md)."""
        if self.reliable:
            return False
        return self.calls > params.plan_replace_min_calls or self.age >= params.dbn_max_age

    def should_remove(self, params: Params) -> bool:
        """rel(o) (prior 1) < 0.05 after at least ``plan_replace_min_calls`` calls (§6.2.2).

        The call minimum is our choice: the text gives none; with prior 1 and 30 calls this
        means no success at all, so a new plan is not thrown away on a bad start.
        """
        return (self.calls >= params.plan_replace_min_calls
                and self.rel(params.prior) < params.plan_remove_below)

    def to_json(self) -> dict:
        return {"calls": self.calls, "successes": self.successes, "failures": self.failures,
                "reliable": self.reliable, "age": self.age}

    @classmethod
    def from_json(cls, data: dict) -> PlanStats:
        return cls(int(data["calls"]), int(data["successes"]), int(data["failures"]),
                   bool(data.get("reliable", False)), int(data.get("age", 0)))


@dataclass(frozen=True)
class PlanSlots:
    """What §6.2.2 allows for one action's plans."""

    remove: tuple[int, ...]
    """Indices of plans to remove (rel(o) < 0.05)."""
    free: int
    """Number of new plans that may be added without replacing one."""
    replaceable: int | None
    """Index of the plan a new plan may replace when ``free == 0``, else None."""

    @property
    def accepts_new(self) -> bool:
        """Whether a new plan can be added (into a free slot or by replacement)."""
        return self.free > 0 or self.replaceable is not None


def plan_slots(plans: Sequence[PlanStats], params: Params,
               action: ActionStats | None = None) -> PlanSlots:
    """The §6.2.2 rule for an action's current plans (indices into ``plans``).

    Plans with rel(o) < 0.05 are removed first. At most ``max_plans_per_action`` remain; if the
    action is full, the plan with the lowest rel(o) (prior 0) among those eligible
    (:meth:`PlanStats.eligible_for_replacement`: called more than 30 times, or old, and never
    sufficiently reliable) may be replaced (ties: the lower index); with
    ``Params.plan_replace == "lowest"`` the lowest rel(o) among all plans not sufficiently
    reliable, and only if it is eligible (docs/decisions.md 100). If no plan qualifies,
    nothing is replaced. A sufficiently reliable ``action`` gets no new plans at all
    (§6.2.1 item 2), though removal still applies.
    """
    remove = tuple(i for i, o in enumerate(plans) if o.should_remove(params))
    kept = [i for i in range(len(plans)) if i not in remove]
    if action is not None and action.sufficiently_reliable(params):
        return PlanSlots(remove, 0, None)
    free = max(0, params.max_plans_per_action - len(kept))
    replaceable: int | None = None
    if free == 0:
        if params.plan_replace == "lowest":
            # The worst plan not sufficiently reliable, if it may go (ties: an eligible one,
            # then the lower index); a better plan never goes while a worse one waits.
            open_ = [i for i in kept if not plans[i].reliable]
            if open_:
                low = min(open_, key=lambda i: (plans[i].replace_reliability(params),
                                                not plans[i].eligible_for_replacement(params), i))
                if plans[low].eligible_for_replacement(params):
                    replaceable = low
        else:
            eligible = [i for i in kept if plans[i].eligible_for_replacement(params)]
            if eligible:
                replaceable = min(eligible,
                                  key=lambda i: (plans[i].replace_reliability(params), i))
    return PlanSlots(remove, free, replaceable)


# ---------------------------------------------------------------------------------------------
# Motor actions (§5.5)
# ---------------------------------------------------------------------------------------------


def motor_interval(var_low: float | None, var_high: float | None, lo: float, hi: float,
                   *, landmark: bool = False) -> tuple[float, float] | None:
    """Where a motor action a(u, q) can put u: q ∩ [var_low, var_high] (§5.5), or None if the
    value is out of the motor's reach (empty, an open interval touching the range only at its
    excluded endpoint, or unbounded)."""
    vlo = -math.inf if var_low is None else float(var_low)
    vhi = math.inf if var_high is None else float(var_high)
    a, b = max(lo, vlo), min(hi, vhi)
    if a > b or (not landmark and a == b and not lo < a < hi):
        return None
    if a != b and not (math.isfinite(a) and math.isfinite(b)):
        return None
    return a, b


def motor_value(var_low: float | None, var_high: float | None, lo: float, hi: float,
                rng: np.random.Generator, *, landmark: bool = False) -> float:
    """A random motor value in qualitative value [lo, hi] ∩ [var_low, var_high] (§5.5, Alg. 6).

    ``landmark`` values are closed ranges [lb, ub] (a point landmark returns lb exactly, no
    random draw); open intervals (lo, hi) never return an endpoint. ``None`` motor bounds are
    unbounded. Raises ValueError if the intersection is empty or unbounded (see
    :func:`motor_interval`; the agent never calls such an action, :func:`motor_reachable`).
    """
    ab = motor_interval(var_low, var_high, lo, hi, landmark=landmark)
    if ab is None:
        vlo = -math.inf if var_low is None else float(var_low)
        vhi = math.inf if var_high is None else float(var_high)
        kind = f"landmark [{lo}, {hi}]" if landmark else f"interval ({lo}, {hi})"
        a, b = max(lo, vlo), min(hi, vhi)
        if a < b:
            raise ValueError(f"unbounded motor range for ({lo}, {hi}) ∩ [{vlo}, {vhi}]")
        raise ValueError(f"{kind} does not meet the motor range [{vlo}, {vhi}]")
    a, b = ab
    if a == b:
        return float(a)
    x = float(rng.uniform(a, b))
    if not landmark and (x <= lo or x >= hi):   # open interval: an endpoint is the landmark
        x = 0.5 * (a + b)
    return x


def motor_value_for(space: QuantitySpace, q: int, var_low: float | None,
                    var_high: float | None, rng: np.random.Generator) -> float:
    """:func:`motor_value` for value ``q`` of a motor's quantity space (§5.5)."""
    lo, hi = space.bounds(q)
    return motor_value(var_low, var_high, lo, hi, rng,
                       landmark=QuantitySpace.is_landmark_value(q))


def motor_reachable(space: QuantitySpace, q: int, var_low: float | None,
                    var_high: float | None) -> bool:
    """Can a(u, q) be performed at all: does value ``q`` meet the motor's range (§5.5)?

    A motor whose range does not straddle a landmark has values it can never take (u_UG in
    [0, 1] below a landmark at 0); such an action is not applicable in any plan and fails
    when called, instead of stopping the control loop.
    """
    lo, hi = space.bounds(q)
    return motor_interval(var_low, var_high, lo, hi,
                          landmark=QuantitySpace.is_landmark_value(q)) is not None


def rest_value(var_low: float | None, var_high: float | None) -> float:
    """A motor's rest value: 0, or the value of its range nearest to 0 (§6.1.1 rest posture)."""
    lo = -math.inf if var_low is None else float(var_low)
    hi = math.inf if var_high is None else float(var_high)
    return float(min(max(0.0, lo), hi))


# ---------------------------------------------------------------------------------------------
# Self (§6.4, Appendix A)
# ---------------------------------------------------------------------------------------------


def is_self(stats: Sequence[ActionStats], k: float, params: Params) -> bool:
    """Every action in ``stats`` is sufficiently reliable and succeeds in < k steps on average.

    For a change variable pass a(v̇, [+]) and a(v̇, [−]) (§6.4); for a nominal variable all of
    its values (App. A). Each action's own mean must be below k (our reading of "the average
    time it takes for the action to set v̇ = [+] and v̇ = [−]"). Empty ``stats`` → False.
    """
    if not stats:
        return False
    for s in stats:
        mean = s.mean_steps_to_success()
        if mean is None or not mean < k or not s.sufficiently_reliable(params):
            return False
    return True


# ---------------------------------------------------------------------------------------------
# Targeted learning (§6.3)
# ---------------------------------------------------------------------------------------------


def targeted(satisfied_fraction: np.ndarray | Sequence[float], params: Params) -> np.ndarray:
    """Events satisfied less than 5% of the time are targeted (§6.3); a bool array.

    Ablations: ``no_targeted`` → all False, ``all_targeted`` → all True (§7.11); both at once
    is an error. A NaN fraction (no data yet) is not targeted.
    """
    frac = np.asarray(satisfied_fraction, dtype=float)
    abl = params.ablations
    if abl.no_targeted and abl.all_targeted:
        raise ValueError("ablations no_targeted and all_targeted are mutually exclusive")
    if abl.no_targeted:
        return np.zeros(frac.shape, dtype=bool)
    if abl.all_targeted:
        return np.ones(frac.shape, dtype=bool)
    with np.errstate(invalid="ignore"):
        return frac < params.rare_event_fraction


def theta_pen_for(is_targeted: bool | np.ndarray, params: Params) -> float | np.ndarray:
    """θ_pen for an event: 0.02 if targeted, else 0.05 (§6.3 eq. 6.4)."""
    if isinstance(is_targeted, np.ndarray):
        return np.where(is_targeted, params.theta_pen_targeted, params.theta_pen)
    return params.theta_pen_targeted if is_targeted else params.theta_pen


def theta_sr_for(is_targeted: bool | np.ndarray, params: Params) -> float | np.ndarray:
    """θ_SR for converting a DBN on an event to a plan: 0.25 if targeted, else 0.75 (eq. 6.5)."""
    if isinstance(is_targeted, np.ndarray):
        return np.where(is_targeted, params.theta_sr_targeted, params.theta_sr)
    return params.theta_sr_targeted if is_targeted else params.theta_sr


# ---------------------------------------------------------------------------------------------
# The table of actions (§5.1)
# ---------------------------------------------------------------------------------------------


class ActionTable:
    """One :class:`ActionStats` per (variable, qualitative value) (§5.1).

    When a variable gains a landmark inside interval ``split`` (:meth:`on_landmark`), values
    above ``split`` shift by 2 and the three new values split, split + 1, split + 2 start with
    fresh statistics. Choice: we reset rather than copy because the old action reached the whole
    interval, a different goal from either half; copying could also carry over the sticky
    "sufficiently reliable" flag and wrongly stop learning for the halves (§6.2.1).
    """

    def __init__(self, params: Params | None = None) -> None:
        self.params = params if params is not None else _DEFAULT_PARAMS
        self.history_len = max(REL_HISTORY_LEN, 2 * self.params.iac_window)
        self._stats: dict[ActionKey, ActionStats] = {}
        self._sizes: dict[int, int] = {}

    def _new(self) -> ActionStats:
        return ActionStats(history_len=self.history_len)

    def ensure_variable(self, var: int, n_values: int) -> None:
        """Create the missing actions a(var, q) for q in 0..n_values−1."""
        if n_values < 1:
            raise ValueError(f"variable {var} needs at least one value, got {n_values}")
        old = self._sizes.get(var, 0)
        if n_values < old:
            raise ValueError(f"variable {var} shrank from {old} to {n_values} values")
        for q in range(old, n_values):
            self._stats[(var, q)] = self._new()
        self._sizes[var] = n_values

    def sync(self, sizes: Sequence[int]) -> None:
        """:meth:`ensure_variable` for every variable, ``sizes[v]`` = |Q(v)|."""
        for v, n in enumerate(sizes):
            self.ensure_variable(v, int(n))

    def n_values(self, var: int) -> int:
        """|Q(var)| as known to the table (0 if unknown)."""
        return self._sizes.get(var, 0)

    def on_landmark(self, var: int, split: int) -> ActionStats:
        """Re-key after a landmark was inserted in interval ``split`` of ``var``; returns the
        split interval's old statistics (the new ones are fresh, see the class docstring)."""
        n = self._sizes.get(var, 0)
        if not 0 <= split < n or split % 2:
            raise ValueError(f"split {split} is not an open interval of variable {var} "
                             f"({n} values)")
        old = self._stats[(var, split)]
        for q in range(n - 1, split, -1):
            self._stats[(var, q + 2)] = self._stats.pop((var, q))
        for q in (split, split + 1, split + 2):
            self._stats[(var, q)] = self._new()
        self._sizes[var] = n + 2
        return old

    def __getitem__(self, key: ActionKey) -> ActionStats:
        try:
            return self._stats[key]
        except KeyError:
            raise KeyError(f"no action a{key}; variable {key[0]} has "
                           f"{self._sizes.get(key[0], 0)} values") from None

    def __contains__(self, key: object) -> bool:
        return key in self._stats

    def __len__(self) -> int:
        return len(self._stats)

    def __iter__(self) -> Iterator[ActionKey]:
        return iter(sorted(self._stats))

    def items(self) -> list[tuple[ActionKey, ActionStats]]:
        """(key, stats) pairs in key order."""
        return [(k, self._stats[k]) for k in sorted(self._stats)]

    def record(self, key: ActionKey, success: bool, steps: int | None = None,
               practised: bool = True) -> None:
        """Record a termination of a(key) with the table's params."""
        self[key].record(success, steps, self.params, practised)

    def is_self(self, var: int, kind: Kind, k: float) -> bool:
        """§6.4 for a change variable ([+] and [−]); Appendix A for a nominal one (all values).

        Other kinds are never part of self.
        """
        if kind is Kind.CHANGE:
            qs: Sequence[int] = (CHANGE_MINUS, CHANGE_PLUS)
        elif kind is Kind.NOMINAL:
            qs = range(self._sizes.get(var, 0))
        else:
            return False
        if any((var, q) not in self._stats for q in qs):
            return False
        return is_self([self._stats[(var, q)] for q in qs], k, self.params)

    def to_json(self) -> dict:
        """JSON-ready dict (checkpoints)."""
        return {"sizes": {str(v): n for v, n in sorted(self._sizes.items())},
                "actions": [[v, q, s.to_json()] for (v, q), s in self.items()]}

    @classmethod
    def from_json(cls, data: dict, params: Params | None = None) -> ActionTable:
        """Inverse of :meth:`to_json`."""
        t = cls(params)
        t._sizes = {int(v): int(n) for v, n in data["sizes"].items()}
        t._stats = {(int(v), int(q)): ActionStats.from_json(s) for v, q, s in data["actions"]}
        return t
