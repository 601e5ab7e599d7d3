"""Success probabilities, the beta test, best reliability and entropy (Appendix B, §4.2.2).

Every formula here is a small pure function so it can be checked against hand-computed numbers.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import betainc as _betainc


def success_probability(successes: float, failures: float, prior: float = 1.0) -> float:
    """p_s = (#success + α) / (#fail + α + #success + β) with α = β = ``prior`` (eq. B.1).

    With a zero prior and no data the probability is undefined; 0.0 is returned then.
    """
    total = successes + failures + 2.0 * prior
    if total <= 0:
        return 0.0
    return (successes + prior) / total


def prob_below(theta: float, successes: float, failures: float, prior: float = 1.0,
               confidence: float = 0.8) -> bool:
    """p_s < θ when beta.cdf(θ, #success + α, #fail + β) ≥ 0.8 (eq. B.2).

    With a zero prior and no observations the beta distribution is undefined: returns False.
    """
    a, b = successes + prior, failures + prior
    if a <= 0 or b <= 0:
        return False
    return bool(_betainc(a, b, theta) >= confidence)          # beta.cdf(θ, a, b)


def prob_above(theta: float, successes: float, failures: float, prior: float = 1.0,
               confidence: float = 0.8) -> bool:
    """p_s > θ when 1 − beta.cdf(θ, #success + α, #fail + β) ≥ 0.8 (Appendix B, item 2)."""
    a, b = successes + prior, failures + prior
    if a <= 0 or b <= 0:
        return False
    return bool(1.0 - _betainc(a, b, theta) >= confidence)    # beta.sf(θ, a, b)


def prob_above_many(theta: np.ndarray, successes: np.ndarray, failures: np.ndarray,
                    prior: float = 1.0, confidence: float = 0.8) -> np.ndarray:
    """Vectorised :func:`prob_above` (used by the pairwise contingency search, §4.1.2)."""
    theta = np.clip(np.asarray(theta, dtype=float), 0.0, 1.0)
    sf = 1.0 - _betainc(np.asarray(successes, dtype=float) + prior,
                        np.asarray(failures, dtype=float) + prior, theta)
    return sf >= confidence


def binary_entropy(p: float) -> float:
    """H of a Bernoulli(p) variable in bits (§2.2); 0 at p ∈ {0, 1}."""
    if p <= 0.0 or p >= 1.0:
        return 0.0
    return -(p * math.log2(p) + (1.0 - p) * math.log2(1.0 - p))


def binary_entropy_array(p: np.ndarray) -> np.ndarray:
    """Vectorised :func:`binary_entropy`."""
    p = np.asarray(p, dtype=float)
    # The usual case (posterior probabilities, all inside (0, 1)) needs no masking; two
    # reductions decide it for less than the element-wise mask (NaN fails both tests).
    if p.ndim and p.size and 0.0 < np.minimum.reduce(p, axis=None) \
            and np.maximum.reduce(p, axis=None) < 1.0:
        return -(p * np.log2(p) + (1 - p) * np.log2(1 - p))
    m = (p > 0) & (p < 1)
    if p.ndim and m.all():
        return -(p * np.log2(p) + (1 - p) * np.log2(1 - p))
    out = np.zeros_like(p)
    q = p[m]
    out[m] = -(q * np.log2(q) + (1 - q) * np.log2(1 - q))
    return out


# Memos of the two functions below, keyed by the counts' bytes: Algorithm 3 scores the same
# contexts on the same stored activations again at every batch (a plan's second-order DBN
# whose calls did not change, §5.4), and the functions are pure. Cleared when full.
_MEMO_SIZE = 1 << 14
_brel_memo: dict[tuple, tuple[float | None, int]] = {}
_entropy_memo: dict[tuple, float] = {}


def best_reliability(successes: np.ndarray, failures: np.ndarray, prior: float = 1.0,
                     min_successes: int = 5) -> tuple[float | None, int]:
    """brel(r) = max over context values q of rel(r, q) (eq. 4.14, B.3–B.4).

    Only cells with at least ``min_successes`` actual successes count; if none has, brel = ⊥,
    returned as ``None``. Also returns the index of the best cell (−1 for ⊥).
    """
    s = np.asarray(successes, dtype=float)
    f = np.asarray(failures, dtype=float)
    key = (s.tobytes(), f.tobytes(), prior, min_successes)
    hit = _brel_memo.get(key)
    if hit is not None:
        return hit
    out: tuple[float | None, int] = (None, -1)
    if prior > 0 and s.size <= 64:
        # The first maximum among the cells that count, as np.argmax below; p has no NaN
        # (its denominator is ≥ 2·prior), so plain comparisons of the same floats agree.
        p = (s + prior) / (s + f + 2.0 * prior)
        best = -1.0
        for i, (si, pi) in enumerate(zip(s.ravel().tolist(), p.ravel().tolist(), strict=True)):
            if si >= min_successes and pi > best:
                best, out = pi, (pi, i)
    else:
        ok = s >= min_successes
        if ok.any():
            p = (s + prior) / (s + f + 2.0 * prior)
            p = np.where(ok, p, -1.0)
            i = int(np.argmax(p))
            out = (float(p.flat[i]), i)
    if len(_brel_memo) >= _MEMO_SIZE:
        _brel_memo.clear()
    _brel_memo[key] = out
    return out


def dbn_entropy(successes: np.ndarray, failures: np.ndarray, prior: float = 1.0) -> float:
    """H(r) = Σ_q H(soon(t, E2) | q, E1(t)) · Pr(q | E1(t)) (eq. 4.15).

    Pr(q | E1) is the fraction of activations in context value q; H(soon | q) uses the cell's
    success probability p_s with the prior of eq. B.1 (so a cell seen once is not "certain").
    Cells never observed have weight 0. With no activations at all H = 1 (nothing is known).
    """
    s = np.asarray(successes, dtype=float)
    f = np.asarray(failures, dtype=float)
    key = (s.tobytes(), f.tobytes(), prior)
    hit = _entropy_memo.get(key)
    if hit is not None:
        return hit
    n = s + f
    total = n.sum()
    if total <= 0:
        out = 1.0
    else:
        p = (s + prior) / (n + 2.0 * prior)
        out = float(np.add.reduce(binary_entropy_array(p) * (n / total), axis=None))
    if len(_entropy_memo) >= _MEMO_SIZE:
        _entropy_memo.clear()
    _entropy_memo[key] = out
    return out


def information_gain(labels: np.ndarray, split: int) -> float:
    """G_c = H(S) − |S⁻|/|S| H(S⁻) − |S⁺|/|S| H(S⁺) for a split after ``split`` items (eq. 4.16).

    ``labels`` are 0/1 success labels in the order of the sorted values; empirical entropies.
    """
    y = np.asarray(labels, dtype=float)
    n = len(y)
    if n == 0 or split <= 0 or split >= n:
        return 0.0
    left, right = y[:split], y[split:]
    return (binary_entropy(y.mean()) - len(left) / n * binary_entropy(left.mean())
            - len(right) / n * binary_entropy(right.mean()))
