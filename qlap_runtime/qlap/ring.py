"""Fixed-capacity ring storage of labelled real states (§4.3, §8.3: bounded memory).

DBNs keep their last 200 activations and plans their last calls as ``(x, ok)`` rows in
preallocated arrays with a write head; these two functions are the whole ring logic, shared so
that both keep the same order and the same checkpointed layout (arrays, head, count).
"""

from __future__ import annotations

import numpy as np


def ring_push(xs: np.ndarray, oks: np.ndarray, head: int, n: int, x: np.ndarray,
              ok: bool) -> tuple[int, int]:
    """Write ``(x, ok)`` at ``head``, overwriting the oldest row when full; returns the new
    ``(head, n)``."""
    cap = xs.shape[0]
    xs[head] = x
    oks[head] = ok
    return (head + 1) % cap, min(n + 1, cap)


def ring_rows(xs: np.ndarray, oks: np.ndarray, head: int, n: int
              ) -> tuple[np.ndarray, np.ndarray]:
    """The stored rows, oldest first (views while not full, copies after)."""
    cap = xs.shape[0]
    if n < cap:
        return xs[:n], oks[:n]
    # Rows head..cap−1 then 0..head−1 (the values of xs[np.r_[head:cap, 0:head]], copied).
    return np.concatenate((xs[head:], xs[:head])), np.concatenate((oks[head:], oks[:head]))
