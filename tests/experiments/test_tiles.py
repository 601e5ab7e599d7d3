"""Hashed tile coding (tiles.C's algorithm, App. H) and one Sarsa(λ) update, checked by hand."""

import numpy as np
import pytest

from qlap_runtime.experiments.baselines.sarsa import SarsaLambda, epsilon_greedy
from qlap_runtime.experiments.baselines.tiles import RNDSEQ_SIZE, TileCoder


def identity_coder(tilings: int = 2, memory: int = 16) -> TileCoder:
    """A coder whose hash table is R[k] = k, so that indices can be summed by hand."""
    return TileCoder(tilings, memory, rndseq=np.arange(RNDSEQ_SIZE))


def test_coordinates_of_a_known_point():
    # floats (0.3, 1.7) in tile widths, 2 tilings: q = ⌊2x⌋ = (0, 3).
    # tiling 0, base (0, 0): c = q − (q mod 2) = (0, 2)
    # tiling 1, base (1, 3) (offsets 1 + 2i): c0 = 0 − ((0 − 1) mod 2) = −1, c1 = 3 − 0 = 3
    coords = identity_coder().coordinates([0.3, 1.7], [2])
    assert coords.tolist() == [[0, 2, 0, 2], [-1, 3, 1, 2]]


def test_tile_indices_of_a_known_point():
    # hash_UNH with R[k] = k: Σ_k ((c_k + 449 k) mod 2048) mod 16
    # tiling 0: 0 + 451 + 898 + 1349 = 2698 → 2698 mod 16 = 10
    # tiling 1: 2047 + 452 + 899 + 1349 = 4747 → 4747 mod 16 = 11
    assert identity_coder().tiles([0.3, 1.7], [2]).tolist() == [10, 11]


def test_points_in_one_tile_share_it_and_offsets_split_them():
    coder = identity_coder(tilings=4, memory=1 << 20)
    a, b = coder.tiles([0.10]), coder.tiles([0.20])      # both in [0, 1) of tiling 0
    assert a[0] == b[0]
    # tiling j's tiles start at j/4 (+ whole tiles) in dimension 0: 0.20 and 0.30 straddle
    # 0.25, a boundary of tiling 1 only
    c, d = coder.tiles([0.20]), coder.tiles([0.30])
    assert [c[j] == d[j] for j in range(4)] == [True, False, True, True]
    assert coder.tiles([0.2], [1]).tolist() != coder.tiles([0.2], [2]).tolist()


def test_action_tiles_are_tiles_with_the_action_last():
    coder = TileCoder(16, 65_536, seed=3)
    floats, ints = [0.4, 2.9, 3.99], [0, 2, 1, 12345]
    table = coder.action_tiles(floats, ints, 20)
    assert table.shape == (20, 16)
    for a in range(20):
        assert table[a].tolist() == coder.tiles(floats, [*ints, a]).tolist()
    assert table.min() >= 0 and table.max() < 65_536


def test_the_same_seed_gives_the_same_tiles():
    assert (TileCoder(16, 65_536, seed=0).tiles([1.3, 0.2], [1]).tolist()
            == TileCoder(16, 65_536, seed=0).tiles([1.3, 0.2], [1]).tolist())


def test_one_sarsa_lambda_update_by_hand():
    rng = np.random.default_rng(0)
    learner = SarsaLambda(memory=8, alpha=0.2, lam=0.9, gamma=1.0, epsilon=0.0, rng=rng,
                          tilings=2, theta=np.array([1.0, 0, 0, 0, 0.5, 0, 0, 0]))
    s0 = np.array([[0, 1], [2, 3]])          # (actions, tilings)
    s1 = np.array([[4, 5], [6, 7]])
    assert learner.start(s0) == 0            # Q(s0) = (1, 0)
    # e = 1 on {0, 1}; δ = −1 − Q(s0, 0) = −2; a' = 0 (Q(s1) = (0.5, 0)); δ += γ·0.5 = −1.5
    # θ += (α/m)·δ·e = 0.1·(−1.5) on {0, 1}; e ← γλe = 0.9
    assert learner.step(-1.0, s1) == 0
    assert learner.theta.tolist() == pytest.approx([0.85, -0.15, 0, 0, 0.5, 0, 0, 0])
    assert learner.e.tolist() == pytest.approx([0.9, 0.9, 0, 0, 0, 0, 0, 0])
    # terminal: e = 1 on {4, 5}; δ = 9.99 − Q(s1, 0) = 9.49; θ += 0.1·9.49·e
    learner.end(9.99)
    assert learner.theta.tolist() == pytest.approx(
        [0.85 + 0.8541, -0.15 + 0.8541, 0, 0, 0.5 + 0.949, 0.949, 0, 0])


def test_replacing_traces_do_not_accumulate():
    learner = SarsaLambda(4, 0.2, 0.9, 1.0, 0.0, np.random.default_rng(0), 1,
                          theta=np.array([1.0, 0.0, 0.0, 0.0]))
    s = np.array([[0], [1]])
    learner.start(s)
    learner.step(0.0, s)                     # a' = 0 again: e_0 = 1, then 0.9
    learner.step(0.0, s)                     # replaced by 1, not 1.9
    assert learner.e[0] == pytest.approx(0.9)


def test_greedy_ties_are_broken_at_random():
    rng = np.random.default_rng(1)
    picks = {epsilon_greedy(np.zeros(20), 0.0, rng) for _ in range(200)}
    assert len(picks) > 10
