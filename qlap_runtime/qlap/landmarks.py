"""The two landmark searches: on DBNs (§4.4.1, Algorithm 4) and on events (§4.4.2, Algorithm 5).

This module holds the numerical cores as pure functions; the learner decides what to search and
applies what is adopted.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from .kernels import kernels
from .probability import binary_entropy_array


@dataclass(frozen=True)
class Cut:
    """A Fayyad–Irani cutpoint c = (lb, ub) between two adjacent sorted values (§4.4.1)."""

    gain: float
    """Information gain G_c (eq. 4.16)."""
    lb: float
    """The largest value below the cut."""
    ub: float
    """The smallest value above the cut."""


def best_cut(values: np.ndarray, labels: np.ndarray, min_gap: float = 0.001) -> Cut | None:
    """The cutpoint of maximum information gain over sorted ``values`` (§4.4.1 step 1).

    Cuts are considered only between adjacent distinct values with ub − lb > ``min_gap``.
    Entropies are empirical (no prior). Ties go to the lowest cut.
    """
    x = np.asarray(values, dtype=float)
    y = np.asarray(labels, dtype=float)
    if len(x) < 2:
        return None
    order = np.argsort(x, kind="stable")
    x, y = x[order], y[order]
    n = len(x)
    gaps = np.diff(x)
    valid = gaps > min_gap
    if not valid.any():
        return None
    left_n = np.arange(1, n)
    left_s = np.cumsum(y)[:-1]
    total_s = y.sum()
    right_n = n - left_n
    right_s = total_s - left_s
    h = binary_entropy_array(np.array([total_s / n]))[0]
    hl = binary_entropy_array(left_s / left_n)
    hr = binary_entropy_array(right_s / right_n)
    gain = h - left_n / n * hl - right_n / n * hr
    gain = np.where(valid, gain, -np.inf)
    i = int(np.argmax(gain))
    return Cut(float(gain[i]), float(x[i]), float(x[i + 1]))


def cut_gain_bounds(X: np.ndarray, ok: np.ndarray, Q: np.ndarray, n_values: int,
                    groups: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Upper bounds of :func:`best_cut`'s gain for every (column, value, group) block at once.

    ``X``/``Q``: real and qualitative values (rows = activations, one column per variable);
    ``groups``: an optional per-row group label (−1 for none). Block (j, q, 0) holds the rows
    with Q[:, j] == q, block (j, q, 1 + i) those that also have the i-th smallest label. The
    bound is the largest gain over all cut positions in the block, valid gap or not; it is
    within a few ulps of an upper bound of best_cut's gain (compare with a margin). −inf where
    the block has fewer than two rows. Returns the bounds and the sorted group labels.
    """
    n, V = X.shape
    labels = np.unique(groups[groups >= 0]) if groups is not None else np.zeros(0, np.int64)
    out = np.full((V, n_values, 1 + len(labels)), -np.inf)
    if n < 2 or V == 0:
        return out, labels
    out[:, :, 0] = _block_bounds(X, ok, Q, n_values)
    # A group's blocks are those of its rows alone: within a block the counts left and right
    # of a cut are those of the group's rows (whole numbers, exact as floats either way), so
    # each group is bounded on its own rows instead of masking all rows once per group.
    assert groups is not None or not len(labels)
    for gi, g in enumerate(labels.tolist(), start=1):
        rows = groups == g
        if np.count_nonzero(rows) >= 2:
            out[:, :, gi] = _block_bounds(X[rows], ok[rows], Q[rows], n_values)
    return out, labels


def _block_bounds(X: np.ndarray, ok: np.ndarray, Q: np.ndarray, n_values: int) -> np.ndarray:
    """The bounds of :func:`cut_gain_bounds` of the blocks (column, value) of all rows (at
    least two): shape (columns, n_values)."""
    order = np.argsort(X, axis=0, kind="stable")
    # Row indices per column (as np.take_along_axis along axis 0, without its overhead).
    col = np.arange(X.shape[1])[None, :]
    return _sorted_block_bounds(Q[order, col], ok.astype(float)[order], n_values)


def _sorted_block_bounds(Qs: np.ndarray, ys: np.ndarray, n_values: int) -> np.ndarray:
    """Each column of ``Qs`` (values of Q in the order of the sorted values) with its success
    labels ``ys`` (0/1 as floats): the highest information gain of a cut inside each block
    (run of equal Q), shape (columns, n_values), −inf where a value has no block."""
    n, V = Qs.shape
    out = np.full((V, n_values), -np.inf)
    col = np.arange(V)[None, :]
    rows = np.arange(n)[:, None]
    is_start = np.ones(Qs.shape, dtype=bool)
    is_start[1:] = Qs[1:] != Qs[:-1]
    is_end = np.ones(Qs.shape, dtype=bool)
    is_end[:-1] = is_start[1:]
    start = np.maximum.accumulate(np.where(is_start, rows, 0), axis=0)
    end = np.minimum.accumulate(np.where(is_end, rows, n)[::-1], axis=0)[::-1]
    # Blocks are runs of equal Q in each sorted column (Q is monotone in the value; NaN rows,
    # Q = −1, sort last): reduce column-major over the run starts.
    flat_start = np.flatnonzero(is_start.T.ravel())
    seg_var = flat_start // n
    seg_q = Qs.T.ravel()[flat_start]
    keep = (seg_q >= 0) & (seg_q < n_values)
    zero = np.zeros((1, V))
    cw = np.broadcast_to(np.arange(1.0, n + 1.0)[:, None], Qs.shape)   # cumsum of ones
    cy = np.cumsum(ys, axis=0)
    base_w = np.vstack([zero, cw])[start, col]
    base_y = np.vstack([zero, cy])[start, col]
    N = cw[end, col] - base_w
    S = cy[end, col] - base_y
    ln = cw - base_w
    ls = cy - base_y
    rn = N - ln
    valid = (rn > 0) & (Qs >= 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        gain = (binary_entropy_array(S / N) - ln / N * binary_entropy_array(ls / ln)
                - rn / N * binary_entropy_array((S - ls) / rn))
    gain = np.where(valid, gain, -np.inf)
    seg_max = np.maximum.reduceat(gain.T.ravel(), flat_start)
    out[seg_var[keep], seg_q[keep]] = seg_max[keep]
    return out


GainItem = tuple[np.ndarray, np.ndarray, np.ndarray, "np.ndarray | None"]
"""The arguments ``(X, ok, Q, groups)`` of one :func:`cut_gain_bounds` call."""

# Elements (sequences × their padded length) per chunk of cut_gain_bounds_many: large enough
# for numpy's per-call overhead to vanish, small enough for the temporaries to stay in cache.
_CHUNK = 1 << 16


def cut_gain_bounds_many(items: list[GainItem], n_values: int
                         ) -> list[tuple[np.ndarray, np.ndarray]]:
    """:func:`cut_gain_bounds` of every item, bit for bit, computed together (§4.4.1 step 1
    for all of a batch's DBNs at once: Algorithm 4 bounds every DBN's blocks, and one DBN's
    arrays are too small for numpy's per-call overhead to pay off).

    Every (item, group, column) is one sequence of values; sequences are padded with NaN
    (sorted last, Q = −1: in no block) to a common length and bounded side by side by
    :func:`_sequence_bounds`, which does per sequence the element-wise operations of
    :func:`_block_bounds` per column (a block's counts are whole numbers, exact either way,
    and no block spans two sequences).
    """
    outs: list[tuple[np.ndarray, np.ndarray]] = []
    subsets: list[tuple[int, int, int, np.ndarray, np.ndarray, np.ndarray]] = []
    for k, (X, ok, Q, groups) in enumerate(items):
        n, V = X.shape
        labels = np.unique(groups[groups >= 0]) if groups is not None else np.zeros(0, np.int64)
        outs.append((np.full((V, n_values, 1 + len(labels)), -np.inf), labels))
        if n < 2 or V == 0:
            continue
        subsets.append((n, k, 0, X, ok, Q))
        for gi, g in enumerate(labels.tolist(), start=1):
            assert groups is not None
            rows = groups == g
            m = int(np.count_nonzero(rows))
            if m >= 2:
                subsets.append((m, k, gi, X[rows], ok[rows], Q[rows]))
    subsets.sort(key=lambda s: s[0])
    i = 0
    while i < len(subsets):
        # A chunk: subsets in order of length, padded to the longest.
        j, cols = i, 0
        while j < len(subsets) and (j == i or (cols + subsets[j][3].shape[1])
                                    * subsets[j][0] <= _CHUNK):
            cols += subsets[j][3].shape[1]
            j += 1
        chunk = subsets[i:j]
        R = chunk[-1][0]
        Xc = np.full((cols, R), np.nan)
        Yc = np.zeros((cols, R))
        Qc = np.full((cols, R), -1, dtype=np.int64)
        c = 0
        for n, _, _, X, ok, Q in chunk:
            V = X.shape[1]
            Xc[c:c + V, :n] = X.T
            Yc[c:c + V, :n] = ok
            Qc[c:c + V, :n] = Q.T
            c += V
        bounds = _sequence_bounds(Xc, Yc, Qc, n_values)
        c = 0
        for _, k, gi, X, _, _ in chunk:
            V = X.shape[1]
            outs[k][0][:, :, gi] = bounds[c:c + V]
            c += V
        i = j
    return outs


_ENTROPY_TABLES: dict[int, np.ndarray] = {}


def entropy_table(n_max: int) -> np.ndarray:
    """``H[n, k]`` = H(k / n) in bits for 1 ≤ n ≤ ``n_max``, 0 ≤ k ≤ n (0 elsewhere), by
    :func:`~.probability.binary_entropy_array` on the quotients k / n: the values it gives
    for the same quotients anywhere (a block's counts are whole numbers up to its length)."""
    H = _ENTROPY_TABLES.get(n_max)
    if H is None:
        n = np.arange(n_max + 1, dtype=float)[:, None]
        k = np.arange(n_max + 1, dtype=float)[None, :]
        ok = (n >= 1) & (k <= n)
        p = np.divide(k, n, out=np.zeros((n_max + 1, n_max + 1)), where=ok)
        H = np.where(ok, binary_entropy_array(p), 0.0)
        H.flags.writeable = False
        _ENTROPY_TABLES[n_max] = H
    return H


def _sequence_bounds(X: np.ndarray, Y: np.ndarray, Q: np.ndarray, n_values: int) -> np.ndarray:
    """:func:`_block_bounds` with one sequence per row (its own success labels ``Y``, 0/1 as
    floats) instead of one per column: shape (rows, n_values). The same element-wise
    operations on the same values, in the transposed layout (compiled: kernels.sequence_bounds
    with the entropies from :func:`entropy_table`)."""
    R = X.shape[1]
    k = kernels()
    if k is not None:
        n_max = max(200, 1 << max(R - 1, 1).bit_length())        # a few tables at most
        return k.sequence_bounds(np.ascontiguousarray(X), np.ascontiguousarray(Y),
                                 np.ascontiguousarray(Q, dtype=np.int64), int(n_values),
                                 entropy_table(n_max))
    order = np.argsort(X, axis=1, kind="stable")
    return _sorted_block_bounds(np.take_along_axis(Q, order, axis=1).T,
                                np.take_along_axis(Y, order, axis=1).T, n_values)


def candidate_range(cut: Cut, vmin: float, vmax: float, bin_size: float,
                    use_bounds: bool = True) -> tuple[float, float]:
    """The candidate landmark's range (§4.4.1 step 3).

    [ub, max] if ub is within one bin of the largest observed value, [min, lb] if lb is within
    one bin of the smallest, [lb, ub] otherwise. ``use_bounds=False`` (motor variables, see
    docs/decisions.md) always gives [lb, ub].
    """
    if use_bounds and bin_size > 0:
        if vmax - cut.ub <= bin_size:
            return cut.ub, vmax
        if cut.lb - vmin <= bin_size:
            return vmin, cut.lb
    return cut.lb, cut.ub


@dataclass(frozen=True)
class DBNLandmark:
    """A landmark Algorithm 4 found for one DBN: its best by weighted gain G*·Pr(v = q)."""

    wgain: float
    dbn_id: int
    var: int
    q: int
    """The open interval of ``var`` it splits (an index into the quantity space)."""
    lb: float
    ub: float


def select_dbn_landmarks(found: Sequence[DBNLandmark], resolution: Callable[[int], float],
                         improved_by: Callable[[DBNLandmark, DBNLandmark], bool] | None
                         ) -> list[DBNLandmark]:
    """The landmarks one execution of Algorithm 4 adds, in order (App. D.2): the DBNs' best
    landmarks by weighted gain (ties: the lower DBN id), one per DBN (``found`` holds one
    each, item 2) and per (v, q) (item 3), none closer than the variable's resolution to one
    adopted before it (docs/decisions.md 35), and — item 1 — none for a DBN that a landmark
    adopted before it already improves (``improved_by(candidate, adopted)``; None skips it)."""
    adopted: list[DBNLandmark] = []
    used: set[tuple[int, int]] = set()
    for c in sorted(found, key=lambda f: (-f.wgain, f.dbn_id)):
        res = resolution(c.var)
        if (c.var, c.q) in used or any(a.var == c.var and max(a.lb - c.ub, c.lb - a.ub) < res
                                       for a in adopted):
            continue
        if improved_by is not None and any(improved_by(c, a) for a in adopted):
            continue
        used.add((c.var, c.q))
        adopted.append(c)
    return adopted


def is_candidate(gain: float, prob_interval: float, theta_ig: float) -> bool:
    """G* > θ_IG and G* · Pr(v = q) > θ_IG / 2 (eq. 4.17)."""
    return gain > theta_ig and gain * prob_interval > theta_ig / 2


@dataclass(frozen=True)
class BinLandmark:
    """A bucket found by Algorithm 5."""

    delta: float
    """Pr(ṽ_{t−1} ∈ b | E(t)) − Pr(ṽ_{t−1} ∈ b) under the normalisation used."""
    lb: float
    ub: float
    bin_index: int
    normalisation: str
    """"local" (three buckets each side) or "global" (all buckets)."""


def _window_sums(c: np.ndarray, half: int) -> np.ndarray:
    """Sum of c over [i − half, i + half] (clipped at the ends) for every i."""
    cs = np.concatenate([[0.0], np.cumsum(c)])
    i = np.arange(len(c))
    return cs[np.minimum(i + half + 1, len(c))] - cs[np.maximum(i - half, 0)]


class EventBinner:
    """Algorithm 5's buckets for one variable ṽ over the stored history (§4.4.2).

    Buckets of width ``bin_size`` start at the smallest value; their overall counts are computed
    once, so each event costs one ``bincount``.
    """

    def __init__(self, all_values: np.ndarray, bin_size: float) -> None:
        self.bin_size = bin_size
        self.lo = float(np.min(all_values))
        self.n_bins = int(np.floor((float(np.max(all_values)) - self.lo) / bin_size)) + 1
        self.bins = np.clip(((all_values - self.lo) / bin_size).astype(np.int64), 0,
                            self.n_bins - 1)
        self.c_all = np.bincount(self.bins, minlength=self.n_bins).astype(float)
        self.s_all = _window_sums(self.c_all, 3)

    def best(self, event_rows: np.ndarray, theta_e: float, min_points: int) -> BinLandmark | None:
        """The bucket with the largest Δ = Pr(b | E) − Pr(b) if Δ > θ_E (eq. 4.18).

        ``event_rows`` index ``all_values`` at the steps t − 1 before each occurrence of E.
        Probabilities are normalised first over three buckets each side of b ("local"), then,
        if nothing is found, over all buckets ("global"). A bucket needs ``min_points`` event
        values (Appendix B.2).
        """
        if len(event_rows) < min_points:
            return None
        c_ev = np.bincount(self.bins[event_rows], minlength=self.n_bins).astype(float)
        enough = c_ev >= min_points
        if not enough.any():
            return None
        s_ev = _window_sums(c_ev, 3)
        with np.errstate(invalid="ignore", divide="ignore"):
            d_local = np.where((self.s_all > 0) & (s_ev > 0),
                               c_ev / s_ev - self.c_all / self.s_all, -np.inf)
        d_global = c_ev / c_ev.sum() - self.c_all / self.c_all.sum()
        for name, d in (("local", d_local), ("global", d_global)):
            d = np.where(enough, d, -np.inf)
            i = int(np.argmax(d))
            if d[i] > theta_e:
                return BinLandmark(float(d[i]), self.lo + i * self.bin_size,
                                   self.lo + (i + 1) * self.bin_size, i, name)
        return None
