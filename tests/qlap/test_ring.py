"""The ring storage of activations and plan calls (qlap_runtime/qlap/ring.py)."""

import numpy as np

from qlap_runtime.qlap.ring import ring_push, ring_rows


def test_ring_keeps_the_last_rows_oldest_first():
    xs, oks = np.zeros((3, 2)), np.zeros(3, dtype=bool)
    head, n = 0, 0
    x, ok = ring_rows(xs, oks, head, n)
    assert x.shape == (0, 2) and ok.shape == (0,)
    for i in range(5):                      # rows 0..4; capacity 3 keeps 2, 3, 4
        head, n = ring_push(xs, oks, head, n, np.array([i, 10 * i]), i % 2 == 0)
    assert (head, n) == (2, 3)
    x, ok = ring_rows(xs, oks, head, n)
    assert x[:, 0].tolist() == [2, 3, 4]
    assert x[:, 1].tolist() == [20, 30, 40]
    assert ok.tolist() == [True, False, True]


def test_ring_before_full_is_in_write_order():
    xs, oks = np.zeros((4, 1)), np.zeros(4, dtype=bool)
    head, n = ring_push(xs, oks, 0, 0, np.array([7.0]), True)
    head, n = ring_push(xs, oks, head, n, np.array([8.0]), False)
    x, ok = ring_rows(xs, oks, head, n)
    assert x[:, 0].tolist() == [7.0, 8.0] and ok.tolist() == [True, False]
