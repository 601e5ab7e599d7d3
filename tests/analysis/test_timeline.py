"""Knowledge over time: counts read from the checkpoints' JSON equal the full agent's, the
growth verdict by hand, means across runs, and what `qlap report` prints of them."""

import json
import math
import shutil
import subprocess
import sys

import pytest

from qlap_runtime.analysis import AnalysisError
from qlap_runtime.analysis.report import main_report, report_data
from qlap_runtime.analysis.timeline import (
    KnowledgePoint,
    checkpoint_counts,
    describe_verdict,
    growth_verdict,
    knowledge_timeline,
    mean_series,
    run_speed,
    speed_problem,
)


def kp(step: int, change: int, magnitude: int = 0, plans: int = 0,
       landmarks: int = 2) -> KnowledgePoint:
    return KnowledgePoint(step, f"step-{step:07d}", change, magnitude, plans, landmarks, 6)


def test_counts_equal_the_full_agents(grown):
    from qlap_runtime.qlap.checkpoint import load_agent

    timeline = knowledge_timeline(grown)
    assert [p.step for p in timeline] == list(range(1000, 10_001, 1000))
    assert timeline[-1].checkpoint == "step-0010000"          # final is a duplicate
    for p in timeline:
        agent = load_agent(grown / "checkpoints" / p.checkpoint)
        kinds = [d.kind for d in agent.learner.dbns.values()]
        lms = sum(len(agent.learner.perception.spaces[v.index].landmarks) for v in agent.table
                  if v.kind.value in ("motor", "magnitude"))
        assert (p.change_dbns, p.magnitude_dbns, p.plans, p.landmarks, p.k) == (
            kinds.count("change"), kinds.count("magnitude"), len(agent.plans), lms,
            agent.learner.k), p.checkpoint
    # the run learned something by its end, and the last counts are summary.json's
    summary = json.loads((grown / "summary.json").read_text())
    last = timeline[-1]
    assert last.change_dbns > 0 and last.landmarks > timeline[0].landmarks
    assert last.change_dbns + last.magnitude_dbns == summary["dbns"]
    assert (last.plans, last.landmarks) == (summary["plans"], summary["landmarks"])
    assert checkpoint_counts(grown / "checkpoints" / "final") == KnowledgePoint(
        10_000, "final", *(getattr(last, f) for f in
                           ("change_dbns", "magnitude_dbns", "plans", "landmarks", "k")))


def test_unreadable_checkpoint(grown, tmp_path):
    bad = shutil.copytree(grown / "checkpoints" / "step-0002000", tmp_path / "bad")
    (bad / "learner.json").write_text("{")
    with pytest.raises(AnalysisError, match="unreadable"):
        checkpoint_counts(bad)
    (bad / "learner.json").write_text('{"format": "something-else"}')
    with pytest.raises(AnalysisError, match="not a qlap-learner"):
        checkpoint_counts(bad)
    assert knowledge_timeline(tmp_path / "nowhere") == []


def test_growth_verdict_by_hand():
    steps = [100_000, 150_000, 200_000, 250_000]
    # 250, 260, 270 from 150k: the fitted rise is 20 of 26 allowed (10 % of the mean 260)
    v = growth_verdict(steps, [900, 250, 260, 270])            # 100k is before the window
    assert v["window"] == [150_000, 200_000, 250_000]
    assert v["rise"] == pytest.approx(20.0) and v["allowed"] == pytest.approx(26.0)
    assert v["slope_per_100k"] == pytest.approx(20.0)
    assert (v["bounded"], v["flat"], v["pass"]) == (True, True, True)
    v = growth_verdict(steps, [100, 250, 300, 350])            # +100 of 30 allowed
    assert (v["rise"], v["flat"], v["pass"]) == (pytest.approx(100.0), False, False)
    # one high checkpoint in the middle does not decide: the fitted line rises by 5
    v = growth_verdict(steps, [100, 250, 320, 255])
    assert v["rise"] == pytest.approx(5.0) and v["pass"] is True
    v = growth_verdict(steps, [100, 300, 250, 200])            # falling: not growing
    assert v["flat"] is True and v["rise"] == pytest.approx(-100.0)
    v = growth_verdict(steps, [0, 700, 700, 700])              # flat but above 600
    assert (v["bounded"], v["flat"], v["pass"]) == (False, True, False)
    assert "FAIL" in describe_verdict(v) and "> 600" in describe_verdict(v)
    v = growth_verdict([100_000, 150_000], [200, 250])         # one checkpoint in the window
    assert v["pass"] is None and v["bounded"] is True and "fewer than two" in v["reason"]
    assert describe_verdict(v).startswith("n/a")
    assert growth_verdict([], [])["pass"] is None
    # other limits, e.g. for short runs
    v = growth_verdict([1000, 2000, 3000], [10, 10, 12], limit=11, after=2000, tolerance=0.5)
    assert (v["rise"], v["allowed"], v["bounded"], v["pass"]) == (
        pytest.approx(2.0), pytest.approx(5.5), False, False)


def test_growth_on_a_real_run(grown):
    timeline = knowledge_timeline(grown)
    steps, counts = [p.step for p in timeline], [p.change_dbns for p in timeline]
    v = growth_verdict(steps, counts, after=9000)
    # two checkpoints in the window: the fitted line goes through both
    assert v["window"] == [9000, 10_000]
    assert v["rise"] == pytest.approx(counts[-1] - counts[-2])
    assert v["last"] == counts[-1] and v["last_step"] == 10_000


def test_mean_series_by_hand():
    t = {"a": [kp(10_000, 10), kp(20_000, 20), kp(30_000, 30)],
         "b": [kp(10_000, 14), kp(20_000, 30)]}
    s10, s20, s30 = mean_series(t)
    assert (s10.mean, s10.n) == (12.0, 2)
    assert s10.stderr == pytest.approx(2.0)                 # s = 2√2, n = 2
    assert s20.mean == 25.0 and s20.stderr == pytest.approx(5.0)
    assert (s30.mean, s30.n) == (30.0, 1) and math.isnan(s30.stderr)
    assert [p.step for p in mean_series(t, common=True)] == [10_000, 20_000]
    assert [p.mean for p in mean_series(t, "landmarks")] == [2.0, 2.0, 2.0]


def test_report_shows_knowledge_over_time(grown, runs):
    data = report_data([grown, runs[0]])
    timeline = knowledge_timeline(grown)
    assert data["timeline"]["g1"] == [p.to_json() for p in timeline]
    assert [q["step"] for q in data["timeline"]["s1"]] == [1000, 2000, 3000]
    assert data["growth"]["g1"]["pass"] is None             # 10,000 steps: not judged
    assert data["growth"]["g1"]["last"] == timeline[-1].change_dbns
    assert data["growth_mean"]["last_step"] == 3000         # steps both runs have
    speeds = [json.loads((d / "summary.json").read_text())["steps_per_s"]
              for d in (grown, runs[0])]
    assert data["speed"]["g1"] == run_speed(grown)
    assert data["speed"]["g1"]["steps_per_s"] == speeds[0]
    assert data["speed"]["g1"]["placement"] == "sync"
    assert data["mean"]["steps_per_s"] == pytest.approx(sum(speeds) / 2)

    text = main_report([grown, runs[0]])
    lines = text.splitlines()
    row = next(x for x in lines if x.startswith("10,000 "))
    last = timeline[-1]
    assert (f"{last.change_dbns} / {last.magnitude_dbns} / {last.plans} / {last.landmarks}"
            in row) and "(1 of 2 runs)" in row
    assert any(x.split()[:2] == ["g1", "n/a:"] for x in lines)
    speed_line = next(x for x in lines if x.strip().startswith("mean") and "steps/s" in x)
    assert f"{sum(speeds) / 2:,.1f} steps/s" in speed_line


def test_report_of_a_checkpoint_dir_has_no_timeline(runs):
    data = report_data([runs[0] / "checkpoints" / "step-0002000"])
    assert data["timeline"] == {"step-0002000": []}
    assert data["speed"] == {"step-0002000": None}
    assert "no checkpoints" in main_report([runs[0] / "checkpoints" / "step-0002000"])


def test_cli_report_json_has_the_timeline(runs):
    r = subprocess.run([sys.executable, "-m", "qlap_runtime.cli", "report", "--json",
                        str(runs[1])], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert [q["step"] for q in out["timeline"]["s2"]] == [1000, 2000, 3000]
    assert out["speed"]["s2"]["steps_per_s"] > 0
    assert out["reference"]["growth"]["limit"] == 600


def test_a_truncated_summary_is_named_not_called_missing(tmp_path):
    run = tmp_path / "r"
    run.mkdir()
    assert run_speed(run) is None and speed_problem(None) == "no summary.json"
    (run / "summary.json").write_text('{"steps_per_s": 2146.0, "plac')     # cut mid-write
    sp = run_speed(run)
    assert sp["steps_per_s"] is None
    assert speed_problem(sp).startswith("summary.json unreadable: ")
    (run / "summary.json").write_text("[1, 2]")
    assert speed_problem(run_speed(run)) == "summary.json is not a JSON object"
    (run / "summary.json").write_text('{"steps": 10}')
    assert speed_problem(run_speed(run)) == "no steps_per_s in summary.json"
