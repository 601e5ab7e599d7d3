"""Perception: raw values -> qualitative state and events (ch. 3, §3.1–3.2).

Each step, the real values of the world's variables (motors included) become a vector over the
agent's variables, with the direction of change of each magnitude computed here per second,
(ṽ(t) − ṽ(t−1)) / ``Params.step_seconds``, the reference's scale (Tables 8.7–8.10). Every
value is mapped to its qualitative value with the current landmarks (vectorised over all
variables), and events X → x are the variables whose value changed;
on magnitude variables they carry ↑ or ↓.

Bounded histories of real and qualitative values are kept for the landmark searches (§4.4,
§8.3): a ring of ``Params.event_history`` steps.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from .kernels import loaded_kernels
from .params import Params
from .quantity import Landmark, QuantitySpace
from .variables import Event, Kind, VariableTable

MAX_ABS_VALUE = 1e12
"""The largest magnitude a world's value may have: beyond it (±1e308, an exploded simulation)
an observation is rejected like a NaN (derivatives and landmarks would overflow)."""


_BY_COLUMN_ROWS = 2000
"""Rows from which :meth:`Perception.quantize_columns` searches column by column."""


class InvalidObservation(ValueError):
    """An observation with a NaN/infinite or huge value (|x| > :data:`MAX_ABS_VALUE`), an
    unknown variable or a bad nominal value."""


@dataclass(frozen=True)
class Percept:
    """The qualitative view of one step."""

    step: int
    """Agent step t."""
    x: np.ndarray
    """Real values by variable index (derivatives included); NaN where unavailable."""
    q: np.ndarray
    """Qualitative values by variable index; −1 where unavailable."""
    events: tuple[Event, ...]
    """Events X_t → x of this step (§3.2)."""
    event_ids: np.ndarray
    """The same events as ids of the current :class:`EventIndex`."""
    discontinuity: bool = False
    """The world jumped at this step (a replaced block, a new trial): no derivative or event
    spans it, and the learners break their histories (docs/decisions.md)."""


def initial_motor_landmark(v, params: Params) -> Landmark:
    """Table 3.1: a motor starts with the landmark 0 (a range of half-width
    ``Params.motor_zero_band``). A motor whose range does not contain 0 in its interior (a
    Gymnasium action in [0, 1], core's u_UG) would never change qualitative value with it, so its
    initial landmark is the middle of its range (docs/decisions.md)."""
    b = params.motor_zero_band
    low = -np.inf if v.low is None else float(v.low)
    high = np.inf if v.high is None else float(v.high)
    if low < -b and b < high:
        return Landmark(-b, b)
    mid = 0.5 * (low + high)
    return Landmark(mid, mid)


class EventIndex:
    """Numbers every possible event given the current quantity spaces.

    A magnitude value has two events (↑ then ↓); any other value one. Consequent candidates
    (§4.1.2 exclusions 1–2: not on a magnitude, not to [0] of a change variable; motors are never
    consequents since the agent sets them) get a second, compact numbering.
    """

    def __init__(self, table: VariableTable, sizes: list[int]) -> None:
        self.table = table
        self.sizes = list(sizes)
        self.mult = np.array([2 if v.kind is Kind.MAGNITUDE else 1 for v in table], dtype=np.int64)
        counts = self.mult * np.array(self.sizes, dtype=np.int64)
        self.offset = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
        self.n_events = int(counts.sum())
        self.event_var = np.repeat(np.arange(len(table)), counts)
        cons = np.full(self.n_events, -1, dtype=np.int64)
        c = 0
        for v in table:
            if v.kind is Kind.CHANGE:
                vals = [0, 2]
            elif v.kind is Kind.NOMINAL:
                vals = list(range(self.sizes[v.index]))
            else:
                continue
            for val in vals:
                cons[self.offset[v.index] + val] = c
                c += 1
        self.cons_of_event = cons
        self.n_cons = c
        self.event_of_cons = np.flatnonzero(cons >= 0)

    def encode(self, e: Event) -> int:
        v = self.table[e.var]
        if not 0 <= e.value < self.sizes[e.var]:
            raise ValueError(f"value {e.value} outside Q({v.name}) of size {self.sizes[e.var]}")
        if v.kind is Kind.MAGNITUDE:
            if e.direction not in (1, -1):
                raise ValueError(f"event on magnitude {v.name} needs direction ±1")
            return int(self.offset[e.var] + 2 * e.value + (0 if e.direction > 0 else 1))
        return int(self.offset[e.var] + e.value)

    def decode(self, eid: int) -> Event:
        var = int(self.event_var[eid])
        rel = int(eid - self.offset[var])
        if self.mult[var] == 2:
            return Event(var, rel // 2, 1 if rel % 2 == 0 else -1)
        return Event(var, rel, 0)


class Perception:
    """Maps raw observations to qualitative states and events with the current landmarks."""

    def __init__(self, table: VariableTable, params: Params) -> None:
        self.table = table
        self.params = params
        n = len(table)
        self.spaces: list[QuantitySpace] = []
        for v in table:
            if v.kind is Kind.MOTOR:
                self.spaces.append(QuantitySpace([initial_motor_landmark(v, params)]))
            elif v.kind is Kind.CHANGE:
                b = params.derivative_zero_band
                self.spaces.append(QuantitySpace([Landmark(-b, b)]))
            else:
                self.spaces.append(QuantitySpace())
        self._names = [v.name for v in table]
        self._world_idx = np.array([v.index for v in table if v.kind is not Kind.CHANGE])
        self._world_names = [v.name for v in table if v.kind is not Kind.CHANGE]
        self._change_idx = np.array([v.index for v in table if v.kind is Kind.CHANGE], dtype=int)
        self._change_src = np.array([v.source for v in table if v.kind is Kind.CHANGE],
                                    dtype=int)
        self._nominal_idx = np.array([v.index for v in table if v.kind is Kind.NOMINAL],
                                     dtype=int)
        self._nominal_size = np.array([len(v.values) for v in table if v.kind is Kind.NOMINAL])
        self._ordered_idx = np.array([v.index for v in table if v.kind is not Kind.NOMINAL],
                                     dtype=int)
        self._ordered_pos = np.full(n, -1, dtype=np.int64)
        self._ordered_pos[self._ordered_idx] = np.arange(len(self._ordered_idx))
        self._change_and_nominal = np.array(
            [v.index for v in table if v.kind in (Kind.CHANGE, Kind.NOMINAL)], dtype=int)
        self._all_seen = False
        self._is_mag = np.array([v.kind is Kind.MAGNITUDE for v in table])
        self._dot_of = {v.source: v.index for v in table if v.kind is Kind.CHANGE}
        self._real_idx = np.array([v.index for v in table
                                   if v.kind in (Kind.MOTOR, Kind.MAGNITUDE)], dtype=int)
        self._rebuild()
        self.prev_x = np.full(n, np.nan)
        self.prev_q = np.full(n, -1, dtype=np.int64)
        # Bounded histories (§8.3): real values and qualitative values of the last H steps.
        cap = params.event_history
        self.hist_x = np.full((cap, n), np.nan)
        self.hist_q = np.full((cap, n), -1, dtype=np.int16)
        self.hist_len = 0
        self.hist_head = 0
        self.steps_seen = 0
        self._estimated = [v.index for v in table
                           if v.kind is Kind.MAGNITUDE and v.resolution is None]
        self.fixed_resolution: dict[int, float] = {}
        """The estimated resolutions, fixed at the end of babbling (:meth:`resolution`)."""

    # -- landmarks --------------------------------------------------------------------------
    def _rebuild(self) -> None:
        """Recompute the padded landmark matrices and the event index after a change."""
        idx = self._ordered_idx
        maxl = max([len(self.spaces[i].landmarks) for i in idx] + [1])
        self._lb = np.full((len(idx), maxl), np.inf)
        self._ub = np.full((len(idx), maxl), np.inf)
        self._nlm = np.zeros(len(idx), dtype=np.int64)
        for r, i in enumerate(idx):
            lms = self.spaces[i].landmarks
            self._nlm[r] = len(lms)
            for c, lm in enumerate(lms):
                self._lb[r, c] = lm.lb
                self._ub[r, c] = lm.ub
        self._rows = np.arange(len(idx))
        self._maxl = maxl
        self._lb_flat = self._lb.ravel()
        self._row_off = self._rows * maxl
        sizes = [len(v.values) if v.kind is Kind.NOMINAL else self.spaces[v.index].size
                 for v in self.table]
        self.events = EventIndex(self.table, sizes)
        # Derived caches: a counter of landmark changes (for caches kept by the learner) and
        # the per-history caches of history()/bin_size()/satisfied_fraction().
        self.landmarks_version = getattr(self, "landmarks_version", 0) + 1
        self._hist_cache: tuple | None = None

    def landmark_signature(self, variables: Iterable[int]) -> tuple:
        """What the qualitative values of ``variables`` are a function of (besides the real
        values): each one's landmarks, in order (a nominal variable has none; its values are
        its indices). Caches of results computed from these variables' qualitative values
        alone stay valid while the signature is equal (landmarks are immutable values), even
        when other variables gained landmarks (``landmarks_version`` changed)."""
        c = self.__dict__.get("_signature_cache")
        if c is None or c[0] != self.landmarks_version or c[1] is not self.spaces:
            # Each variable's landmarks as a tuple, kept until the landmarks change.
            c = self._signature_cache = (self.landmarks_version, self.spaces,
                                         [tuple(s.landmarks) for s in self.spaces])
        per_var = c[2]
        return tuple([per_var[v] for v in variables])

    def add_landmark(self, var: int, lm: Landmark) -> int:
        """Insert a landmark on a motor or magnitude variable; returns the split interval."""
        v = self.table[var]
        if v.kind not in (Kind.MOTOR, Kind.MAGNITUDE):
            raise ValueError(f"landmarks are learned only on motor and magnitude variables, "
                             f"not on {v.name} ({v.kind.value})")
        split = self.spaces[var].insert(lm)
        self._rebuild()
        # Keep the previous qualitative value consistent with the new numbering so that the
        # next step does not report spurious events.
        if not math.isnan(self.prev_x[var]):
            self.prev_q[var] = self.spaces[var].value_of(float(self.prev_x[var]))
        return split

    def _quantize_row(self, x: np.ndarray) -> np.ndarray:
        """Fast path of :meth:`quantize` for one finite-or-NaN row (the per-step work)."""
        xo = x[self._ordered_idx]
        j = (self._ub < xo[:, None]).sum(axis=1)
        lbj = self._lb_flat[self._row_off + np.minimum(j, self._maxl - 1)]
        q = np.empty(len(x), dtype=np.int64)
        q[self._ordered_idx] = 2 * j + ((j < self._nlm) & (xo >= lbj))
        if len(self._nominal_idx):
            q[self._nominal_idx] = x[self._nominal_idx]
        return q

    def quantize(self, x: np.ndarray) -> np.ndarray:
        """Qualitative values of a full real vector (or a matrix of them, rows = steps)."""
        x = np.asarray(x, dtype=float)
        single = x.ndim == 1
        X = x[None, :] if single else x
        Q = np.full(X.shape, -1, dtype=np.int64)
        xo = X[:, self._ordered_idx]                                   # (T, m)
        if len(X) > 8:
            # One searchsorted per variable: j = #{ub < x} as below (NaN: masked to −1).
            j = np.empty(xo.shape, dtype=np.int64)
            for r, nl in enumerate(self._nlm.tolist()):
                j[:, r] = np.searchsorted(self._ub[r, :nl], xo[:, r], side="left")
        else:
            j = (self._ub[None, :, :] < xo[:, :, None]).sum(axis=2)   # (T, m, L) -> (T, m)
        jc = np.minimum(j, self._lb.shape[1] - 1)
        lbj = self._lb[self._rows[None, :], jc]
        at = (j < self._nlm[None, :]) & (xo >= lbj)
        qo = 2 * j + at
        Q[:, self._ordered_idx] = np.where(np.isnan(xo), -1, qo)
        if len(self._nominal_idx):
            xn = X[:, self._nominal_idx]
            Q[:, self._nominal_idx] = np.where(np.isnan(xn), -1, np.nan_to_num(xn, nan=-1))
        return Q[0] if single else Q

    def quantize_columns(self, X: np.ndarray, cols) -> np.ndarray:
        """Qualitative values of the columns ``cols`` of a matrix of real vectors (rows = steps),
        as :meth:`quantize_var` gives them column by column; shape (rows, len(cols))."""
        X = np.asarray(X, dtype=float)
        cols = np.asarray(cols, dtype=np.int64)
        return self.quantize_values(X[:, cols], cols)

    def quantize_values(self, Xc: np.ndarray, cols) -> np.ndarray:
        """:meth:`quantize_columns` of a matrix whose column i holds values of variable
        ``cols[i]`` (``X[:, cols]``): the same values."""
        Xc = np.asarray(Xc, dtype=float)
        cols = np.asarray(cols, dtype=np.int64)
        out = np.empty((Xc.shape[0], len(cols)), dtype=np.int64)
        if not len(cols):
            return out
        pos = self._ordered_pos[cols]
        ordered = pos >= 0
        if ordered.any() and Xc.shape[0] > _BY_COLUMN_ROWS:
            # Many rows (a batch's activations at once): one binary search per column, j =
            # #{ub < x} as below (the upper bounds increase), the same values.
            for c in np.flatnonzero(ordered).tolist():
                r = int(pos[c])
                nl = int(self._nlm[r])
                xo = Xc[:, c]
                j = np.searchsorted(self._ub[r, :nl], xo, side="left")
                at = (j < nl) & (xo >= self._lb[r, np.minimum(j, self._maxl - 1)])
                out[:, c] = np.where(np.isnan(xo), -1, 2 * j + at)
        elif ordered.any():
            ro = pos[ordered]
            xo = Xc[:, ordered]
            nl = self._nlm[ro]
            ub = self._ub[ro]
            j = np.zeros(xo.shape, dtype=np.int64)
            for c in range(int(nl.max())):          # j = #{ub < x} (inf padding never counts)
                j += ub[:, c] < xo
            lbj = self._lb[ro[None, :], np.minimum(j, self._maxl - 1)]
            at = (j < nl) & (xo >= lbj)
            out[:, ordered] = np.where(np.isnan(xo), -1, 2 * j + at)
        if not ordered.all():
            xn = Xc[:, ~ordered]
            out[:, ~ordered] = np.where(np.isnan(xn), -1, np.nan_to_num(xn, nan=-1))
        return out

    def quantize_var(self, var: int, x: np.ndarray) -> np.ndarray:
        """Qualitative values of one variable's real values (nominal: the index itself)."""
        if self.table[var].kind is Kind.NOMINAL:
            x = np.asarray(x, dtype=float)
            return np.where(np.isnan(x), -1, np.nan_to_num(x, nan=-1)).astype(np.int64)
        return self.spaces[var].values_of(x)

    # -- the per-step work ------------------------------------------------------------------
    def vector(self, obs: Mapping[str, float]) -> np.ndarray:
        """Real values of the world variables (derivative slots left NaN), validated."""
        n = len(self.table)
        x = np.full(n, np.nan)
        if len(obs) == len(self._world_names):
            try:
                x[self._world_idx] = [obs[k] for k in self._world_names]
                return x
            except (KeyError, TypeError, ValueError):
                x[:] = np.nan
        by_name = self.table.by_name
        for name, value in obs.items():
            v = by_name.get(name)
            if v is None or v.kind is Kind.CHANGE:
                raise InvalidObservation(
                    f"unknown variable {name!r} in observation; known: "
                    f"{', '.join(self._world_names)}")
            try:
                x[v.index] = float(value)
            except (TypeError, ValueError):
                raise InvalidObservation(
                    f"variable {name!r} has non-numeric value {value!r}") from None
        return x

    def break_history(self) -> None:
        """A discontinuity: forget the previous values, so that no derivative or event spans
        the jump (the next step has no direction of change, the one after has no event)."""
        self.prev_x = np.full(len(self.table), np.nan)
        self.prev_q = np.full(len(self.table), -1, dtype=np.int64)
        self._all_seen = False

    def perceive(self, step: int, x: np.ndarray, copy: bool = True,
                 discontinuity: bool = False, remember: bool = True) -> Percept:
        """Turn the real vector of one step into qualitative values and events.

        ``discontinuity``: the world jumped since the previous step (:meth:`break_history`).
        ``remember=False`` (evaluation, learning off): the step becomes the previous one but
        does not enter the history, so nothing derived from it (bin sizes, resolutions,
        satisfied fractions) changes.
        Raises :class:`InvalidObservation` naming the variable if an available value is NaN or
        infinite, or a nominal value is not one of its indices; the state is then unchanged.
        """
        x = np.array(x, dtype=float) if copy else x
        finite = self._validate(step, x)
        if discontinuity:
            self.break_history()
        # Direction of change per second (§3.1, Tables 8.7–8.10).
        x[self._change_idx] = (x[self._change_src] - self.prev_x[self._change_src]) \
            / self.params.step_seconds
        k = loaded_kernels()
        if finite and self._all_seen:
            if k is not None:                   # the same values, compiled
                q = k.quantize_row(x, self._ordered_idx, self._ub, self._lb, self._nlm,
                                   self._nominal_idx)
            else:
                q = self._quantize_row(x)
        else:
            q = self.quantize(x)
            self._all_seen = bool((q >= 0).all())
        prev = self.prev_q
        if k is not None and prev.dtype == np.int64 and q.dtype == np.int64:
            ev, val, dirs, ids = k.events_of(q, prev, self._is_mag, self.events.offset,
                                             self.events.mult)
            events = tuple(map(Event, ev.tolist(), val.tolist(), dirs.tolist()))
        else:
            ev_vars = ((q != prev) & (q >= 0) & (prev >= 0)).nonzero()[0]
            if len(ev_vars):
                qv = q[ev_vars]
                down = self._is_mag[ev_vars] & (qv < prev[ev_vars])
                up = self._is_mag[ev_vars] & ~down
                ids = self.events.offset[ev_vars] + qv * self.events.mult[ev_vars] + down
                dirs = up.astype(np.int64) - down
                events = tuple(map(Event, ev_vars.tolist(), qv.tolist(), dirs.tolist()))
            else:
                ids = ev_vars
                events = ()
        if remember:
            self._remember(x, q)
        else:
            self.prev_x = x
            self.prev_q = q
        return Percept(step, x, q, events, ids, discontinuity)

    def _remember(self, x: np.ndarray, q: np.ndarray) -> None:
        """The step's values become the previous ones and enter the bounded history."""
        self.steps_seen += 1
        cap = self.hist_x.shape[0]
        self.hist_x[self.hist_head] = x
        self.hist_q[self.hist_head] = q
        self.hist_head = (self.hist_head + 1) % cap
        self.hist_len = min(self.hist_len + 1, cap)
        self.prev_x = x
        self.prev_q = q
        if self.steps_seen == self.params.babble_steps and self._estimated:
            self.fix_resolutions()

    def fix_resolutions(self) -> None:
        """Fix the estimated resolution of every magnitude that declares none at its value
        now, from the history of the babbling period (docs/decisions.md 77); one that never
        changed (estimate 0) stays estimated."""
        for var in self._estimated:
            r = 0.5 * self.bin_size(var)
            if r > 0:
                self.fixed_resolution[var] = r

    def ingest(self, p: Percept) -> Percept:
        """Record a percept computed by another perception with the same landmarks (the
        perception actor): the side effects of :meth:`perceive` without recomputing it.
        Returns the percept with event ids of this object's index."""
        x = np.array(p.x, dtype=float)
        q = np.array(p.q, dtype=np.int64)
        off, mult = self.events.offset, self.events.mult
        ids = np.array([off[e.var] + e.value * mult[e.var] + (1 if e.direction < 0 else 0)
                        for e in p.events], dtype=np.int64)
        if p.discontinuity:
            self.break_history()
        self._remember(x, q)
        return Percept(p.step, x, q, p.events, ids, p.discontinuity)

    def _validate(self, step: int, x: np.ndarray) -> bool:
        """Check one row; returns True when every world variable is present and finite."""
        world = x[self._world_idx]
        finite = bool((np.abs(world) <= MAX_ABS_VALUE).all())    # False on NaN, ±inf, huge
        if not finite:
            for i in self._world_idx[~(np.abs(world) <= MAX_ABS_VALUE)]:
                v = self.table[i]
                if np.isnan(x[i]) and step < v.available_from:
                    continue
                if np.isfinite(x[i]):
                    raise InvalidObservation(
                        f"variable {v.name!r} has value {float(x[i])!r} beyond "
                        f"±{MAX_ABS_VALUE:g} at step {step}")
                raise InvalidObservation(
                    f"variable {v.name!r} has non-finite value {float(x[i])!r} at step {step}")
        if len(self._nominal_idx) and not (x[self._nominal_idx]
                                           == self.prev_x[self._nominal_idx]).all():
            vals = x[self._nominal_idx]
            ok = np.isnan(vals) | ((vals == np.floor(vals)) & (vals >= 0)
                                   & (vals < self._nominal_size))
            if not ok.all():
                k = int(np.flatnonzero(~ok)[0])
                v = self.table[int(self._nominal_idx[k])]
                raise InvalidObservation(
                    f"nominal variable {v.name!r} has value {vals[k]!r}; expected an index in "
                    f"0..{len(v.values) - 1} ({', '.join(v.values)})")
        return finite

    def _history_cache(self) -> dict:
        """Per-history derived values, valid until the next perceive (or a new history)."""
        # The history arrays themselves are held and compared by identity (an id() alone could
        # name a new array at a freed one's address).
        key = (self.steps_seen, self.hist_len, self.hist_head)
        c = getattr(self, "_hist_cache", None)
        if c is None or c[0] != key or c[1] is not self.hist_x or c[2] is not self.hist_q:
            c = (key, self.hist_x, self.hist_q, {})
            self._hist_cache = c
        return c[3]

    def history(self) -> tuple[np.ndarray, np.ndarray]:
        """The stored real and qualitative histories in time order (oldest first).

        The arrays are shared between calls until the next step: treat them as read-only.
        """
        cache = self._history_cache()
        h = cache.get("history")
        if h is None:
            cap = self.hist_x.shape[0]
            if self.hist_len < cap:
                h = self.hist_x[: self.hist_len], self.hist_q[: self.hist_len]
            else:
                order = np.r_[self.hist_head:cap, 0:self.hist_head]
                h = self.hist_x[order], self.hist_q[order]
            cache["history"] = h
        return h

    def bin_size(self, var: int) -> float:
        """Bin size for ṽ: twice the average change (§4.4.2) over the stored history; a change
        counts when |ṽ(t) − ṽ(t−1)| > 0.001. 0 if it never changed. A magnitude's changes are
        read from its direction of change, which is undefined across a discontinuity, so a
        replaced block's jump is not a change."""
        cache = self._history_cache().setdefault("bin_size", {})
        b = cache.get(var)
        if b is None:
            hx, _ = self.history()
            dot = self._dot_of.get(var)
            if dot is not None:
                d = np.abs(hx[:, dot]) * self.params.step_seconds
                d = d[~np.isnan(d)]
            else:
                d = np.abs(np.diff(hx[:, var]))
            d = d[d > self.params.change_epsilon]
            b = cache[var] = 2.0 * float(d.mean()) if len(d) else 0.0
        return b

    def resolution(self, var: int) -> float:
        """The smallest distinction worth a landmark on ``var``: the world's declared
        resolution, else a motor's ``Params.motor_resolution`` of its range and a magnitude's
        average change per step (half the §4.4.2 bin), estimated on the history until the end
        of babbling and fixed from then on (:meth:`fix_resolutions`). No learned landmark is
        narrower, and none closer to another (docs/decisions.md 35, 77)."""
        v = self.table[var]
        if v.resolution is not None:
            return v.resolution
        if v.kind is Kind.MOTOR:
            return self.params.motor_resolution * (float(v.high) - float(v.low))
        fixed = self.fixed_resolution.get(var)
        return fixed if fixed is not None else 0.5 * self.bin_size(var)

    def satisfied_fraction(self) -> np.ndarray:
        """Fraction of the stored history's steps in which each consequent event was satisfied
        (§6.3 "sufficiently rare")."""
        _, hq = self.history()
        out = np.zeros(self.events.n_cons)
        if not len(hq):
            return out
        ev = self.events
        cons_e = ev.event_of_cons
        cons_var = ev.event_var[cons_e]
        # Consequents are on change and nominal variables (one event per value): the value is
        # the event's offset within its variable.
        cons_val = cons_e - ev.offset[cons_var]
        n = len(hq)
        for var in np.unique(cons_var).tolist():
            sel = np.flatnonzero(cons_var == var)
            col = hq[:, var].astype(np.int64)
            counts = np.bincount(col[col >= 0], minlength=int(cons_val[sel].max()) + 1)
            # Same value as np.mean(bool column): an exact integer count over n.
            out[sel] = counts[cons_val[sel]] / n
        return out

    # -- state (checkpoints, snapshots) -----------------------------------------------------
    def to_state(self) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        """The perception's state as (JSON object, arrays): the quantity spaces (the learned
        landmarks), the bounded history's position and the counters; the previous values and
        the histories as arrays (the live ones, not copies: write them before the next step).
        :meth:`load_state` is its inverse; docs/checkpoint.md describes the fields."""
        meta = {"spaces": [s.to_json() for s in self.spaces], "hist_len": self.hist_len,
                "hist_head": self.hist_head, "steps_seen": self.steps_seen,
                "all_seen": self._all_seen}
        if self.fixed_resolution:
            meta["fixed_resolution"] = [[v, r] for v, r in sorted(self.fixed_resolution.items())]
        arrays = {"prev_x": self.prev_x, "prev_q": self.prev_q, "hist_x": self.hist_x,
                  "hist_q": self.hist_q}
        return meta, arrays

    def load_state(self, meta: Mapping[str, Any], arrays: Mapping[str, np.ndarray]) -> None:
        """Restore :meth:`to_state`'s state into this perception (built for the same variable
        table); the landmark matrices and the event index are rebuilt from the spaces."""
        self.spaces = [QuantitySpace.from_json(s) for s in meta["spaces"]]
        self._rebuild()
        self.prev_x = arrays["prev_x"].astype(float)
        self.prev_q = arrays["prev_q"].astype(np.int64)
        self.hist_x = arrays["hist_x"].astype(float)
        self.hist_q = arrays["hist_q"].astype(np.int16)
        self.hist_len, self.hist_head = int(meta["hist_len"]), int(meta["hist_head"])
        self.steps_seen, self._all_seen = int(meta["steps_seen"]), bool(meta["all_seen"])
        self.fixed_resolution = {int(v): float(r) for v, r in meta.get("fixed_resolution", [])}
