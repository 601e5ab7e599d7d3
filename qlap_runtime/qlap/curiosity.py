"""Exploration choices: babbling schedule, IAC over actions, ε-greedy plan choice (§6.1, App. E).

* :func:`iac_weight` — w_a = max(0.001, rel_new − rel_old) over windows of θ = 25 (eq. 6.1).
* :func:`fallback_weight` — w_a = H(rel(a))·rel(o, s) before 2θ = 50 calls (eq. 6.2).
* :func:`action_weight` — whichever of the two applies to an :class:`ActionStats`.
* :func:`choose_action` — sample an applicable action ∝ w_a (uniform under the no_iac ablation).
* :func:`plan_weight`, :func:`choose_plan` — w = rel(r, s)·rel(o, s) (eq. 6.3), ε-greedy 0.05,
  plans whose antecedent action is in the call list excluded (§6.1.2).
* :func:`is_babbling_period`, :func:`babble_instead`, :class:`BabbleSchedule` — 20,000 steps of
  motor babbling, then a babbling command with probability 0.1 (§6.1.1).
* :class:`IACChoice` — one logged choice (for the TUI).

Every random choice takes an explicit :class:`numpy.random.Generator`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .actions import ActionKey, ActionStats
from .params import Params
from .probability import binary_entropy

# ---------------------------------------------------------------------------------------------
# Weights (§6.1.1)
# ---------------------------------------------------------------------------------------------


def iac_weight(rel_history: Sequence[float], params: Params) -> float | None:
    """w_a = max(0.001, mean(last θ) − mean(the θ before)) (eq. 6.1); None before 2θ records.

    ``rel_history`` holds rel(a) recorded at each termination, oldest first.
    """
    n = params.iac_window
    if len(rel_history) < 2 * n:
        return None
    h = np.asarray(list(rel_history)[-2 * n:], dtype=float)
    return max(params.iac_min_weight, float(h[n:].mean() - h[:n].mean()))


def fallback_weight(rel_a: float, rel_o_s: float) -> float:
    """w_a = H(rel(a))·rel(o, s) (eq. 6.2), H the binary entropy in bits."""
    return binary_entropy(rel_a) * rel_o_s


def action_weight(stats: ActionStats, rel_o_s: float | None, params: Params) -> float:
    """IAC weight of an action: eq. 6.1 once it has 2θ records, else eq. 6.2.

    ``rel_o_s`` is rel(o, s) of the plan :func:`choose_plan` picks for the action in the current
    state (None when no plan can be chosen → weight 0 in the eq. 6.2 regime).
    """
    w = iac_weight(stats.history, params)
    if w is not None:
        return w
    if rel_o_s is None:
        return 0.0
    return fallback_weight(stats.rel(params.prior), rel_o_s)


# ---------------------------------------------------------------------------------------------
# Choices
# ---------------------------------------------------------------------------------------------


def choose_action(applicable: Sequence[ActionKey], weights: Sequence[float],
                  rng: np.random.Generator, no_iac: bool = False
                  ) -> tuple[ActionKey | None, np.ndarray]:
    """Sample an action with probability ∝ its weight (§6.1.1).

    Uniform when ``no_iac`` (ablation, §7.11) or when every weight is 0. Returns the action
    (None if nothing is applicable) and the normalised probabilities actually used.
    """
    if len(applicable) != len(weights):
        raise ValueError(f"{len(applicable)} actions but {len(weights)} weights")
    n = len(applicable)
    if n == 0:
        return None, np.zeros(0)
    w = np.asarray(weights, dtype=float)
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError(f"weights must be finite and >= 0, got {w.tolist()}")
    total = w.sum()
    p = np.full(n, 1.0 / n) if no_iac or total <= 0 else w / total
    i = int(rng.choice(n, p=p))
    return applicable[i], p


def plan_weight(rel_r_s: float, rel_o_s: float) -> float:
    """w_o^s = rel(r, s)·rel(o, s) (eq. 6.3)."""
    return rel_r_s * rel_o_s


def choose_plan(plans_w: Sequence[float], excluded: Sequence[bool], rng: np.random.Generator,
                epsilon: float) -> int | None:
    """ε-greedy choice among the non-excluded plans (§6.1.2); None if all are excluded.

    With probability ε a uniformly random candidate, else the highest weight (ties broken
    uniformly at random). ``excluded[i]`` is True when plan i's antecedent action is already in
    the call list.
    """
    if len(plans_w) != len(excluded):
        raise ValueError(f"{len(plans_w)} plan weights but {len(excluded)} exclusion flags")
    # Plain Python: an action has at most three plans, and this runs for every applicable
    # action at every IAC choice, where numpy's per-call overhead dominated.
    cand = [i for i, e in enumerate(excluded) if not e]
    if not cand:
        return None
    if rng.random() < epsilon:
        return cand[int(rng.integers(len(cand)))]
    best = max(float(plans_w[i]) for i in cand)
    top = [i for i in cand if float(plans_w[i]) == best]
    return top[0] if len(top) == 1 else top[int(rng.integers(len(top)))]


# ---------------------------------------------------------------------------------------------
# Babbling schedule (§6.1, App. E)
# ---------------------------------------------------------------------------------------------


def is_babbling_period(step: int, params: Params) -> bool:
    """Steps 0 … babble_steps − 1 are the initial motor-babbling period (§6.1)."""
    return step < params.babble_steps


def babble_instead(rng: np.random.Generator, params: Params) -> bool:
    """After the babbling period: a babbling command with probability 0.1 (§6.1.1)."""
    return bool(rng.random() < params.babble_probability)


@dataclass(frozen=True)
class BabbleSchedule:
    """The two functions above bound to one :class:`Params`."""

    params: Params

    def is_babbling_period(self, step: int) -> bool:
        return is_babbling_period(step, self.params)

    def babble_instead(self, rng: np.random.Generator) -> bool:
        return babble_instead(rng, self.params)

    def should_babble(self, step: int, rng: np.random.Generator) -> bool:
        """Babble now? Always in the period (no draw), else with probability 0.1 (one draw)."""
        return self.is_babbling_period(step) or self.babble_instead(rng)


# ---------------------------------------------------------------------------------------------
# Log record
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class IACChoice:
    """One exploration choice, for the log the TUI shows."""

    step: int
    """Agent step of the choice."""
    action: ActionKey | None
    """Chosen action (None when babbling or nothing was applicable)."""
    weight: float
    """Normalised probability of the chosen action (0 when none)."""
    n_applicable: int
    """Size of the applicable set."""
    babbling: bool
    """True if a babbling command was chosen instead of an action."""
    weights: tuple[float, ...] = ()
    """Normalised probabilities of all applicable actions, in their order."""

    def __deepcopy__(self, memo: dict) -> IACChoice:
        """Immutable (frozen, of numbers and tuples): its own copy (docs/decisions.md 101)."""
        return self

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return {"step": self.step, "action": list(self.action) if self.action else None,
                "weight": self.weight, "n_applicable": self.n_applicable,
                "babbling": self.babbling, "weights": list(self.weights)}
