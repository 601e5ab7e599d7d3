"""The delta book's schedule (docs/decisions.md 54, 88): ``due_keys`` visits only
the batch steps, ``none_due`` decides without listing; both against the step-by-step listing."""

from __future__ import annotations

from qlap_runtime.qlap import Params
from qlap_runtime.runtime.lockstep import DeltaBook, batch_kinds


def listing(book: DeltaBook, step: int) -> list[tuple[int, str]]:
    """Every step in (last, step], its batch step t − L, unless skipped."""
    out = []
    for s in range(book.last + 1, step + 1):
        computed = s - book.params.batch_lag
        if computed not in book.skipped:
            out += [(computed, kind) for kind in batch_kinds(book.params, computed)]
    return out


def test_due_keys_and_none_due_agree_with_the_step_by_step_listing():
    for period, lm, lags in ((500, 1000, (0, 1, 200, 499)), (7, 21, (0, 3, 6)), (2, 6, (0, 1))):
        for lag in lags:
            book = DeltaBook(Params(batch_lag=lag, dbn_period=period, landmark_period=lm))
            book.skipped = {period * 3, period * 3 + 1, 2 * lm}
            for last in (-1, 0, period - 1, period, lag + period, 5 * lm + 3):
                book.last = last
                for step in range(last - 2, last + 3 * lm + lag + 5, 1 if period < 500 else 7):
                    expected = listing(book, step)
                    assert book.due_keys(step) == expected, (lag, period, last, step)
                    assert book.none_due(step) == (not any(
                        batch_kinds(book.params, s - lag)
                        for s in range(book.last + 1, step + 1))), (lag, period, last, step)
