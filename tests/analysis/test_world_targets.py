"""World-aware targets of the results page: core's page is byte-identical to the one the code
made before targets depended on the world, and pong's verdicts, computed by hand on small
synthetic inputs."""

import copy
import json
import math
from pathlib import Path

import pytest

from qlap_runtime.analysis import reference_values as ref
from qlap_runtime.analysis.curve import CurveRow, aggregate
from qlap_runtime.analysis.report import report_data
from qlap_runtime.analysis.results import (
    ResultsConfig,
    TaskResult,
    _knowledge_rows,
    clearly_above,
    other_pages,
    task_targets,
)
from qlap_runtime.analysis.timeline import growth_verdict
from qlap_runtime.telemetry import pretty

from .pages import CORE2D_PAGE, CORE_PAGE, core_inputs, render
from .test_report import KNOWLEDGE, lm

SEEDS = [f"pong-s{i}" for i in range(1, 6)]
CLEARLY = ("clearly above the random policy: mean − random > 2 s.e. of the difference, and "
           "every seed above random")
RISES = "each of the last three checkpoints above the 20k one"


def pong_result(final: list[float], random_se: float = 0.05) -> TaskResult:
    """Five seeds evaluated at 20k (0.40 each), 80k, 90k (0.70, 0.75 each) and 100k
    (``final``), against a random policy at 0.29 ± ``random_se``."""
    rows = [CurveRow(run, step, "pong_volley", value, 0.1, value, 100, 0, "pong", "qlap",
                     f"step-{step:07d}")
            for step, values in ((20_000, [0.4] * 5), (80_000, [0.7] * 5),
                                 (90_000, [0.75] * 5), (100_000, final))
            for run, value in zip(SEEDS, values, strict=True)]
    base = CurveRow("random", None, "pong_volley", 0.29, random_se, 0.29, 100, 0, "pong",
                    "random", "")
    return TaskResult("pong_volley", "pong", aggregate(rows, 5), base, list(SEEDS), 100)


def test_targets_by_world():
    assert ref.targets_for("pong") is ref.PONG_TARGETS
    assert ref.targets_for("pong:wide") is ref.PONG_TARGETS
    for world in ("core", "core:floating", "core2d", "gym:Pendulum-v1"):
        assert ref.targets_for(world) is ref.CORE_TARGETS
    core = ref.CORE_TARGETS        # core's targets are the constants the page used before
    assert (core.task_reward, core.above_random, core.change_dbn_limit, core.growth_after,
            core.growth_tolerance, core.steps_per_s, core.k_range) == (
        ref.TASK_REWARD, 2.0, 600, 150_000, 0.10, 1500.0, (4, 8))
    assert core.actions == ref.ACTIONS and core.clearly_above_random is None
    pong = ref.PONG_TARGETS
    assert (pong.steps, pong.growth_after, pong.landmarks_max, pong.landmarks_median) == (
        100_000, 50_000, 9, None)
    assert pong.actions == () and pong.steps_per_s is None and pong.above_random is None


def test_core_pages_are_unchanged(tmp_path, monkeypatch):
    for world, golden in (("core", CORE_PAGE), ("core2d", CORE2D_PAGE)):
        (tmp_path / world).mkdir()
        cfg, tasks, data = core_inputs(tmp_path / world, world)
        assert render(cfg, tasks, data, monkeypatch) == golden.read_text(), world


def test_core_links_the_pong_page_and_nothing_else_changes(tmp_path, monkeypatch):
    out = tmp_path / "docs"
    assert other_pages(out, ref.CORE_TARGETS) == []
    (out / "pong").mkdir(parents=True)
    (out / "pong" / "results.md").write_text("# Learning results: pong\n")
    links = other_pages(out, ref.CORE_TARGETS)
    assert links == [("the same page for pong (100,000-step runs, at least 5 seeds)",
                      "pong/results.md")]
    assert other_pages(out, ref.PONG_TARGETS) == []
    cfg, tasks, data = core_inputs(tmp_path)
    page = render(cfg, tasks, data, monkeypatch, see_also=links).splitlines()
    golden = CORE_PAGE.read_text().splitlines()
    line = ("- See also: the same page for pong (100,000-step runs, at least 5 seeds), "
            "[pong/results.md](pong/results.md).")
    at = page.index(line)
    assert page[:at] + page[at + 1:] == golden and page[at - 1].startswith("- World `core`")


def test_pong_clearly_above_random_by_hand():
    # 0.9, 0.8, 1.0, 0.7, 0.6: mean 0.80, s = √(0.1/4) = 0.1581, s.e. 0.0707; with the random
    # policy's 0.05 the difference's s.e. is √(0.005 + 0.0025) = 0.0866, 2 s.e. = 0.17
    res = pong_result([0.9, 0.8, 1.0, 0.7, 0.6])
    assert res.points[-1].stderr == pytest.approx(math.sqrt(0.025 / 5))
    clearly, rises = task_targets(res)                   # no reward floor, no "+2" margin
    assert clearly == (CLEARLY, "+0.51 (0.80 against 0.29), 2 s.e. = 0.17; 5/5 seeds above",
                       True)
    assert rises == (RISES, "0.70, 0.75, 0.80 against 0.40", True)

    # the same mean, one seed under the random policy: not clearly above
    one_below = task_targets(pong_result([1.2, 1.0, 0.25, 0.9, 0.65]))[0]
    assert one_below[1].endswith("4/5 seeds above") and one_below[2] is False

    # 0.30, 0.31, 0.60, 0.50, 0.54: mean 0.45, s.e. across seeds √(0.0188/5) = 0.0613; the
    # margin 0.16 is above 2 × 0.0613 = 0.123 but not above 2 √(0.0613² + 0.06²) = 0.172
    near = pong_result([0.3, 0.31, 0.6, 0.5, 0.54], random_se=0.06)
    assert near.points[-1].stderr == pytest.approx(math.sqrt(0.0188 / 5))
    _, measured, met = task_targets(near)[0]
    assert measured == "+0.16 (0.45 against 0.29), 2 s.e. = 0.17; 5/5 seeds above"
    assert met is False
    assert task_targets(near, ref.CORE_TARGETS)[0][0] == "at least 2 above the random policy"

    # a dip at 90k under the 20k value fails the rise; one seed alone is not judged
    res = pong_result([0.9, 0.8, 1.0, 0.7, 0.6])
    dip = TaskResult(res.task, res.world, [*res.points[:2],
                                           type(res.points[2])(90_000, 0.35, 0.0, 0.3, {}),
                                           res.points[3]], res.baseline, res.labels, 100)
    assert task_targets(dip)[1] == (RISES, "0.70, 0.35, 0.80 against 0.40", False)
    alone = clearly_above(res.points[-1].__class__(100_000, 0.8, math.nan, 0.8,
                                                   {"pong-s1": 0.8}),
                          res.baseline, 1, 2.0)
    assert alone[2] is None and "not judged" in alone[1]
    assert clearly_above(None, res.baseline, 5, 2.0) == (CLEARLY, "—", None)


def _pong_data(tmp_path: Path) -> dict:
    dirs = []
    for label, change, u_marks in (("pong-s1", 439, 7), ("pong-s2", 520, 10)):
        knowledge = copy.deepcopy(KNOWLEDGE)
        knowledge["k"] = 6
        knowledge["dbns"] = [{"kind": "change"}] * change + [{"kind": "magnitude"}] * 100
        knowledge["landmarks"] = {
            "u": [lm(-0.05 - i, -0.05 - i) for i in range(u_marks - 1)]
            + [lm(0.0, 0.0, "initial")],
            "b_y": [lm(3.0, 3.0), lm(6.0, 6.0)], "cl_y": [lm(0.0, 0.0)]}
        (tmp_path / label).mkdir()
        (tmp_path / label / "knowledge.json").write_text(json.dumps(knowledge))
        dirs.append(tmp_path / label)
    data = report_data(dirs, ref.PONG_TARGETS)
    steps = list(range(50_000, 100_001, 10_000))
    rule = {"after": 50_000}
    data["growth"] = {"pong-s1": growth_verdict(steps, [400, 420, 430, 435, 440, 440], **rule),
                      "pong-s2": growth_verdict(steps, [300, 350, 400, 450, 500, 520], **rule)}
    data["growth_mean"] = growth_verdict(steps, [350, 385, 415, 442.5, 470, 480], **rule)
    return data


def test_pong_knowledge_rows_by_hand(tmp_path):
    data = _pong_data(tmp_path)
    rows = {r[0]: r for r in _knowledge_rows(data, ref.PONG_TARGETS)}
    assert list(rows) == ["window k (App. C)", "change DBNs at the end",
                          "change DBNs not growing after 50k", "magnitude DBNs at the end",
                          "landmarks per variable, median", "landmarks per variable, max",
                          "values narrower than the resolution"]        # no chapter-8 rows
    assert rows["window k (App. C)"][2:] == ["4 to 8", "6", "6", "6.0", "2/2", "✅ pass"]
    assert rows["change DBNs at the end"][1:] == ["—", "≤ 600", "439", "520", "479.5", "2/2",
                                                  "✅ pass"]
    # s1: slope 132.5 / 17.5 = 7.571 per 10k, rise 37.9 over 50k, allowed 10 % of 427.5;
    # s2: 800 / 17.5 = 45.71 per 10k, rise 228.6 against 42.0; the mean: 466.25 / 17.5 =
    # 26.64 per 10k, rise 133.2 against 42.4
    growth = rows["change DBNs not growing after 50k"]
    assert growth[1:] == ["—", "fitted rise ≤ 10% of the mean", "+37.9 of 42.8 allowed",
                          "+228.6 of 42.0 allowed", "+133.2 of 42.4 allowed", "1/2", "❌ fail"]
    assert rows["landmarks per variable, median"][1:3] == ["—", "—"]
    assert rows["landmarks per variable, median"][-1] == "— n/a"     # shown, not judged
    top = rows["landmarks per variable, max"]
    assert top[1:] == ["—", "≤ 9", "7 (u)", "10 (u)", "8.5", "1/2", "✅ pass"]   # the mean
    assert rows["values narrower than the resolution"][-1] == "✅ pass"   # 0.1 % rule: none
    # core's targets on the same knowledge: the Table 8.1 reference and the chapter-8 rows
    core = {r[0] for r in _knowledge_rows(data, ref.CORE_TARGETS)}
    assert "change DBNs at the end (Fig. 7.9)" in core
    assert f"rel {pretty('a(h_x.dot, [+])')} (Table 8.2)" in core


def test_report_data_judges_growth_by_the_world(grown):
    core = report_data([grown])
    pong = report_data([grown], ref.PONG_TARGETS)
    assert core["growth"]["g1"]["after"] == 150_000 and core["growth"]["g1"]["pass"] is None
    from dataclasses import replace
    early = replace(ref.PONG_TARGETS, growth_after=5000)
    v = report_data([grown], early)["growth"]["g1"]
    assert v["after"] == 5000 and v["window"] == [5000, 6000, 7000, 8000, 9000, 10_000]
    assert pong["growth"]["g1"]["after"] == 50_000
    assert core["runs"] == pong["runs"]                  # the figures do not depend on it


def test_pong_page(tmp_path, monkeypatch):
    data = _pong_data(tmp_path)
    data["timeline"] = {label: [] for label in data["runs"]}
    data["speed"] = {"pong-s1": {"steps_per_s": 1256.9, "placement": "sync",
                                 "steps": 100_000, "wall_time_s": 79.6}, "pong-s2": None}
    cfg = ResultsConfig(world="pong", seeds=[1, 2, 3, 4, 5], steps=100_000, trials=100,
                        every=10_000, jobs=1, runs_dir=Path("runs/pong-results"),
                        out=Path("docs/pong"))
    data["runs"]["pong-s2"]["narrow"] = [{"variable": "b_y", "value": "[3.5, 3.7]",
                                          "width": 0.2, "limit": 0.25}]
    res = pong_result([0.9, 0.8, 1.0, 0.7, 0.6])
    page = render(cfg, [res], data, monkeypatch,
                  {"pong_volley": "results/curve-pong_volley.png"})
    assert page.startswith("# Learning results: pong\n")
    assert "Not the targets' protocol" not in page                # 5 seeds, 100k, 100 trials
    assert ("| pong_volley | " + CLEARLY + " | +0.51 (0.80 against 0.29), 2 s.e. = 0.17; "
            "5/5 seeds above | ✅ pass |") in page
    assert "| knowledge | landmarks per variable, max: ≤ 9 | 8.5 | ✅ pass |" in page
    assert "| 20k (end of babbling) | 0.40 ± 0.00 |" in page
    assert "volleys per trial" in page and "plays somewhat well" in page
    for absent in ("u_x landmarks centred", "(Table 8.2) |", "≥ 1,500", "| speed |",
                   "mean reward at the end ≥"):
        assert absent not in page, absent
    assert "No target for this world" in page
    assert "Mean of the runs made alone 1,256.9 steps/s (not judged)." in page
    assert "| u | 7 | 10 | 10 |" in page                          # landmarks per variable
    assert "| pong-s2 | b_y | [3.5, 3.7] | 0.2 | 0.25 | 80.0% |" in page     # 0.2 / 0.25
    assert "**change DBNs ≤ 600 and not growing after 50,000 steps**" in page
    # 2 task targets + 5 judged knowledge rows (the median is shown, not judged)
    assert "6 of 7 judged targets met" in page          # the growth fails (s2 rises 229)


def test_script_defaults_follow_the_world():
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "learning_results", Path(__file__).resolve().parents[2] / "scripts" /
        "learning_results.py")
    assert spec is not None and spec.loader is not None
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)

    def cfg(*argv: str) -> ResultsConfig:
        return script.make_config(script.build_parser().parse_args(list(argv)), [])

    core = cfg()
    assert (core.world, core.steps, core.runs_dir, core.out) == (
        "core", 250_000, Path("runs/results"), Path("docs"))
    assert cfg("--world", "core2d").out == Path("docs")           # core-like: as before
    pong = cfg("--world", "pong", "--jobs", "1")
    assert (pong.steps, pong.runs_dir, pong.out, pong.jobs, pong.every) == (
        100_000, Path("runs/pong-results"), Path("docs/pong"), 1, 10_000)
    assert cfg("--world", "pong", "--steps", "3000", "--out", "/tmp/x").out == Path("/tmp/x")
