"""qlap curve: checkpoints found, evaluated in worker processes as `qlap eval` does, resumed,
aggregated across runs (mean and s/√n), drawn."""

import json
import math
import shutil
import subprocess
import sys

import pytest

from qlap_runtime.analysis import AnalysisError
from qlap_runtime.analysis.curve import (
    CurveRow,
    EvalJob,
    aggregate,
    evaluate_job,
    main_curve,
    read_rows,
    select_every,
    write_rows,
)
from qlap_runtime.analysis.runs import (
    Checkpoint,
    checkpoint_step,
    find_checkpoints,
    run_world,
)

from .conftest import tiny_run


def row(run: str, step: int, mean: float, stderr: float = 0.5,
        success: float = 0.5) -> CurveRow:
    return CurveRow(run, step, "move_block", mean, stderr, success, 10, 0, "core2d", "qlap",
                    f"step-{step:07d}")


def test_checkpoints_final_only_when_not_a_duplicate(runs, tmp_path):
    found = find_checkpoints(runs[0], "s1")
    assert [(c.name, c.step) for c in found] == [
        ("step-0001000", 1000), ("step-0002000", 2000), ("step-0003000", 3000)]
    assert checkpoint_step(runs[0] / "checkpoints" / "final") == 3000   # a duplicate
    odd = tiny_run(tmp_path / "odd", seed=3, steps=2500)
    assert [(c.name, c.step) for c in find_checkpoints(odd, "odd")] == [
        ("step-0001000", 1000), ("step-0002000", 2000), ("final", 2500)]


def test_world_from_summary_or_option(runs, tmp_path):
    found = find_checkpoints(runs[0], "s1")
    assert run_world(runs[0], found, None) == "core2d"        # summary.json's world
    assert run_world(runs[0], found, "core2d") == "core2d"
    bare = tmp_path / "bare"
    shutil.copytree(runs[0] / "checkpoints", bare / "checkpoints")
    # the checkpoints record their world: no summary.json needed
    assert run_world(bare, find_checkpoints(bare, "bare"), None) == "core2d"
    for meta in bare.glob("checkpoints/*/agent.json"):     # checkpoints of an older format
        d = json.loads(meta.read_text())
        d.pop("world")
        meta.write_text(json.dumps(d))
    with pytest.raises(AnalysisError, match="--world"):
        run_world(bare, find_checkpoints(bare, "bare"), None)
    assert run_world(bare, find_checkpoints(bare, "bare"), "core2d") == "core2d"


def test_aggregate_across_runs_by_hand():
    rows = [row("a", 10_000, 1.0), row("b", 10_000, 2.0), row("c", 10_000, 4.0),
            row("a", 20_000, 3.0, success=0.2), row("b", 20_000, 5.0, success=0.6)]
    p10, p20 = aggregate(rows, n_runs=3)
    assert p10.step == 10_000 and p10.runs == {"a": 1.0, "b": 2.0, "c": 4.0}
    assert p10.mean_reward == pytest.approx(7 / 3)
    # deviations −4/3, −1/3, 5/3: s² = (16 + 1 + 25)/9/2 = 7/3, s.e. = √(7/3)/√3 = √7/3
    assert p10.stderr == pytest.approx(math.sqrt(7) / 3)
    assert p20.mean_reward == pytest.approx(4.0)
    assert p20.stderr == pytest.approx(1.0)              # s = √2, n = 2
    assert p20.success_rate == pytest.approx(0.4)
    (only,) = aggregate([row("c", 10_000, 4.0)], n_runs=3)
    assert math.isnan(only.stderr)                      # one run of several: no spread
    (single,) = aggregate([row("a", 10_000, 1.0, stderr=0.25)], n_runs=1)
    assert single.stderr == 0.25                        # one run: s.e. over its trials


def test_csv_round_trip(tmp_path):
    rows = [row("a", 10_000, 1 / 3),
            CurveRow("random", None, "move_block", 6.407, 1.59, 0.7, 10, 0, "core2d",
                     "random", "")]
    write_rows(tmp_path / "curve.csv", rows)
    back = read_rows(tmp_path / "curve.csv")
    assert back[0].policy == "random" and back[0].step is None   # the baseline first
    assert sorted(back, key=lambda r: r.run) == sorted(rows, key=lambda r: r.run)
    assert not list(tmp_path.glob(".curve.csv.*"))                # no temporary left


def test_a_damaged_curve_csv_is_a_one_line_error(tmp_path):
    path = tmp_path / "curve.csv"
    path.write_bytes(b"policy,run\n\xff\xfe garbage\n")
    with pytest.raises(AnalysisError, match=r"curve.csv: not a curve.csv \(not UTF-8 text: "
                                            r"invalid start byte at byte 11\)"):
        read_rows(path)
    path.write_text("run,step\nx,1\n")
    with pytest.raises(AnalysisError, match=r"not a curve.csv \(columns run, step, task"):
        read_rows(path)


def test_curve_of_one_run_then_of_two_resumes(runs, tmp_path):
    s1, s2 = (shutil.copytree(r, tmp_path / r.name) for r in runs)
    lines: list[str] = []
    assert main_curve([s1], "move_block", trials=4, jobs=2, echo=lines.append) == 0
    rows = read_rows(s1 / "curve.csv")
    assert [(r.run, r.step, r.checkpoint) for r in rows] == [
        ("random", None, ""), ("s1", 1000, "step-0001000"), ("s1", 2000, "step-0002000"),
        ("s1", 3000, "step-0003000")]
    assert all((r.task, r.trials, r.seed, r.world) == ("move_block", 4, 0, "core2d")
               for r in rows)
    assert sum(line.startswith("[") for line in lines) == 4        # one line per evaluation
    assert (s1 / "curve.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the numbers are those of `qlap eval` (the same function, here in this process)
    direct = evaluate_job(EvalJob(str(s1 / "checkpoints" / "step-0002000"), "core2d",
                                  "move_block", 4, 0))
    assert rows[2].mean_reward == direct["mean_reward"]
    assert rows[2].stderr == direct["stderr"]
    rnd = evaluate_job(EvalJob(None, "core2d", "move_block", 4, 0))
    assert rows[0].mean_reward == rnd["mean_reward"]

    lines.clear()                                        # resumed: nothing recomputed
    assert main_curve([s1], "move_block", trials=4, jobs=2, echo=lines.append) == 0
    assert "nothing to run" in lines[0] and not any(x.startswith("[") for x in lines)

    out = tmp_path / "both"
    lines.clear()
    assert main_curve([s1, s2], "move_block", trials=4, jobs=2, out=out,
                      echo=lines.append) == 0
    assert "4 of 7 evaluations" in lines[0]              # s1's own curve.csv was reused
    both = read_rows(out / "curve.csv")
    assert len(both) == 7 and (out / "curve.png").exists()
    for step in (1000, 2000, 3000):
        a, b = (next(r.mean_reward for r in both if r.run == run and r.step == step)
                for run in ("s1", "s2"))
        mean_line = next(x for x in "\n".join(lines).splitlines()
                         if x.split()[:2] == [str(step), "2"])
        assert float(mean_line.split()[2]) == pytest.approx((a + b) / 2, abs=5e-4)
        assert float(mean_line.split()[3]) == pytest.approx(abs(a - b) / 2, abs=5e-4)


def test_curve_errors(runs, tmp_path):
    with pytest.raises(AnalysisError, match="--out"):
        main_curve(runs, "move_block", trials=2, echo=lambda s: None)
    with pytest.raises(AnalysisError, match="no task 'pickup'"):
        main_curve([runs[0]], "pickup", trials=2, out=tmp_path, echo=lambda s: None)
    with pytest.raises(AnalysisError, match="no agent checkpoints"):
        main_curve([tmp_path], "move_block", trials=2, echo=lambda s: None)
    final = runs[0] / "checkpoints" / "final"
    with pytest.raises(AnalysisError, match=r"is a checkpoint, not a run directory: give the "
                                            rf"run that holds it \({runs[0].resolve()}\)"):
        main_curve([final], "move_block", trials=2, echo=lambda s: None)
    loose = shutil.copytree(final, tmp_path / "ck")
    with pytest.raises(AnalysisError, match=r"ck is a checkpoint, not a run directory: give a "
                                            r"run directory \(one with checkpoints/\)"):
        main_curve([loose], "move_block", trials=2, echo=lambda s: None)
    with pytest.raises(AnalysisError, match=r"checkpoints holds a run's checkpoints: give the "
                                            r"run directory"):
        main_curve([runs[0] / "checkpoints"], "move_block", trials=2, echo=lambda s: None)
    (tmp_path / "afile").write_text("")
    with pytest.raises(AnalysisError, match="afile: a file, not a run directory"):
        main_curve([tmp_path / "afile"], "move_block", trials=2, echo=lambda s: None)


def test_a_refused_curve_leaves_no_out_directory(runs, tmp_path):
    out = tmp_path / "new" / "curve"
    r = subprocess.run([sys.executable, "-m", "qlap_runtime.cli", "curve", str(runs[0]),
                        "--task", "pickup", "--out", str(out)], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2 and "no task 'pickup'" in r.stderr
    assert not (tmp_path / "new").exists()                 # nor the parent it made


def test_cli_hook(runs):
    r = subprocess.run([sys.executable, "-m", "qlap_runtime.cli", "curve", *map(str, runs),
                        "--task", "move_block"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "--out" in r.stderr


def test_a_broken_checkpoint_fails_alone(runs, tmp_path):
    s1 = shutil.copytree(runs[0], tmp_path / "s1")
    (s1 / "checkpoints" / "step-0002000" / "learner.json").write_text("{")
    lines: list[str] = []
    assert main_curve([s1], "move_block", trials=2, jobs=2, echo=lines.append) == 1
    assert any("step-0002000" in x and "FAILED" in x for x in lines)
    assert [r.step for r in read_rows(s1 / "curve.csv")] == [None, 1000, 3000]


def test_select_every_by_hand(tmp_path):
    def ck(run: str, step: int, name: str | None = None) -> Checkpoint:
        return Checkpoint(run, tmp_path, step, name or f"step-{step:07d}")

    cks = [ck("a", s) for s in range(10_000, 250_001, 10_000)] + [
        ck("b", 10_000), ck("b", 20_000), ck("b", 25_000, "final")]
    assert select_every(cks, None) == cks
    got = select_every(cks, 50_000)
    assert [(c.run, c.step) for c in got] == [
        ("a", 50_000), ("a", 100_000), ("a", 150_000), ("a", 200_000), ("a", 250_000),
        ("b", 25_000)]                                   # b's last, though no multiple
    assert [c.step for c in select_every(cks, 10_000) if c.run == "a"] == list(
        range(10_000, 250_001, 10_000))                  # the reference's schedule: all
    with pytest.raises(AnalysisError, match="positive"):
        select_every(cks, 0)
    assert [(c.run, c.step) for c in select_every(cks, 100_000, at=(20_000, 230_000))] == [
        ("a", 20_000), ("a", 100_000), ("a", 200_000), ("a", 230_000), ("a", 250_000),
        ("b", 20_000), ("b", 25_000)]
    with pytest.raises(AnalysisError, match=r"--at 12345 230001: no run has a checkpoint of "
                                            r"that step \(the steps: 10,000, 20,000, 25,000"):
        select_every(cks, 100_000, at=(20_000, 12_345, 230_001))


def test_curve_every(runs, tmp_path):
    s1 = shutil.copytree(runs[0], tmp_path / "s1")
    lines: list[str] = []
    assert main_curve([s1], "move_block", trials=2, jobs=2, echo=lines.append,
                      every=2000) == 0
    assert "2 of 3 checkpoints (steps multiple of 2,000, and each run's last)" in lines[0]
    assert [(r.step, r.checkpoint) for r in read_rows(s1 / "curve.csv")] == [
        (None, ""), (2000, "step-0002000"), (3000, "step-0003000")]
    lines.clear()                                        # all of them: only 1000 is new
    assert main_curve([s1], "move_block", trials=2, jobs=2, echo=lines.append) == 0
    assert "3 of 4 evaluations" in lines[0]
    assert [r.step for r in read_rows(s1 / "curve.csv")] == [None, 1000, 2000, 3000]


def test_cli_every_must_be_positive(runs):
    r = subprocess.run([sys.executable, "-m", "qlap_runtime.cli", "curve", str(runs[0]),
                        "--task", "move_block", "--every", "0"], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 2 and "--every" in r.stderr and "positive" in r.stderr


def test_cli_at_adds_steps_to_every(runs, tmp_path):
    """`--at` reaches main_curve: the page's command (docs/results.md) reproduces its curves."""
    s1 = shutil.copytree(runs[0], tmp_path / "s1")
    r = subprocess.run([sys.executable, "-m", "qlap_runtime.cli", "curve", str(s1),
                        "--task", "move_block", "--trials", "2", "--jobs", "2",
                        "--every", "3000", "--at", "1000"], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    assert [r.step for r in read_rows(s1 / "curve.csv")] == [None, 1000, 3000]


def test_sigterm_stops_the_workers_at_once(runs, tmp_path):
    """`kill` of `qlap curve`: its worker processes are stopped with it (not orphaned, not
    waited for); curve.csv keeps the evaluations that finished."""
    import signal
    import time

    s1 = shutil.copytree(runs[0], tmp_path / "s1")
    p = subprocess.Popen([sys.executable, "-m", "qlap_runtime.cli", "curve", str(s1), "--task",
                          "move_block", "--trials", "100000", "--jobs", "2"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert p.stdout is not None
    p.stdout.readline()                                   # the plan: the workers are starting
    time.sleep(3)
    t0 = time.monotonic()
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=60)
    assert time.monotonic() - t0 < 20 and p.returncode == 130, err
    assert "interrupted" in err
