"""Synthetic inputs of the results page (no runs): a core page whose Markdown is pinned in
``data/core_page.md``, so that a change to the world-aware targets cannot alter core's page."""

from __future__ import annotations

import copy
import json
import platform
from pathlib import Path
from typing import Any

import pytest

from qlap_runtime.analysis import results
from qlap_runtime.analysis.curve import CurvePoint, CurveRow
from qlap_runtime.analysis.report import report_data
from qlap_runtime.analysis.results import ResultsConfig, TaskResult, render_page
from qlap_runtime.analysis.timeline import KnowledgePoint, growth_verdict, mean_series

from .test_report import KNOWLEDGE

CORE_PAGE = Path(__file__).parent / "data" / "core_page.md"
CORE2D_PAGE = Path(__file__).parent / "data" / "core2d_page.md"
LABELS = ["core-s1", "core-s2"]
STEPS = [20_000, *range(50_000, 250_001, 50_000), 230_000, 240_000]


def _curve(task: str, base: float, rise: float, rand: float, world: str) -> TaskResult:
    pts = []
    for step in sorted(set(STEPS)):
        a = base + rise * step / 250_000
        b = a + 0.6 - step / 1_000_000
        pts.append(CurvePoint(step, (a + b) / 2, abs(a - b) / 2, 0.4 + step / 1_000_000,
                              {"core-s1": a, "core-s2": b}))
    return TaskResult(task, world, pts,
                      CurveRow("random", None, task, rand, 0.41, 0.46, 100, 0, world,
                               "random", ""), list(LABELS), 100)


def core_inputs(tmp_path: Path, world: str = "core"
                ) -> tuple[ResultsConfig, list[TaskResult], dict[str, Any]]:
    """Two seeds of a hand-made 250,000-step run of ``world`` (core's tasks): curves,
    knowledge, DBN timelines."""
    dirs = []
    for label, k, rel in (("core-s1", 6, 0.95), ("core-s2", 7, 0.86)):
        knowledge = copy.deepcopy(KNOWLEDGE)
        knowledge["k"] = k
        knowledge["actions"][0].update(reliability=rel, plans=[{"id": 3}])
        (tmp_path / label).mkdir()
        (tmp_path / label / "knowledge.json").write_text(json.dumps(knowledge))
        dirs.append(tmp_path / label)
    data = report_data(dirs)
    timelines = {
        label: [KnowledgePoint(s, f"step-{s:07d}", 200 + off + (s // 10_000) * (3 - i),
                               40 + i, 12, 30 + s // 50_000, 6)
                for s in range(10_000, 250_001, 10_000)]
        for i, (label, off) in enumerate((("core-s1", 0), ("core-s2", 17)))}
    data["timeline"] = {label: [p.to_json() for p in pts] for label, pts in timelines.items()}
    data["growth"] = {label: growth_verdict([p.step for p in pts],
                                            [p.change_dbns for p in pts])
                      for label, pts in timelines.items()}
    common = mean_series(timelines, common=True)
    data["growth_mean"] = growth_verdict([p.step for p in common], [p.mean for p in common])
    data["speed"] = {"core-s1": {"steps_per_s": 1612.5, "placement": "sync", "steps": 250_000,
                                 "wall_time_s": 155.0},
                     "core-s2": None}
    tasks = [_curve("move_block", 2.0, 4.1, 3.817, world),
             _curve("hit_floor", 1.5, 0.2, -0.423, world),
             _curve("pickup", 0.3, 2.5, -0.104, world)]
    cfg = ResultsConfig(world=world, seeds=[1, 2], steps=250_000, trials=100, every=50_000,
                        at=[20_000, 230_000, 240_000], jobs=2, runs_dir=Path("runs/results"),
                        out=Path("docs"),
                        argv=["scripts/learning_results.py", "--every", "50000"])
    return cfg, tasks, data


def render(cfg: ResultsConfig, tasks: list[TaskResult], data: dict[str, Any],
           monkeypatch: pytest.MonkeyPatch, images: dict[str, str] | None = None,
           see_also: list[tuple[str, str]] | None = None) -> str:
    """The page with the date, machine, Python and commit fixed; core-s1 made alone and
    core-s2 beside another run (pong-s1 alone), as their logs would say (``runs_at_a_time``)."""
    monkeypatch.setattr(results, "runs_at_a_time",
                        lambda d: {"core-s1": 1, "core-s2": 2, "pong-s1": 1}.get(Path(d).name))
    monkeypatch.setattr(platform, "python_version", lambda: "3.11.7")
    monkeypatch.setattr(platform, "system", lambda: "Linux")
    shown = images if images is not None else {
        **{t.task: f"results/curve-{t.task}.png" for t in tasks}, "dbn": "results/dbn-count.png"}
    return render_page(cfg, tasks, data, shown, [Path("runs/results") / x for x in data["runs"]],
                       date="2026-12-02 06:29 UTC", cores=2, commit="e774191",
                       see_also=see_also or ())
