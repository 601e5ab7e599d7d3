"""Quantity spaces: landmarks as ranges and the qualitative values they define (ch. 3, §3.1).

A quantity space with n landmarks has 2n + 1 qualitative values, numbered from the bottom of the
number line: even numbers are open intervals, odd numbers are landmarks. Value 2i + 1 is the
landmark i, value 2i the open interval just below it, value 2n the interval (v*_n, +∞).

Landmarks are ranges [lb, ub] (footnote 3 of §4.4.1): a real value within [lb, ub] is *at* the
landmark. A point landmark has lb == ub.
"""

from __future__ import annotations

import math
from bisect import bisect_left
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Landmark:
    """One landmark v* with its range (§4.4.1 footnote 3)."""

    lb: float
    """Lower end of the range (inclusive)."""
    ub: float
    """Upper end of the range (inclusive)."""
    step: int = 0
    """Agent step at which the landmark was adopted (0 for the initial ones of Table 3.1)."""
    source: str = "initial"
    """How it was found: "initial", "dbn" (Algorithm 4) or "event" (Algorithm 5)."""

    @property
    def centre(self) -> float:
        return 0.5 * (self.lb + self.ub)

    def label(self) -> str:
        if self.lb == self.ub:
            return _num(self.lb)
        return f"[{_num(self.lb)}, {_num(self.ub)}]"


def _num(x: float) -> str:
    """A landmark's number in a label: six significant digits, and 0 never written -0 (a
    motor's initial landmark 0 of Table 3.1 may be stored as -0.0)."""
    return f"{x + 0.0:.6g}"


class QuantitySpace:
    """Ordered, disjoint landmarks of one variable and the values they define."""

    # Invariant: landmarks are sorted and disjoint (ub_i < lb_{i+1}).

    def __init__(self, landmarks: list[Landmark] | None = None) -> None:
        self.landmarks: list[Landmark] = []
        for lm in sorted(landmarks or [], key=lambda m: m.lb):
            self.insert(lm)

    @property
    def size(self) -> int:
        """|Q(v)| = 2n + 1."""
        return 2 * len(self.landmarks) + 1

    def value_of(self, x: float) -> int:
        """The qualitative value of the real value ``x``: 2i below landmark i (x < lb_i),
        2i + 1 on it (x ≤ ub_i), 2n above all (NaN too: no comparison holds)."""
        lms = self.landmarks
        c = self.__dict__.get("_bounds")
        if c is None or c[0] is not lms or c[1] != len(lms):
            # The bounds as lists, kept while the list of (immutable) landmarks is this one
            # with as many elements (insert() only adds; a copy gets a new list).
            c = self._bounds = (lms, len(lms), [m.lb for m in lms], [m.ub for m in lms])
        if x != x:
            return 2 * len(lms)
        # j = #{ub < x}: landmarks below j are passed, as by the loop over them in order.
        j = bisect_left(c[3], x)
        if j < len(lms) and x >= c[2][j]:
            return 2 * j + 1
        return 2 * j

    def values_of(self, x: np.ndarray) -> np.ndarray:
        """Vectorised :meth:`value_of` (NaN gives −1)."""
        x = np.asarray(x, dtype=float)
        if not self.landmarks:
            out = np.zeros(x.shape, dtype=np.int64)
        else:
            lbs = np.array([m.lb for m in self.landmarks])
            ubs = np.array([m.ub for m in self.landmarks])
            j = np.searchsorted(ubs, x, side="left")
            at = np.zeros(x.shape, dtype=bool)
            inside = j < len(ubs)
            at[inside] = x[inside] >= lbs[j[inside]]
            out = 2 * j + at
        out = np.where(np.isnan(x), -1, out)
        return out.astype(np.int64)

    @staticmethod
    def is_landmark_value(q: int) -> bool:
        return q % 2 == 1

    def bounds(self, q: int) -> tuple[float, float]:
        """The real range covered by value ``q``: a landmark's [lb, ub] or an interval's ends."""
        self._check(q)
        if q % 2 == 1:
            lm = self.landmarks[q // 2]
            return lm.lb, lm.ub
        i = q // 2
        lo = self.landmarks[i - 1].ub if i > 0 else -math.inf
        hi = self.landmarks[i].lb if i < len(self.landmarks) else math.inf
        return lo, hi

    def label(self, q: int) -> str:
        """Human-readable value, e.g. "(-inf, 0.3)", "[0.29, 0.31]" or "(0.31, +inf)"."""
        self._check(q)
        if q % 2 == 1:
            return self.landmarks[q // 2].label()
        lo, hi = self.bounds(q)
        lo_s = "-inf" if lo == -math.inf else _num(lo)
        hi_s = "+inf" if hi == math.inf else _num(hi)
        return f"({lo_s}, {hi_s})"

    def interval_of_range(self, lb: float, ub: float) -> int | None:
        """The open interval that strictly contains [lb, ub], or None if it overlaps a landmark."""
        q_lo, q_hi = self.value_of(lb), self.value_of(ub)
        if q_lo != q_hi or q_lo % 2 == 1:
            return None
        lo, hi = self.bounds(q_lo)
        if not (lo < lb and ub < hi):
            return None
        return q_lo

    def insert(self, lm: Landmark) -> int:
        """Add a landmark inside an open interval; returns the split interval's old value.

        After the insertion the old interval 2i becomes 2i (below), 2i + 1 (the landmark) and
        2i + 2 (above); every value above it shifts up by 2 (see :func:`remap_after_insert`).
        """
        if not (lm.lb <= lm.ub) or math.isnan(lm.lb) or math.isnan(lm.ub):
            raise ValueError(f"landmark range must satisfy lb <= ub, got [{lm.lb}, {lm.ub}]")
        if not self.landmarks:
            self.landmarks.append(lm)
            return 0
        q = self.interval_of_range(lm.lb, lm.ub)
        if q is None:
            raise ValueError(
                f"landmark [{lm.lb}, {lm.ub}] overlaps an existing landmark "
                f"({', '.join(m.label() for m in self.landmarks)})")
        self.landmarks.insert(q // 2, lm)
        return q

    def _check(self, q: int) -> None:
        if not 0 <= q < self.size:
            raise ValueError(f"qualitative value {q} outside 0..{self.size - 1}")

    def to_json(self) -> list[dict]:
        return [{"lb": m.lb, "ub": m.ub, "step": m.step, "source": m.source}
                for m in self.landmarks]

    @classmethod
    def from_json(cls, data: list[dict]) -> QuantitySpace:
        return cls([Landmark(float(d["lb"]), float(d["ub"]), int(d.get("step", 0)),
                             str(d.get("source", "initial"))) for d in data])


def remap_after_insert(q: int, split: int) -> int:
    """New index of old value ``q`` after the interval ``split`` was split by a landmark.

    Values below the split are unchanged, values above shift by 2. The split interval itself
    has no unique image; callers decide (it is returned as the lower part, ``split``).
    """
    if q > split:
        return q + 2
    return q
