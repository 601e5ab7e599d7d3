"""--engine ray: the same scheduler and jobs on a local Ray (ray.init(num_cpus=2)), the same
results as in process."""

import dataclasses

import pytest

from qlap_runtime.experiments.engine import RayBackend, run_sweep
from qlap_runtime.experiments.sweep import plan

from .conftest import TINY, InlineBackend

pytest.importorskip("ray")


def test_ray_gives_the_same_results(tiny_root, tmp_path):
    one = dataclasses.replace(TINY, agents=1)
    inline = plan(one, tmp_path / "inline")
    run_sweep(inline, InlineBackend(), echo=None, live=False)
    sweep = plan(one, tiny_root)
    backend = RayBackend(jobs=2)
    try:
        assert backend.slots == 2
        res = run_sweep(sweep, backend, echo=None, live=False)
    finally:
        backend.close()
    assert res.failures == [] and (res.runs_done, res.evals_done) == (2, 5)
    assert {k: v.mean_reward for k, v in sweep.rows().items()} == \
        {k: v.mean_reward for k, v in inline.rows().items()}


def test_an_interrupted_sweep_cancels_the_tasks_still_running(monkeypatch):
    """close(cancel=True) — the sweep's Ctrl-C — cancels what is still running (on a cluster
    it would go on writing run directories); a task that returned is not cancelled."""
    backend = RayBackend(jobs=2)
    cancelled: list = []
    try:
        ray = backend.ray
        backend.remote["echo"] = ray.remote(num_cpus=1, max_retries=0)(lambda p: p)
        backend.remote["sleep"] = ray.remote(num_cpus=1, max_retries=0)(
            lambda p: __import__("time").sleep(float(p)))
        done = backend.submit("echo", "hi")
        assert backend.wait([done], timeout=60) == [(done, "hi")]
        running = backend.submit("sleep", "60")
        monkeypatch.setattr(ray, "cancel", lambda ref, force=False: cancelled.append(ref))
    finally:
        backend.close(cancel=True)
    assert cancelled == [running] and backend.pending == set()
