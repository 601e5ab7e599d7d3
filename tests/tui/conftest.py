"""Fixtures: a real agent (the local driver on an embedded Zenoh session) in core2d."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest

from qlap_runtime.qlap import Params
from tui import LocalDriver

FAST = Params(babble_steps=2000, dbn_period=500, landmark_period=1000)
"""Short babbling and batch periods: the first plans appear after ~5,000 steps (seconds)."""


def make_driver(**kw) -> LocalDriver:
    import worlds

    kw.setdefault("params", FAST)
    kw.setdefault("seed", 0)
    return LocalDriver(worlds.make("core2d"), **kw)


@pytest.fixture(scope="module")
def driver(tmp_path_factory) -> Iterator[LocalDriver]:
    """A running agent shared by a module's tests (each test leaves it running)."""
    d = make_driver(run_id="tui-test", checkpoint_dir=tmp_path_factory.mktemp("ck"))
    d.start()
    try:
        yield d
    finally:
        d.stop()
        assert not d.alive


def wait_for(predicate, timeout: float = 60.0, poll: float = 0.05) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise TimeoutError("condition not reached")
        time.sleep(poll)
