"""The terminal UI's local runner (tui.driver.LocalDriver) driven to the end of its steps, for
tests that compare what it leaves with the synchronous loop."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any


@contextmanager
def finished_driver(world: Any, timeout_s: float = 60.0, **kwargs: Any) -> Iterator[Any]:
    """A LocalDriver on ``world`` started and waited for until it has run its steps (or
    ``timeout_s`` passed: the test then sees ``finished`` False); stopped afterwards."""
    from tui.driver import LocalDriver

    d = LocalDriver(world, **kwargs)
    try:
        d.start()
        for _ in range(int(timeout_s / 0.1)):
            if d.finished:
                break
            d.wait(0.1)
        yield d
    finally:
        d.stop()
