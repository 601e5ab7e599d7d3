"""The pairwise search for contingencies and the learning of the window k (§4.1, Appendix C).

:class:`PairStatistics` counts, for every antecedent event E1 and every consequent candidate E2,
how often ``soon(t, E2)`` followed ``event(t, E1)``, and how often ``soon(t, E2)`` holds at a
random step. Counts are updated only where events happen: when E2 occurs at t', every E1 that
occurred in the window (t' − k, t'] and was not already credited for E2 gets one success,
through one vectorised ``np.add.at``; an occurrence of E1 is counted as a trial once its window
has closed, so Pr(soon | E1) is exact.

:class:`WindowLearner` implements Appendix C: for motor → direction-of-change transitions it
records the delay until the consequent occurs while the motor value still holds.
"""

from __future__ import annotations

import copy
from collections import deque

import numpy as np

from .kernels import loaded_kernels
from .perception import EventIndex
from .probability import prob_above_many


class PairStatistics:
    """Statistics for event(t, E1) ⇒ soon(t, E2) over all event pairs (§4.1.2)."""

    def __init__(self, index: EventIndex, k: int) -> None:
        self.k = int(k)
        self.reset(index)

    def reset(self, index: EventIndex) -> None:
        """Start counting afresh for a new event index (after landmarks or k changed)."""
        self.index = index
        n, c = index.n_events, index.n_cons
        self.occurrences = np.zeros(n, dtype=np.int64)      # resolved E1 occurrences
        self.soon_given = np.zeros((n, c), dtype=np.int64)  # E1 occurrences followed soon by E2
        self.soon_steps = np.zeros(c, dtype=np.int64)       # steps t with E2 in [t, t+k)
        self.last_cons = np.full(c, -(10**12), dtype=np.int64)
        # The events of the last k steps, flattened: their step and id.
        self.win_t = np.zeros(0, dtype=np.int64)
        self.win_ids = np.zeros(0, dtype=np.int64)
        self.steps = 0
        self.first_step: int | None = None

    def update(self, step: int, event_ids: np.ndarray) -> None:
        """Account for the events of one step (vectorised over the window)."""
        if self.first_step is None:
            self.first_step = step
        k = self.k
        kern = loaded_kernels()
        if kern is not None and event_ids.dtype == np.int64 and self.win_t.dtype == np.int64 \
                and self.win_ids.dtype == np.int64:
            # The same counts, compiled (kernels.pairs_update).
            self.win_t, self.win_ids = kern.pairs_update(
                int(step), int(k), int(self.first_step), event_ids, self.win_t, self.win_ids,
                self.occurrences, self.soon_given, self.soon_steps, self.last_cons,
                self.index.cons_of_event)
            self.steps += 1
            return
        # Occurrences whose window [t, t+k) closed before this step become trials.
        if len(self.win_t) and self.win_t[0] <= step - k:
            cut = int(np.searchsorted(self.win_t, step - k, side="right"))
            np.add.at(self.occurrences, self.win_ids[:cut], 1)
            self.win_t, self.win_ids = self.win_t[cut:], self.win_ids[cut:]
        if len(event_ids):
            self.win_t = np.concatenate([self.win_t, np.full(len(event_ids), step)])
            self.win_ids = np.concatenate([self.win_ids, event_ids])
            cons = self.index.cons_of_event[event_ids]
            cons = cons[cons >= 0]
            if len(cons):
                lo = np.maximum(np.maximum(self.last_cons[cons] + 1, step - k + 1),
                                self.first_step)
                self.soon_steps[cons] += step - lo + 1
                self.last_cons[cons] = step
                # E1 occurrences at t >= lo(c) are credited once for c.
                start = np.searchsorted(self.win_t, lo, side="left")
                counts = len(self.win_t) - start
                rows = np.concatenate([self.win_ids[s:] for s in start.tolist()])
                cols = np.repeat(cons, counts)
                np.add.at(self.soon_given, (rows, cols), 1)
        self.steps += 1

    def drop_open_windows(self) -> None:
        """A discontinuity: the occurrences whose window is still open are dropped, neither
        trials nor successes (no soon-window spans a jump)."""
        self.win_t = np.zeros(0, dtype=np.int64)
        self.win_ids = np.zeros(0, dtype=np.int64)

    def resolved_steps(self) -> int:
        """Steps whose soon-window has closed."""
        return max(0, self.steps - self.k + 1)

    def contingencies(self, theta_pen: np.ndarray, min_points: int, prior: float,
                      confidence: float) -> list[tuple[int, int, float, float]]:
        """Pairs with Pr(soon|E1) − Pr(soon) > θ_pen by the beta test (eq. 4.6, App. B).

        ``theta_pen`` is per consequent (targeted learning lowers it, §6.3). The exclusion of
        same-variable pairs (§4.1.2 item 3) is applied here; exclusions 1–2 are built into the
        consequent numbering. Returns (E1 id, E2 id, Pr(soon|E1), Pr(soon)).
        """
        n = self.resolved_steps()
        if n <= 0:
            return []
        base = np.minimum(self.soon_steps / n, 1.0)                      # (c,)
        trials = self.occurrences[:, None]
        ok = trials >= min_points
        if not ok.any():
            return []
        ev_var = self.index.event_var
        cons_var = ev_var[self.index.event_of_cons]                      # (c,)
        same = ev_var[:, None] == cons_var[None, :]
        cand = ok & ~same & (self.soon_given > 0)
        r, c = np.nonzero(cand)
        if not len(r):
            return []
        s = self.soon_given[r, c]
        f = self.occurrences[r] - s
        thr = base[c] + theta_pen[c]
        good = prob_above_many(thr, s, f, prior, confidence) & (thr < 1.0)
        out = []
        for i in np.flatnonzero(good):
            e2 = int(self.index.event_of_cons[c[i]])
            out.append((int(r[i]), e2, float(s[i] / self.occurrences[r[i]]), float(base[c[i]])))
        return out

    def to_state(self) -> tuple[dict, dict[str, np.ndarray]]:
        meta = {"k": self.k, "steps": self.steps, "first_step": self.first_step}
        arrays = {"occurrences": self.occurrences, "soon_given": self.soon_given,
                  "soon_steps": self.soon_steps, "last_cons": self.last_cons,
                  "win_t": self.win_t, "win_ids": self.win_ids}
        return meta, arrays

    def load_state(self, meta: dict, arrays: dict[str, np.ndarray]) -> None:
        self.k = int(meta["k"])
        self.steps = int(meta["steps"])
        self.first_step = meta["first_step"]
        for name in ("occurrences", "soon_given", "soon_steps", "last_cons", "win_t", "win_ids"):
            setattr(self, name, np.asarray(arrays[name], dtype=np.int64).copy())


def soon_fraction(times: np.ndarray, k: int, start: int, end: int) -> float:
    """Fraction of steps t in [start, end] with an occurrence in [t, t + k) (eq. 4.2).

    The union of the windows (o − k, o] over the occurrence times o, clipped, over the span.
    """
    span = end - start + 1
    if span <= 0 or len(times) == 0:
        return 0.0
    o = np.sort(np.asarray(times, dtype=np.int64))
    lo = np.maximum(o - k + 1, start)
    hi = np.minimum(o, end)
    # Merge overlapping intervals [lo, hi].
    covered = 0
    cur_lo, cur_hi = int(lo[0]), int(hi[0])
    for a, b in zip(lo[1:], hi[1:], strict=True):
        if a <= cur_hi + 1:
            cur_hi = max(cur_hi, int(b))
        else:
            covered += cur_hi - cur_lo + 1
            cur_lo, cur_hi = int(a), int(b)
    covered += cur_hi - cur_lo + 1
    return covered / span


class WindowLearner:
    """Appendix C: the average delay k_r of successful motor → change transitions.

    An *episode* starts when a motor variable u takes a new value (event u → q) and lasts while
    u = q. The first change event E2 on each direction-of-change variable during the episode is
    a successful transition of the pair (u → q, E2) with delay t' − t + 1; each episode is one
    trial. The delays are kept as a histogram, so that the pair can be tested with "the same
    statistics that [QLAP] keeps to learn DBNs, except that k_r is used for k": a success counts
    only if it came within k_r steps, against the base rate of E2 in a window of k_r steps.
    (Counting every success of a hold of up to 40 steps against a k_r-step base rate lets
    spurious motor → change pairs pass and inflates k; docs/decisions.md.)
    """

    def __init__(self, motor_vars: list[int], history: int) -> None:
        self.motor_vars = list(motor_vars)
        # motor var -> (E1 id, start step, consequents already credited)
        self.open: dict[int, tuple[int, int, set[int]]] = {}
        self.trials: dict[int, int] = {}                       # E1 id -> episodes
        self.delays: dict[tuple[int, int], list[int]] = {}     # (E1, E2) -> counts by delay − 1
        self.cons_times: dict[int, deque[int]] = {}            # E2 id -> occurrence times
        self.history = history
        self.first_step: int | None = None
        self.last_step = -1

    def __deepcopy__(self, memo: dict) -> WindowLearner:
        """What ``copy.deepcopy`` gives (a batch's copy of the learner), without a call per
        count: the histograms and times are lists and deques of ints (decision 101)."""
        c = object.__new__(type(self))
        memo[id(self)] = c
        state = c.__dict__
        for k, v in self.__dict__.items():
            if k == "delays":
                state[k] = {key: list(counts) for key, counts in v.items()}
            elif k == "cons_times":
                state[k] = {key: deque(times, times.maxlen) for key, times in v.items()}
            elif k == "trials":
                state[k] = dict(v)
            else:
                state[k] = copy.deepcopy(v, memo)
        return c

    def update(self, step: int, motor_events: list[tuple[int, int]],
               cons_events: list[tuple[int, int]]) -> None:
        """``motor_events``: (motor var, E1 id) that occurred; ``cons_events``: (change var,
        E2 id, or −1 for a change to [0], which is not a consequent, §4.1.2). Only the first
        change of each variable in an episode is the command's transition: a later reversal
        (the hand stopping, or bouncing at its limit) is not."""
        if self.first_step is None:
            self.first_step = step
        self.last_step = step
        for var, e1 in motor_events:
            old = self.open.get(var)
            if old is not None:
                self.trials[old[0]] = self.trials.get(old[0], 0) + 1
            self.open[var] = (e1, step, set())
        for var, e2 in cons_events:
            if e2 >= 0:
                times = self.cons_times.setdefault(e2, deque(maxlen=self.history))
                times.append(step)
            for e1, t0, credited in self.open.values():
                if var not in credited:
                    credited.add(var)
                    if e2 < 0:
                        continue                        # a change to [0]: not a consequent
                    hist = self.delays.setdefault((e1, e2), [])
                    d = step - t0                                # delay − 1
                    if d >= len(hist):
                        hist.extend([0] * (d + 1 - len(hist)))
                    hist[d] += 1

    def drop_open_episodes(self) -> None:
        """A discontinuity: the open episodes end without being counted as trials."""
        self.open.clear()

    def learnable(self, min_points: int, theta_pen: float, prior: float,
                  confidence: float) -> list[tuple[int, int, float]]:
        """Pairs (E1, E2, k_r) that pass the contingency test with their own window k_r:
        Pr(E2 within k_r of E1) − Pr(soon_{k_r}(E2)) > θ_pen by the beta test (eq. 4.6)."""
        out = []
        if self.first_step is None:
            return out
        for (e1, e2), hist in sorted(self.delays.items()):
            n = self.trials.get(e1, 0)
            s = sum(hist)
            if n < min_points or s == 0:
                continue
            mean = sum((d + 1) * c for d, c in enumerate(hist)) / s
            k_r = max(1, round(mean))
            s_eff = min(sum(hist[:k_r]), n)
            base = soon_fraction(np.fromiter(self.cons_times.get(e2, ()), dtype=np.int64), k_r,
                                 max(self.first_step, self.last_step - self.history + 1),
                                 self.last_step)
            thr = base + theta_pen
            if thr < 1.0 and prob_above_many(np.array([thr]), np.array([s_eff]),
                                             np.array([n - s_eff]), prior, confidence)[0]:
                out.append((e1, e2, mean))
        return out

    def to_state(self) -> dict:
        return {"open": {str(k): [e, t, sorted(c)] for k, (e, t, c) in self.open.items()},
                "trials": [[k, v] for k, v in self.trials.items()],
                "delays": [[a, b, h] for (a, b), h in self.delays.items()],
                "cons_times": [[k, list(v)] for k, v in self.cons_times.items()],
                "first_step": self.first_step, "last_step": self.last_step}

    def load_state(self, d: dict) -> None:
        if "delays" not in d:
            raise ValueError("window state of an older format (no delay histograms); "
                             "this checkpoint predates the Appendix C fix and cannot resume")
        self.open = {int(k): (int(e), int(t), set(c)) for k, (e, t, c) in d["open"].items()}
        self.trials = {int(k): int(v) for k, v in d["trials"]}
        self.delays = {(int(a), int(b)): [int(c) for c in h] for a, b, h in d["delays"]}
        self.cons_times = {int(k): deque(v, maxlen=self.history) for k, v in d["cons_times"]}
        self.first_step = d["first_step"]
        self.last_step = int(d["last_step"])
