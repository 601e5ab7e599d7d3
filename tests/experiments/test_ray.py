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
