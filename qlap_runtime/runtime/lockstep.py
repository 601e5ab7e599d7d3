"""Lockstep bookkeeping: which knowledge deltas must be applied at which step
(docs/architecture.md §2).

A batch of Algorithm 2 starts at every step t that is a positive multiple of
``Params.dbn_period`` (lines 6–9, by the contingency actor) and, when t is a multiple of
``Params.landmark_period``, also lines 10–13 (by the landmarks actor). Each produces one delta,
possibly empty, computed from the data up to t and applied by every consumer at the boundary of
step t + L, in the order (computed_at, dbn before landmarks). Because the schedule is known in
advance, a consumer knows exactly which deltas it must hold before it may pass step t + L; if
one has not arrived it waits, and counts the wait.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..qlap.delta import KINDS, Delta, batch_kinds, delta_version
from ..qlap.params import Params

__all__ = ["KINDS", "DeltaBook", "batch_kinds", "delta_version"]



@dataclass
class DeltaBook:
    """Deltas received but not yet applied, and the schedule of those due.

    ``due_keys(step)`` lists every delta whose apply step lies in (last step asked, step] and
    whose batch step was not skipped (a rejected observation skips its batch, as in the
    synchronous loop); they are applied in (computed_at, kind) order.
    """

    params: Params
    received: dict[tuple[int, str], Delta] = field(default_factory=dict)
    skipped: set[int] = field(default_factory=set)
    """Steps whose observation was rejected (no batch was computed there)."""
    last: int = -1
    """The last step whose due deltas were handed out."""
    applied_versions: int = 0
    waits: int = 0
    """How many times a consumer had to wait for a due delta."""

    def add(self, kind: str, delta: Delta) -> None:
        if kind not in KINDS:
            raise ValueError(f"unknown delta kind {kind!r}")
        self.received[(delta.computed_at, kind)] = delta

    def due_keys(self, step: int) -> list[tuple[int, str]]:
        """(computed_at, kind) of the deltas to apply at the boundary of ``step``: those of
        the batch steps (the positive multiples of ``dbn_period``) in (last step asked,
        step] − L, visited directly (the range spans every step since the last delta)."""
        lag, period = self.params.batch_lag, self.params.dbn_period
        lo, hi = max(self.last + 1 - lag, 1), step - lag
        out = []
        for computed in range(-(-lo // period) * period, hi + 1, period):
            if computed not in self.skipped:
                out += [(computed, kind) for kind in batch_kinds(self.params, computed)]
        return out

    def none_due(self, step: int) -> bool:
        """True when no delta of the schedule applies in (last step asked, step]: most steps,
        decided without listing them (every batch step is a positive multiple of
        ``dbn_period``)."""
        lag, period = self.params.batch_lag, self.params.dbn_period
        lo, hi = max(self.last + 1 - lag, 1), step - lag
        return hi < lo or -(-lo // period) * period > hi

    def ready(self, step: int) -> bool:
        return all(k in self.received for k in self.due_keys(step))

    def missing(self, step: int) -> list[tuple[int, str]]:
        return [k for k in self.due_keys(step) if k not in self.received]

    def pop_due(self, step: int) -> list[Delta]:
        """The deltas due at ``step`` in apply order; all must have arrived."""
        out = [self.received.pop(key) for key in self.due_keys(step)]
        self.applied_versions += len(out)
        self.last = step
        return out

    def arrived_prefix(self, step: int) -> list[Delta]:
        """Realtime clock: the deltas of batches up to ``step`` that have arrived, in apply
        order, stopping at the first one still missing (so dbn(t) always precedes
        landmarks(t)); never waits."""
        out = []
        s = self.last + 1
        while s <= step:
            keys_s = [] if s in self.skipped else [(s, k) for k in batch_kinds(self.params, s)]
            if not all(k in self.received for k in keys_s):
                break
            out += [self.received.pop(k) for k in keys_s]
            self.last = s
            s += 1
        self.applied_versions += len(out)
        return out
