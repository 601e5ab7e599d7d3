"""A learning actor's snapshot is one frame of raw arrays (docs/decisions.md 90): read back, the
learner continues exactly as the one that wrote it; an older snapshot (the checkpoint's
``learner.{json,npz}``) still reads; a damaged frame is a one-line error."""

from __future__ import annotations

from itertools import islice

import numpy as np
import pytest

from qlap_runtime.qlap import ModelLearner, Params
from qlap_runtime.qlap.checkpoint import CheckpointError, learner_state, save_learner
from qlap_runtime.runtime.snapshot import (
    LEARNER_FRAME,
    load_learner_snapshot,
    save_learner_snapshot,
)
from tests.qlap.toyworld import SPECS, babble_stream


def learner_after(steps: int) -> ModelLearner:
    learner = ModelLearner(SPECS, Params(event_history=50, dbn_period=100, landmark_period=200))
    for t, obs in islice(babble_stream(400, seed=3), steps):
        learner.observe(t, obs)
    return learner


def same_state(a: ModelLearner, b: ModelLearner) -> bool:
    (ma, xa), (mb, xb) = learner_state(a), learner_state(b)
    return ma == mb and xa.keys() == xb.keys() and all(
        np.array_equal(xa[k], xb[k], equal_nan=True) and xa[k].dtype == xb[k].dtype for k in xa)


def test_a_learner_read_from_its_snapshot_goes_on_as_the_one_that_wrote_it(tmp_path):
    learner = learner_after(250)                # batches applied, rings wrapped
    save_learner_snapshot(learner, tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == [LEARNER_FRAME]
    back = load_learner_snapshot(tmp_path)
    assert same_state(back, learner)
    for t, obs in islice(babble_stream(400, seed=3), 250, 330):    # a batch at 300 included
        learner.observe(t, obs)
        back.observe(t, obs)
    assert same_state(back, learner)


def test_a_snapshot_in_the_checkpoint_format_still_reads(tmp_path):
    learner = learner_after(150)
    save_learner(learner, tmp_path)
    assert same_state(load_learner_snapshot(tmp_path), learner)


def test_a_cut_frame_is_a_one_line_error(tmp_path):
    save_learner_snapshot(learner_after(150), tmp_path)
    path = tmp_path / LEARNER_FRAME
    path.write_bytes(path.read_bytes()[:-10])
    with pytest.raises(CheckpointError, match="unreadable learner snapshot"):
        load_learner_snapshot(tmp_path)


def test_a_snapshot_is_atomic_but_not_fsynced_and_a_checkpoint_is_both(tmp_path, monkeypatch):
    """docs/decisions.md 124: only a restart on the live machine reads a snapshot, so its files
    skip the fsync (the learners' process waited on it every snapshot_every steps); the
    checkpoints that ``--resume`` reads stay durable."""
    import os

    from qlap_runtime.qlap.checkpoint import atomic_write_json
    from qlap_runtime.runtime.snapshot import latest_snapshot, write_snapshot

    synced: list[int] = []
    real = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: (synced.append(fd), real(fd))[1])
    learner = learner_after(150)
    final = write_snapshot(tmp_path / "snaps", "contingency", 149, {"last": 149},
                           lambda d: save_learner_snapshot(learner, d))
    assert synced == []
    assert latest_snapshot(tmp_path / "snaps", "contingency") == (149, final)
    assert same_state(load_learner_snapshot(final), learner)
    assert not [p for p in final.parent.rglob("*") if p.name.endswith(".tmp")]
    atomic_write_json(tmp_path / "summary.json", {"steps": 1})
    assert len(synced) == 1
    save_learner(learner, tmp_path / "ckpt")                  # a checkpoint's learner files
    assert len(synced) > 1
