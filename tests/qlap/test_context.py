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


def test_update_contexts_many_by_hand():
    # Two problems on the same 8 activations (vars 0, 1, 2 with 2 values each): var 1 is the
    # success label, so the first (no context yet) gets (1,); the second already has it.
    from qlap_runtime.qlap.context import update_contexts_many

    Q = np.array([[0, 0, 1], [1, 1, 0], [0, 1, 1], [1, 0, 0],
                  [0, 0, 0], [1, 1, 1], [0, 1, 0], [1, 0, 1]] * 4, dtype=np.int64)
    ok = Q[:, 1] == 1
    assert update_contexts_many([((), [0, 1, 2], Q, ok), ((1,), [0, 1, 2], Q, ok)],
                                [2, 2, 2], P) == [(1,), None]


@pytest.mark.parametrize("compiled", [True, False])
def test_update_contexts_many_answers_as_update_context_one_by_one(
        compiled: bool, monkeypatch: pytest.MonkeyPatch):
    # Algorithm 3 on all DBNs at once: the answers of update_context with
    # StoredActivations.choose for each, on random activations (unknown values, uneven
    # sizes, current contexts of 0–2 variables, reliable and unreliable models, both
    # ablations of the choice), with the compiled count (kernels.context_counts) and without.
    from qlap_runtime.qlap import context
    from qlap_runtime.qlap.context import StoredActivations, update_contexts_many

    if not compiled:
        monkeypatch.setattr(context, "kernels", lambda: None)

    rng = np.random.default_rng(7)
    for params in (P, Params(ablations=Ablations(entropy_only=True)), Params(max_context_vars=3)):
        for _ in range(40):
            sizes = rng.integers(1, 6, size=8).tolist()
            problems = []
            for _ in range(int(rng.integers(1, 8))):
                n = int(rng.integers(1, 200))
                Q = np.stack([rng.integers(-1 if rng.random() < 0.3 else 0, s, size=n)
                              for s in sizes], axis=1).astype(np.int64)
                key = rng.integers(0, 8)
                bias = rng.random()
                ok = np.where(Q[:, key] == 0, rng.random(n) < bias, rng.random(n) < 1 - bias)
                cands = sorted(rng.choice(8, size=int(rng.integers(0, 7)),
                                          replace=False).tolist())
                current = tuple(sorted(rng.choice(8, size=int(rng.integers(0, 3)),
                                                  replace=False).tolist()))
                problems.append((current, cands, Q, ok))
            once = (rng.random(len(problems)) < 0.5).tolist()
            want, want_once = [], []
            for (current, cands, Q, ok), was in zip(problems, once, strict=True):
                acts = StoredActivations(Q, ok, sizes, params)
                want.append(update_context(current, cands, acts.evaluate, params, acts.choose))
                want_once.append(update_context(current, cands, acts.evaluate, params,
                                                acts.choose, reliable_once=was))
            assert update_contexts_many(problems, sizes, params) == want
            assert update_contexts_many(problems, sizes, params, once) == want_once


def test_a_model_once_sufficiently_reliable_stays_so_in_algorithm_1():
    # §4.2.2: "a DBN r is sufficiently reliable if at any time brel(r) > θ_SR". 60 activations
    # of two 2-valued variables; successes by cell (v0, v1): (0, 0) 4 of 15, (1, 0) 6 of 15,
    # none where v1 = 1. By hand (App. B.1, prior 1, 5 successes for a cell to count):
    # brel ∅ = 11/62 = 0.177; {v0}: cell v0=1 7/32 = 0.219 (v0=0 has 4 successes: ⊥);
    # {v1}: 11/32 = 0.344; {v0, v1}: 7/17 = 0.412, +0.068 over {v1}, short of (1+1)·0.05.
    # So Algorithm 3 climbs ∅ → {v1} (+0.167 > 0.1) and stops; against the current {v0}
    # {v1} gains 0.125 > 0.05 in brel — but if {v0}'s DBN was once sufficiently reliable,
    # Algorithm 1 asks a sufficiently reliable r′, and {v1} (0.344 ≤ 0.75) is not.
    from qlap_runtime.qlap.context import StoredActivations, once_reliable, update_contexts_many

    cells = [(0, 0, 4), (0, 1, 0), (1, 0, 6), (1, 1, 0)]
    Q = np.array([[a, b] for a, b, _ in cells for _ in range(15)], dtype=np.int64)
    ok = np.array([i < s for _, _, s in cells for i in range(15)])
    acts = StoredActivations(Q, ok, [2, 2], P)
    assert acts.evaluate((0,)).brel == pytest.approx(7 / 32)
    assert acts.evaluate((1,)).brel == pytest.approx(11 / 32)
    assert acts.evaluate((0, 1)).brel == pytest.approx(7 / 17)
    assert update_context((0,), [0, 1], acts.evaluate, P, acts.choose) == (1,)
    assert update_context((0,), [0, 1], acts.evaluate, P, acts.choose,
                          reliable_once=True) is None
    assert update_contexts_many([((0,), [0, 1], Q, ok)] * 2, [2, 2], P,
                                [False, True]) == [(1,), None]
    r = acts.evaluate((0,))
    assert not r.reliable and once_reliable(r, True).reliable
    assert once_reliable(r, True).brel == r.brel and once_reliable(r, False) is r
