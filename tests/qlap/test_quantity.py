"""Quantity spaces, qualitative values and events (ch. 3, Table 3.1)."""

import math

import numpy as np
import pytest

from qlap_runtime.qlap import InvalidObservation, Landmark, Params, QuantitySpace
from qlap_runtime.qlap.perception import Perception
from qlap_runtime.qlap.quantity import remap_after_insert
from qlap_runtime.qlap.variables import Event, Kind, VariableTable
from tests.qlap.toyworld import Spec


def test_two_landmarks_make_five_values():
    qs = QuantitySpace([Landmark(2.0, 2.0), Landmark(-1.0, -0.5)])
    assert qs.size == 5
    # (-inf,-1) [-1,-0.5] (-0.5,2) 2 (2,+inf)
    assert [qs.value_of(x) for x in (-3, -1, -0.7, -0.5, 0, 2, 2.0001)] == [0, 1, 1, 1, 2, 3, 4]
    assert qs.values_of(np.array([-3, -0.7, 0, 2, 5, np.nan])).tolist() == [0, 1, 2, 3, 4, -1]
    assert qs.bounds(2) == (-0.5, 2.0)
    assert qs.bounds(0) == (-math.inf, -1.0)
    assert qs.label(4) == "(2, +inf)"
    assert qs.label(1) == "[-1, -0.5]"


def test_insert_splits_interval_and_shifts_values_above():
    qs = QuantitySpace([Landmark(0.0, 0.0)])
    split = qs.insert(Landmark(5.0, 6.0))
    assert split == 2                      # (0, +inf) was value 2
    assert qs.size == 5
    assert [remap_after_insert(q, split) for q in (0, 1, 3)] == [0, 1, 5]
    with pytest.raises(ValueError, match="overlaps"):
        qs.insert(Landmark(5.5, 7.0))


def test_initial_landmarks_of_table_3_1():
    table = VariableTable.from_specs([Spec("u", "motor", -1, 1), Spec("x", "magnitude"),
                                      Spec("T", "nominal", values=("f", "t"))])
    assert [v.name for v in table] == ["u", "x", "x.dot", "T"]
    assert [v.kind for v in table] == [Kind.MOTOR, Kind.MAGNITUDE, Kind.CHANGE, Kind.NOMINAL]
    per = Perception(table, Params(derivative_zero_band=0.1))
    assert [len(s.landmarks) for s in per.spaces] == [1, 0, 1, 0]
    assert per.spaces[2].landmarks[0] == Landmark(-0.1, 0.1)


def test_events_with_up_and_down_on_magnitudes():
    table = VariableTable.from_specs([Spec("u", "motor", -1, 1), Spec("x", "magnitude")])
    per = Perception(table, Params())
    per.add_landmark(1, Landmark(5.0, 5.0))                  # Q(x) = (-inf,5), 5, (5,+inf)
    p0 = per.perceive(0, np.array([0.0, 4.0, np.nan]))
    assert p0.events == ()
    assert per.perceive(1, np.array([0.0, 4.0, np.nan])).events == ()   # first x.dot: no event
    p1 = per.perceive(2, np.array([0.5, 5.0, np.nan]))
    # u: 0 -> (0,+inf) [value 2]; x: (-inf,5) -> 5 from below (↑); x.dot: [0] -> [+] (Δ = 1)
    assert set(p1.events) == {Event(0, 2, 0), Event(1, 1, 1), Event(2, 2, 0)}
    p2 = per.perceive(3, np.array([0.5, 4.0, np.nan]))
    # x: 5 -> (-inf,5) ↓ ; x.dot: [+] -> [-]
    assert set(p2.events) == {Event(1, 0, -1), Event(2, 0, 0)}
    ids = {per.events.decode(int(i)) for i in p2.event_ids}
    assert ids == set(p2.events)


def test_nan_and_unknown_variables_are_rejected_with_names():
    table = VariableTable.from_specs([Spec("u", "motor", -1, 1), Spec("x", "magnitude"),
                                      Spec("T", "nominal", values=("f", "t"))])
    per = Perception(table, Params())
    with pytest.raises(InvalidObservation, match="'x'.*non-finite"):
        per.perceive(0, per.vector({"u": 0.0, "x": float("nan"), "T": 0}))
    with pytest.raises(InvalidObservation, match="'x'.*non-finite"):
        per.perceive(0, per.vector({"u": 0.0, "x": float("inf"), "T": 0}))
    with pytest.raises(InvalidObservation, match="unknown variable 'y'"):
        per.vector({"u": 0.0, "x": 1.0, "y": 2.0})
    with pytest.raises(InvalidObservation, match="nominal variable 'T'"):
        per.perceive(0, per.vector({"u": 0.0, "x": 1.0, "T": 2}))
    assert per.steps_seen == 0                               # nothing was learned from them


def test_value_of_is_the_loop_over_landmarks():
    # value_of searches the upper bounds (bisect): the values of the plain loop over the
    # landmarks in order, on the landmarks' own bounds, between them, outside, ±inf and NaN;
    # after an insert the cached bounds follow.
    import numpy as np

    from qlap_runtime.qlap.quantity import Landmark, QuantitySpace

    def loop(space, x):
        for i, lm in enumerate(space.landmarks):
            if x < lm.lb:
                return 2 * i
            if x <= lm.ub:
                return 2 * i + 1
        return 2 * len(space.landmarks)

    assert QuantitySpace([Landmark(0.0, 1.0)]).value_of(1.0) == 1
    assert QuantitySpace([Landmark(0.0, 1.0)]).value_of(float("nan")) == 2
    rng = np.random.default_rng(0)
    for _ in range(200):
        space = QuantitySpace()
        for _ in range(int(rng.integers(0, 6))):
            c = float(rng.normal(0, 10))
            try:
                space.insert(Landmark(c, c + float(rng.choice([0.0, 0.5]))))
            except ValueError:
                pass
            bounds = [b for lm in space.landmarks for b in (lm.lb, lm.ub)]
            for x in [*bounds, *(np.nextafter(b, s) for b in bounds for s in (-1e9, 1e9)),
                      *rng.normal(0, 12, 20).tolist(), float("inf"), -float("inf"),
                      float("nan"), -0.0]:
                assert space.value_of(x) == loop(space, x)
