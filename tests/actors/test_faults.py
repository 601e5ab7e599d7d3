"""Faults (docs/architecture.md §2, processes): an actor process SIGKILLed mid-run is restarted
from its latest snapshot by the supervisor and the run goes on, to the very knowledge of a run
without the fault. With the default process groups the learners' process restarts both
learners from one snapshot step; with ``groups="each"`` any actor but the world restarts
alone."""

from __future__ import annotations

import json
import logging
import os
import signal
import time

import pytest

import worlds
from qlap_runtime import agent_run
from qlap_runtime.agent_run import params_for_world
from qlap_runtime.bus.recorder import read_mcap
from qlap_runtime.placements.launcher import run_processes
from qlap_runtime.qlap import Params
from qlap_runtime.runtime.context import RunContext
from qlap_runtime.runtime.snapshot import latest_snapshot, snapshot_steps
from qlap_runtime.runtime.supervisor import Supervisor

STEPS = 3000
SNAPSHOT_EVERY = 500
# A short run that learns something to compare: batches every 500 steps, k fixed (Appendix C
# needs more data than 3,000 steps give) and 15 data points instead of 30 (App. B.2).
BASE = Params(babble_steps=1500, dbn_period=500, landmark_period=1000, batch_lag=200, k_fixed=5,
              min_data_points=15)


def sync_knowledge(params: Params, seed: int) -> str:
    """The oracle: the synchronous loop's knowledge with the same seed and parameters."""
    return agent_run.sync_knowledge("core2d", STEPS, seed, params)


def context(tmp_path, params: Params, seed: int, run_id: str) -> RunContext:
    world = worlds.make("core2d")
    params = params_for_world(world, params)
    world.close()
    return RunContext(run_id, "core2d", STEPS, seed, params, out=tmp_path,
                      snapshot_every=SNAPSHOT_EVERY)


class Killer:
    """Called at every supervisor poll: SIGKILLs ``victim`` once its snapshot at or after
    ``after`` exists, i.e. mid-run with something to resume from."""

    def __init__(self, victim: str, after: int) -> None:
        self.victim, self.after = victim, after
        self.killed_at: float | None = None
        self.snapshot_step: int | None = None
        self.pid: int | None = None

    def __call__(self, sup: Supervisor) -> None:
        if self.killed_at is not None or sup.snapshot_dir is None:
            return
        latest = latest_snapshot(sup.snapshot_dir, self.victim)
        if latest is None or latest[0] < self.after:
            return
        p = sup.process_of(self.victim)
        self.pid, self.snapshot_step = p.pid, latest[0]
        os.kill(p.pid, signal.SIGKILL)
        self.killed_at = time.monotonic()


@pytest.mark.parametrize(("victim", "groups"), [
    ("contingency", "two"),     # the learners' process: both learners, one snapshot step
    ("planner", "each"),        # compilations: requests and deltas fetched again
    pytest.param("perception", "each", marks=pytest.mark.slow),
    pytest.param("landmarks", "each", marks=pytest.mark.slow),
    pytest.param("contingency", "each", marks=pytest.mark.slow),  # batches in flight, its
    pytest.param("executor", "each", marks=pytest.mark.slow)])    # own deltas served again
def test_a_killed_actor_is_restarted_and_the_run_ends_as_if_nothing_happened(
        tmp_path, caplog, victim, groups):
    expected = sync_knowledge(BASE, seed=7)
    snaps = tmp_path / "snapshots"
    ctx = context(tmp_path, BASE, 7, f"t-fault-{victim}-{groups}").with_(snapshot_dir=snaps)
    killer = Killer(victim, after=2 * SNAPSHOT_EVERY - 1)
    mcap = tmp_path / "run.mcap"
    t0 = time.monotonic()
    with caplog.at_level(logging.WARNING, logger="qlap.supervisor"):
        summary = run_processes(ctx, record=mcap, on_poll=killer, groups=groups)
    wall = time.monotonic() - t0

    process = "contingency+landmarks" if groups == "two" else victim
    actors = process.split("+")
    assert killer.killed_at is not None, "the run ended before the victim was killed"
    assert summary["restarts"] == 1
    assert summary["restarted"] == [{"actor": process, "actors": actors, "attempt": 1,
                                     "exit_code": -9, "from_step": killer.snapshot_step}]
    assert f"restarting {process} from snapshot at step {killer.snapshot_step} (attempt 1)" \
        in caplog.text
    for actor in actors:
        assert summary["actors"][actor]["resumed_from_step"] == killer.snapshot_step
    assert summary["steps"] == STEPS
    if groups == "two":             # the pair snapshots together (docs/decisions.md 71)
        steps = snapshot_steps(snaps, "contingency")
        assert steps and set(steps) == set(snapshot_steps(snaps, "landmarks"))

    senses = [msg.step for topic, msg, _ in read_mcap(mcap) if topic.endswith("/sense")]
    assert sorted(senses) == list(range(STEPS)), "every sense step exactly once"

    got = (tmp_path / "knowledge.json").read_text()
    assert json.loads(got)["dbns"], "nothing was learned: the comparison would be empty"
    assert got == expected, "the restarted run learned something else than the unkilled one"
    longest = {a: r.get("snapshot_max_s") for a, r in summary["actors"].items()}
    print(f"{process}: killed after its snapshot at step {killer.snapshot_step}; "
          f"run of {STEPS} steps in {wall:.1f} s; longest snapshot write per actor {longest}")


def test_a_dead_world_stops_the_run_with_a_clear_error(tmp_path):
    ctx = context(tmp_path, BASE, 7, "t-fault-world")

    def kill_world(sup: Supervisor) -> None:
        under_way = sup.board.slot("world").data[0] >= SNAPSHOT_EVERY
        world = sup.process_of("world")
        if under_way and world.is_alive():
            os.kill(world.pid, signal.SIGKILL)

    t0 = time.monotonic()
    with pytest.raises(RuntimeError, match="the world actor cannot be restarted"):
        run_processes(ctx, on_poll=kill_world)
    assert time.monotonic() - t0 < 60
    assert not (tmp_path / "summary.json").exists()


def test_a_process_group_resumes_from_the_newest_step_all_its_actors_have(tmp_path):
    """A group's actors write their snapshots one after the other (the pair: landmarks, then
    contingency); a process killed between the two writes leaves them at different latest
    steps, and the previous snapshot is kept, so the group resumes from the step both have."""
    from qlap_runtime.runtime.snapshot import common_snapshot, write_snapshot

    for step in (499, 999):
        write_snapshot(tmp_path, "landmarks", step, {})
        write_snapshot(tmp_path, "contingency", step, {})
    write_snapshot(tmp_path, "landmarks", 1499, {})          # killed before contingency's
    assert sorted(snapshot_steps(tmp_path, "landmarks")) == [999, 1499]   # one older kept
    step, dirs = common_snapshot(tmp_path, ("contingency", "landmarks"))
    assert step == 999
    assert dirs == {a: tmp_path / a / "step-000000999" for a in ("contingency", "landmarks")}
    assert common_snapshot(tmp_path, ("landmarks",))[0] == 1499
    assert common_snapshot(tmp_path, ("perception", "landmarks")) is None
