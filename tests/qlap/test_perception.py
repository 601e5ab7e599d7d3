"""Perception: derivatives per second, discontinuities, initial motor landmarks, resolution."""

from __future__ import annotations

import numpy as np
import pytest

from qlap_runtime.qlap import ModelLearner, Params
from qlap_runtime.qlap.perception import Perception, initial_motor_landmark
from qlap_runtime.qlap.quantity import Landmark
from qlap_runtime.qlap.variables import VariableTable
from tests.qlap.toyworld import Spec

SPECS = [Spec("u", "motor", -1000.0, 1000.0), Spec("g", "motor", 0.0, 1.0), Spec("x", "magnitude")]


def perception(**changes) -> tuple[Perception, VariableTable]:
    table = VariableTable.from_specs(SPECS)
    return Perception(table, Params(**changes)), table


def dot(per: Perception, table: VariableTable, xs: list[float]) -> list[int]:
    """The qualitative value of x.dot at each step for the x values ``xs``."""
    i = table.index("x.dot")
    out = []
    for t, x in enumerate(xs):
        p = per.perceive(t, per.vector({"u": 0.0, "g": 0.0, "x": x}))
        out.append(int(p.q[i]))
    return out


def test_derivative_is_per_second_with_the_reference_band():
    """Table 8.1/8.8: ḣ_x in [−0.05, 0.05] is [0]. With 0.05 s steps a change of 0.002 per step
    is 0.04/s -> [0]; 0.003 per step is 0.06/s -> [+]; −0.003 -> [−] (values 1, 2, 0)."""
    per, table = perception(step_seconds=0.05)
    q = dot(per, table, [1.0, 1.002, 1.005, 1.002])
    assert q == [-1, 1, 2, 0]
    x = per.history()[0][:, table.index("x.dot")]
    assert np.allclose(x[1:], [0.04, 0.06, -0.06])


def test_a_discontinuity_makes_no_derivative_and_no_event():
    per, table = perception()
    i = table.index("x.dot")
    per.perceive(0, per.vector({"u": 0.0, "g": 0.0, "x": 1.0}))
    per.perceive(1, per.vector({"u": 0.0, "g": 0.0, "x": 1.0}))
    jump = per.perceive(2, per.vector({"u": 0.0, "g": 0.0, "x": 9.0}), discontinuity=True)
    assert np.isnan(jump.x[i]) and jump.q[i] == -1 and jump.events == ()
    after = per.perceive(3, per.vector({"u": 0.0, "g": 0.0, "x": 9.0}))
    assert after.q[i] == 1 and after.events == ()              # [0], but no event from "unknown"
    moved = per.perceive(4, per.vector({"u": 0.0, "g": 0.0, "x": 9.5}))
    assert [(e.var, e.value) for e in moved.events] == [(i, 2)]


def test_learner_drops_open_windows_at_a_discontinuity():
    """u → (0, +∞) at step 1 opens a soon-window; x jumps at 2 (a replaced object): the window
    is dropped, so neither a success nor a trial is counted for the pair."""
    learner = ModelLearner(SPECS, Params(k_fixed=5))
    obs = [(0.0, 1.0), (500.0, 1.0), (500.0, 5.0), (500.0, 6.0), (500.0, 7.0), (500.0, 8.0),
           (500.0, 9.0), (500.0, 9.0), (500.0, 9.0)]
    for t, (u, x) in enumerate(obs):
        learner.observe(t, {"u": u, "g": 0.0, "x": x}, discontinuity=(t == 2))
    ps = learner.pairs
    assert ps.occurrences.sum() == 0 and ps.soon_given.sum() == 0


def test_initial_motor_landmark_is_zero_or_the_middle_of_the_range():
    """Table 3.1 gives motors the landmark 0; a motor whose range does not straddle 0 gets the
    middle of its range (docs/decisions.md)."""
    table = VariableTable.from_specs(SPECS)
    p = Params()
    assert initial_motor_landmark(table[table.index("u")], p) == Landmark(0.0, 0.0)
    assert initial_motor_landmark(table[table.index("g")], p) == Landmark(0.5, 0.5)
    per = Perception(table, p)
    g = table.index("g")
    assert per.quantize_var(g, np.array([0.0, 0.5, 0.9])).tolist() == [0, 1, 2]


def test_landmarks_keep_to_the_variable_resolution():
    """A motor's resolution is 1 % of its range (20 for u in [−1000, 1000]): a cut [299, 300] is
    widened to [289.5, 309.5]; one within 20 of an existing landmark is refused."""
    learner = ModelLearner(SPECS, Params())
    u = learner.table.index("u")
    assert learner.perception.resolution(u) == 20.0
    assert learner._fit_resolution(u, 299.0, 300.0) == (289.5, 309.5)
    learner.perception.add_landmark(u, Landmark(289.5, 309.5))
    assert learner._fit_resolution(u, 320.0, 330.0) is None          # gap 10.5 < 20
    assert learner._fit_resolution(u, 330.0, 352.0) == (330.0, 352.0)  # gap 20.5
    assert learner._fit_resolution(u, -12.0, -8.0) is None            # 8 from the landmark 0


def test_an_estimated_resolution_is_fixed_at_the_end_of_babbling():
    """A magnitude without a declared resolution has its average change per step as the
    estimate (half the §4.4.2 bin) until the end of babbling, and keeps that value after
    (docs/decisions.md 77): x moves 0.2 a step for the 100 babbling steps, then 0.6 a step;
    the resolution stays 0.2 where the live estimate rises to 0.468, also through a
    checkpoint. A magnitude that did not move while babbling stays estimated."""
    per, table = perception(babble_steps=100)
    x = table.index("x")
    for t in range(100):
        if t == 99:
            assert per.resolution(x) == pytest.approx(0.2) and per.fixed_resolution == {}
        per.perceive(t, per.vector({"u": 0.0, "g": 0.0, "x": 0.2 * t}))
    assert per.fixed_resolution == {x: pytest.approx(0.2)}
    for t in range(100, 300):
        per.perceive(t, per.vector({"u": 0.0, "g": 0.0, "x": 19.8 + 0.6 * (t - 99)}))
    assert 0.5 * per.bin_size(x) == pytest.approx(0.4676, abs=1e-4)  # (99·0.2 + 200·0.6) / 299
    assert per.resolution(x) == pytest.approx(0.2)
    meta, arrays = per.to_state()
    again, _ = perception(babble_steps=100)
    again.load_state(meta, arrays)
    assert again.resolution(x) == pytest.approx(0.2)
    still, _ = perception(babble_steps=100)
    for t in range(150):
        moved = 0.1 * max(t - 119, 0)                          # from step 120 on, 0.1 a step
        still.perceive(t, still.vector({"u": 0.0, "g": 0.0, "x": 1.0 + moved}))
    assert still.fixed_resolution == {} and still.resolution(x) == pytest.approx(0.1)


def test_landmark_signature_changes_only_with_the_variables_landmarks():
    per, table = perception()
    u, g, x = table.index("u"), table.index("g"), table.index("x")
    before = per.landmark_signature((u, x))
    assert before == (tuple(per.spaces[u].landmarks), ())
    per.add_landmark(g, Landmark(0.3, 0.31))            # another variable: same signature
    assert per.landmark_signature((u, x)) == before
    per.add_landmark(x, Landmark(2.0, 2.1))
    after = per.landmark_signature((u, x))
    assert after != before and after[1] == (Landmark(2.0, 2.1),)
