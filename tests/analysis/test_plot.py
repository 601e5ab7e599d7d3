"""``qlap plot``'s learning-curve panel (:mod:`qlap_runtime.analysis.plot`)."""

from __future__ import annotations

import pytest

from qlap_runtime.analysis import plot
from qlap_runtime.analysis.curve import RANDOM_RUN, CurveRow, write_rows


def _row(run: str, step: int | None, reward: float) -> CurveRow:
    return CurveRow(run=run, step=step, task="pickup", mean_reward=reward, stderr=0.5,
                    success_rate=0.3, trials=10, seed=0, world="core",
                    policy="random" if run == RANDOM_RUN else "qlap",
                    checkpoint="" if step is None else f"step-{step:07d}")


def test_a_curve_of_several_runs_draws_a_line_per_run(tmp_path):
    """`qlap curve s1 s2 --out DIR` then `qlap plot DIR`: one line per run (not one zigzag
    through both runs' points), the random policy once."""
    write_rows(tmp_path / "curve.csv", [
        _row(RANDOM_RUN, None, -0.4),
        _row("s1", 10000, 1.0), _row("s1", 20000, 2.0),
        _row("s2", 10000, 3.0), _row("s2", 20000, 4.0),
    ])
    groups = plot._curve_groups(tmp_path / "curve.csv")
    assert [(label, [r.mean_reward for r in rows], base is not None)
            for label, rows, base in groups] == [
        ("pickup (core, 10 trials, seed 0), s1", [1.0, 2.0], True),
        ("pickup (core, 10 trials, seed 0), s2", [3.0, 4.0], False),
    ]
    assert plot.plot_run(tmp_path).stat().st_size > 0         # metrics.png drawn from it


def test_a_curve_of_one_run_keeps_its_plain_label(tmp_path):
    write_rows(tmp_path / "curve.csv", [_row("s1", 10000, 1.0), _row(RANDOM_RUN, None, 0.0)])
    [(label, rows, base)] = plot._curve_groups(tmp_path / "curve.csv")
    assert label == "pickup (core, 10 trials, seed 0)" and [r.step for r in rows] == [10000]
    assert base is not None and base.mean_reward == 0.0


def test_a_metrics_log_of_no_records_and_an_unwritable_picture_are_named(tmp_path):
    from qlap_runtime.analysis import AnalysisError
    from qlap_runtime.analysis.plot import plot_run

    (tmp_path / "metrics.jsonl").write_text("garbage\n[1, 2]\n\n{\"step\": \"x\"}\n")
    with pytest.raises(AnalysisError, match=r"metrics.jsonl: none of its 3 lines is a metrics "
                                            r"record"):
        plot_run(tmp_path)
    (tmp_path / "metrics.jsonl").write_text('{"step": 10, "dbns": 3}\n')
    target = tmp_path / "adir.png"
    target.mkdir()                                  # a directory where the picture would go
    with pytest.raises(AnalysisError, match=rf"{target}: cannot write \("):
        plot_run(tmp_path, target)
