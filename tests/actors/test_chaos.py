"""The chaos harness (scripts/chaos.py, issue 13) as a test: SIGKILLs to random actors, right
after snapshots and at random steps, and the run still ends byte-identical to the synchronous
loop (or with a one-line error in bounded time; never a hang). Slow: ~40 s per trial."""

from __future__ import annotations

import json

import pytest

from .test_lossy import load_chaos


@pytest.mark.slow
def test_three_chaos_trials_with_three_kills_end_as_the_sync_loop(capsys):
    code = load_chaos().main(["--trials", "3", "--kills", "3", "--steps", "3000",
                              "--stall-s", "20", "--limit-s", "300"])
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert code == 0
    assert summary["identical"] == 3 and summary["hung"] == 0


@pytest.mark.slow
def test_three_chaos_trials_with_kills_drops_and_delays_end_as_the_sync_loop(capsys):
    code = load_chaos().main(["--trials", "3", "--kills", "3", "--steps", "3000",
                              "--stall-s", "20", "--limit-s", "300", "--drop", "0.01",
                              "--delay", "0.01"])
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert code == 0
    assert summary["identical"] == 3 and summary["hung"] == 0
