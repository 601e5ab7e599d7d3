"""The model learner: perception, contingencies, DBNs and landmarks on schedule (ch. 4, Alg. 2).

:class:`ModelLearner` observes one step at a time (Algorithm 2 lines 2–5) and runs the batches of
lines 6–13 every ``Params.dbn_period`` / ``Params.landmark_period`` steps. A batch is computed as
a :class:`~.delta.Delta`, an ordered list of operations, and applied at step t + L
(``Params.batch_lag``); L = 0 is Algorithm 2 to the letter. Applying the same deltas at the same
steps gives the same knowledge, which is what lets the actor runtime reproduce this object.
"""

from __future__ import annotations

import copy
from collections import deque
from collections.abc import Mapping
from typing import Any

import numpy as np

from .context import is_model_improvement, update_contexts_many
from .contingency import PairStatistics, WindowLearner
from .dbn import CHANGE, DBN, MAGNITUDE, ModelStats, context_cells, counts_by_cell, model_stats
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
from .params import Params
from .perception import EventIndex, Percept, Perception
from .quantity import Landmark, QuantitySpace
from .variables import Event, Kind, VariableTable

CHANGE_MINUS, CHANGE_ZERO, CHANGE_PLUS = 0, 1, 2


# Margin between a fast bound/estimate and the exact value (floating-point rounding only; the
# estimates differ from the exact values by far less).
_TOL = 1e-9


class ModelLearner:
    """QLAP's perception and model learning (ch. 3–4) as one deterministic object."""

    def __init__(self, variables: VariableTable | Any, params: Params | None = None) -> None:
        self.params = params or Params()
        self.table = variables if isinstance(variables, VariableTable) else \
            VariableTable.from_specs(variables)
        self.names = [v.name for v in self.table]
        self.perception = Perception(self.table, self.params)
        self.k: int = self.params.k_fixed or self.params.k_initial
        self.k_learned = self.params.k_fixed is not None
        self.pairs = PairStatistics(self.perception.events, self.k)
        motors = [v.index for v in self.table if v.kind is Kind.MOTOR]
        self.window = WindowLearner(motors, self.params.event_history)
        self.dbns: dict[int, DBN] = {}
        self.next_id = 0
        self.step = -1
        self.version = 0
        self.pending_deltas: deque[Delta] = deque()
        self.applied: list[dict] = []          # short log of applied deltas (for knowledge())
        self.applied_count = 0                  # deltas applied so far (consumers poll it)
        self.splits: list[tuple[int, int]] = []  # (var, split) of landmarks added, for consumers
        # Set by the acting side (ch. 5–6); empty while only the learner runs.
        self.reliable_actions: set[tuple[int, int]] = set()
        # The actor runtime drives batches itself (auto_batches False); the executor's copy
        # is a follower: it keeps the DBN statistics but not the pair statistics of DBN search.
        self.auto_batches = True
        self.follower = False
        self.keeps_pairs = False
        """A follower that keeps the pair and window statistics of DBN search all the same:
        the embedded placement's, whose batch copies the learning actors take
        (docs/decisions.md 72)."""
        self._expiry: deque[tuple[int, DBN, list]] = deque()
        self._mag_active: dict[int, list[DBN]] = {}
        self._reindex()

    # ------------------------------------------------------------------------------------------
    # per-step work (Algorithm 2 lines 2–5)
    # ------------------------------------------------------------------------------------------
    def observe(self, step: int, obs: Mapping[str, float], discontinuity: bool = False) -> Percept:
        """Observe the real values of step ``step`` (motor values included) and learn.

        ``discontinuity``: the world jumped since the previous step (``World.discontinuity``: a
        replaced block, a new trial); the histories break there (:meth:`break_history`).
        Raises :class:`~.perception.InvalidObservation` (a ValueError naming the variable) for
        NaN/infinite values or unknown names, leaving the learner unchanged.
        """
        return self._observe(step, self.perception.vector(obs), discontinuity)

    def break_history(self) -> None:
        """A discontinuity in the world: no derivative, event, soon-window or activation spans
        it. The perception forgets its previous values; the antecedent occurrences and DBN
        activations still waiting for their window are dropped, neither successes nor failures,
        as between two trials (a replaced block is not block motion; docs/decisions.md)."""
        self.perception.break_history()
        self._drop_open_windows()

    @property
    def pairs_kept(self) -> bool:
        """Whether each step updates the pair and window statistics (:attr:`keeps_pairs`)."""
        return not self.follower or self.keeps_pairs

    def _drop_open_windows(self) -> None:
        if self.pairs_kept:
            self.pairs.drop_open_windows()
            self.window.drop_open_episodes()
        for entry in (e for _, _, e in self._expiry):
            entry[2] = True
        self._expiry.clear()
        for dbn in self.dbns.values():
            dbn.pending.clear()
        self._mag_active.clear()

    def observe_percept(self, p: Percept) -> Percept:
        """Learn from a percept computed elsewhere (the perception actor) with the same
        landmarks: Algorithm 2 lines 4–5 only; batches are the caller's business (the actor
        runtime computes them with :meth:`compute_parts` and applies their deltas)."""
        if p.step <= self.step:
            raise ValueError(f"steps must increase: got {p.step} after {self.step}")
        if p.discontinuity:
            self._drop_open_windows()
        return self._learn_step(self.perception.ingest(p))

    def observe_own(self, p: Percept) -> Percept:
        """Learn from a percept this learner's own perception has just computed and remembered
        (``self.perception.perceive``; the perception actor hosted beside the executor
        perceives with it, docs/decisions.md 83): Algorithm 2 lines 4–5 exactly as
        :meth:`observe` does them after perceiving, without ingesting the percept again."""
        if p.step <= self.step:
            raise ValueError(f"steps must increase: got {p.step} after {self.step}")
        return self._learn_own(p)

    def _learn_own(self, p: Percept) -> Percept:
        """Lines 4–5 on a percept this learner's perception computed and remembered."""
        if p.discontinuity:
            self._drop_open_windows()
        self._own = p
        try:
            return self._learn_step(p)
        finally:
            self._own = None

    def _learn_step(self, p: Percept) -> Percept:
        self.step = p.step
        if self.pairs_kept:
            self.pairs.update(p.step, p.event_ids)
            if not self.k_learned:
                self._update_window(p)
        if self._index_dirty:
            self._reindex()
        self._update_dbns(p)
        return p

    def _observe(self, step: int, x: np.ndarray, discontinuity: bool = False) -> Percept:
        if step <= self.step:
            raise ValueError(f"steps must increase: got {step} after {self.step}")
        p = self._learn_own(self.perception.perceive(step, x, copy=False,
                                                     discontinuity=discontinuity))
        if not self.auto_batches:
            return p
        while self.pending_deltas and self.pending_deltas[0].apply_at <= step:
            self.apply_delta(self.pending_deltas.popleft())
        if step > 0 and step % self.params.dbn_period == 0:
            delta = self.compute_batch(step)
            if self.params.batch_lag == 0:
                self.apply_delta(delta)
            else:
                self.pending_deltas.append(delta)
        return p

    _batch_work: ModelLearner | None = None

    def take_batch(self) -> ModelLearner | None:
        """The learner of the batch computed at the latest step, with the batch's operations
        applied, for the plan compilation that follows it (Algorithm 2 line 15); once, None
        when no batch was computed since the last call. With a lag it is the batch's own copy,
        else :meth:`planning_view` of this learner."""
        work, self._batch_work = self._batch_work, None
        return self.planning_view() if work is self else work

    def planning_view(self) -> ModelLearner:
        """This learner as a plan compilation on the same step sees it. A compilation reads
        the learner and writes only its ``splits`` (taken) and its DBNs' ``is_plan`` flags:
        those are the view's own, all else is shared — no copy of histories and statistics
        (a deep copy cost 71 ms a batch at 60,000 core steps, 9% of the sync loop)."""
        view = copy.copy(self)
        view.splits = list(self.splits)
        view.dbns = {i: copy.copy(d) for i, d in self.dbns.items()}
        return view

    def _update_window(self, p: Percept) -> None:
        motor_events = [(e.var, int(i)) for e, i in zip(p.events, p.event_ids, strict=True)
                        if self.table[e.var].kind is Kind.MOTOR]
        cons = [(e.var, int(i) if e.value != CHANGE_ZERO else -1)
                for e, i in zip(p.events, p.event_ids, strict=True)
                if self.table[e.var].kind is Kind.CHANGE]
        if motor_events or cons:
            self.window.update(p.step, motor_events, cons)

    def _update_dbns(self, p: Percept) -> None:
        t = p.step
        # Change DBNs: expire windows that closed without the consequent (failure).
        exp = self._expiry
        while exp and exp[0][0] <= t:
            _, dbn, entry = exp.popleft()
            if not entry[2]:
                entry[2] = True
                dbn.pending.remove(entry)
                self._resolve(dbn, entry[1], False)
        # Activations by antecedent events, then consequents (soon includes t itself, eq. 4.2).
        if p is self._own:
            self._remember_q(p)
        for e in p.events:
            for dbn in self._by_antecedent.get(e, ()):
                entry = [t, p.x, False]
                dbn.pending.append(entry)
                exp.append((t + self.k, dbn, entry))
        for e in p.events:
            for dbn in self._by_consequent.get((e.var, e.value), ()):
                for entry in dbn.pending:
                    entry[2] = True
                    self._resolve(dbn, entry[1], True)
                dbn.pending.clear()
        if self._mag_by_var:
            self._update_magnitude_dbns(p)

    def _update_magnitude_dbns(self, p: Percept) -> None:
        """§4.5: r± activated when Ẏ → [±] with Y on the near side; resolved on reach or stop."""
        q = p.q.tolist()                      # Python ints: the same tests, faster to read
        for yvar, active in list(self._mag_active.items()):
            dvar = self._dot_of[yvar]
            keep = []
            for dbn in active:
                y = dbn.consequent.value
                d = dbn.consequent.direction
                want = CHANGE_PLUS if d > 0 else CHANGE_MINUS
                if q[yvar] == y:
                    self._resolve_mag(dbn, True)
                elif q[dvar] != want or (q[yvar] - y) * d > 0 or q[yvar] < 0:
                    self._resolve_mag(dbn, False)
                else:
                    keep.append(dbn)
            if keep:
                self._mag_active[yvar] = keep
            else:
                del self._mag_active[yvar]
        for e in p.events:
            yvar = self.table[e.var].source
            if yvar < 0 or e.value == CHANGE_ZERO or yvar not in self._mag_by_var:
                continue
            d = 1 if e.value == CHANGE_PLUS else -1
            cur = q[yvar]
            if cur < 0:
                continue
            for dbn in self._mag_by_var[yvar]:
                if dbn.consequent.direction == d and (dbn.consequent.value - cur) * d > 0 \
                        and not dbn.pending:
                    dbn.pending.append([p.step, p.x, False])
                    self._mag_active.setdefault(yvar, []).append(dbn)

    def _resolve_mag(self, dbn: DBN, success: bool) -> None:
        entry = dbn.pending.pop()
        self._resolve(dbn, entry[1], success)

    def _resolve(self, dbn: DBN, x: np.ndarray, success: bool) -> None:
        cell = self._cell_of(dbn, x)
        dbn.record(x, success, cell)

    _own: Percept | None = None
    _Q_HORIZON = 64

    def _remember_q(self, p: Percept) -> None:
        """Keep the qualitative values of the step's real vector ``p.x`` (as perceived here,
        with the current landmarks) for :meth:`_cell_of`, which reads the context values of
        the activations started at this step when they resolve: ``p.q[v]`` is
        :meth:`value_of` ``(v, p.x[v])`` while the landmarks are these. Kept for
        ``_Q_HORIZON`` steps (an activation resolved later is quantized again)."""
        reg = self.__dict__.get("_x_q")
        if reg is None:
            reg = self._x_q = {}
            self._x_q_order: deque[tuple[int, int]] = deque()
        order = self._x_q_order
        while order and order[0][0] < p.step - self._Q_HORIZON:
            reg.pop(order.popleft()[1], None)
        reg[id(p.x)] = (p.x, p.q.tolist(), self.perception.landmarks_version)
        order.append((p.step, id(p.x)))

    def _cell_of(self, dbn: DBN, x: np.ndarray) -> int:
        if not dbn.context:
            return 0
        reg = self.__dict__.get("_x_q")
        hit = reg.get(id(x)) if reg is not None else None
        if hit is not None and hit[0] is x and hit[2] == self.perception.landmarks_version:
            q_list, sizes = hit[1], self.perception.events.sizes
            cell = 0
            for v in dbn.context:
                q = q_list[v]
                if q < 0:
                    return -1
                cell = cell * sizes[v] + q
            return cell
        cell = 0
        for v in dbn.context:
            q = self.value_of(v, x[v])
            if q < 0:
                return -1
            cell = cell * self._size(v) + q
        return cell

    def value_of(self, var: int, value: float) -> int:
        """The qualitative value of real value ``value`` of ``var`` (−1 for NaN)."""
        value = float(value)
        if value != value:                                  # NaN
            return -1
        if self.table[var].kind is Kind.NOMINAL:
            return int(value)
        return self.perception.spaces[var].value_of(value)

    def _size(self, var: int) -> int:
        return self.perception.events.sizes[var]

    # ------------------------------------------------------------------------------------------
    # indexes
    # ------------------------------------------------------------------------------------------
    def _reindex(self) -> None:
        self._by_antecedent: dict[Event, list[DBN]] = {}
        self._by_consequent: dict[tuple[int, int], list[DBN]] = {}
        self._mag_by_var: dict[int, list[DBN]] = {}
        self._dot_of = {v.source: v.index for v in self.table if v.kind is Kind.CHANGE}
        for dbn in self.dbns.values():
            if dbn.kind == CHANGE:
                self._by_antecedent.setdefault(dbn.antecedent, []).append(dbn)
                self._by_consequent.setdefault(
                    (dbn.consequent.var, dbn.consequent.value), []).append(dbn)
            else:
                self._mag_by_var.setdefault(dbn.consequent.var, []).append(dbn)
        self._pairs_of = {(d.antecedent, d.consequent) for d in self.dbns.values()}
        self._index_dirty = False

    _index_dirty = False

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
            return copy.deepcopy(self, memo)
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
            key = (dbn.total, dbn.context, tuple(cands), signature((*cands, *dbn.context)))
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
        answers = update_contexts_many(problems, sizes, self.params)
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
                    r = self.evaluator(dbn)(dbn.context)
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

    # ------------------------------------------------------------------------------------------
    # applying operations (shared by the batch and by delayed deltas)
    # ------------------------------------------------------------------------------------------
    def _apply_op(self, op: Op) -> None:
        match op:
            case Refresh():
                self._refresh_reliability()
                return
            case SetK(k=k):
                self.k = int(k)
                self.k_learned = True
                self.pairs.k = self.k
                self.pairs.reset(self.perception.events)
            case AddDBN(kind=dkind, antecedent=e1, consequent=e2, context=ctx):
                self._add_dbn(dkind, e1, e2, ctx)
            case SetContext(dbn_id=dbn_id, context=ctx):
                dbn = self.dbns.get(int(dbn_id))
                if dbn is not None:
                    dbn.context = ctx
                    self._recount(dbn)
            case DeleteDBN(dbn_id=dbn_id):
                self._delete(int(dbn_id))
            case AddLandmark(var=var, lb=lb, ub=ub, source=source, step=step, dbn_id=dbn_id,
                             antecedent=ante, context=ctx):
                self._add_landmark(int(var), Landmark(float(lb), float(ub), int(step), source),
                                   dbn_id, ante, ctx)
            case _:
                raise ValueError(f"unknown delta operation {op!r}")
        # The event indexes are only read per step: rebuilt once, before the next step. The set
        # of (antecedent, consequent) pairs is kept exact after every operation (add_dbn adds to
        # it; a landmark may remap events and a deletion may leave a duplicate's pair).
        if isinstance(op, AddLandmark | DeleteDBN):
            self._pairs_of = {(d.antecedent, d.consequent) for d in self.dbns.values()}
        self._index_dirty = True

    def _add_dbn(self, kind: str, e1: Event, e2: Event, ctx: tuple[int, ...]) -> DBN | None:
        if (e1, e2) in self._pairs_of:
            return None
        dbn = DBN(self.next_id, kind, e1, e2, ctx, max(self.step, 0), len(self.table),
                  self.params.stored_activations)
        self.next_id += 1
        self._recount(dbn)
        self.dbns[dbn.id] = dbn
        self._pairs_of.add((e1, e2))
        return dbn

    def _delete(self, dbn_id: int) -> None:
        dbn = self.dbns.pop(dbn_id, None)
        if dbn is None:
            return
        self._pairs_of.discard((dbn.antecedent, dbn.consequent))
        for entry in dbn.pending:
            entry[2] = True
        dbn.pending.clear()
        self._expiry = deque(x for x in self._expiry if x[1] is not dbn)
        for yvar, active in list(self._mag_active.items()):
            if dbn in active:
                active.remove(dbn)
                if not active:
                    del self._mag_active[yvar]

    def _recount(self, dbn: DBN) -> None:
        """Recompute the CPT from the stored activations (context or landmarks changed)."""
        sizes = [self._size(v) for v in dbn.context]
        n_cells = int(np.prod(sizes)) if sizes else 1
        X, ok = dbn.stored()
        if dbn.context:
            cells = context_cells([self.perception.quantize_var(v, X[:, v])
                                   for v in dbn.context], sizes)
        else:
            cells = np.zeros(len(ok), dtype=np.int64)
        dbn.cpt_s, dbn.cpt_f = counts_by_cell(cells, ok, n_cells)

    def _add_landmark(self, var: int, lm: Landmark, dbn_id: int | None, ante: Event | None,
                      ctx: tuple[int, ...] | None) -> None:
        space = self.perception.spaces[var]
        if space.interval_of_range(lm.lb, lm.ub) is None and space.landmarks:
            return                                  # overlaps since computed: skip, deterministic
        old_index = self.perception.events
        split = self.perception.add_landmark(var, lm)
        self.splits.append((var, split))
        new_index = self.perception.events
        # How landmarks change DBNs (§4.4.1): remap events on var, refresh CPTs.
        for d_id in sorted(self.dbns):
            dbn = self.dbns[d_id]
            if dbn.kind != CHANGE:
                if var in dbn.context:
                    self._recount(dbn)
                continue
            a = dbn.antecedent
            if a.var == var:
                if d_id == dbn_id and ante is not None:
                    dbn.antecedent = Event(*ante)
                elif a.value > split:
                    dbn.antecedent = Event(var, a.value + 2, a.direction)
                elif a.value == split:
                    dbn.antecedent = self._choose_half(dbn, var, split, a.direction)
            if d_id == dbn_id and ctx is not None:
                dbn.context = tuple(ctx)
            if var in dbn.context or a.var == var or d_id == dbn_id:
                self._recount(dbn)
        # Drop change DBNs that became duplicates; a DBN that is a plan is the one kept.
        seen: set[tuple[Event, Event]] = set()
        for d_id in sorted(self.dbns, key=lambda i: (not self.dbns[i].is_plan, i)):
            dbn = self.dbns[d_id]
            key = (dbn.antecedent, dbn.consequent)
            if key in seen:
                self._delete(d_id)
            seen.add(key)
        if self.table[var].kind is Kind.MAGNITUDE:
            self._rebuild_magnitude_dbns(var, split)
        self._remap_pairs(old_index, new_index, var, split)
        if not self.k_learned:
            self.window = WindowLearner(self.window.motor_vars, self.params.event_history)

    def _choose_half(self, dbn: DBN, var: int, split: int, direction: int) -> Event:
        """The half of a split antecedent interval with more successes (§4.4.1 step 4)."""
        X, ok = dbn.stored()
        qv = self.perception.quantize_var(var, X[:, var])
        lo = int(ok[qv == split].sum())
        hi = int(ok[qv == split + 2].sum())
        return Event(var, split + 2 if hi > lo else split, direction)

    def _rebuild_magnitude_dbns(self, var: int, split: int) -> None:
        """§4.5: two DBNs per value of a magnitude variable; remapped after a new landmark."""
        old = {(d.consequent.value, d.consequent.direction): d
               for d in self.dbns.values() if d.kind == MAGNITUDE and d.consequent.var == var}
        for (val, d), dbn in sorted(old.items(), key=lambda kv: kv[1].id):
            if val == split:
                self._delete(dbn.id)
            elif val > split:
                dbn.consequent = Event(var, val + 2, d)
        size = self.perception.spaces[var].size
        dot = self._dot_of[var]
        existing = {(d.consequent.value, d.consequent.direction)
                    for d in self.dbns.values() if d.kind == MAGNITUDE and d.consequent.var == var}
        for val in range(size):
            for d, ante_val in ((1, CHANGE_PLUS), (-1, CHANGE_MINUS)):
                if (d > 0 and val == 0) or (d < 0 and val == size - 1):
                    continue                                  # unreachable from that side
                if (val, d) not in existing:
                    self._add_dbn(MAGNITUDE, Event(dot, ante_val, 0), Event(var, val, d), ())
        for dbn in self.dbns.values():
            if dbn.kind == MAGNITUDE and dbn.consequent.var == var:
                self._recount(dbn)

    def _remap_pairs(self, old: EventIndex, new: EventIndex, var: int, split: int) -> None:
        """Keep the pair statistics of unaffected events across a new landmark."""
        emap = np.full(old.n_events, -1, dtype=np.int64)
        for eid in range(old.n_events):
            e = old.decode(eid)
            if e.var == var:
                if e.value == split:
                    continue
                if e.value > split:
                    e = Event(var, e.value + 2, e.direction)
            emap[eid] = new.encode(e)
        cmap = np.full(old.n_cons, -1, dtype=np.int64)
        for c in range(old.n_cons):
            cmap[c] = new.cons_of_event[emap[old.event_of_cons[c]]]
        ps = self.pairs
        keep_e = np.flatnonzero(emap >= 0)
        occ = np.zeros(new.n_events, dtype=np.int64)
        occ[emap[keep_e]] = ps.occurrences[keep_e]
        sg = np.zeros((new.n_events, new.n_cons), dtype=np.int64)
        sg[np.ix_(emap[keep_e], cmap)] = ps.soon_given[np.ix_(keep_e, np.arange(old.n_cons))]
        ss = np.zeros(new.n_cons, dtype=np.int64)
        ss[cmap] = ps.soon_steps
        lc = np.full(new.n_cons, -(10**12), dtype=np.int64)
        lc[cmap] = ps.last_cons
        wids = emap[ps.win_ids]
        keep = wids >= 0
        ps.index = new
        ps.occurrences, ps.soon_given, ps.soon_steps, ps.last_cons = occ, sg, ss, lc
        ps.win_t, ps.win_ids = ps.win_t[keep], wids[keep]

    # ------------------------------------------------------------------------------------------
    # reading the knowledge
    # ------------------------------------------------------------------------------------------
    def value_label(self, var: int, value: int) -> str:
        v = self.table[var]
        if v.kind in (Kind.NOMINAL, Kind.CHANGE):
            return v.values[value] if v.kind is Kind.NOMINAL else f"[{v.values[value]}]"
        return self.perception.spaces[var].label(value)

    def dbn_label(self, dbn: DBN) -> str:
        return dbn.label(self.names, self.value_label)

    def knowledge(self) -> dict[str, Any]:
        """A JSON-ready summary of what has been learned (landmarks, k, DBNs)."""
        lms = {}
        for v in self.table.of_kind(Kind.MOTOR, Kind.MAGNITUDE):
            lms[v.name] = [dict(m, label=lm.label()) for m, lm in
                           zip(self.perception.spaces[v.index].to_json(),
                               self.perception.spaces[v.index].landmarks, strict=True)]
        dbns = []
        for dbn_id in sorted(self.dbns):
            d = self.dbns[dbn_id]
            st = model_stats(d.cpt_s, d.cpt_f, len(d.context), self.params)
            dbns.append({
                "id": d.id, "kind": d.kind, "label": self.dbn_label(d),
                "antecedent": self._event_json(d.antecedent),
                "consequent": self._event_json(d.consequent),
                "context": [self.names[v] for v in d.context],
                "brel": st.brel, "entropy": round(st.entropy, 12),
                "sufficiently_reliable": d.ever_reliable, "plan": d.is_plan,
                "activations": d.total, "created": d.created})
        res = {v.name: self.perception.resolution(v.index)
               for v in self.table.of_kind(Kind.MOTOR, Kind.MAGNITUDE)}
        return {"step": self.step, "k": self.k, "k_learned": self.k_learned,
                "landmarks": lms, "resolution": res, "dbns": dbns}

    def _event_json(self, e: Event) -> dict[str, Any]:
        return {"variable": self.names[e.var], "value": self.value_label(e.var, e.value),
                "index": e.value, "direction": e.direction}

    def find_dbns(self, antecedent_var: str | None = None, consequent_var: str | None = None,
                  kind: str = CHANGE) -> list[DBN]:
        """DBNs filtered by variable names (for tests and tools)."""
        out = []
        for d in self.dbns.values():
            if d.kind != kind:
                continue
            if antecedent_var is not None and self.names[d.antecedent.var] != antecedent_var:
                continue
            if consequent_var is not None and self.names[d.consequent.var] != consequent_var:
                continue
            out.append(d)
        return sorted(out, key=lambda d: d.id)

    def stats(self, dbn: DBN) -> ModelStats:
        return model_stats(dbn.cpt_s, dbn.cpt_f, len(dbn.context), self.params)

    # ------------------------------------------------------------------------------------------
    # state (checkpoints, snapshots): the bookkeeping that no public field holds
    # ------------------------------------------------------------------------------------------
    def to_state(self) -> dict[str, Any]:
        """The open DBN activations as JSON: ``expiry``, the change DBNs' activations waiting
        for their window, in expiry order, as ``[expire_step, dbn_id, i]`` (``i``: the
        activation's index in the DBN's ``pending``); ``mag_active``, the active magnitude DBNs
        per variable as ``[var, [dbn_id, ...]]``. Every other part of the learner's state is in
        public fields (``qlap_runtime/qlap/checkpoint/`` writes them); :meth:`load_state` is
        the inverse."""
        pos = {d.id: {id(e): i for i, e in enumerate(d.pending)} for d in self.dbns.values()}
        return {"expiry": [[t, d.id, pos[d.id][id(e)]] for t, d, e in self._expiry
                           if d.id in pos and id(e) in pos[d.id]],
                "mag_active": [[y, [d.id for d in ds]] for y, ds in self._mag_active.items()]}

    def load_state(self, state: Mapping[str, Any]) -> None:
        """Restore :meth:`to_state`'s open activations once ``dbns`` hold the saved DBNs (with
        their ``pending`` activations), and rebuild the indexes derived from the DBNs."""
        self._expiry = deque((int(t), self.dbns[int(i)], self.dbns[int(i)].pending[int(j)])
                             for t, i, j in state["expiry"])
        self._mag_active = {int(y): [self.dbns[int(i)] for i in ids]
                            for y, ids in state["mag_active"]}
        self._reindex()
