"""Fayyad–Irani cut, the candidate test and range rule (§4.4.1), event bins (§4.4.2)."""

import numpy as np
import pytest

from qlap_runtime.qlap.landmarks import (
    Cut,
    DBNLandmark,
    EventBinner,
    best_cut,
    candidate_range,
    is_candidate,
    select_dbn_landmarks,
)


def test_best_cut_on_a_small_labelled_set():
    values = np.array([0.1, 0.2, 0.25, 0.35, 0.5, 0.9])
    labels = np.array([0, 0, 0, 1, 1, 1])
    cut = best_cut(values, labels)
    assert cut == Cut(1.0, 0.25, 0.35)          # pure split: G = H(S) = 1


def test_best_cut_gain_hand_computed_and_min_gap():
    # labels 0 1 0 1 1 1 over 1..6: best after the 3rd value: H(S)=0.918296,
    # left {0,1,0}: H=0.918296 (w .5), right pure: G = 0.918296 - 0.459148 = 0.459148
    values = np.arange(1.0, 7.0)
    cut = best_cut(values, np.array([0, 1, 0, 1, 1, 1]))
    assert cut is not None and cut.lb == 3.0 and cut.ub == 4.0
    assert cut.gain == pytest.approx(0.459148, abs=1e-6)
    # gaps of 0.0005 are not cut points (ub - lb > 0.001 required)
    assert best_cut(np.array([1.0, 1.0005, 1.001]), np.array([0, 1, 1])) is None


def test_candidate_test_and_range_rule():
    assert is_candidate(0.5, 0.4, 0.3)               # 0.5 > 0.3 and 0.2 > 0.15
    assert not is_candidate(0.5, 0.29, 0.3)          # 0.145 < 0.15
    assert not is_candidate(0.29, 1.0, 0.3)
    cut = Cut(0.5, 9.8, 10.0)
    assert candidate_range(cut, 0.0, 10.0, 0.5) == (10.0, 10.0)      # near max: [ub, max]
    assert candidate_range(Cut(0.5, 0.0, 0.2), 0.0, 10.0, 0.5) == (0.0, 0.0)   # near min
    assert candidate_range(Cut(0.5, 4.0, 4.1), 0.0, 10.0, 0.5) == (4.0, 4.1)
    assert candidate_range(cut, 0.0, 10.0, 0.5, use_bounds=False) == (9.8, 10.0)


def test_event_bins_hand_computed():
    # 100 values: 10 in each of bins 0..9 (bin size 1). Event rows all fall in bin 7.
    all_values = np.repeat(np.arange(10) + 0.5, 10)
    b = EventBinner(all_values, 1.0)
    rows = np.flatnonzero(np.floor(all_values) == 7)
    rows = np.concatenate([rows, rows, rows, rows])[:35]       # 35 event points in bin 7
    found = b.best(rows, theta_e=0.3, min_points=30)
    # local: bins 4..9 (clipped at 9): Pr(b7|E) = 1, Pr(b7) = 10/60 -> Δ = 0.8333
    assert found is not None and found.normalisation == "local"
    assert found.delta == pytest.approx(1 - 10 / 60)
    assert (found.lb, found.ub) == (7.5, 8.5)           # buckets start at the minimum, 0.5
    # fewer than 30 event points in the bucket: nothing (Appendix B.2)
    assert b.best(rows[:29], 0.3, 30) is None


def test_event_bins_global_normalisation_when_local_fails():
    # Events spread over 7 neighbouring bins so the local Δ stays below θ_E, but in all 20 bins
    # Pr(b|E) for the middle bin is 0.3 while Pr(b) is 0.05 -> global Δ = 0.25 < 0.3; add more.
    all_values = np.repeat(np.arange(20) + 0.5, 50)                 # 1000 values, 50 per bin
    mid = np.flatnonzero(np.floor(all_values) == 10)
    near = np.flatnonzero((np.floor(all_values) >= 7) & (np.floor(all_values) <= 13))
    rows = np.concatenate([np.repeat(mid, 2), near])              # 100 + 350 event points
    b = EventBinner(all_values, 1.0)
    found = b.best(rows, theta_e=0.05, min_points=30)
    # local at bin 10: Pr(b|E) = 150/450 = 0.3333, Pr(b) = 50/350 = 0.142857 -> 0.190476
    assert found is not None and found.normalisation == "local"
    assert found.delta == pytest.approx(150 / 450 - 50 / 350)
    found2 = b.best(rows, theta_e=0.2, min_points=30)
    # global at bin 10: 150/450 - 50/1000 = 0.28333 > 0.2 (local 0.19 fails)
    assert found2 is not None and found2.normalisation == "global"
    assert found2.delta == pytest.approx(150 / 450 - 0.05)


def test_cut_gain_bounds_bound_every_block_best_cut():
    from qlap_runtime.qlap.landmarks import cut_gain_bounds

    rng = np.random.default_rng(3)
    for _ in range(30):
        n, V = int(rng.integers(2, 120)), 3
        X = np.round(rng.normal(size=(n, V)), int(rng.integers(0, 3)))
        X[rng.random(X.shape) < 0.05] = np.nan
        ok = rng.random(n) < rng.random()
        Q = np.where(np.isnan(X), -1, (X > -0.5).astype(int) * 2 + (X > 0.5) * 2)
        groups = rng.integers(-1, 3, size=n)
        bound, labels = cut_gain_bounds(X, ok, Q, 5, groups)
        for j in range(V):
            for q in range(5):
                for gi, g in enumerate([None, *labels.tolist()]):
                    m = (Q[:, j] == q) & (True if g is None else groups == g)
                    cut = best_cut(X[m, j], ok[m]) if m.sum() >= 2 else None
                    if cut is not None:
                        assert cut.gain <= bound[j, q, gi] + 1e-12
                    if m.sum() < 2:
                        assert bound[j, q, gi] == -np.inf


def test_cut_gain_bounds_of_some_columns_are_those_columns_of_all():
    # The learner bounds only the columns a DBN may take a landmark on (App. D.2): each
    # column's bounds do not depend on the other columns, bit for bit.
    from qlap_runtime.qlap.landmarks import cut_gain_bounds

    rng = np.random.default_rng(4)
    for _ in range(30):
        n, V = int(rng.integers(2, 200)), int(rng.integers(2, 8))
        X = np.round(rng.normal(size=(n, V)), int(rng.integers(0, 3)))
        X[rng.random(X.shape) < 0.05] = np.nan
        ok = rng.random(n) < rng.random()
        Q = np.where(np.isnan(X), -1, (X > -0.5).astype(int) * 2 + (X > 0.5) * 2)
        groups = rng.integers(-1, 3, size=n) if rng.random() < 0.5 else None
        full, labels = cut_gain_bounds(X, ok, Q, 5, groups)
        some = np.flatnonzero(rng.random(V) < 0.5)
        part, part_labels = cut_gain_bounds(X[:, some], ok, Q[:, some], 5, groups)
        assert part.tobytes() == full[some].tobytes()
        assert part_labels.tobytes() == labels.tobytes()


def _gain_bounds_masked(X, ok, Q, n_values, groups=None):
    """cut_gain_bounds as it was first written: each group as a mask over all rows."""
    from qlap_runtime.qlap.probability import binary_entropy_array

    n, V = X.shape
    labels = np.unique(groups[groups >= 0]) if groups is not None else np.zeros(0, np.int64)
    out = np.full((V, n_values, 1 + len(labels)), -np.inf)
    if n < 2 or V == 0:
        return out, labels
    order = np.argsort(X, axis=0, kind="stable")
    col = np.arange(V)[None, :]
    Qs = Q[order, col]
    ys = ok.astype(float)[order]
    rows = np.arange(n)[:, None]
    is_start = np.ones(Qs.shape, dtype=bool)
    is_start[1:] = Qs[1:] != Qs[:-1]
    is_end = np.ones(Qs.shape, dtype=bool)
    is_end[:-1] = is_start[1:]
    start = np.maximum.accumulate(np.where(is_start, rows, 0), axis=0)
    end = np.minimum.accumulate(np.where(is_end, rows, n)[::-1], axis=0)[::-1]
    flat_start = np.flatnonzero(is_start.T.ravel())
    seg_var = flat_start // n
    seg_q = Qs.T.ravel()[flat_start]
    keep = (seg_q >= 0) & (seg_q < n_values)
    zero = np.zeros((1, V))
    masks = [None] + [groups[order] == g for g in labels.tolist()]
    for gi, W in enumerate(masks):
        w = np.ones(Qs.shape) if W is None else W.astype(float)
        cw = np.cumsum(w, axis=0)
        cy = np.cumsum(w * ys, axis=0)
        base_w = np.vstack([zero, cw])[start, col]
        base_y = np.vstack([zero, cy])[start, col]
        N = cw[end, col] - base_w
        S = cy[end, col] - base_y
        ln = cw - base_w
        ls = cy - base_y
        rn = N - ln
        valid = (w > 0) & (rn > 0) & (Qs >= 0)
        with np.errstate(invalid="ignore", divide="ignore"):
            gain = (binary_entropy_array(S / N) - ln / N * binary_entropy_array(ls / ln)
                    - rn / N * binary_entropy_array((S - ls) / rn))
        gain = np.where(valid, gain, -np.inf)
        seg_max = np.maximum.reduceat(gain.T.ravel(), flat_start)
        out[seg_var[keep], seg_q[keep], gi] = seg_max[keep]
    return out, labels


def test_cut_gain_bounds_of_each_group_on_its_rows_are_those_of_the_masks():
    # Groups bounded on their own rows give bit for bit the bounds of masking all rows.
    from qlap_runtime.qlap.landmarks import cut_gain_bounds

    rng = np.random.default_rng(12)
    for _ in range(60):
        n, V = int(rng.choice([1, 2, 3, 10, 60, 200])), int(rng.integers(1, 6))
        X = np.round(rng.normal(size=(n, V)), int(rng.integers(0, 3)))
        X[rng.random(X.shape) < 0.05] = np.nan
        ok = rng.random(n) < rng.random()
        Q = np.where(np.isnan(X), -1, (X > -0.5).astype(int) * 2 + (X > 0.5) * 2)
        groups = rng.integers(-1, int(rng.integers(1, 8)), size=n) if rng.random() < 0.8 \
            else None
        got, labels = cut_gain_bounds(X, ok, Q, 5, groups)
        want, want_labels = _gain_bounds_masked(X, ok, Q, 5, groups)
        assert got.shape == want.shape and got.tobytes() == want.tobytes()
        assert labels.tobytes() == want_labels.tobytes()


def test_cut_gain_bounds_many_are_those_of_each_call():
    # Algorithm 4 bounds all DBNs at once (cut_gain_bounds_many): sequences of any length,
    # NaNs, groups and column counts give bit for bit the bounds of one call per DBN.
    from qlap_runtime.qlap.landmarks import cut_gain_bounds, cut_gain_bounds_many

    rng = np.random.default_rng(5)
    for _ in range(100):
        items = []
        for _ in range(int(rng.integers(1, 12))):
            n, V = int(rng.choice([0, 1, 2, 3, 10, 60, 199, 200])), int(rng.integers(0, 6))
            X = np.round(rng.normal(size=(n, V)), int(rng.integers(0, 3)))
            X[rng.random(X.shape) < 0.05] = np.nan
            ok = rng.random(n) < rng.random()
            Q = np.where(np.isnan(X), -1, (X > -0.5).astype(int) * 2 + (X > 0.5) * 2)
            groups = rng.integers(-1, int(rng.integers(1, 8)), size=n) \
                if rng.random() < 0.5 else None
            items.append((X, ok, Q, groups))
        for (X, ok, Q, groups), (got, labels) in zip(items, cut_gain_bounds_many(items, 5),
                                                     strict=True):
            want, want_labels = cut_gain_bounds(X, ok, Q, 5, groups)
            assert got.shape == want.shape and got.tobytes() == want.tobytes()
            assert labels.tobytes() == want_labels.tobytes()


def test_cut_gain_bounds_many_by_hand():
    # One sequence 1, 2, 3, 4 with labels 1, 1, 0, 0 in one block (Q = 0): the cut after 2
    # separates them (gain 1 bit); a second DBN with one row has no block (−inf).
    from qlap_runtime.qlap.landmarks import cut_gain_bounds_many

    X = np.array([[3.0], [1.0], [4.0], [2.0]])
    ok = np.array([False, True, False, True])
    Q = np.zeros((4, 1), dtype=np.int64)
    (b1, l1), (b2, _) = cut_gain_bounds_many(
        [(X, ok, Q, None), (X[:1], ok[:1], Q[:1], None)], 3)
    assert b1.shape == (1, 3, 1) and len(l1) == 0
    assert b1[0, 0, 0] == 1.0 and b1[0, 1, 0] == -np.inf and b1[0, 2, 0] == -np.inf
    assert (b2 == -np.inf).all()


def test_one_execution_of_algorithm_4_adopts_by_weighted_gain_under_items_1_to_3():
    """App. D.2, by hand. Variables 0 and 1 with resolution 0.1. DBN 7's landmark on variable
    0 has the highest weighted gain and goes first. DBN 3's (same v and q) is item 3's second;
    DBN 5's lies 0.05 from DBN 7's, closer than the resolution; DBN 9's, on variable 1, is
    adopted unless DBN 7's landmark already improves DBN 9 (item 1); DBN 2 ties DBN 4 on
    weighted gain and goes first by its lower id."""
    a = DBNLandmark(0.40, 7, 0, 1, 2.00, 2.10)
    same_vq = DBNLandmark(0.35, 3, 0, 1, 3.00, 3.10)
    too_close = DBNLandmark(0.30, 5, 0, 3, 2.15, 2.25)
    other_var = DBNLandmark(0.25, 9, 1, 1, 0.50, 0.60)
    tie_late = DBNLandmark(0.20, 4, 1, 3, 5.00, 5.10)
    tie_early = DBNLandmark(0.20, 2, 1, 5, 8.00, 8.10)
    found = [tie_late, other_var, too_close, same_vq, a, tie_early]
    res = {0: 0.1, 1: 0.1}.__getitem__
    assert select_dbn_landmarks(found, res, None) == [a, other_var, tie_early, tie_late]
    improves = {(9, 7)}                      # (candidate's DBN, adopted landmark's DBN)
    got = select_dbn_landmarks(found, res, lambda c, ad: (c.dbn_id, ad.dbn_id) in improves)
    assert got == [a, tie_early, tie_late]
    # 0.1 apart exactly is not closer than the resolution
    edge = DBNLandmark(0.30, 5, 0, 3, 2.20, 2.30)
    assert select_dbn_landmarks([a, edge], res, None) == [a, edge]
