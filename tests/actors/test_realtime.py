"""The realtime clock: the world ticks at a fixed rate and counts late and missed ticks."""

from __future__ import annotations

from qlap_runtime.placements.launcher import run_embedded
from qlap_runtime.qlap import Params
from qlap_runtime.runtime.context import RunContext

PARAMS = Params(babble_steps=300, dbn_period=200, landmark_period=400)


def test_realtime_ticks_at_the_rate_and_reports_its_lateness(tmp_path):
    steps, hz = 600, 100.0
    ctx = RunContext("rt-test", "core2d", steps, 0, PARAMS, out=tmp_path,
                     clock="realtime", hz=hz)
    s = run_embedded(ctx)
    assert s["clock"] == "realtime"
    assert s["steps"] == steps
    # 600 ticks at 100 Hz take 6 s (a tick more than one period late is skipped and counted,
    # which only shortens nothing: the run still performs its 600 ticks).
    assert 5.9 <= s["wall_time_s"] < 6.0 + 0.01 * s["missed_ticks"] + 10
    for key in ("late_ticks", "missed_ticks", "lateness_p50_ms", "lateness_p99_ms"):
        assert key in s
    assert 0 <= s["lateness_p50_ms"] <= s["lateness_p99_ms"]
    assert s["actors"]["contingency"]["batches"] == 2      # batches at 200 and 400 ran
    assert (tmp_path / "knowledge.json").exists()
