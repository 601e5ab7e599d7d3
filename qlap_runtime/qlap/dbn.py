"""Change and magnitude DBNs with their CPTs and stored activations (§4.2–4.3, §4.5).

A DBN r = ⟨C : E1 ⇒ E2⟩ is *activated* when its antecedent happens; the activation succeeds if
the consequent follows soon (change DBNs, eq. 4.8) or is reached while the derivative is held
(magnitude DBNs, eq. 4.21–4.22). Each resolved activation is counted in the CPT cell of the
context value it started in, and the last ``Params.stored_activations`` activations are kept
with the full real-valued state, so that contexts (Algorithm 3) and landmarks (Algorithm 4) can
be re-evaluated under any discretisation.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from .params import Params
from .probability import best_reliability, dbn_entropy, prob_above
from .ring import ring_push, ring_rows
from .variables import Event

CHANGE = "change"
MAGNITUDE = "magnitude"


@dataclass(frozen=True)
class ModelStats:
    """What Algorithm 1 needs to know about a DBN under some context."""

    n_context: int
    """|r|, the number of context variables."""
    brel: float | None
    """Best reliability, None for ⊥ (Appendix B.1)."""
    entropy: float
    """H(r) (eq. 4.15)."""
    reliable: bool
    """brel(r) > θ_SR, decided with the beta test on the best cell (§4.2.2, App. B)."""
    best_successes: int = 0
    """Successes in the best cell (used to pick between split antecedents, §4.4.1 step 4)."""
    successes: int = 0
    """All successes."""


# A memo of model_stats (a pure function of the counts, |context| and four constants): a
# batch scores the same counts again and again (Algorithm 3's empty context of a DBN whose
# success rate did not move, the plans' conversions). Cleared when full.
_STATS_MEMO_SIZE = 1 << 14
_stats_memo: dict[tuple, ModelStats] = {}


def model_stats(s: np.ndarray, f: np.ndarray, n_context: int, params: Params) -> ModelStats:
    """ModelStats from per-context-value success and failure counts."""
    s_arr = np.asarray(s, dtype=float)
    f_arr = np.asarray(f, dtype=float)
    key = (s_arr.tobytes(), f_arr.tobytes(), s_arr.shape, n_context, params.prior,
           params.brel_min_successes, params.theta_sr, params.beta_confidence)
    hit = _stats_memo.get(key)
    if hit is not None:
        return hit
    brel, i = best_reliability(s, f, params.prior, params.brel_min_successes)
    reliable = brel is not None and prob_above(params.theta_sr, float(s[i]), float(f[i]),
                                               params.prior, params.beta_confidence)
    out = ModelStats(n_context, brel, dbn_entropy(s, f, params.prior), bool(reliable),
                     int(s[i]) if i >= 0 else 0, int(np.sum(s)))
    if len(_stats_memo) >= _STATS_MEMO_SIZE:
        _stats_memo.clear()
    _stats_memo[key] = out
    return out


_ATOMS = frozenset({int, float, bool, str, type(None)})
"""Immutable values a :class:`DBN`'s deep copy keeps as they are."""


class DBN:
    """One change or magnitude DBN (its structure, CPT and activation store)."""

    def __init__(self, dbn_id: int, kind: str, antecedent: Event, consequent: Event,
                 context: tuple[int, ...], created: int, n_vars: int, capacity: int) -> None:
        self.id = dbn_id
        self.kind = kind
        self.antecedent = antecedent
        self.consequent = consequent
        self.context = tuple(context)
        self.created = created
        self.ever_reliable = False
        self.is_plan = False
        self.context_unchanged: tuple | None = None
        """The learner's cache: the inputs of Algorithm 3's last search that found no change."""
        # Activation store: a ring of the last `capacity` resolved activations.
        self.act_x = np.full((capacity, n_vars), np.nan)
        self.act_ok = np.zeros(capacity, dtype=bool)
        self.act_n = 0
        self.act_head = 0
        self.total = 0
        # CPT counts over the current context's values (§4.2.1).
        self.cpt_s = np.zeros(1)
        self.cpt_f = np.zeros(1)
        # Change DBNs: open activations (step, x); magnitude DBNs: at most one.
        self.pending: list[tuple[int, np.ndarray]] = []

    def __deepcopy__(self, memo: dict) -> DBN:
        """What ``copy.deepcopy`` would give (a batch's copy of a learner holds hundreds of
        DBNs), without its reduce-and-rebuild per object: numbers, strings and tuples of ints
        are kept, everything else is deep-copied with the same ``memo``, so arrays and
        pending entries shared with the learner stay shared in the copy (decision 101)."""
        c = object.__new__(type(self))
        memo[id(self)] = c
        state = c.__dict__
        for k, v in self.__dict__.items():
            t = type(v)
            if t in _ATOMS or (t is tuple and all(type(x) is int for x in v)):
                state[k] = v
            else:
                state[k] = copy.deepcopy(v, memo)
        return c

    # -- activations --------------------------------------------------------------------------
    def record(self, x: np.ndarray, success: bool, cell: int) -> None:
        """Store a resolved activation and count it in the CPT cell ``cell``."""
        self.act_head, self.act_n = ring_push(self.act_x, self.act_ok, self.act_head,
                                              self.act_n, x, success)
        self.total += 1
        if cell >= 0:
            if success:
                self.cpt_s[cell] += 1
            else:
                self.cpt_f[cell] += 1

    def stored(self) -> tuple[np.ndarray, np.ndarray]:
        """Stored activations (oldest first): real states and success labels."""
        return ring_rows(self.act_x, self.act_ok, self.act_head, self.act_n)

    def cell_reliabilities(self, prior: float) -> list[float]:
        """rel(r, q) = (s_q + α) / (s_q + f_q + 2α) of every CPT cell (eq. B.1, α = β =
        ``prior``), as Python floats: the values of the formula on the CPT's own numbers.

        Kept until the CPT changes: :meth:`record` counts every in-place change in ``total``,
        and a recount or a load replaces the arrays (a pure cache, never saved).
        """
        return cell_reliabilities(self, self.cpt_s, self.cpt_f, self.total, prior)

    def label(self, names: list[str], value_label) -> str:
        """The reference's notation, e.g. ⟨{h_x}: u_x→(300, +inf) ⇒ h_x.dot→+⟩."""
        ctx = ", ".join(names[v] for v in self.context)
        return (f"⟨{{{ctx}}}: {event_label(self.antecedent, names, value_label)} ⇒ "
                f"{event_label(self.consequent, names, value_label)}⟩")


def cell_reliabilities(owner: object, s: np.ndarray, f: np.ndarray, count: int,
                      prior: float) -> list[float]:
    """(s + α) / (s + f + 2α) per cell as Python floats, cached on ``owner`` (in its
    ``cell_rel_cache`` attribute) while the very arrays ``s`` and ``f``, the counter ``count`` of
    in-place changes and α are those of the last call. Element-wise the same operations as on
    one cell's numbers, so each value is bit for bit the scalar formula's."""
    hit = getattr(owner, "cell_rel_cache", None)
    if hit is not None and hit[0] is s and hit[1] is f and hit[2] == count and hit[3] == prior:
        return hit[4]
    out = ((s + prior) / (s + f + 2 * prior)).tolist()
    owner.cell_rel_cache = (s, f, count, prior, out)  # type: ignore[attr-defined]
    return out


def event_label(e: Event, names: list[str], value_label) -> str:
    arrow = {1: "↑", -1: "↓"}.get(e.direction, "")
    return f"{arrow}{names[e.var]}→{value_label(e.var, e.value)}"


def context_cells(qs: list[np.ndarray], sizes: list[int]) -> np.ndarray:
    """Mixed-radix index of the joint context value; −1 where any variable is unavailable."""
    if not qs:
        return np.zeros(0 if not len(qs) else len(qs[0]), dtype=np.int64)
    cell = np.zeros(len(qs[0]), dtype=np.int64)
    bad = np.zeros(len(qs[0]), dtype=bool)
    for q, size in zip(qs, sizes, strict=True):
        bad |= q < 0
        cell = cell * size + np.maximum(q, 0)
    return np.where(bad, -1, cell)


def counts_by_cell(cells: np.ndarray, ok: np.ndarray,
                   n_cells: int) -> tuple[np.ndarray, np.ndarray]:
    """Success and failure counts per cell (rows with cell −1 are ignored)."""
    m = cells >= 0
    s = np.bincount(cells[m], weights=ok[m].astype(float), minlength=n_cells)
    tot = np.bincount(cells[m], minlength=n_cells).astype(float)
    return s, tot - s
