"""The sweep: every run and evaluation once, resumed without recomputing what is done, the
same results through the local process pool (and Ray, tests/experiments/test_ray.py)."""

import dataclasses
import json

import pytest

from qlap_runtime.analysis.curve import read_rows, write_rows
from qlap_runtime.experiments.engine import LocalBackend, make_backend, run_sweep
from qlap_runtime.experiments.spec import ExperimentError
from qlap_runtime.experiments.sweep import plan, run_done

from .conftest import TINY, InlineBackend


def _mtimes(path):
    return {p: p.stat().st_mtime_ns for p in path.rglob("*") if p.is_file()}


def test_sweep_runs_everything_once_then_nothing(tiny_root):
    sweep = plan(TINY, tiny_root)
    assert len(sweep.runs) == 4 and len(sweep.evals) == 2 * 2 * 2 + 1
    backend = InlineBackend()
    res = run_sweep(sweep, backend, echo=None, live=False)
    assert (res.runs_done, res.evals_done, res.failures) == (4, 9, [])
    assert all(run_done(sweep.run_dir(k), s) for k, s in sweep.runs.items())
    for key in sweep.runs:
        rows = read_rows(sweep.run_dir(key) / "curve.csv")
        assert sorted(r.step for r in rows) == [1000, 2000]
        assert json.loads((sweep.run_dir(key) / "run.json").read_text())["key"] == key
    assert len(read_rows(tiny_root / "random" / "curve.csv")) == 1

    again = InlineBackend()
    res = run_sweep(plan(TINY, tiny_root), again, echo=None, live=False)
    assert again.submitted == []
    assert (res.runs_reused, res.evals_reused, res.runs_done, res.evals_done) == (4, 9, 0, 0)


def test_killed_sweep_continues_without_recomputing(tiny_root):
    sweep = plan(TINY, tiny_root)
    run_sweep(sweep, InlineBackend(), echo=None, live=False)
    a, b = list(sweep.arms["QLAP"].runs)
    # as if killed: run a never finished (no summary.json), one evaluation of b is missing
    (sweep.run_dir(a) / "summary.json").unlink()
    rows = read_rows(sweep.run_dir(b) / "curve.csv")
    write_rows(sweep.run_dir(b) / "curve.csv", [r for r in rows if r.step != 2000])
    others = {k: _mtimes(sweep.run_dir(k) / "checkpoints") for k in sweep.runs if k != a}
    backend = InlineBackend()
    res = run_sweep(plan(TINY, tiny_root), backend, echo=None, live=False)
    kinds = sorted(k for k, _ in backend.submitted)
    assert kinds == ["eval", "eval", "eval", "run"]          # run a, its 2 evaluations, b's one
    assert (res.runs_done, res.evals_done, res.runs_reused) == (1, 3, 3)
    for k, before in others.items():                         # finished runs untouched
        assert _mtimes(sweep.run_dir(k) / "checkpoints") == before
    assert run_done(sweep.run_dir(a), sweep.runs[a])


def test_a_failing_job_is_reported_and_the_rest_goes_on(tiny_root, monkeypatch):
    sweep = plan(TINY, tiny_root)
    bad = sweep.arms["random landmarks"].runs[0]
    broken = dict(sweep.runs)
    broken[bad] = dataclasses.replace(sweep.runs[bad], world="no-such-world")
    sweep.runs = broken
    res = run_sweep(sweep, InlineBackend(), echo=None, live=False)
    assert len(res.failures) == 1 and bad in res.failures[0]
    assert res.runs_done == 3 and res.evals_done == 9 - 2


def test_local_pool_gives_the_same_results(tiny_root, tmp_path):
    one = dataclasses.replace(TINY, agents=1)
    inline = plan(one, tmp_path / "inline")
    run_sweep(inline, InlineBackend(), echo=None, live=False)
    pooled = plan(one, tiny_root)
    backend = LocalBackend(2)
    try:
        res = run_sweep(pooled, backend, echo=None, live=False)
    finally:
        backend.close()
    assert res.failures == [] and res.evals_done == 5
    assert {k: v.mean_reward for k, v in pooled.rows().items()} == \
        {k: v.mean_reward for k, v in inline.rows().items()}


def test_backend_options():
    with pytest.raises(ExperimentError, match="--address goes with --engine ray"):
        make_backend("local", 1, "127.0.0.1:6379")
    with pytest.raises(ExperimentError, match="unknown engine"):
        make_backend("slurm", 1, None)
