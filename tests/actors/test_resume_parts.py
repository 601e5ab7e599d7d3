"""An actor placement's checkpoints resume exactly (issue 13, docs/decisions.md 41): the world
actor adds the world's state and the contingency actor the pair statistics the executor's
follower learner lacks, so `--resume` of step-N with the synchronous loop ends with the
uninterrupted run's knowledge byte for byte."""

from __future__ import annotations

import pytest

import worlds
from qlap_runtime.agent_run import run_agent
from qlap_runtime.placements.launcher import run_embedded, run_processes
from qlap_runtime.qlap.checkpoint import (
    load_agent,
    load_world_state,
    restore_world,
    statistics_missing,
)

from .test_faults import BASE, STEPS, context, sync_knowledge


def _resumed(ckpt, steps: int, out) -> str:
    world = worlds.make("core2d")
    restore_world(world, load_world_state(ckpt), ckpt)
    run_agent(world, steps, 0, out, params=BASE.replace(step_seconds=world.step_seconds),
              agent=load_agent(ckpt), restored=True)
    return (out / "knowledge.json").read_text()


def _check(tmp_path, placement: str, seed: int) -> None:
    expected = sync_knowledge(BASE, seed)
    ctx = context(tmp_path / "run", BASE, seed, f"t-parts-{placement}").with_(
        checkpoint_every=1000)
    (run_embedded if placement == "embedded" else run_processes)(ctx)
    assert (tmp_path / "run" / "knowledge.json").read_text() == expected
    ckpt = tmp_path / "run" / "checkpoints" / "step-0002000"
    names = {p.name for p in ckpt.iterdir()}
    assert {"agent.json", "learner.json", "world.json", "stats.json", "stats.npz"} <= names
    assert not statistics_missing(ckpt)
    assert _resumed(ckpt, STEPS - 2000, tmp_path / "resumed") == expected
    final = tmp_path / "run" / "checkpoints" / "final"
    assert (final / "world.json").is_file() and (final / "stats.json").is_file()
    assert not (tmp_path / "run" / "checkpoints" / ".final-parts").exists()
    # The last step's checkpoint, written after the loop from the agent itself (decision
    # 87): whole, and final is a link to it (nothing changed the agent since).
    last = tmp_path / "run" / "checkpoints" / f"step-{STEPS:07d}"
    assert {"agent.json", "learner.json", "world.json", "stats.json"} <= \
        {p.name for p in last.iterdir()}
    assert final.is_symlink() and final.resolve() == last.resolve()
    assert load_agent(last).step_count == STEPS - 1


def test_an_embedded_checkpoint_resumes_as_the_uninterrupted_run(tmp_path):
    _check(tmp_path, "embedded", 3)


@pytest.mark.slow
def test_a_processes_checkpoint_resumes_as_the_uninterrupted_run(tmp_path):
    _check(tmp_path, "processes", 5)
