"""The executor decides on its learner's percept, as the synchronous loop does.

A landmark applied at step t renumbers the qualitative values of step t's percept in place
(``Perception.add_landmark`` keeps the previous values consistent with the new numbering), so
the decision at t reads them with the new landmarks. The synchronous loop decides on the
percept its learner returned; the executor must decide on the one its follower learner returns
from ``observe_percept``, not on its own copy from the message (a 30,000-step core run parted
from the synchronous loop at the first landmark applied during practice, step 28,500).
"""

from __future__ import annotations

import worlds
from actors.convert import QStateCodec
from qlap_runtime.qlap import ModelLearner, Params
from qlap_runtime.qlap.delta import AddLandmark, Delta
from qlap_runtime.qlap.perception import Perception


def test_a_landmark_applied_after_observing_renumbers_the_returned_percept():
    world = worlds.make("core2d")
    specs = world.variables
    obs = world.reset(seed=0)
    world.close()
    params = Params()
    sync = ModelLearner(specs, params)
    follower = ModelLearner(specs, params)
    follower.auto_batches, follower.follower = False, True
    perception = Perception(sync.table, params)               # the perception actor
    var = next(v for v in sync.table if v.name == "h_x")
    full = {**obs, **{v.name: 0.0 for v in sync.table if v.kind.value == "motor"}}

    for t in (0, 1):
        p_sync = sync.observe(t, full)
        msg = QStateCodec(perception.table).message(perception.perceive(t, perception.vector(full)))
        p_exec = follower.observe_percept(QStateCodec(follower.table).percept(msg))
    x = float(p_sync.x[var.index])
    before = int(p_sync.q[var.index])
    assert int(p_exec.q[var.index]) == before

    # A landmark below h_x: its qualitative value moves up by two (landmark + interval).
    delta = Delta(1, 0, 1, (AddLandmark(var.index, x - 0.5, x - 0.5, "event", 0),))
    sync.apply_delta(delta)
    follower.apply_delta(delta)
    assert int(p_sync.q[var.index]) == before + 2
    assert int(p_exec.q[var.index]) == before + 2
    assert (p_exec.q == p_sync.q).all()
