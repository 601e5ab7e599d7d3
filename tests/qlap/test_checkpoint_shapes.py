"""Checkpoint arrays of inconsistent shapes: refused at load with a one-line CheckpointError
"FILE: inconsistent checkpoint: ARRAY …", not a broadcast or zip() error later in the run."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

import worlds
from qlap_runtime.agent_run import run_agent
from qlap_runtime.qlap import Params
from qlap_runtime.qlap.checkpoint import (
    STATS_PART,
    CheckpointError,
    load_agent,
    load_learner,
    resolve_checkpoint,
    save_statistics,
)
from qlap_runtime.qlap.checkpoint.files import read_npz, write_npz

ROOT = Path(__file__).resolve().parents[2]

Arrays = dict[str, np.ndarray]


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> Path:
    """A real agent checkpoint of a short learning run in core (about 3 s): DBNs with contexts
    of 1, 3 and 9 cells, pending activations, plans with C_o of 1 and 3 cells and Q-tables of
    several shapes, with traces."""
    out = tmp_path_factory.mktemp("ckpt")
    world = worlds.make("core")
    try:
        run_agent(world, 8000, 3, out=out,
                  params=Params(babble_steps=4000, dbn_period=500, landmark_period=1000))
    finally:
        world.close()
    return resolve_checkpoint(out / "checkpoints" / "final")


def copy_of(good: Path, tmp_path: Path) -> Path:
    bad = tmp_path / "bad"
    shutil.copytree(good, bad)
    return bad


def rewrite(ckpt: Path, name: str, edit: Callable[[Arrays], None]) -> None:
    """Edit the arrays of ``ckpt/name`` as stored (grouped, row-indexed) and write them back."""
    arrays = read_npz(ckpt / name)
    edit(arrays)
    write_npz(ckpt / name, arrays)


def swap_shapes(arrays: Arrays, key: str) -> str:
    """Swap the shapes of the first two objects of the grouped array ``key`` whose sizes
    differ, so that the values still add up; the name of the first object's array."""
    shapes, ids = arrays[f"{key}.shapes"].copy(), arrays[f"{key}.ids"]
    sizes = shapes.prod(axis=1)
    first = int(np.flatnonzero(sizes != sizes.min())[0])
    other = int(np.flatnonzero(sizes == sizes.min())[0])
    i, j = sorted((first, other))
    shapes[[i, j]] = shapes[[j, i]]
    arrays[f"{key}.shapes"] = shapes
    return key.replace("*", str(int(ids[i])))


def move_a_row(arrays: Arrays, key: str) -> str:
    """One row fewer for the first object of the grouped array ``key``, one more for the
    second (the total unchanged); the first object's array."""
    shapes = arrays[f"{key}.shapes"].copy()
    assert len(shapes) >= 2 and shapes[0, 0] >= 1
    shapes[0, 0] -= 1
    shapes[1, 0] += 1
    arrays[f"{key}.shapes"] = shapes
    return key.replace("*", str(int(arrays[f"{key}.ids"][0]))).removesuffix("@rows")


def cut_soon_given(a: Arrays) -> str:
    a["pairs.soon_given"] = a["pairs.soon_given"][:, :2].copy()       # the user trial's
    return "pairs.soon_given"


def reverse_cpt_ids(a: Arrays) -> str:
    a["dbn.*.cpt_s.ids"] = a["dbn.*.cpt_s.ids"][::-1].copy()          # the user trial's
    return "dbn.*.cpt_s.ids"


def cut(key: str) -> Callable[[Arrays], str]:
    """One value (or row) fewer in ``key``; the array named is the one it is stored for."""
    def edit(a: Arrays) -> str:
        a[key] = a[key][:-1].copy()
        return key.removesuffix("@rows")
    return edit


def index_past_the_table(a: Arrays) -> str:
    a["dbn.*.act_x@rows"] = a["dbn.*.act_x@rows"] + len(a["_rows"])
    return "act_x@rows"


def reverse_plan_ids(a: Arrays) -> str:
    a["plan.*.q_na.ids"] = a["plan.*.q_na.ids"][::-1].copy()
    return "plan.*.q_na.ids"


def transpose_traces(a: Arrays) -> str:
    """Every plan's traces transposed (the values add up still): the first plan whose
    Q-table is not square is named."""
    shapes = a["plan.*.traces.shapes"]
    a["plan.*.traces.shapes"] = shapes[:, ::-1].copy()
    first = int(np.flatnonzero(shapes[:, 0] != shapes[:, 1])[0])
    return f"plan.{int(a['plan.*.traces.ids'][first])}.traces"


LEARNER_CASES: dict[str, Callable[[Arrays], str]] = {
    "soon_given cut to (N, 2)": cut_soon_given,
    "cpt_s ids reversed": reverse_cpt_ids,
    "cpt_s shapes swapped": lambda a: swap_shapes(a, "dbn.*.cpt_s"),
    "pending_x rows moved": lambda a: move_a_row(a, "dbn.*.pending_x@rows"),
    "act_ok one value short": cut("dbn.*.act_ok"),
    "act_x rows past the table": index_past_the_table,
    "occurrences cut": cut("pairs.occurrences"),
    "prev_q cut": cut("perception.prev_q"),
    "hist_x rows cut": cut("perception.hist_x@rows"),
}

AGENT_CASES: dict[str, Callable[[Arrays], str]] = {
    "plan cpt_s shapes swapped": lambda a: swap_shapes(a, "plan.*.cpt_s"),
    "plan q_na ids reversed": reverse_plan_ids,
    "plan traces transposed": transpose_traces,
    "plan call_ok one value short": cut("plan.*.call_ok"),
}


def expect_inconsistent(bad: Path, name: str, load=load_agent) -> str:
    with pytest.raises(CheckpointError) as info:
        load(bad)
    msg = str(info.value)
    assert "inconsistent checkpoint" in msg and name in msg, msg
    assert "\n" not in msg
    return msg


def test_an_unmodified_checkpoint_loads(good):
    arrays = read_npz(good / "learner.npz")
    # the fixture has what the cases corrupt
    assert len(set(arrays["dbn.*.cpt_s.shapes"][:, 0].tolist())) >= 2
    assert len(arrays["dbn.*.pending_x@rows.ids"]) >= 2
    assert len(set(read_npz(good / "agent.npz")["plan.*.cpt_s.shapes"][:, 0].tolist())) >= 2
    agent = load_agent(good)
    assert agent.plans and agent.learner.dbns
    learner = load_learner(good)
    assert learner.pairs.soon_given.shape == (learner.perception.events.n_events,
                                              learner.perception.events.n_cons)


@pytest.mark.parametrize("case", list(LEARNER_CASES))
def test_learner_arrays_of_inconsistent_shapes_are_named(good, tmp_path, case):
    bad = copy_of(good, tmp_path)
    name: list[str] = []
    rewrite(bad, "learner.npz", lambda a: name.append(LEARNER_CASES[case](a)))
    msg = expect_inconsistent(bad, name[0], load_learner)
    assert msg.startswith(f"{bad / 'learner'}: "), msg
    expect_inconsistent(bad, name[0])                   # the agent's load says the same


@pytest.mark.parametrize("case", list(AGENT_CASES))
def test_agent_arrays_of_inconsistent_shapes_are_named(good, tmp_path, case):
    bad = copy_of(good, tmp_path)
    name: list[str] = []
    rewrite(bad, "agent.npz", lambda a: name.append(AGENT_CASES[case](a)))
    msg = expect_inconsistent(bad, name[0])
    assert msg.startswith(f"{bad / 'agent'}: "), msg


def test_a_q_table_not_of_its_plans_shape_is_named(good, tmp_path):
    """A Q-table whose stored arrays agree with each other (``q_shape``, the bit mask, the
    values, the traces) but not with the plan's states × actions: found once the plan is
    rebuilt from its DBN."""
    bad = copy_of(good, tmp_path)
    meta = json.loads((bad / "agent.json").read_text())
    plan = next(p for p in meta["plans"] if p["q_shape"][0] != p["q_shape"][1])
    plan["q_shape"] = plan["q_shape"][::-1]
    (bad / "agent.json").write_text(json.dumps(meta))

    def transpose_its_traces(a: Arrays) -> None:
        k = a["plan.*.traces.ids"].tolist().index(plan["id"])
        shapes = a["plan.*.traces.shapes"].copy()
        shapes[k] = shapes[k][::-1]
        a["plan.*.traces.shapes"] = shapes

    rewrite(bad, "agent.npz", transpose_its_traces)
    msg = expect_inconsistent(bad, f"plan.{plan['id']}.q_values")
    assert re.search(r"expected \(\d+, \d+\) \(plan \d+'s states × actions\)", msg), msg


def test_pair_statistics_of_the_stats_part_name_it(good, tmp_path):
    """An actor placement's checkpoint has its pair statistics in ``stats.npz``
    (:data:`STATS_PART`): a wrong shape there names that file."""
    bad = copy_of(good, tmp_path)
    save_statistics(load_learner(good), bad)
    assert load_learner(bad).pairs.soon_given.shape == load_learner(good).pairs.soon_given.shape
    rewrite(bad, f"{STATS_PART}.npz", cut_soon_given)
    msg = expect_inconsistent(bad, "pairs.soon_given", load_learner)
    assert msg.startswith(f"{bad / STATS_PART}: "), msg


@pytest.mark.parametrize("case", ["soon_given cut to (N, 2)", "cpt_s ids reversed"])
def test_show_and_resume_refuse_in_one_line(good, tmp_path, case):
    """The user trial's two checkpoints: ``qlap show`` and ``qlap run --resume`` end with one
    line naming the array, not a traceback from the middle of the run."""
    bad = copy_of(good, tmp_path)
    name: list[str] = []
    rewrite(bad, "learner.npz", lambda a: name.append(LEARNER_CASES[case](a)))
    qlap = str(Path(sys.executable).parent / "qlap")
    for args in (["show", str(bad)],
                 ["run", "--headless", "--placement", "sync", "--resume", str(bad),
                  "--steps", "200", "--out", str(tmp_path / "out")]):
        r = subprocess.run([qlap, *args], capture_output=True, text=True, timeout=300,
                           cwd=ROOT)
        assert r.returncode != 0, (args, r.stdout, r.stderr)
        lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
        assert len(lines) == 1 and "inconsistent checkpoint" in lines[0] \
            and name[0] in lines[0], (args, r.stderr)
        assert "Traceback" not in r.stderr


@pytest.mark.parametrize(("key", "edit", "fragment"), [
    ("perception.prev_q", lambda a: a.__setitem__(0, 10**6), "perception.prev_q holds 1000000"),
    ("perception.prev_q", lambda a: a.__setitem__(0, -7), "perception.prev_q holds -7"),
    ("perception.hist_q", lambda a: a.__setitem__((0, 1), 30000), "perception.hist_q holds 30000"),
    ("pairs.occurrences", lambda a: a.__setitem__(0, -3), "pairs.occurrences holds a negative"),
])
def test_values_out_of_their_range_are_named(good, tmp_path, key, edit, fragment):
    # Small arrays only: the qualitative values the perception remembers must be values of
    # their variable (or −1), the pair counts not negative.
    from qlap_runtime.qlap.checkpoint.files import read_npz, write_npz

    bad_ckpt = tmp_path / "bad"
    shutil.copytree(good, bad_ckpt)
    arrays = read_npz(bad_ckpt / "learner.npz")
    edit(arrays[key])
    write_npz(bad_ckpt / "learner.npz", arrays)
    with pytest.raises(CheckpointError, match=f"inconsistent checkpoint: {re.escape(fragment)}"):
        load_learner(bad_ckpt)
