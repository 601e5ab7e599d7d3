"""Semantically corrupt checkpoints: a CheckpointError naming the field (issue 13, item 6)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import worlds
from qlap_runtime.agent_run import run_agent
from qlap_runtime.qlap import Params
from qlap_runtime.qlap.checkpoint import (
    CheckpointError,
    check_learner,
    load_agent,
    read_checkpoint,
    resolve_checkpoint,
)

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("ckpt")
    world = worlds.make("core2d")
    try:
        run_agent(world, 3000, 3, out=out,
                  params=Params(babble_steps=1500, dbn_period=500, landmark_period=1000))
    finally:
        world.close()
    return resolve_checkpoint(out / "checkpoints" / "final")


def corrupt(good: Path, tmp_path: Path, name: str, edit) -> Path:
    bad = tmp_path / "bad"
    shutil.copytree(good, bad)
    meta = json.loads((bad / name).read_text())
    edit(meta)
    (bad / name).write_text(json.dumps(meta))
    return bad


def set_dbn_var(m):
    m["dbns"][0]["consequent"][0] = 999


CASES = {
    "motor": ("agent.json", lambda m: m.update(motor="abc")),
    "motor name": ("agent.json", lambda m: m.update(motor={"nope": 1.0})),
    "dbns[0].consequent": ("learner.json", set_dbn_var),
    "k": ("learner.json", lambda m: m.update(k=10_000_000)),
    # fields a run would only trip over later, in its loop (a new user's edits)
    "goal string": ("agent.json", lambda m: m.update(goal="x")),
    "goal empty": ("agent.json", lambda m: m.update(goal=[])),
    "goal value": ("agent.json", lambda m: m.update(goal=[0, 999])),
    "self_vars": ("agent.json", lambda m: m.update(self_vars="x")),
    "step_count": ("agent.json", lambda m: m.update(step_count=-1)),
    "learning": ("agent.json", lambda m: m.update(learning="x")),
    "mode": ("agent.json", lambda m: m.update(mode="dance")),
    "world": ("agent.json", lambda m: m.update(world=17)),
    "variables": ("learner.json", lambda m: m.update(variables="x")),
    # fields read without a check of their own: the error names the part being read
    "actions": ("agent.json", lambda m: m.update(actions=["x"])),
    "babbler": ("agent.json", lambda m: m.update(babbler=[])),
    "call_list": ("agent.json", lambda m: m.update(call_list=[{"key": 1}])),
    "iac_log": ("agent.json", lambda m: m.update(iac_log=[[]])),
    "counters": ("agent.json", lambda m: m.update(counters={"nope": 1})),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_corrupt_fields_are_named(good, tmp_path, case):
    name, edit = CASES[case]
    assert json.loads((good / "learner.json").read_text())["dbns"], "no DBN to corrupt"
    bad = corrupt(good, tmp_path, name, edit)
    with pytest.raises(CheckpointError, match=case.split()[0].replace("[", r"\[")
                       .replace("]", r"\]")):
        load_agent(bad)


def test_wrong_array_shapes_are_named(good):
    meta, arrays = read_checkpoint(good, "learner")
    check_learner(meta, arrays, good)                       # the good one passes
    for key in ("perception.prev_x", "perception.hist_q"):
        broken = dict(arrays)
        broken[key] = arrays[key].reshape(-1)[:3]
        with pytest.raises(CheckpointError, match=key.replace(".", r"\.")):
            check_learner(meta, broken, good)


def test_eval_refuses_a_corrupt_checkpoint_in_one_line(good, tmp_path):
    bad = corrupt(good, tmp_path, "agent.json", lambda m: m.update(motor="abc"))
    qlap = str(Path(sys.executable).parent / "qlap")
    r = subprocess.run([qlap, "eval", "--checkpoint", str(bad), "--world", "core2d",
                        "--task", "x", "--trials", "1"], capture_output=True, text=True,
                       timeout=300, cwd=ROOT)
    assert r.returncode != 0
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "motor" in lines[0], r.stderr
