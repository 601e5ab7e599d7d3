"""The model learner: perception, contingencies, DBNs and landmarks on schedule (ch. 4, Alg. 2).

:class:`ModelLearner` observes one step at a time (Algorithm 2 lines 2–5) and runs the batches of
lines 6–13 every ``Params.dbn_period`` / ``Params.landmark_period`` steps. A batch is computed as
a :class:`~.delta.Delta`, an ordered list of operations, and applied at step t + L
(``Params.batch_lag``); L = 0 is Algorithm 2 to the letter. Applying the same deltas at the same
steps gives the same knowledge, which is what lets the actor runtime reproduce this object.
This module holds the per-step work, reading and state; the batches are
:mod:`.learner_batch`'s and the operations that change the knowledge :mod:`.learner_ops`'s.
"""

from __future__ import annotations

import copy
from collections import deque
from collections.abc import Mapping
from typing import Any

import numpy as np

from .contingency import PairStatistics, WindowLearner
from .dbn import CHANGE, DBN, ModelStats, model_stats
from .delta import Delta
from .learner_batch import BatchLearning
from .learner_ops import KnowledgeOps
from .params import Params
from .perception import Percept, Perception
from .variables import Event, Kind, VariableTable

CHANGE_MINUS, CHANGE_ZERO, CHANGE_PLUS = 0, 1, 2


class ModelLearner(BatchLearning, KnowledgeOps):
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
