"""Compiled loops for the agent's numeric work (numba): value iteration with its bisimulation
quotient, Dyna and Sarsa(λ) (§5.2.2), Algorithm 3's counts (§4.2.1), Algorithm 4's gain bounds
(§4.4.1), the pairwise contingency counts (§4.1.2) and a step's quantization and events (§3.2).

Each function here is the loop of a numpy computation, written element by element with the
same floating-point operations in the same order (products, sums, maxima, whole-number counts:
no transcendental function — entropies come from a table of numpy's values — and no reordered
sum), so its results are bit for bit numpy's; ``tests/qlap/test_kernels.py`` pins each one
against the numpy path, which the callers keep. numpy's per-call overhead dominated these
loops (value iteration runs ~130 sweeps over a few hundred pairs; a DBN has 200 activations).

They are compiled by numba on first use (:func:`kernels`, cached on disk: the first run on a
machine compiles them, ~15 s of CPU spread over its first batches), so importing the agent
and its first steps stay as fast as before (the per-step callers use :func:`loaded_kernels`);
without numba (or with ``QLAP_NO_NUMBA=1``) the callers keep their numpy code.
"""

from __future__ import annotations

import math
import os
from types import SimpleNamespace

import numpy as np

_compiled: SimpleNamespace | None = None
_tried = False


def loaded_kernels() -> SimpleNamespace | None:
    """:func:`kernels` if already loaded, else None without loading them: for the per-step
    callers (perception, pair counts), so that a run's first steps do not wait for numba's
    import (the first batch that needs a kernel loads them)."""
    return _compiled


def kernels() -> SimpleNamespace | None:
    """The compiled functions (``vi_sweeps``, ``dyna``, ``sarsa``, ``context_counts``,
    ``bisimilar``, ``sequence_bounds``, ``quantize_row``, ``events_of``, ``pairs_update``,
    ``value_iteration``), or None without numba."""
    global _compiled, _tried
    if not _tried:
        _tried = True
        if os.environ.get("QLAP_NO_NUMBA"):
            return None
        try:
            import numba
        except ImportError:                               # pragma: no cover - a dependency
            return None
        jit = numba.njit(cache=True, fastmath=False, nogil=True)
        global _row_classes, _bisimilar, _vi_sweeps, _sweep_table_k
        _row_classes = jit(row_classes)                # called by the kernels below, compiled
        _bisimilar = jit(bisimilar)
        _vi_sweeps = jit(vi_sweeps)
        _sweep_table_k = jit(_sweep_table)
        _compiled = SimpleNamespace(vi_sweeps=_vi_sweeps, dyna=jit(dyna), sarsa=jit(sarsa),
                                    context_counts=jit(context_counts),
                                    bisimilar=_bisimilar,
                                    sequence_bounds=jit(sequence_bounds),
                                    quantize_row=jit(quantize_row), events_of=jit(events_of),
                                    pairs_update=jit(pairs_update),
                                    value_iteration=jit(value_iteration))
    return _compiled


def kernel_signatures() -> dict[str, list[tuple]]:
    """The argument types each compiled kernel is called with in a run (what the callers
    pass: C-contiguous arrays, the frozen models' read-only ones), by kernel name; empty
    without numba. :func:`warm_kernels` loads these."""
    if kernels() is None:
        return {}
    from numba import types as nt

    def arr(dtype: object, ndim: int, readonly: bool = False) -> object:
        return nt.Array(dtype, ndim, "C", readonly=readonly)

    f8, i8, b1 = nt.float64, nt.int64, nt.boolean
    f1, f2, i1, i2, bv = arr(f8, 1), arr(f8, 2), arr(i8, 1), arr(i8, 2), arr(b1, 1)
    return {
        "vi_sweeps": [(f1, f1, f1, f1, i1, i1, i1, i1, i8, f8, f8, i8)],
        "dyna": [(f2, i1, f1, f1, f1, f1, i1, i1, f8, f8)],
        "sarsa": [(f2, f2, i8, i8, f8, f8, b1)],
        "context_counts": [(i2, i1, i1, i1, i1, i1, i1, i1, i1, i1, i8)],
        "bisimilar": [(i2, arr(i8, 2, True), arr(i8, 2, True))],
        "sequence_bounds": [(f2, f2, i2, i8, arr(f8, 2, True))],
        "quantize_row": [(f1, i1, f2, f2, i1, i1)],
        "events_of": [(i1, i1, bv, i1, i1)],
        "pairs_update": [(i8, i8, i8, i1, i1, i1, i1, i2, i1, i1, i1)],
        "value_iteration": [(arr(f8, 2, True), arr(i8, 2, True), arr(i8, 2, True),
                             arr(b1, 2, True), arr(b1, 1, True), f8, f8, f8, f8, i8)],
    }


def warm_kernels() -> int:
    """Load the compiled kernels now, with the machine code of every signature a run calls
    them with (:func:`kernel_signatures`; from numba's disk cache, compiled if it has none):
    an actor process calls it at start-up, before the world's clock starts, since the first
    call of each kernel in a fresh process otherwise pays numba's import and the cache's
    load on the step chain (455 ms at core's first plan compilation, docs/decisions.md 95).
    Nothing is run: the results of every later call are those without the warm-up. Returns
    the number of signatures loaded (0 without numba)."""
    k = kernels()
    if k is None:
        return 0
    n = 0
    for name, sigs in kernel_signatures().items():
        for sig in sigs:
            getattr(k, name).compile(sig)
            n += 1
    return n


def vi_sweeps(q_app: np.ndarray, er: np.ndarray, a1: np.ndarray, a2: np.ndarray,
              n1: np.ndarray, n2: np.ndarray, starts: np.ndarray, live: np.ndarray,
              n_states: int, g: float, tol: float, max_sweeps: int) -> np.ndarray:
    """The sweeps of :func:`~.mdp._sweeps` on the applicable pairs: V(s) = max over each
    state's run of pairs (``starts``/``live``), then Q ← E[R] + γ(p1·V(s1) + p2·V(s2)) until
    no value moves by ``tol``. Returns the final values of the pairs (``q_app`` may be
    overwritten)."""
    n = q_app.size
    ns = starts.size
    v = np.zeros(n_states)
    new = np.empty(n)
    for _ in range(max_sweeps):
        for i in range(ns):
            b = starts[i]
            e = starts[i + 1] if i + 1 < ns else n
            m = q_app[b]
            for k in range(b + 1, e):
                if q_app[k] > m:
                    m = q_app[k]
            v[live[i]] = m
        delta = 0.0
        for i in range(n):
            x = er[i] + (a1[i] * v[n1[i]] + a2[i] * v[n2[i]]) * g
            d = abs(x - q_app[i])
            if d > delta:
                delta = d
            new[i] = x
        q_app, new = new, q_app
        if delta < tol:
            break
    return q_app


def dyna(q: np.ndarray, flat: np.ndarray, p1: np.ndarray, p2: np.ndarray, r1: np.ndarray,
         r2: np.ndarray, n1: np.ndarray, n2: np.ndarray, g: float, alpha: float) -> None:
    """One synchronous Dyna sweep of :func:`~.mdp.dyna_sweep` on a C-contiguous Q-table, in
    place: V(s) = max_a Q(s, a) (0 where nothing is applicable) from the table before the
    sweep, then each applicable pair Q ← (1 − α)Q + α·(p1(r1 + γV(s1)) + p2(r2 + γV(s2)))."""
    n_s, n_a = q.shape
    v = np.zeros(n_s)
    for s in range(n_s):
        m = -math.inf
        for a in range(n_a):
            if q[s, a] > m:
                m = q[s, a]
        v[s] = m if math.isfinite(m) else 0.0
    qf = q.reshape(-1)
    keep = 1.0 - alpha
    for i in range(flat.size):
        j = flat[i]
        target = p1[i] * (r1[i] + g * v[n1[i]]) + p2[i] * (r2[i] + g * v[n2[i]])
        qf[j] = keep * qf[j] + alpha * target


def sarsa(q: np.ndarray, e: np.ndarray, s: int, a: int, step: float, decay: float,
          terminal: bool) -> None:
    """The trace part of :meth:`~.mdp.SarsaLambda.update`: e(s, a) = 1, Q += step·e where
    e > 0 (``step`` = αδ), then the traces cleared (terminal) or multiplied by ``decay``."""
    e[s, a] = 1.0
    qf = q.reshape(-1)
    ef = e.reshape(-1)
    for i in range(ef.size):
        if ef[i] > 0.0:
            qf[i] = qf[i] + step * ef[i]
    if terminal:
        ef[:] = 0.0
    else:
        for i in range(ef.size):
            ef[i] = ef[i] * decay


def context_counts(Q: np.ndarray, ok: np.ndarray, row_lo: np.ndarray, row_hi: np.ndarray,
                   opts: np.ndarray,
                   opt_ptr: np.ndarray, seg_off: np.ndarray, ctx: np.ndarray,
                   ctx_ptr: np.ndarray, sizes: np.ndarray, total: int
                   ) -> tuple[np.ndarray, np.ndarray]:
    """One round of Algorithm 3 for many searches: per search i (rows ``row_lo[i]`` to
    ``row_hi[i]`` of ``Q``), option ``opts[j]`` (j from ``opt_ptr[i]`` to ``opt_ptr[i + 1]``)
    and row, the row's cell of the context
    sorted(ctx_i ∪ {v}) (mixed radix in order of variable; skipped where a value is unknown)
    is counted as a success or failure in bin ``seg_off[j] + cell``. Whole numbers: the
    counts of :meth:`~.context.StoredActivations.choose`'s bincounts."""
    succ = np.zeros(total, dtype=np.int64)
    fail = np.zeros(total, dtype=np.int64)
    n_search = row_lo.size
    for i in range(n_search):
        c0, c1 = ctx_ptr[i], ctx_ptr[i + 1]
        for j in range(opt_ptr[i], opt_ptr[i + 1]):
            v = opts[j]
            base = seg_off[j]
            for r in range(row_lo[i], row_hi[i]):
                cell = 0
                placed = False
                bad = False
                for k in range(c0, c1):
                    u = ctx[k]
                    if not placed and v < u:
                        q = Q[r, v]
                        if q < 0:
                            bad = True
                            break
                        cell = cell * sizes[v] + q
                        placed = True
                    q = Q[r, u]
                    if q < 0:
                        bad = True
                        break
                    cell = cell * sizes[u] + q
                if bad:
                    continue
                if not placed:
                    q = Q[r, v]
                    if q < 0:
                        continue
                    cell = cell * sizes[v] + q
                if ok[r]:
                    succ[base + cell] += 1
                else:
                    fail[base + cell] += 1
    return succ, fail


def row_classes(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Classes of equal rows of an int64 matrix, numbered in the order of their first rows:
    (class of each row, first row of each class) — :func:`~.mdp._row_classes`' answer (the
    canonical one: exact equality, first-occurrence numbering). Rows are bucketed by a hash
    and compared whole within a bucket."""
    n, w = rows.shape
    h = np.empty(n, dtype=np.uint64)
    for i in range(n):
        acc = np.uint64(1469598103934665603)
        for j in range(w):
            acc = (acc ^ np.uint64(rows[i, j])) * np.uint64(1099511628211)
        h[i] = acc
    order = np.argsort(h, kind="mergesort")            # stable: rows of a bucket by index
    label = np.empty(n, dtype=np.int64)
    bucket = np.empty(n, dtype=np.int64)               # the distinct rows of a bucket
    start = 0
    while start < n:
        end = start + 1
        while end < n and h[order[end]] == h[order[start]]:
            end += 1
        nb = 0
        for t in range(start, end):
            r = order[t]
            found = -1
            for b in range(nb):
                c = bucket[b]
                same = True
                for j in range(w):
                    if rows[r, j] != rows[c, j]:
                        same = False
                        break
                if same:
                    found = c
                    break
            if found < 0:
                bucket[nb] = r
                nb += 1
                label[r] = r
            else:
                label[r] = found
        start = end
    cls = np.empty(n, dtype=np.int64)
    reps = np.empty(n, dtype=np.int64)
    k = 0
    for i in range(n):
        if label[i] == i:
            cls[i] = k
            reps[k] = i
            k += 1
        else:
            cls[i] = cls[label[i]]
    return cls, reps[:k].copy()


_row_classes = row_classes
"""What :func:`bisimilar` calls: :func:`row_classes`, compiled by :func:`kernels`."""


def bisimilar(init: np.ndarray, next1: np.ndarray, next2: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`~.mdp._bisimilar` from its first signature ``init`` (per state the bits of
    E[R] and p1 of each action, as int64): refine the classes by the classes of the next
    states until every state agrees with its class's first state."""
    n_s, n_a = next1.shape
    cls, reps = _row_classes(init)
    sig = np.empty((n_s, 2 * n_a + 1), dtype=np.int64)
    while True:
        for s in range(n_s):
            sig[s, 0] = cls[s]
            for a in range(n_a):
                sig[s, 1 + a] = cls[next1[s, a]]
                sig[s, 1 + n_a + a] = cls[next2[s, a]]
        stable = True
        for s in range(n_s):
            r = reps[cls[s]]
            for j in range(2 * n_a + 1):
                if sig[s, j] != sig[r, j]:
                    stable = False
                    break
            if not stable:
                break
        if stable:
            return cls, reps
        cls, reps = _row_classes(sig)


def sequence_bounds(X: np.ndarray, Y: np.ndarray, Q: np.ndarray, n_values: int,
                    H: np.ndarray) -> np.ndarray:
    """:func:`~.landmarks._sequence_bounds` with the binary entropies read from the table
    ``H[n, k]`` = H(k / n) (numpy's values, :func:`entropy_table`): per row, its values sorted
    stably (NaN last, in order), runs of equal Q are the blocks, and each block's bound is the
    largest gain H(S/N) − ln/N·H(ls/ln) − rn/N·H(rs/rn) over its cut positions with rn > 0
    (whole-number counts; the same operations on the same numbers as numpy's)."""
    C, R = X.shape
    out = np.full((C, n_values), -np.inf)
    order = np.empty(R, dtype=np.int64)
    for c in range(C):
        n_ok = 0
        for i in range(R):
            if not np.isnan(X[c, i]):
                n_ok += 1
        idx = np.empty(n_ok, dtype=np.int64)
        vals = np.empty(n_ok)
        m = 0
        for i in range(R):
            if not np.isnan(X[c, i]):
                idx[m] = i
                vals[m] = X[c, i]
                m += 1
        srt = np.argsort(vals, kind="mergesort")
        for i in range(n_ok):
            order[i] = idx[srt[i]]
        m = n_ok
        for i in range(R):
            if np.isnan(X[c, i]):
                order[m] = i
                m += 1
        b = 0
        while b < R:
            q = Q[c, order[b]]
            e = b
            while e + 1 < R and Q[c, order[e + 1]] == q:
                e += 1
            n_blk = e - b + 1
            s_blk = 0
            for i in range(b, e + 1):
                s_blk += int(Y[c, order[i]])
            best = -np.inf
            if q >= 0:
                N = float(n_blk)
                h_all = H[n_blk, s_blk]
                ls = 0
                for i in range(b, e + 1):
                    ls += int(Y[c, order[i]])
                    ln = i - b + 1
                    rn = n_blk - ln
                    if rn > 0:
                        g = h_all - float(ln) / N * H[ln, ls] - float(rn) / N * H[rn, s_blk - ls]
                        if g > best:
                            best = g
            if 0 <= q < n_values:
                out[c, q] = best
            b = e + 1
    return out


def quantize_row(x: np.ndarray, ordered_idx: np.ndarray, ub: np.ndarray, lb: np.ndarray,
                 nlm: np.ndarray, nominal_idx: np.ndarray) -> np.ndarray:
    """:meth:`~.perception.Perception._quantize_row`: per ordered variable j = #{ub < x} and
    2j + (x on landmark j); a nominal variable's value is its index (truncated)."""
    q = np.empty(x.size, dtype=np.int64)
    for r in range(ordered_idx.size):
        i = ordered_idx[r]
        xv = x[i]
        nl = nlm[r]
        j = 0
        for c in range(nl):
            if ub[r, c] < xv:
                j += 1
        q[i] = 2 * j + (1 if (j < nl and xv >= lb[r, j]) else 0)
    for i in nominal_idx:
        q[i] = np.int64(x[i])
    return q


def events_of(q: np.ndarray, prev: np.ndarray, is_mag: np.ndarray, offset: np.ndarray,
              mult: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The events of :meth:`~.perception.Perception.perceive`: the variables whose known value
    changed, their new values, directions (±1 on magnitudes, 0 elsewhere) and event ids."""
    n = 0
    for i in range(q.size):
        if q[i] != prev[i] and q[i] >= 0 and prev[i] >= 0:
            n += 1
    ev = np.empty(n, dtype=np.int64)
    val = np.empty(n, dtype=np.int64)
    dirs = np.empty(n, dtype=np.int64)
    ids = np.empty(n, dtype=np.int64)
    k = 0
    for i in range(q.size):
        if q[i] != prev[i] and q[i] >= 0 and prev[i] >= 0:
            down = 1 if (is_mag[i] and q[i] < prev[i]) else 0
            up = 1 if (is_mag[i] and down == 0) else 0
            ev[k] = i
            val[k] = q[i]
            dirs[k] = up - down
            ids[k] = offset[i] + q[i] * mult[i] + down
            k += 1
    return ev, val, dirs, ids


def pairs_update(step: int, k: int, first_step: int, event_ids: np.ndarray,
                 win_t: np.ndarray, win_ids: np.ndarray, occurrences: np.ndarray,
                 soon_given: np.ndarray, soon_steps: np.ndarray, last_cons: np.ndarray,
                 cons_of_event: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`~.contingency.PairStatistics.update` on its arrays (in place; returns the new
    window): occurrences whose window closed become trials, then each consequent event of
    the step credits once every antecedent occurrence in its window not yet credited."""
    n = win_t.size
    cut = 0
    while cut < n and win_t[cut] <= step - k:
        occurrences[win_ids[cut]] += 1
        cut += 1
    m = event_ids.size
    new_t = np.empty(n - cut + m, dtype=np.int64)
    new_ids = np.empty(n - cut + m, dtype=np.int64)
    for i in range(cut, n):
        new_t[i - cut] = win_t[i]
        new_ids[i - cut] = win_ids[i]
    for i in range(m):
        new_t[n - cut + i] = step
        new_ids[n - cut + i] = event_ids[i]
    total = n - cut + m
    for i in range(m):
        c = cons_of_event[event_ids[i]]
        if c < 0:
            continue
        lo = max(max(last_cons[c] + 1, step - k + 1), first_step)
        soon_steps[c] += step - lo + 1
        last_cons[c] = step
        s = 0
        while s < total and new_t[s] < lo:
            s += 1
        for r in range(s, total):
            soon_given[new_ids[r], c] += 1
    return new_t, new_ids


_bisimilar = bisimilar
_vi_sweeps = vi_sweeps
"""What :func:`value_iteration` calls, compiled by :func:`kernels`."""


def _sweep_table(q: np.ndarray, er: np.ndarray, p1: np.ndarray, p2: np.ndarray,
                 n1: np.ndarray, n2: np.ndarray, app: np.ndarray, g: float, tol: float,
                 max_sweeps: int) -> None:
    """:func:`~.mdp._sweeps` in place on ``q`` (rows × actions, C order): the applicable
    pairs in row-major order, each row's run of pairs for V(s)."""
    n_s, n_a = app.shape
    m = 0
    for s in range(n_s):
        for a in range(n_a):
            if app[s, a]:
                m += 1
    e = np.empty(m)
    a1 = np.empty(m)
    a2 = np.empty(m)
    t1 = np.empty(m, dtype=np.int64)
    t2 = np.empty(m, dtype=np.int64)
    qa = np.empty(m)
    starts = np.empty(n_s, dtype=np.int64)
    live = np.empty(n_s, dtype=np.int64)
    n_runs = 0
    i = 0
    for s in range(n_s):
        first = True
        for a in range(n_a):
            if app[s, a]:
                if first:
                    starts[n_runs] = i
                    live[n_runs] = s
                    n_runs += 1
                    first = False
                e[i] = er[s, a]
                a1[i] = p1[s, a]
                a2[i] = p2[s, a]
                t1[i] = n1[s, a]
                t2[i] = n2[s, a]
                qa[i] = q[s, a]
                i += 1
    out = _vi_sweeps(qa, e, a1, a2, t1, t2, starts[:n_runs], live[:n_runs], n_s, g, tol,
                     max_sweeps)
    i = 0
    for s in range(n_s):
        for a in range(n_a):
            if app[s, a]:
                q[s, a] = out[i]
                i += 1


def value_iteration(p1: np.ndarray, next1: np.ndarray, next2: np.ndarray, app: np.ndarray,
                    goal: np.ndarray, r_goal: float, r_step: float, g: float, tol: float,
                    max_sweeps: int) -> np.ndarray:
    """:func:`~.mdp.value_iteration` whole: R of eq. 5.5 (``r_goal`` into a goal state, else
    ``r_step``), E[R] = p1·R1 + (1 − p1)·R2, the bisimulation quotient (:func:`bisimilar` on
    the bits of E[R] and p1 of the applicable pairs) and the sweeps on one state per class,
    copied back to every state."""
    n_s, n_a = app.shape
    p2 = np.empty((n_s, n_a))
    er = np.empty((n_s, n_a))
    er_sig = np.empty((n_s, n_a))
    p1_sig = np.empty((n_s, n_a))
    for s in range(n_s):
        for a in range(n_a):
            r1 = r_goal if goal[next1[s, a]] else r_step
            r2 = r_goal if goal[next2[s, a]] else r_step
            p2[s, a] = 1.0 - p1[s, a]
            er[s, a] = p1[s, a] * r1 + p2[s, a] * r2
            if app[s, a]:
                er_sig[s, a] = er[s, a]
                p1_sig[s, a] = p1[s, a]
            else:
                er_sig[s, a] = np.nan
                p1_sig[s, a] = 0.0
    init = np.empty((n_s, 2 * n_a), dtype=np.int64)
    init[:, :n_a] = er_sig.view(np.int64)
    init[:, n_a:] = p1_sig.view(np.int64)
    cls, reps = _bisimilar(init, next1, next2)
    k = reps.size
    if k == n_s:
        q = np.empty((n_s, n_a))
        for s in range(n_s):
            for a in range(n_a):
                q[s, a] = 0.0 if app[s, a] else -np.inf
        _sweep_table_k(q, er, p1, p2, next1, next2, app, g, tol, max_sweeps)
        return q
    qr = np.empty((k, n_a))
    er_r = np.empty((k, n_a))
    p1_r = np.empty((k, n_a))
    p2_r = np.empty((k, n_a))
    n1_r = np.empty((k, n_a), dtype=np.int64)
    n2_r = np.empty((k, n_a), dtype=np.int64)
    app_r = np.empty((k, n_a), dtype=np.bool_)
    for c in range(k):
        s = reps[c]
        for a in range(n_a):
            qr[c, a] = 0.0 if app[s, a] else -np.inf
            er_r[c, a] = er[s, a]
            p1_r[c, a] = p1[s, a]
            p2_r[c, a] = p2[s, a]
            n1_r[c, a] = cls[next1[s, a]]
            n2_r[c, a] = cls[next2[s, a]]
            app_r[c, a] = app[s, a]
    _sweep_table_k(qr, er_r, p1_r, p2_r, n1_r, n2_r, app_r, g, tol, max_sweeps)
    q = np.empty((n_s, n_a))
    for s in range(n_s):
        for a in range(n_a):
            q[s, a] = qr[cls[s], a]
    return q


_sweep_table_k = _sweep_table
"""What :func:`value_iteration` calls for the sweeps, compiled by :func:`kernels`."""
