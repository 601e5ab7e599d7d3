"""Appendix B and eq. 4.14–4.16 with hand-computed numbers."""

import math

import numpy as np
import pytest

from qlap_runtime.qlap.probability import (
    best_reliability,
    binary_entropy,
    dbn_entropy,
    information_gain,
    prob_above,
    prob_below,
    success_probability,
)


def test_success_probability_priors():
    assert success_probability(3, 1) == pytest.approx(4 / 6)          # (3+1)/(1+1+3+1)
    assert success_probability(3, 1, prior=2) == pytest.approx(5 / 8)
    assert success_probability(3, 1, prior=0) == pytest.approx(3 / 4)
    assert success_probability(0, 0, prior=0) == 0.0


def test_beta_test_against_closed_form():
    # Beta(a=1+s, b=1+f) with s=9, f=0: cdf(θ) = θ^10.  θ=0.75 -> 0.0563; 1 - cdf = 0.9437 >= 0.8
    assert prob_above(0.75, 9, 0)
    # s=4, f=0: 1 - 0.75^5 = 0.7627 < 0.8 -> not above
    assert not prob_above(0.75, 4, 0)
    # s=5, f=0: 1 - 0.75^6 = 0.822 -> above
    assert prob_above(0.75, 5, 0)
    # below: s=0, f=4: Beta(1,5) cdf(0.3) = 1 - 0.7^5 = 0.832 >= 0.8
    assert prob_below(0.3, 0, 4)
    assert not prob_below(0.3, 0, 3)                                  # 1 - 0.7^4 = 0.7599


def test_brel_is_bottom_until_five_successes():
    assert best_reliability(np.array([4, 1]), np.array([0, 0])) == (None, -1)
    brel, i = best_reliability(np.array([5, 9]), np.array([0, 9]))
    assert i == 0 and brel == pytest.approx(6 / 7)                     # (5+1)/(5+0+2)


def test_entropy_of_a_dbn():
    assert binary_entropy(0.5) == 1.0
    assert binary_entropy(0.25) == pytest.approx(0.811278, abs=1e-6)
    # Two cells: (s=2, f=0) and (s=0, f=2). With prior 1: p = 3/4 and 1/4, H = 0.811278 each.
    assert dbn_entropy(np.array([2, 0]), np.array([0, 2])) == pytest.approx(0.811278, abs=1e-6)
    # One cell (s=3, f=1): p = 4/6, H = 0.918296
    assert dbn_entropy(np.array([3]), np.array([1])) == pytest.approx(0.918296, abs=1e-6)
    # Weighted: cells (6,0) and (1,1): p 7/8 -> 0.543564, p 1/2 -> 1; weights 6/8, 2/8
    expect = 0.75 * 0.543564 + 0.25 * 1.0
    assert dbn_entropy(np.array([6, 1]), np.array([0, 1])) == pytest.approx(expect, abs=1e-6)


def test_information_gain_hand_computed():
    # S = 1 1 0 0 split in the middle: H(S) = 1, both halves pure -> G = 1
    assert information_gain(np.array([1, 1, 0, 0]), 2) == pytest.approx(1.0)
    # S = 1 1 1 0 split after 2: H(S)=0.811278; left pure, right {1,0} H=1 weight 1/2
    assert information_gain(np.array([1, 1, 1, 0]), 2) == pytest.approx(0.811278 - 0.5, abs=1e-6)
    assert math.isclose(information_gain(np.array([1, 0]), 0), 0.0)


def _brel_reference(s, f, prior, min_successes):
    """best_reliability as first written (all numpy, no memo)."""
    s, f = np.asarray(s, dtype=float), np.asarray(f, dtype=float)
    ok = s >= min_successes
    if not ok.any():
        return None, -1
    p = np.where(ok, (s + prior) / (s + f + 2.0 * prior), -1.0)
    i = int(np.argmax(p))
    return float(p[i]), i


def _entropy_reference(s, f, prior):
    """dbn_entropy as first written (masked entropies, no memo)."""
    s, f = np.asarray(s, dtype=float), np.asarray(f, dtype=float)
    n = s + f
    total = n.sum()
    if total <= 0:
        return 1.0
    p = (s + prior) / (n + 2.0 * prior)
    m = (p > 0) & (p < 1)
    h = np.zeros_like(p)
    h[m] = -(p[m] * np.log2(p[m]) + (1 - p[m]) * np.log2(1 - p[m]))
    return float(np.sum(h * (n / total)))


@pytest.mark.parametrize("n_cells", [1, 2, 9, 64, 65, 300])
def test_fast_and_memoised_statistics_are_bit_identical(n_cells):
    rng = np.random.default_rng(n_cells)
    for _ in range(30):
        s = rng.integers(0, 12, n_cells).astype(float)
        f = rng.integers(0, 12, n_cells).astype(float)
        s[rng.random(n_cells) < 0.3] = 0.0
        for prior in (1.0, 0.5, 0.0):
            for _twice in range(2):                 # the second call comes from the memo
                with np.errstate(invalid="ignore"):     # prior 0: empty cells are 0/0
                    assert best_reliability(s, f, prior, 5) == _brel_reference(s, f, prior, 5)
                if prior > 0:
                    assert dbn_entropy(s, f, prior) == _entropy_reference(s, f, prior)
    # ties: the first best cell, as np.argmax
    assert best_reliability([5, 7, 5, 7], [1, 3, 1, 3]) == _brel_reference(
        [5, 7, 5, 7], [1, 3, 1, 3], 1.0, 5)
