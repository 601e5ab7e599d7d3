"""Applying the learner's operations: DBNs added and deleted, contexts set, landmarks added.

:class:`KnowledgeOps` is the part of :class:`~.learner.ModelLearner` that changes its
knowledge, shared by the batch that computes an operation and by a delayed delta applied at
t + L: a new landmark renumbers the qualitative values of its variable (§4.4), so the events,
the DBNs that use them (the three ways of §4.4.1), the magnitude DBNs (§4.5) and the pair
statistics follow it.
"""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING

import numpy as np

from .contingency import WindowLearner
from .dbn import CHANGE, DBN, MAGNITUDE, context_cells, counts_by_cell
from .delta import AddDBN, AddLandmark, DeleteDBN, Op, Refresh, SetContext, SetK
from .perception import EventIndex
from .quantity import Landmark
from .variables import Event, Kind

if TYPE_CHECKING:
    from collections import deque

    from .contingency import PairStatistics, WindowLearner
    from .params import Params
    from .perception import Perception
    from .variables import VariableTable

CHANGE_MINUS, CHANGE_PLUS = 0, 2


class KnowledgeOps:
    """Operations on the learner's knowledge (a mixin of :class:`~.learner.ModelLearner`)."""

    if TYPE_CHECKING:   # the learner's fields and methods this part uses (ModelLearner's __init__)
        dbns: dict[int, DBN]
        next_id: int
        pairs: PairStatistics
        params: Params
        perception: Perception
        splits: list[tuple[int, int]]
        step: int
        table: VariableTable
        window: WindowLearner
        _expiry: deque[tuple[int, DBN, list]]
        _mag_active: dict[int, list[DBN]]

        def _refresh_reliability(self) -> None: ...
        def _size(self, var: int) -> int: ...

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
        # The pairs' set under the new numbering before any is added: with the old one the
        # new landmark's value and the upper half would find their old numbers' pairs there
        # and get no DBN (§4.5: two for each qualitative value).
        self._pairs_of = {(dbn.antecedent, dbn.consequent) for dbn in self.dbns.values()}
        size = self.perception.spaces[var].size
        dot = self._dot_of[var]
        for val in range(size):
            for d, ante_val in ((1, CHANGE_PLUS), (-1, CHANGE_MINUS)):
                if (d > 0 and val == 0) or (d < 0 and val == size - 1):
                    continue                                  # unreachable from that side
                # _add_dbn adds it unless its pair is there already (the DBN kept above).
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

