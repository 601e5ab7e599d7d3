"""The model learner's batches: Algorithm 2 lines 6–13 computed as a delta (ch. 4).

:class:`BatchLearning` is the part of :class:`~.learner.ModelLearner` that runs on a batch's
copy of the learner: new DBNs from the pairwise contingency search (§4.1, Algorithm 1, with the
window k of Appendix C and targeted learning §6.3), contexts by hill-climbing (§4.2–4.3,
Algorithm 3), deletions of DBNs that stayed unreliable, landmarks on events (§4.4.2,
Algorithm 5) and on DBNs (§4.4.1, Algorithm 4). It returns a :class:`~.delta.Delta` of
operations, applied at step t + L (:meth:`~.learner.ModelLearner.apply_delta`).
"""

from __future__ import annotations

import copy
from collections import deque
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from .context import is_model_improvement, once_reliable, update_contexts_many
from .dbn import CHANGE, DBN, ModelStats, context_cells, counts_by_cell, model_stats
from .delta import (
    AddDBN,
    AddLandmark,
    DeleteDBN,
    Delta,
    Op,
    Refresh,
    SetContext,
    SetK,
    delta_version,
)
from .landmarks import (
    DBNLandmark,
    EventBinner,
    best_cut,
    candidate_range,
    cut_gain_bounds_many,
    is_candidate,
    select_dbn_landmarks,
)
from .quantity import Landmark, QuantitySpace
from .variables import Event, Kind

if TYPE_CHECKING:
    from .contingency import PairStatistics, WindowLearner
    from .learner import ModelLearner
    from .params import Params
    from .perception import Perception
    from .variables import Event, VariableTable

CHANGE_MINUS, CHANGE_PLUS = 0, 2

# Margin between a fast bound/estimate and the exact value (floating-point rounding only; the
# estimates differ from the exact values by far less).
_TOL = 1e-9


class BatchLearning:
    """Algorithm 2 lines 6–13 on the learner (a mixin of :class:`~.learner.ModelLearner`)."""

    if TYPE_CHECKING:   # the learner's fields and methods this part uses (ModelLearner's __init__)
        applied: list[dict]
        applied_count: int
        dbns: dict[int, DBN]
        k_learned: bool
        pairs: PairStatistics
        params: Params
        pending_deltas: deque[Delta]
        perception: Perception
        reliable_actions: set[tuple[int, int]]
        step: int
        table: VariableTable
        version: int
        window: WindowLearner
        _batch_work: ModelLearner | None
        _dot_of: dict[int, int]
        _pairs_of: set[tuple[Event, Event]]

        def _apply_op(self, op: Op) -> None: ...
        def _size(self, var: int) -> int: ...

    # ------------------------------------------------------------------------------------------
    # batches (Algorithm 2 lines 6–13)
    # ------------------------------------------------------------------------------------------
    def compute_batch(self, step: int) -> Delta:
        """Compute the batch due at ``step`` from the data up to ``step``, as a Delta.

        With a lag the batch runs on a copy of the learner, so the live state is untouched until
        the delta is applied at ``step + L``.
        """
        work = self if self.params.batch_lag == 0 else self._clone_for_batch()
        kinds = ("dbn", "landmarks") if step % self.params.landmark_period == 0 else ("dbn",)
        parts = work._compute_parts(step, kinds)
        self.version += 1
        ops = tuple(op for kind in kinds for op in parts[kind].ops)
        delta = Delta(version=self.version, computed_at=step,
                      apply_at=step + self.params.batch_lag, ops=ops)
        if work is self:
            delta = delta.mark_applied()
        self._batch_work = work
        return delta

    def batch_copy(self) -> ModelLearner:
        """A private copy on which a batch may be computed while this learner goes on."""
        return self._clone_for_batch()

    def compute_parts(self, step: int, kinds: tuple[str, ...]) -> dict[str, Delta]:
        """Compute a batch's parts on THIS object (call it on :meth:`batch_copy`): "dbn" is
        Algorithm 2 lines 6–9, "landmarks" lines 10–13 computed after them. Each part is a
        Delta (version from its step and kind) applied by every consumer at step + L."""
        return self._compute_parts(step, kinds)

    def _compute_parts(self, step: int, kinds: tuple[str, ...]) -> dict[str, Delta]:
        out: dict[str, Delta] = {}
        lag = self.params.batch_lag
        ops: list[Op] = []
        self._recording = ops
        try:
            # The sticky "sufficiently reliable" flags are refreshed as the batch's first op,
            # so that every replica refreshes at the same point (§4.2.2).
            self._do(Refresh())
            self._learn_dbns()
            self._update_contexts()
            self._delete_dbns(step)
            out["dbn"] = Delta(delta_version(step, "dbn"), step, step + lag, tuple(ops))
            if "landmarks" in kinds:
                ops = []
                self._recording = ops
                self._learn_event_landmarks(step)
                self._learn_dbn_landmarks(step)
                out["landmarks"] = Delta(delta_version(step, "landmarks"), step, step + lag,
                                         tuple(ops))
        finally:
            self._recording = None
        return out

    _recording: list[Op] | None = None

    def _do(self, op: Op) -> None:
        """Record an operation of the batch being computed and apply it to this state."""
        assert self._recording is not None
        self._recording.append(op)
        self._apply_op(op)

    def apply_delta(self, delta: Delta) -> None:
        """Apply a batch's delta at a step boundary (idempotent for an already applied one)."""
        if not delta.applied:
            for op in delta.ops:
                self._apply_op(op)
        self.applied_count += 1
        self.applied.append({"version": delta.version, "computed_at": delta.computed_at,
                             "applied_at": self.step, "ops": len(delta.ops)})
        del self.applied[:-50]

    def _clone_for_batch(self) -> ModelLearner:
        # The histories are copied too (a few MB): they are rings, and once full this learner,
        # going on while a batch computes in another thread, writes over the oldest rows the
        # batch still reads (embedded core runs of 30,000 steps parted from the synchronous
        # loop in 3 of 6 trials, Params.event_history being 20,000 steps).
        memo: dict[int, Any] = {id(self.pending_deltas): deque()}
        work, self._batch_work = self._batch_work, None     # never part of a copy
        try:
            return cast("ModelLearner", copy.deepcopy(self, memo))
        finally:
            self._batch_work = work

    def _refresh_reliability(self) -> None:
        """Sticky "sufficiently reliable at any time" flags from the CPTs (§4.2.2)."""
        for dbn in self.dbns.values():
            if not dbn.ever_reliable:
                st = model_stats(dbn.cpt_s, dbn.cpt_f, len(dbn.context), self.params)
                dbn.ever_reliable = st.reliable

    # -- learning new DBNs (§4.1–4.2, App. C, §6.2.3, §6.3) -----------------------------------
    def _targeted(self) -> np.ndarray:
        """Per consequent: is it chosen for targeted learning (§6.3)?"""
        ab = self.params.ablations
        n = self.perception.events.n_cons
        if ab.no_targeted:
            return np.zeros(n, dtype=bool)
        if ab.all_targeted:
            return np.ones(n, dtype=bool)
        return self.perception.satisfied_fraction() < self.params.rare_event_fraction

    def _learn_dbns(self) -> None:
        p = self.params
        index = self.perception.events
        if not self.k_learned:
            found = self.window.learnable(p.min_data_points, p.theta_pen, p.prior,
                                          p.beta_confidence)
            if not found:
                return
            k = max(1, round(float(np.mean([kr for _, _, kr in found]))))
            self._do(SetK(k))
            candidates = [(index.decode(e1), index.decode(e2)) for e1, e2, _ in found]
        else:
            theta = np.where(self._targeted(), p.theta_pen_targeted, p.theta_pen)
            found4 = self.pairs.contingencies(theta, p.min_data_points, p.prior,
                                              p.beta_confidence)
            candidates = [(index.decode(e1), index.decode(e2)) for e1, e2, _, _ in found4]
        # The reliable change DBNs' consequents: adding DBNs (never reliable yet) keeps them.
        reliable = {(d.consequent.var, d.consequent.value) for d in self.dbns.values()
                    if d.kind == CHANGE and d.ever_reliable}
        for e1, e2 in sorted(candidates):
            if self._may_add_dbn(e1, e2, reliable):
                self._do(AddDBN(CHANGE, e1, e2))

    def _may_add_dbn(self, e1: Event, e2: Event,
                     reliable_cons: set[tuple[int, int]] | None = None) -> bool:
        if (e1, e2) in self._pairs_of:
            return False
        if (e2.var, e2.value) in self.reliable_actions:
            return False                                           # §6.2.1 item 3
        if self.params.ablations.nrc:
            return True
        kind = self.table[e1.var].kind
        if kind is Kind.MOTOR:
            return True
        if reliable_cons is None:
            reliable_cons = {(d.consequent.var, d.consequent.value) for d in self.dbns.values()
                             if d.kind == CHANGE and d.ever_reliable}
        if kind is Kind.MAGNITUDE:                                   # §6.2.3: can move v
            dot = self._dot_of[e1.var]
            return any(var == dot for var, _ in reliable_cons)
        return (e1.var, e1.value) in reliable_cons

    # -- contexts (Algorithm 3) -----------------------------------------------------------------
    def context_candidates(self, dbn: DBN) -> list[int]:
        """Valid context variables (App. D.1): magnitude with ≥ 1 landmark, or nominal."""
        # Keyed by the perception object itself (held, so never mistaken for a later one at
        # the same address) and its landmarks' version.
        per, version = self.perception, self.perception.landmarks_version
        cached = getattr(self, "_candidate_vars", None)
        if cached is None or cached[0] is not per or cached[1] != version:
            base = [v.index for v in self.table if v.kind is Kind.NOMINAL or (
                v.kind is Kind.MAGNITUDE and per.spaces[v.index].landmarks)]
            cached = self._candidate_vars = (per, version, base)
        return [v for v in cached[2] if v not in (dbn.antecedent.var, dbn.consequent.var)]

    def evaluator(self, dbn: DBN, extra: tuple[int, QuantitySpace] | None = None,
                  rows: np.ndarray | None = None):
        """A function context -> ModelStats on the DBN's stored activations.

        ``extra`` replaces one variable's quantity space (a candidate landmark, §4.4.1 step 4);
        ``rows`` restricts the activations (a split antecedent).
        """
        X, ok = dbn.stored()
        if rows is not None:
            X, ok = X[rows], ok[rows]
        cache: dict[int, np.ndarray] = {}

        def column(v: int) -> np.ndarray:
            if v not in cache:
                if extra is not None and extra[0] == v:
                    cache[v] = extra[1].values_of(X[:, v])
                else:
                    cache[v] = self.perception.quantize_var(v, X[:, v])
            return cache[v]

        def size(v: int) -> int:
            if extra is not None and extra[0] == v:
                return extra[1].size
            return self._size(v)

        def evaluate(ctx: tuple[int, ...]) -> ModelStats:
            sizes = [size(v) for v in ctx]
            n_cells = int(np.prod(sizes)) if ctx else 1
            cells = context_cells([column(v) for v in ctx], sizes) if ctx else \
                np.zeros(len(ok), dtype=np.int64)
            s, f = counts_by_cell(cells, ok, n_cells)
            return model_stats(s, f, len(ctx), self.params)

        return evaluate

    def _update_contexts(self) -> None:
        signature = self.perception.landmark_signature
        searched: list[tuple[int, tuple, list[int], np.ndarray, np.ndarray]] = []
        for dbn_id in sorted(self.dbns):
            dbn = self.dbns[dbn_id]
            if dbn.act_n < 1:
                continue
            cands = self.context_candidates(dbn)
            # Algorithm 3 is a function of the stored activations (changed only by record(),
            # which counts dbn.total), the context, the candidates and the quantity spaces of
            # the candidates and context variables: a DBN whose search gave "no change" with
            # the same inputs gives it again (landmarks of other variables do not matter).
            key = (dbn.total, dbn.context, tuple(cands), signature((*cands, *dbn.context)),
                   dbn.ever_reliable)
            if dbn.context_unchanged == key:
                continue
            X, ok = dbn.stored()
            searched.append((dbn_id, key, cands, X, ok))
        if not searched:
            return
        # The searches are independent (a new context changes its DBN alone): all DBNs'
        # activations are quantized in one call and searched together (update_contexts_many,
        # the answers of update_context one by one), then applied in order of id. Only the
        # variables searched are quantized, as columns 0, 1, … in order of index (an
        # increasing renumbering: the same ties, choices and statistics).
        cols = sorted({v for _, _, cands, _, _ in searched for v in cands}
                      | {v for d_id, *_ in searched for v in self.dbns[d_id].context})
        at = {v: i for i, v in enumerate(cols)}
        Q_all = self.perception.quantize_values(
            np.concatenate([X[:, cols] for *_, X, _ in searched]), cols)
        all_sizes = self.perception.events.sizes
        sizes = [all_sizes[v] for v in cols]
        problems = []
        row = 0
        for dbn_id, _, cands, X, ok in searched:
            problems.append((tuple(at[v] for v in self.dbns[dbn_id].context),
                             [at[v] for v in cands], Q_all[row:row + len(X)], ok))
            row += len(X)
        answers = update_contexts_many(problems, sizes, self.params,
                                       [self.dbns[d_id].ever_reliable for d_id, *_ in searched])
        for (dbn_id, key, _, _, _), new in zip(searched, answers, strict=True):
            if new is not None:
                self._do(SetContext(dbn_id, tuple(cols[i] for i in new)))
            else:
                self.dbns[dbn_id].context_unchanged = key

    def _delete_dbns(self, step: int) -> None:
        """§6.2.3 (old, never deterministic, not a plan) and §6.2.1 item 4."""
        for dbn_id in sorted(self.dbns):
            dbn = self.dbns[dbn_id]
            if dbn.kind != CHANGE or dbn.is_plan:
                continue
            old = step - dbn.created > self.params.dbn_max_age and not dbn.ever_reliable
            done = (dbn.consequent.var, dbn.consequent.value) in self.reliable_actions
            if old or done:
                self._do(DeleteDBN(dbn_id))

    # -- landmarks on events (Algorithm 5) --------------------------------------------------
    def _learn_event_landmarks(self, step: int) -> None:
        p = self.params
        hx, hq = self.perception.history()
        if len(hx) < 2:
            return
        cands: list[tuple[float, int, int, int, float, float]] = []  # Δ, event, v, q, lb, ub
        events: list[tuple[int, int, np.ndarray]] = []
        for c in self.table.of_kind(Kind.CHANGE):
            for val in (CHANGE_MINUS, CHANGE_PLUS):
                if (c.index, val) in self.reliable_actions:
                    continue                                           # §6.2.1 item 1
                col = hq[:, c.index]
                occ = np.flatnonzero((col[1:] == val) & (col[:-1] != val) & (col[:-1] >= 0))
                if len(occ) >= p.min_data_points:
                    events.append((c.index, val, occ))       # rows t−1 of each event at t
        if not events:
            return
        for v in self.table.of_kind(Kind.MOTOR, Kind.MAGNITUDE):
            b = self.perception.bin_size(v.index)
            vals = hx[:-1, v.index]
            good = ~np.isnan(vals)
            if b <= 0 or good.sum() < p.min_data_points:
                continue
            binner = EventBinner(np.where(good, vals, np.nanmin(vals)), b)
            space = self.perception.spaces[v.index]
            for cvar, val, occ in events:
                occ = occ[good[occ]]
                found = binner.best(occ, p.theta_e, p.min_data_points)
                if found is None:
                    continue
                if any(found.lb - 2 * b <= lm.ub and lm.lb <= found.ub + 2 * b
                       for lm in space.landmarks):
                    continue                                           # D.3 item 1
                fitted = self._fit_resolution(v.index, found.lb, found.ub)
                if fitted is None:
                    continue
                q = space.interval_of_range(*fitted)
                if q is None:
                    continue
                eid = cvar * 3 + val
                cands.append((found.delta, eid, v.index, q, *fitted))
        # D.3 items 2–3: one per (v, q) and one per event, the highest Δ first.
        cands.sort(key=lambda c: (-c[0], c[1], c[2], c[3]))
        used_vq: set[tuple[int, int]] = set()
        used_e: set[int] = set()
        for _, eid, var, q, lb, ub in cands:
            if (var, q) in used_vq or eid in used_e or self._fit_resolution(var, lb, ub) is None:
                continue
            used_vq.add((var, q))
            used_e.add(eid)
            self._do(AddLandmark(var, lb, ub, "event", step))

    # -- landmarks on DBNs (Algorithm 4) ----------------------------------------------------
    def _prob_interval(self, var: int, space: QuantitySpace) -> np.ndarray:
        hx, _ = self.perception.history()
        col = hx[:, var]
        col = col[~np.isnan(col)]
        if not len(col):
            return np.zeros(space.size)
        return np.bincount(space.values_of(col), minlength=space.size) / len(col)

    def _learn_dbn_landmarks(self, step: int) -> None:
        p = self.params
        found: list[DBNLandmark] = []
        props: dict[int, tuple[tuple, ModelStats, np.ndarray]] = {}   # dbn id: proposal, r, X
        real_vars = self.table.of_kind(Kind.MOTOR, Kind.MAGNITUDE)
        cols = np.array([v.index for v in real_vars], dtype=np.int64)
        spaces = self.perception.spaces
        n_values = max([spaces[v.index].size for v in real_vars] + [1])
        prob = np.zeros((len(real_vars), n_values))
        for i, v in enumerate(real_vars):
            pr = self._prob_interval(v.index, spaces[v.index])
            prob[i, :len(pr)] = pr
        # A gain is at most 1 bit, so eq. 4.17 needs Pr(v = q) > θ_IG / 2: only variables with
        # such an open interval are searched.
        open_prob = prob.copy()
        open_prob[:, 1::2] = 0.0
        useful = (open_prob > p.theta_ig / 2 - _TOL).any(axis=1)
        real_vars = [v for v, u in zip(real_vars, useful.tolist(), strict=True) if u]
        cols, prob = cols[useful], prob[useful]
        is_motor = np.array([v.kind is Kind.MOTOR for v in real_vars], dtype=bool)
        stored = [(dbn_id, self.dbns[dbn_id]) for dbn_id in sorted(self.dbns)
                  if self.dbns[dbn_id].kind == CHANGE
                  and self.dbns[dbn_id].act_n >= p.min_data_points]
        acts = [dbn.stored() for _, dbn in stored]
        # The columns of every DBN quantized in one call (column by column the values of
        # quantize_columns on each DBN's rows).
        Q_cols = self.perception.quantize_values(
            np.concatenate([X[:, cols] for X, _ in acts]), cols) if acts and len(cols) \
            else np.zeros((sum(len(X) for X, _ in acts), len(cols)), dtype=np.int64)
        row = 0
        searched = []
        for (dbn_id, dbn), (X, ok) in zip(stored, acts, strict=True):
            # App. D.2: a motor only as the DBN's antecedent, a magnitude only if it is not
            # (D.1: no motor in a context): only these columns are bounded; the others keep
            # a bound of −inf, so no landmark is sought on them.
            rel = np.flatnonzero(is_motor == (cols == dbn.antecedent.var))
            used = cols[rel]
            Q = np.full(X.shape, -1, dtype=np.int64)              # only the columns used
            Q[:, used] = Q_cols[row:row + len(X), rel]
            row += len(X)
            cq = None
            if len(dbn.context) == 1:                                 # §4.4.1 footnote 2
                cq = self.perception.quantize_columns(X, dbn.context)[:, 0]
            searched.append((dbn_id, dbn, X, ok, Q, cq, rel, used))
        # Blocks whose gain bound cannot pass eq. 4.17 are skipped: best_cut there could
        # only give a cut that is_candidate rejects (cut_gain_bounds is column by column, so
        # the columns bounded give the bounds they have among all columns). The bounds of
        # all DBNs are computed at once (cut_gain_bounds_many: the same numbers).
        all_bounds = cut_gain_bounds_many(
            [(X[:, used], ok, Q[:, used], cq) for _, _, X, ok, Q, cq, _, used in searched],
            n_values)
        for (dbn_id, dbn, X, ok, Q, cq, rel, _), (sub, labels) in zip(searched, all_bounds,
                                                                     strict=True):
            bound = np.full((len(cols), *sub.shape[1:]), -np.inf)
            bound[rel] = sub
            with np.errstate(invalid="ignore"):
                passing = (bound > p.theta_ig - _TOL) & \
                    (bound * prob[:, :, None] > p.theta_ig / 2 - _TOL)
            passing[:, 1::2, :] = False
            if not passing.any():
                continue
            r: ModelStats | None = None
            best: tuple[DBNLandmark, tuple] | None = None    # the landmark, its proposal
            for i, q, gi in np.argwhere(passing).tolist():
                v = real_vars[i]
                var = v.index
                col = X[:, var]
                space = spaces[var]
                in_q = Q[:, var] == q
                if in_q.sum() < p.min_data_points:
                    continue                                            # App. B.2 item 2
                m = in_q if gi == 0 else in_q & (cq == labels[gi - 1])
                if m.sum() < 2:
                    continue
                cut = best_cut(col[m], ok[m], p.cut_min_gap)
                if cut is None or not is_candidate(cut.gain, prob[i, q], p.theta_ig):
                    continue
                wgain = cut.gain * prob[i, q]
                if best is not None and wgain <= best[0].wgain:
                    continue
                lb, ub = candidate_range(cut, float(col[in_q].min()),
                                         float(col[in_q].max()),
                                         self.perception.bin_size(var),
                                         use_bounds=v.kind is Kind.MAGNITUDE)
                fitted = self._fit_resolution(var, lb, ub)
                if fitted is None:
                    continue
                lb, ub = fitted
                if space.interval_of_range(lb, ub) != q:
                    continue
                if r is None:
                    r = once_reliable(self.evaluator(dbn)(dbn.context), dbn.ever_reliable)
                prop = self._landmark_proposal(dbn, r, var, lb, ub, X)
                if prop is not None:
                    best = (DBNLandmark(wgain, dbn_id, var, q, prop[0], prop[1]), prop)
            if best is not None:
                assert r is not None
                found.append(best[0])
                props[dbn_id] = (best[1], r, X)
        # D.2 items 1–3, decided on the quantity spaces before this execution; then applied.
        motors = {v.index for v in self.table.of_kind(Kind.MOTOR)}

        def improved_by(c: DBNLandmark, a: DBNLandmark) -> bool:
            """Does the landmark adopted for another DBN already improve c's DBN
            (isModelImprovement(r, r′) in any of §4.4.1's three ways; a motor only as the
            antecedent, D.1)?"""
            dbn = self.dbns[c.dbn_id]
            if (a.var in motors) != (a.var == dbn.antecedent.var):
                return False
            _, r, X = props[c.dbn_id]
            return self._landmark_proposal(dbn, r, a.var, a.lb, a.ub, X) is not None

        for c in select_dbn_landmarks(found, self.perception.resolution,
                                      improved_by if p.landmark_once else None):
            (lb, ub, ante, ctx), _, _ = props[c.dbn_id]
            self._do(AddLandmark(c.var, lb, ub, "dbn", step, c.dbn_id, ante, ctx))

    def _fit_resolution(self, var: int, lb: float, ub: float) -> tuple[float, float] | None:
        """A candidate landmark at the variable's resolution (docs/decisions.md): widened about
        its centre to at least ``Perception.resolution(var)``, and refused (None) when it would
        come closer than that to an existing landmark, where the interval between them would
        be a sliver that no step can be seen in (§4.4.1 asks for ub − lb > 0.001 between the
        values of a cut; Table 8.1 has no two landmarks of a motor, nor of h_x, closer)."""
        res = self.perception.resolution(var)
        if ub - lb < res:
            c = 0.5 * (lb + ub)
            lb, ub = c - 0.5 * res, c + 0.5 * res
            while ub - lb < res:                        # rounding: at least res, exactly
                ub = float(np.nextafter(ub, np.inf))
        for lm in self.perception.spaces[var].landmarks:
            if max(lm.lb - ub, lb - lm.ub) < res:
                return None
        return lb, ub

    def _landmark_proposal(self, dbn: DBN, r: ModelStats, var: int, lb: float, ub: float,
                           X: np.ndarray) -> tuple | None:
        """Step 4 of §4.4.1: r' with the landmark; returned if isModelImprovement(r, r')."""
        src = self.perception.spaces[var]
        space = copy.copy(src)                      # landmarks are immutable: copy the list only
        space.landmarks = list(src.landmarks)
        try:
            split = space.insert(Landmark(lb, ub))
        except ValueError:
            return None
        if var == dbn.antecedent.var:
            if dbn.antecedent.value != split:
                return None
            qv = space.values_of(X[:, var])
            best = None
            for half in (split, split + 2):                 # below and above the landmark
                st = self.evaluator(dbn, (var, space), rows=qv == half)(dbn.context)
                if best is None or st.successes > best[1].successes:
                    best = (half, st)
            assert best is not None
            if is_model_improvement(r, best[1], self.params):
                return (lb, ub, [var, best[0], dbn.antecedent.direction], None)
            return None
        ctx = dbn.context
        if var not in ctx:
            if len(ctx) >= self.params.max_context_vars:
                return None
            ctx = tuple(sorted((*ctx, var)))
        st = self.evaluator(dbn, (var, space))(ctx)
        if is_model_improvement(r, st, self.params):
            return (lb, ub, None, list(ctx))
        return None

