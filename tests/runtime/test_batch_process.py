"""Batches in a worker process (docs/decisions.md 80): the learner's checkpoint state goes
there as JSON and raw arrays (no pickle), and the deltas that come back are the ones computed
in place."""

from __future__ import annotations

import io

import numpy as np
import pytest

import worlds
from qlap_runtime.agent_run import params_for_world, run_agent
from qlap_runtime.qlap import ModelLearner, Params
from qlap_runtime.qlap.checkpoint import learner_state
from qlap_runtime.runtime.background import Background
from qlap_runtime.runtime.batch_process import (
    BatchProcess,
    BatchProcessError,
    read_frame,
    write_frame,
)
from qlap_runtime.runtime.context import world_variables


def test_a_frame_carries_json_and_arrays_exactly():
    arrays = {"f": np.array([[1.5, np.nan], [-0.0, 1e-300]]), "i": np.arange(5, dtype=np.int16),
              "b": np.array([True, False]), "empty": np.zeros((0, 3)), "scalar": np.float64(2.5),
              "strided": np.arange(12.0).reshape(3, 4)[:, ::2]}
    buf = io.BytesIO()
    write_frame(buf, {"step": 7, "meta": {"x": [1, "y"]}}, arrays)
    write_frame(buf, {"done": True})
    buf.seek(0)
    header, got = read_frame(buf)
    assert header == {"step": 7, "meta": {"x": [1, "y"]}}
    assert list(got) == list(arrays)
    for k, v in arrays.items():
        assert got[k].dtype == np.asarray(v).dtype and got[k].shape == np.shape(v)
        assert np.array_equal(got[k], v, equal_nan=True)
    assert read_frame(buf) == ({"done": True}, {})
    assert read_frame(buf) is None                  # the end of the stream
    with pytest.raises(TypeError, match="Python objects"):
        write_frame(io.BytesIO(), {}, {"o": np.array([{}, 1], dtype=object)})
    cut = io.BytesIO(buf.getvalue()[:40])
    with pytest.raises(EOFError):
        read_frame(cut)


def learner_at(steps: int) -> ModelLearner:
    """The learner of a core2d run after ``steps`` steps (DBNs and landmarks learned)."""
    world = worlds.make("core2d")
    params = params_for_world(world, Params(babble_steps=1500, dbn_period=500,
                                            landmark_period=1000, batch_lag=100))
    agent, _ = run_agent(world, steps, 3, params=params)
    world.close()
    return agent.learner


def test_the_worker_computes_the_deltas_computed_in_place():
    learner = learner_at(2501)                 # DBNs found at step 2,500
    step = learner.step
    process = BatchProcess()
    try:
        for kinds in (("dbn",), ("dbn", "landmarks")):
            work = learner.batch_copy()
            before = learner_state(work)[0]
            away = process.compute(work, step, kinds)
            assert learner_state(work)[0] == before        # left as it was here
            here = work.compute_parts(step, kinds)
            assert {k: d.to_json() for k, d in away.items()} == \
                {k: d.to_json() for k, d in here.items()}
        assert len(here["dbn"].ops) > 5                 # the batch found something
        assert len(process.times) == 2
    finally:
        process.close()
    assert process.proc.returncode == 0                    # it ends with its input


def test_a_dead_worker_is_an_error_naming_the_step():
    process = BatchProcess()
    process.proc.kill()
    process.proc.wait()
    with pytest.raises(BatchProcessError, match="step 400"):
        process.compute(ModelLearner(world_variables("core2d")[0]), 400, ("dbn",))
    process.close()


def test_a_background_job_runs_one_at_a_time_and_its_error_is_raised():
    done: list[int] = []
    writer = Background("t")
    writer.start(done.append, 1)
    writer.start(done.append, 2)                    # after the first
    writer.wait()
    assert done == [1, 2]

    def fails() -> None:
        raise OSError("disk full")
    writer.start(fails)
    with pytest.raises(OSError, match="disk full"):
        writer.wait()
    writer.wait()                                   # raised once
