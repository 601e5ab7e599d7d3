"""``--resume`` inside the actor placements (issue 13): a checkpoint written by any placement
(sync, embedded, processes) resumed with ``embedded`` or ``processes`` ends with the
uninterrupted run's ``knowledge.json`` byte for byte; a checkpoint that cannot resume exactly
there is refused in one line that says what to use instead (docs/decisions.md 50)."""

from __future__ import annotations

import json
import os
import shutil
import signal
from pathlib import Path

import pytest

import worlds
from qlap_runtime.agent_run import params_for_world, run_agent
from qlap_runtime.placements.launcher import run_embedded, run_processes
from qlap_runtime.placements.resume import ResumeRefused, resume_context
from qlap_runtime.runtime.context import RunContext
from tests.test_cli_errors import assert_one_line, qlap

from .test_faults import BASE, STEPS, context, sync_knowledge

RESUME_AT = 2000
"""A DBN and landmark batch step (BASE: periods 500 and 1000, lag 200): the resumed run's
first batch reads the checkpoint's batch context."""

RUN = {"embedded": run_embedded, "processes": run_processes}


def _params():
    world = worlds.make("core2d")
    try:
        return params_for_world(world, BASE)
    finally:
        world.close()


def _source(tmp_path: Path, placement: str, seed: int) -> Path:
    """A STEPS-step run of ``placement`` with a checkpoint every 1,000 steps."""
    out = tmp_path / f"src-{placement}"
    if placement == "sync":
        run_agent(worlds.make("core2d"), STEPS, seed, out, params=_params(),
                  checkpoint_every=1000)
    else:
        ctx = context(out, BASE, seed, f"t-rsrc-{placement}").with_(checkpoint_every=1000)
        RUN[placement](ctx)
    return out / "checkpoints" / f"step-{RESUME_AT:07d}"


def _resumed(ckpt: Path, placement: str, out: Path) -> str:
    ctx = RunContext(f"t-resume-{placement}", "core2d", STEPS - RESUME_AT, 0, _params(),
                     out=out, placement=placement, snapshot_every=500)
    ctx = resume_context(ctx, ckpt)
    assert ctx.start == RESUME_AT and ctx.resume_checkpoint is not None
    RUN[placement](ctx)
    return (out / "knowledge.json").read_text()


@pytest.mark.parametrize(("source", "target"), [
    ("sync", "embedded"),
    ("embedded", "embedded"),
    ("sync", "processes"),
    pytest.param("embedded", "processes", marks=pytest.mark.slow),
    pytest.param("processes", "embedded", marks=pytest.mark.slow),
    pytest.param("processes", "processes", marks=pytest.mark.slow)])
def test_a_checkpoint_of_any_placement_resumes_exactly_in_the_actor_placements(
        tmp_path, source, target):
    seed = 9
    expected = sync_knowledge(BASE, seed)
    assert json.loads(expected)["dbns"], "nothing learned: the comparison would be empty"
    ckpt = _source(tmp_path, source, seed)
    got = _resumed(ckpt, target, tmp_path / "resumed")
    assert got == expected
    final = tmp_path / "resumed" / "checkpoints" / "final"
    assert (final / "world.json").is_file() and (final / "stats.json").is_file()


def test_checkpoints_that_cannot_resume_exactly_are_refused_in_one_line(capsys, tmp_path):
    """A sync checkpoint with a batch in flight (its pending delta): only the sync loop; an
    actor placement's with one: none; no world state; the realtime clock."""
    src = tmp_path / "src"
    run_agent(worlds.make("core2d"), 1200, 1, src, params=_params(), checkpoint_every=1100)
    ckpt = src / "checkpoints" / "step-0001100"          # batch 1000 applies at 1200
    ctx = RunContext("t-refuse", "core2d", 100, 0, _params(), placement="embedded")
    with pytest.raises(ResumeRefused) as info:
        resume_context(ctx, ckpt)
    assert "only --placement sync" in str(info.value) and "\n" not in str(info.value)
    emb = context(tmp_path / "emb", BASE, 1, "t-refuse-emb").with_(steps=1200,
                                                                    checkpoint_every=1100)
    run_embedded(emb)
    with pytest.raises(ResumeRefused) as info:
        resume_context(ctx.with_(placement="processes"),
                       tmp_path / "emb" / "checkpoints" / "step-0001100")
    assert "no placement resumes it exactly" in str(info.value)
    code, _, err = qlap(capsys, "run", "--headless", "--quiet", "--placement", "sync",
                        "--world", "core2d", "--steps", "10", "--resume",
                        str(tmp_path / "emb" / "checkpoints" / "step-0001100"),
                        "--out", str(tmp_path / "sync-refused"))
    assert_one_line(code, err, "no placement resumes it exactly")
    bare = tmp_path / "bare"
    shutil.copytree(src / "checkpoints" / "final", bare)
    (bare / "world.json").unlink()
    with pytest.raises(ResumeRefused) as info:
        resume_context(ctx, bare)
    assert "no world state" in str(info.value)
    with pytest.raises(ResumeRefused) as info:
        resume_context(ctx.with_(clock="realtime"), src / "checkpoints" / "final")
    assert "lockstep" in str(info.value)


def test_qlap_run_resume_in_embedded(capsys, tmp_path):
    """The command line: a sync run's final checkpoint resumed with ``--placement embedded``
    equals the uninterrupted sync run; refusals and a corrupt checkpoint are one line."""
    base = ("run", "--headless", "--quiet", "--world", "core2d", "--seed", "3")
    code, _, err = qlap(capsys, *base, "--placement", "sync", "--steps", "700", "--out",
                        str(tmp_path / "whole"))
    assert code == 0, err
    code, _, err = qlap(capsys, *base, "--placement", "sync", "--steps", "500", "--out",
                        str(tmp_path / "first"))
    assert code == 0, err
    final = tmp_path / "first" / "checkpoints" / "final"
    code, _, err = qlap(capsys, *base, "--placement", "embedded", "--steps", "200",
                        "--resume", str(final), "--out", str(tmp_path / "rest"))
    assert code == 0, err
    assert (tmp_path / "rest" / "knowledge.json").read_bytes() == \
        (tmp_path / "whole" / "knowledge.json").read_bytes()
    code, _, err = qlap(capsys, *base, "--placement", "embedded", "--steps", "200",
                        "--resume", str(final), "--clock", "realtime",
                        "--out", str(tmp_path / "rt"))
    assert code == 2
    assert_one_line(code, err, "lockstep")
    assert not (tmp_path / "rt").exists()
    code, _, err = qlap(capsys, *base, "--placement", "processes", "--steps", "200",
                        "--resume", str(final), "--out", str(tmp_path / "first"))
    assert_one_line(code, err, "would write over the run")
    (final / "agent.json").write_text("{not json")
    code, _, err = qlap(capsys, *base, "--placement", "processes", "--steps", "200",
                        "--resume", str(final), "--out", str(tmp_path / "bad"))
    assert code == 2
    assert_one_line(code, err, "corrupt agent checkpoint")


@pytest.mark.slow
def test_an_actor_killed_before_its_first_snapshot_restarts_from_the_checkpoint(tmp_path):
    """processes: the supervisor restarts the learners' process of a resumed run that died
    before its first snapshot; they load the checkpoint again (not a fresh learner) and the run
    still ends byte-identical."""
    seed = 9
    expected = sync_knowledge(BASE, seed)
    ckpt = _source(tmp_path, "sync", seed)
    ctx = resume_context(RunContext("t-resume-kill", "core2d", STEPS - RESUME_AT, 0, _params(),
                                    out=tmp_path / "resumed", placement="processes",
                                    snapshot_every=500), ckpt)
    killed: list[int] = []

    def kill(sup) -> None:
        step = int(sup.board.slot("world").data[0])
        if not killed and step >= RESUME_AT + 100:
            os.kill(sup.process_of("contingency").pid, signal.SIGKILL)
            killed.append(step)

    summary = run_processes(ctx, on_poll=kill)
    assert killed and killed[0] < RESUME_AT + 499, "killed after its first snapshot: vacuous"
    assert [(r["actors"], r["from_step"]) for r in summary["restarted"]] == \
        [(["contingency", "landmarks"], None)]           # the learners' process
    assert (tmp_path / "resumed" / "knowledge.json").read_text() == expected
