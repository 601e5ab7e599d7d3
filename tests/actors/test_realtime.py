"""The realtime clock: the world ticks at a fixed rate and counts late and missed ticks."""

from __future__ import annotations

from qlap_runtime.placements.launcher import niceness_for, run_embedded, run_processes
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


def test_realtime_processes_run_the_learners_nicer_than_the_step_chain(tmp_path):
    """Decision 111: under the realtime clock the learners' process yields the cores to the
    step chain's (a CPU-bound neighbour at the same niceness put a bare 100 Hz loop's p99 at
    1.85 ms, at niceness 10 at 0.11 ms); every process reports its niceness."""
    steps = 600
    ctx = RunContext("rt-proc", "core2d", steps, 0, PARAMS, out=tmp_path,
                     clock="realtime", hz=100.0)
    s = run_processes(ctx)
    assert s["steps"] == steps and s["clock"] == "realtime"
    actors = s["actors"]
    assert actors["contingency"]["batches"] == 2            # batches at 200 and 400 ran
    assert {a: actors[a]["niceness"] for a in ("world", "perception", "executor")} == \
        dict.fromkeys(("world", "perception", "executor"), 0)
    assert actors["contingency"]["niceness"] == actors["landmarks"]["niceness"] == 10
    assert isinstance(s["missed_at"], list)


def test_in_lockstep_no_process_runs_nicer():
    """In lockstep the chain waits for the learners' deltas: nicer learners would slow it."""
    lockstep = RunContext("ls", "core2d", 10, 0, PARAMS)
    realtime = lockstep.with_(clock="realtime")
    learners, chain = ("contingency", "landmarks"), ("world", "perception", "executor", "planner")
    assert niceness_for(learners, lockstep) == niceness_for(chain, lockstep) == 0
    assert niceness_for(learners, realtime) == 10 and niceness_for(chain, realtime) == 0
