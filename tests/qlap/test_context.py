"""Algorithm 1 (isModelImprovement), every branch, and Algorithm 3 on a built example."""

import numpy as np
import pytest

from qlap_runtime.qlap import Ablations, Params
from qlap_runtime.qlap.context import is_model_improvement, update_context
from qlap_runtime.qlap.dbn import ModelStats, model_stats

P = Params()


def st(n, brel, h, rel):
    return ModelStats(n, brel, h, rel)


def test_reliable_r_needs_reliable_r_prime():
    assert not is_model_improvement(st(0, 0.9, 0.5, True), st(1, 0.95, 0.0, False), P)


def test_reliable_equal_or_larger_context_uses_entropy():
    # |r| = 0, |r'| = 1: needs H(r) - H(r') > 2 * 0.05 = 0.1
    assert is_model_improvement(st(0, 0.8, 0.5, True), st(1, 0.8, 0.39, True), P)
    assert not is_model_improvement(st(0, 0.8, 0.5, True), st(1, 0.8, 0.41, True), P)
    # same size: > 0.05
    assert is_model_improvement(st(1, 0.8, 0.5, True), st(1, 0.8, 0.44, True), P)


def test_reliable_smaller_context_is_the_negation_of_the_reverse():
    # |r|=2 > |r'|=1: not isModelImprovement(r', r); reverse needs H(r')-H(r) > 0.1
    r, r2 = st(2, 0.9, 0.30, True), st(1, 0.9, 0.35, True)
    assert is_model_improvement(r, r2, P)            # 0.35 - 0.30 = 0.05 <= 0.1 -> reverse false
    r2b = st(1, 0.9, 0.45, True)
    assert not is_model_improvement(r, r2b, P)       # reverse: 0.45 - 0.30 = 0.15 > 0.1


def test_unreliable_uses_brel_with_bottom():
    assert is_model_improvement(st(0, 0.5, 1, False), st(1, 0.61, 1, False), P)   # 0.11 > 0.1
    assert not is_model_improvement(st(0, 0.5, 1, False), st(1, 0.59, 1, False), P)
    assert is_model_improvement(st(0, None, 1, False), st(1, 0.2, 1, False), P)   # > ⊥
    assert not is_model_improvement(st(0, 0.5, 1, False), st(1, None, 1, False), P)
    # smaller r': not isModelImprovement(r', r): brel(r) - brel(r') > 0.1 ?
    assert is_model_improvement(st(1, 0.6, 1, False), st(0, 0.55, 1, False), P)
    assert not is_model_improvement(st(1, 0.7, 1, False), st(0, 0.55, 1, False), P)


def test_entropy_only_ablation():
    p = Params(ablations=Ablations(entropy_only=True))
    assert is_model_improvement(st(0, 0.5, 0.9, False), st(1, 0.5, 0.7, False), p)
    assert not is_model_improvement(st(0, 0.5, 0.9, False), st(1, 0.9, 0.85, False), p)


def test_update_context_finds_the_predictive_variable():
    # 200 activations; variable 7 (2 values) predicts success perfectly, variable 3 is noise.
    rng = np.random.default_rng(0)
    v7 = rng.integers(0, 2, 200)
    v3 = rng.integers(0, 3, 200)
    ok = v7 == 1

    def evaluate(ctx):
        cells = np.zeros(200, dtype=int)
        sizes = {7: 2, 3: 3}
        n = 1
        for v in ctx:
            cells = cells * sizes[v] + (v7 if v == 7 else v3)
            n *= sizes[v]
        s = np.bincount(cells, weights=ok, minlength=n)
        f = np.bincount(cells, minlength=n) - s
        return model_stats(s, f, len(ctx), P)

    assert update_context((), [3, 7], evaluate, P) == (7,)
    assert update_context((7,), [3, 7], evaluate, P) is None        # already the best
    with pytest.raises(AssertionError):
        assert update_context((), [3], evaluate, P) is not None
