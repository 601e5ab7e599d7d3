"""Hill-climbing on contexts: isModelImprovement (Algorithm 1) and Update Context (Algorithm 3).

Both work on :class:`~.dbn.ModelStats`, so they can be tested with hand-made numbers.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

import numpy as np

from .dbn import ModelStats, context_cells, counts_by_cell, model_stats
from .kernels import kernels
from .params import Params
from .probability import binary_entropy_array, dbn_entropy

# Margin between a fast estimate and the exact value (floating-point rounding only).
_TOL = 1e-9


def _brel_gain(new: float | None, old: float | None) -> float:
    """brel(r') − brel(r) with ⊥ below every value (Appendix B.1)."""
    if new is None:
        return float("-inf")
    if old is None:
        return float("inf")
    return new - old


def _segment_entropies(s: np.ndarray, f: np.ndarray, offs: np.ndarray, n_cells: np.ndarray,
                       prior: float) -> np.ndarray:
    """Per segment of cells (one candidate context each): H(r) of eq. 4.15 from its success and
    failure counts, as one vectorised pass (1 where a segment has no counts); a fast estimate,
    whose near-ties are decided by :func:`~.probability.dbn_entropy`."""
    tot = s + f
    seg_tot = np.add.reduceat(tot, offs)
    pe = (s + prior) / (tot + 2.0 * prior)
    with np.errstate(invalid="ignore", divide="ignore"):
        terms = binary_entropy_array(pe) * (tot / np.repeat(seg_tot, n_cells))
    return np.where(seg_tot > 0, np.add.reduceat(np.nan_to_num(terms), offs), 1.0)


def _segment_best_rel(s: np.ndarray, f: np.ndarray, offs: np.ndarray,
                      params: Params) -> np.ndarray:
    """Per segment of cells: its best reliability (App. B.1), −1 where no cell has enough
    successes (⊥)."""
    rel = (s + params.prior) / (s + f + 2.0 * params.prior)
    rel = np.where(s >= params.brel_min_successes, rel, -1.0)
    return np.maximum.reduceat(rel, offs)


def is_model_improvement(r: ModelStats, r2: ModelStats, params: Params) -> bool:
    """Algorithm 1: is r' (``r2``) a sufficient improvement over r? (§4.3.1)

    The ``entropy_only`` ablation (§7.11) always uses the entropy branch.
    """
    delta = r2.n_context - r.n_context
    theta = params.theta_pen
    if params.ablations.entropy_only:
        if r.n_context <= r2.n_context:
            return r.entropy - r2.entropy > (1 + delta) * theta
        return not is_model_improvement(r2, r, params)
    if r.reliable:
        if not r2.reliable:
            return False
        if r.n_context <= r2.n_context:
            return r.entropy - r2.entropy > (1 + delta) * theta
        return not is_model_improvement(r2, r, params)
    if r.n_context <= r2.n_context:
        return _brel_gain(r2.brel, r.brel) > (1 + delta) * theta
    return not is_model_improvement(r2, r, params)


Chooser = Callable[[tuple[int, ...], list[int], bool], tuple[int, ModelStats]]


def update_context(current: tuple[int, ...], candidates: Sequence[int],
                   evaluate: Callable[[tuple[int, ...]], ModelStats],
                   params: Params, choose: Chooser | None = None,
                   reliable_once: bool = False) -> tuple[int, ...] | None:
    """Algorithm 3 (Appendix D.1): rebuild a context from ∅ by hill-climbing.

    ``evaluate(context)`` gives the DBN's statistics under a context on the stored activations.
    Returns the new context if it improves on ``current`` (isModelImprovement), else None.
    At most ``params.max_context_vars`` variables are added (§4.2.1 footnote 1). Ties are broken
    by the lower variable index, so the result is deterministic.

    ``choose(ctx, options, by_entropy)``, if given, returns the option and statistics the
    default would pick for one round (the lowest entropy if ``by_entropy``, else the highest
    brel, ties to the lower index) — a faster way to score all options at once.

    ``reliable_once``: the model was sufficiently reliable at some time (§4.2.2), so the final
    comparison treats it as sufficiently reliable (:func:`once_reliable`).
    """
    # evaluate is pure: each context is scored once (the final comparison with ``current``
    # often meets a context the climb already scored).
    scores: dict[tuple[int, ...], ModelStats] = {}

    def score(c: tuple[int, ...]) -> ModelStats:
        r = scores.get(c)
        if r is None:
            r = scores[c] = evaluate(c)
        return r

    ctx: tuple[int, ...] = ()
    r1 = score(ctx)
    while len(ctx) < params.max_context_vars:
        options = [v for v in candidates if v not in ctx]
        if not options:
            break
        by_entropy = r1.reliable or params.ablations.entropy_only
        if choose is not None:
            v, r2 = choose(ctx, options, by_entropy)
            scores.setdefault(tuple(sorted((*ctx, v))), r2)
        else:
            scored = [(v, score(tuple(sorted((*ctx, v))))) for v in options]
            if by_entropy:
                v, r2 = min(scored, key=lambda p: (p[1].entropy, p[0]))
            else:
                v, r2 = max(scored,
                            key=lambda p: (-1.0 if p[1].brel is None else p[1].brel, -p[0]))
        if not is_model_improvement(r1, r2, params):
            break
        ctx = tuple(sorted((*ctx, v)))
        r1 = r2
    if tuple(sorted(current)) != ctx:
        # r: the DBN under its current context (evaluated only when needed).
        r = once_reliable(score(tuple(current)), reliable_once)
        if is_model_improvement(r, r1, params):
            return ctx
    return None


def once_reliable(r: ModelStats, reliable_once: bool) -> ModelStats:
    """A model's statistics for Algorithm 1 with "sufficiently reliable" read as §4.2.2 defines
    it: "a DBN r is sufficiently reliable if at any time brel(r) > θ_SR" — a model that was
    stays so, whatever its last 200 activations say now (docs/decisions.md 117). Only the
    existing model has a history; a candidate context is judged on its statistics."""
    if reliable_once and not r.reliable:
        return dataclasses.replace(r, reliable=True)
    return r


class StoredActivations:
    """A model's stored activations quantized once, for Algorithm 3 (all candidates at once):
    a DBN's (§4.2.1) or a plan's second-order calls (§5.4.2).

    Every count is an exact integer, the statistics of the chosen candidate are computed with
    :func:`~.dbn.model_stats` on the same counts as the one-candidate-at-a-time evaluation, and
    the vectorised entropies are only used to short-list the exact ones, so the choices are
    those of :func:`~.context.update_context`'s default.
    """

    def __init__(self, Q: np.ndarray, ok: np.ndarray, sizes, params: Params) -> None:
        """``Q``: the activations' qualitative values (rows = activations, a column per
        variable, −1 where unknown or not needed); ``ok``: their success labels."""
        self.Q, self.ok = Q, ok
        self.okf = ok.astype(float)
        self.ok_int = ok.astype(np.int64)
        self.sizes = np.asarray(sizes, dtype=np.int64)
        self.params = params

    @classmethod
    def quantized(cls, X: np.ndarray, ok: np.ndarray,
                  quantize_columns: Callable[[np.ndarray, np.ndarray], np.ndarray],
                  cols: Sequence[int], sizes, params: Params) -> StoredActivations:
        """From real-valued activations ``X``: only the columns ``cols`` (the variables that
        will be evaluated) are quantized."""
        cols = np.asarray(sorted(set(cols)), dtype=np.int64)
        Q = np.full((len(X), len(sizes)), -1, dtype=np.int64)
        Q[:, cols] = quantize_columns(X, cols)
        return cls(Q, ok, sizes, params)

    def evaluate(self, ctx: tuple[int, ...]) -> ModelStats:
        if not ctx:
            # One cell: the counts the bincounts below give (whole numbers as floats).
            k = int(np.count_nonzero(self.ok))
            return model_stats(np.array([float(k)]), np.array([float(len(self.ok) - k)]), 0,
                               self.params)
        sizes = [int(self.sizes[v]) for v in ctx]
        n_cells = int(np.prod(sizes)) if ctx else 1
        cells = context_cells([self.Q[:, v] for v in ctx], sizes) if ctx else \
            np.zeros(len(self.ok), dtype=np.int64)
        s, f = counts_by_cell(cells, self.ok, n_cells)
        return model_stats(s, f, len(ctx), self.params)

    def choose(self, ctx: tuple[int, ...], options: list[int],
               by_entropy: bool) -> tuple[int, ModelStats]:
        p = self.params
        Q, sizes = self.Q, self.sizes
        m = len(ctx)
        opts = np.asarray(options, dtype=np.int64)
        Qo = Q[:, opts]
        so = sizes[opts]
        if m:
            cells, good, n_cells = self._cells_with(ctx, opts, Qo, so)
        else:                   # the first round: each option's own values are the cells
            cells, good, n_cells = Qo, Qo >= 0, so
        offs = np.zeros(len(opts), dtype=np.int64)
        np.cumsum(n_cells[:-1], out=offs[1:])
        total = int(n_cells.sum())
        idx = (cells + offs)[good]
        w = np.broadcast_to(self.okf[:, None], cells.shape)[good]
        s = np.bincount(idx, weights=w, minlength=total)
        f = np.bincount(idx, minlength=total).astype(float) - s
        if by_entropy:
            approx = _segment_entropies(s, f, offs, n_cells, p.prior)
            short = np.flatnonzero(approx <= approx.min() + _TOL)
            best = min((dbn_entropy(s[offs[j]:offs[j] + n_cells[j]],
                                    f[offs[j]:offs[j] + n_cells[j]], p.prior), int(opts[j]), j)
                       for j in short.tolist())
            j = best[2]
        else:
            j = int(np.lexsort((opts, -_segment_best_rel(s, f, offs, p)))[0])
        a, b = int(offs[j]), int(offs[j] + n_cells[j])
        return int(opts[j]), model_stats(s[a:b], f[a:b], m + 1, p)

    def _cells_with(self, ctx: tuple[int, ...], opts: np.ndarray, Qo: np.ndarray,
                    so: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per row and option v: the mixed-radix cell of sorted((*ctx, v)), whether the row has
        a value of every variable of it, and each option's number of cells."""
        Q, sizes = self.Q, self.sizes
        n, m = len(self.ok), len(ctx)
        # Mixed-radix cell of sorted((*ctx, v)) = (lo·|v| + q_v)·P_hi + hi, where lo/hi are the
        # cells of the context variables below/above v.
        lo = np.zeros((m + 1, n), dtype=np.int64)
        hi = np.zeros((m + 1, n), dtype=np.int64)
        phi = np.ones(m + 1, dtype=np.int64)
        bad = np.zeros(n, dtype=bool)
        for i, c in enumerate(ctx):
            lo[i + 1] = lo[i] * sizes[c] + np.maximum(Q[:, c], 0)
            bad |= Q[:, c] < 0
        for i in range(m - 1, -1, -1):
            hi[i] = np.maximum(Q[:, ctx[i]], 0) * phi[i + 1] + hi[i + 1]
            phi[i] = phi[i + 1] * sizes[ctx[i]]
        kv = np.searchsorted(np.asarray(ctx, dtype=np.int64), opts)
        cells = (lo[kv].T * so + np.maximum(Qo, 0)) * phi[kv] + hi[kv].T
        good = ~(bad[:, None] | (Qo < 0))
        return cells, good, phi[0] * so


ContextProblem = tuple[tuple[int, ...], Sequence[int], np.ndarray, np.ndarray]
"""One Algorithm 3 search: ``(current context, candidates, Q, ok)`` (Q and ok as for
:class:`StoredActivations`)."""


def update_contexts_many(problems: Sequence[ContextProblem], sizes, params: Params,
                         reliable_once: Sequence[bool] | None = None
                         ) -> list[tuple[int, ...] | None]:
    """:func:`update_context` with :meth:`StoredActivations.choose` for every problem, the
    same answers, with each round's counting done for all problems at once (Algorithm 3 on
    all of a batch's DBNs, §4.2.1, App. D.1: one DBN's arrays are too small for numpy's
    per-call overhead to pay off).

    Each problem's round counts its rows in its own bins of one ``bincount`` (the same sums
    of the same weights in the same order as its own call), the entropies and reliabilities
    are the same element-wise operations, and each problem's choice and statistics are
    then made from its own slice of the counts exactly as :meth:`StoredActivations.choose`
    makes them. ``reliable_once[i]``: problem i's model was sufficiently reliable at some time
    (``update_context``'s ``reliable_once``).
    """
    p = params
    acts = [StoredActivations(Q, ok, sizes, p) for _, _, Q, ok in problems]
    scores: list[dict[tuple[int, ...], ModelStats]] = []
    r1: list[ModelStats] = []
    for a in acts:                                  # the empty context: one cell
        r = a.evaluate(())
        scores.append({(): r})
        r1.append(r)
    ctx: list[tuple[int, ...]] = [() for _ in problems]
    active = list(range(len(problems))) if p.max_context_vars > 0 else []
    kern = kernels() if problems else None
    if kern is not None:
        # The compiled count (kernels.context_counts) reads all problems' rows at once.
        Q_all = np.ascontiguousarray(np.concatenate([a.Q for a in acts]), dtype=np.int64)
        ok_all = np.concatenate([a.ok_int for a in acts])
        row_ptr = np.zeros(len(acts) + 1, dtype=np.int64)
        np.cumsum([len(a.ok) for a in acts], out=row_ptr[1:])
        size_arr = np.asarray(sizes, dtype=np.int64)
    while active:
        rounds: list[tuple[int, np.ndarray, bool]] = []
        for i in active:
            options = [v for v in problems[i][1] if v not in ctx[i]]
            if options:
                rounds.append((i, np.asarray(options, dtype=np.int64),
                               r1[i].reliable or p.ablations.entropy_only))
        if not rounds:
            break
        # Each option's segment of cells (as many as the values of its context), problem
        # after problem: one count for all.
        seg_n = np.concatenate([acts[i].sizes[opts] * (int(np.prod(acts[i].sizes[list(
            ctx[i])])) if ctx[i] else 1) for i, opts, _ in rounds])
        offs = np.zeros(len(seg_n), dtype=np.int64)
        np.cumsum(seg_n[:-1], out=offs[1:])
        first_seg = np.zeros(len(rounds), dtype=np.int64)
        np.cumsum([len(r[1]) for r in rounds[:-1]], out=first_seg[1:])
        total = int(seg_n.sum())
        if kern is not None:
            sel = np.array([i for i, _, _ in rounds], dtype=np.int64)
            opt_ptr = np.zeros(len(rounds) + 1, dtype=np.int64)
            opt_ptr[1:] = [*first_seg[1:].tolist(), len(seg_n)]
            ctx_lists = [ctx[i] for i, _, _ in rounds]
            ctx_ptr = np.zeros(len(rounds) + 1, dtype=np.int64)
            np.cumsum([len(c) for c in ctx_lists], out=ctx_ptr[1:])
            sc, fc = kern.context_counts(
                Q_all, ok_all, row_ptr[sel], row_ptr[sel + 1],
                np.concatenate([o for _, o, _ in rounds]), opt_ptr, offs,
                np.asarray([v for c in ctx_lists for v in c], dtype=np.int64), ctx_ptr,
                size_arr, total)
            s = sc.astype(float)
            f = fc.astype(float)
        else:
            # Bin 2·cell + ok: the successes and failures of each cell as whole numbers, the
            # values (as floats) of choose's weighted and unweighted bincounts and difference.
            idx_parts = []
            for (i, opts, _), s0 in zip(rounds, first_seg.tolist(), strict=True):
                a = acts[i]
                Qo = a.Q[:, opts]
                so = a.sizes[opts]
                if ctx[i]:
                    cells, good, _ = a._cells_with(ctx[i], opts, Qo, so)
                else:
                    cells, good = Qo, Qo >= 0
                idx_parts.append(((cells + offs[s0:s0 + len(opts)]) * 2
                                  + a.ok_int[:, None])[good])
            counts = np.bincount(np.concatenate(idx_parts), minlength=2 * total)
            s = counts[1::2].astype(float)
            f = counts[0::2].astype(float)
        ent = [r[2] for r in rounds]
        if any(ent):
            approx = _segment_entropies(s, f, offs, seg_n, p.prior)
        if not all(ent):
            seg_max = _segment_best_rel(s, f, offs, p)
        still = []
        for (i, opts, by_entropy), s0 in zip(rounds, first_seg.tolist(), strict=True):
            k = len(opts)
            o = offs[s0:s0 + k]
            n_cells = seg_n[s0:s0 + k]
            if by_entropy:
                ap = approx[s0:s0 + k]
                short = np.flatnonzero(ap <= ap.min() + _TOL)
                j = min((dbn_entropy(s[o[j]:o[j] + n_cells[j]], f[o[j]:o[j] + n_cells[j]],
                                     p.prior), int(opts[j]), j) for j in short.tolist())[2]
            else:
                j = int(np.lexsort((opts, -seg_max[s0:s0 + k]))[0])
            a0, b0 = int(o[j]), int(o[j] + n_cells[j])
            v = int(opts[j])
            r2 = model_stats(s[a0:b0], f[a0:b0], len(ctx[i]) + 1, p)
            new_ctx = tuple(sorted((*ctx[i], v)))
            scores[i].setdefault(new_ctx, r2)
            if not is_model_improvement(r1[i], r2, p):
                continue
            ctx[i], r1[i] = new_ctx, r2
            if len(new_ctx) < p.max_context_vars:
                still.append(i)
        active = still
    out: list[tuple[int, ...] | None] = []
    for i, (current, _, _, _) in enumerate(problems):
        if tuple(sorted(current)) == ctx[i]:
            out.append(None)
            continue
        r = scores[i].get(tuple(current))
        if r is None:
            r = acts[i].evaluate(tuple(current))
        r = once_reliable(r, bool(reliable_once and reliable_once[i]))
        out.append(ctx[i] if is_model_improvement(r, r1[i], p) else None)
    return out
