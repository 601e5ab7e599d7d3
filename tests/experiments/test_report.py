"""RESULTS.md and its figures and tables, from a tiny sweep; knowledge over time (Figs. 7.9,
7.21–7.23) read from checkpoints."""

import csv

from qlap_runtime.experiments.engine import run_sweep
from qlap_runtime.experiments.knowledge import action_calls, call_series, dbn_series
from qlap_runtime.experiments.report import collect, write_report
from qlap_runtime.experiments.sweep import plan

from .conftest import TINY, InlineBackend


def test_results_page(tiny_root):
    sweep = plan(TINY, tiny_root)
    result = run_sweep(sweep, InlineBackend(), echo=None, live=False)
    page = write_report(sweep, "qlap experiment tiny --quick", "qlap experiment tiny …", result)
    out = sweep.out
    assert page == out / "RESULTS.md"
    for name in ("move_block.png", "dbn-count.png", "calls-1.png", "curves.csv",
                 "agents.csv", "tests.csv", "experiment.json"):
        assert (out / name).is_file(), name
    text = page.read_text()
    assert "qlap experiment tiny --quick" in text and "QLAP does something." in text
    assert "F = 12.500, sig. = 0.001 (Fig. 0)" in text       # the reference beside
    assert "Provisional" in text and "The reference says so." in text
    tests = list(csv.DictReader((out / "tests.csv").read_text().splitlines()))
    assert [(t["arm"], t["versus"]) for t in tests] == [("random landmarks", "QLAP")]
    curves = list(csv.DictReader((out / "curves.csv").read_text().splitlines()))
    assert {(c["arm"], c["step"], c["agents"]) for c in curves} == {
        ("QLAP", "1000", "2"), ("QLAP", "2000", "2"),
        ("random landmarks", "1000", "2"), ("random landmarks", "2000", "2")}
    res = collect(sweep)
    assert set(res.dbns) == {"QLAP"} and len(res.dbns["QLAP"]) == 2
    assert res.random[("core2d", "move_block")] == next(
        r.mean_reward for r in sweep.rows().values() if r.policy == "random")


def test_knowledge_over_time(tiny_root):
    sweep = plan(TINY, tiny_root)
    run_sweep(sweep, InlineBackend(), echo=None, live=False)
    run = sweep.run_dir(sweep.arms["QLAP"].runs[0])
    assert sorted(dbn_series(run)) == [1000, 2000]
    calls = action_calls(run / "checkpoints" / "step-0002000")
    assert "h_x.dot=+" in calls and all(v >= 0 for v in calls.values())
    series = call_series(run)
    assert set(series) == {"move the hand (Fig. 7.21)", "move the block (Fig. 7.22)",
                           "pick up the block (Fig. 7.23)"}
    hand = series["move the hand (Fig. 7.21)"]
    assert hand[2000] >= hand[1000] >= 0                     # cumulative
