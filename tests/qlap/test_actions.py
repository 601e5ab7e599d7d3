"""Actions, plans, motor values, self and targeted learning (§5.1, §5.5, §6.2–6.4, App. A–B)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from qlap_runtime.qlap.actions import (
    REL_HISTORY_LEN,
    ActionStats,
    ActionTable,
    PlanStats,
    is_self,
    motor_interval,
    motor_reachable,
    motor_value,
    motor_value_for,
    plan_slots,
    rest_value,
    targeted,
    theta_pen_for,
    theta_sr_for,
)
from qlap_runtime.qlap.params import Ablations, Params
from qlap_runtime.qlap.quantity import Landmark, QuantitySpace
from qlap_runtime.qlap.variables import Kind

P = Params()


def stats(successes: int, failures: int, steps: int | None = None) -> ActionStats:
    a = ActionStats()
    for _ in range(successes):
        a.record(True, steps, P)
    for _ in range(failures):
        a.record(False, None, P)
    return a


def plan(successes: int, failures: int, reliable: bool = False, age: int = 0) -> PlanStats:
    return PlanStats(successes + failures, successes, failures, reliable, age)


# --- rel(a) and sufficiently reliable ---------------------------------------------------------


def test_rel_with_priors() -> None:
    a = stats(3, 1)
    assert a.calls == 4
    assert a.rel(1.0) == pytest.approx(4 / 6)
    assert a.rel(2.0) == pytest.approx(5 / 8)
    assert a.rel(0.0) == pytest.approx(3 / 4)
    o = plan(3, 1)
    assert o.rel() == pytest.approx(4 / 6)
    assert o.replace_reliability(P) == pytest.approx(3 / 4)
    assert PlanStats().replace_reliability(P) == 0.0


def test_history_records_rel_at_each_termination_and_is_bounded() -> None:
    a = ActionStats(history_len=5)
    a.record(True, None, P)                      # (1+1)/(1+2) = 2/3
    a.record(False, None, P)                     # (1+1)/(2+2) = 1/2
    assert list(a.history) == pytest.approx([2 / 3, 1 / 2])
    for _ in range(5):
        a.record(True, None, P)
    assert len(a.history) == 5
    assert a.history[-1] == pytest.approx(7 / 9)  # 6 successes, 1 failure


def test_sufficiently_reliable_beta_test_prior_two() -> None:
    # Prior 2, no failures: P(p > 0.75) = 1 − I_0.75(s+2, 2).
    # s = 7: 1 − (10·0.75⁹·0.25 + 0.75¹⁰) = 0.7560 < 0.8 → not reliable.
    # s = 8: 1 − (11·0.75¹⁰·0.25 + 0.75¹¹) = 0.8029 ≥ 0.8 → reliable.
    # (With the default prior 1, five successes would already pass: 1 − 0.75⁶ = 0.822.)
    assert not stats(7, 0).sufficiently_reliable(P)
    assert not stats(5, 0).sufficiently_reliable(P)
    assert stats(8, 0).sufficiently_reliable(P)


def test_sufficiently_reliable_is_sticky() -> None:
    a = stats(8, 20)
    assert not a.check_reliable(P)               # now rel(a) = 10/32
    assert a.sufficiently_reliable(P)            # but it was reliable at some time (§6.2.1)
    b = stats(0, 20)
    for _ in range(8):
        b.record(True, None, P)
    assert not b.sufficiently_reliable(P)


def test_mean_steps_to_success() -> None:
    a = ActionStats()
    assert a.mean_steps_to_success() is None
    a.record(True, 3, P)
    a.record(True, 5, P)
    a.record(False, 10, P)
    a.record(True, None, P)
    assert a.mean_steps_to_success() == pytest.approx(4.0)
    with pytest.raises(ValueError, match="steps"):
        a.record(True, -1, P)


def test_action_stats_json_roundtrip() -> None:
    a = stats(8, 3, steps=2)
    b = ActionStats.from_json(a.to_json())
    assert b == a
    assert b.history.maxlen == a.history_len


# --- plans (§6.2.2) ---------------------------------------------------------------------------


def test_plan_eligibility_and_removal() -> None:
    assert not plan(20, 10).eligible_for_replacement(P)   # 30 calls: not "more than 30"
    assert plan(20, 11).eligible_for_replacement(P)
    # "sufficiently reliable" is the plan's sticky brel(o) flag (§5.4.1), set by the planner
    assert plan(26, 5, reliable=True).sufficiently_reliable(P)
    assert not plan(26, 5, reliable=True).eligible_for_replacement(P)
    assert not plan(25, 6).sufficiently_reliable(P)
    assert plan(25, 6).eligible_for_replacement(P)
    # a plan almost never called holds its slot for dbn_max_age = 100,000 steps at most
    assert not plan(0, 3, age=99_999).eligible_for_replacement(P)
    assert plan(0, 3, age=100_000).eligible_for_replacement(P)
    assert plan(0, 0, age=100_000).eligible_for_replacement(P)
    assert not plan(0, 3, reliable=True, age=100_000).eligible_for_replacement(P)
    # removal: rel(o) (prior 1) < 0.05 with ≥ 30 calls
    assert plan(0, 30).should_remove(P)                   # 1/32 = 0.031
    assert not plan(0, 29).should_remove(P)               # too few calls, though 1/31 < 0.05
    assert plan(1, 39).should_remove(P)                   # 2/42 = 0.0476
    assert not plan(2, 40).should_remove(P)               # 3/44 = 0.068


def test_plan_slots_no_replacement_when_young_or_reliable() -> None:
    young = [plan(5, 5), plan(1, 20), plan(0, 3)]
    slots = plan_slots(young, P)
    assert slots == type(slots)((), 0, None)
    assert not slots.accepts_new
    # the two old ones are sufficiently reliable (sticky brel(o) flag), the third is young
    reliable = [plan(30, 1, reliable=True), plan(1, 20), plan(28, 4, reliable=True)]
    assert plan_slots(reliable, P).replaceable is None


def test_plan_slots_a_plan_never_called_does_not_block_the_action_for_ever() -> None:
    # three young plans: none replaceable; once the first is 100,000 steps old with 10 calls
    # it is (rel(o) with prior 0: 5/10 = 0.5), the others being young
    young = [plan(5, 5, age=99_999), plan(1, 20, age=50_000), plan(0, 0, age=10)]
    assert plan_slots(young, P).replaceable is None
    young[0] = plan(5, 5, age=100_000)
    assert plan_slots(young, P).replaceable == 0
    # among eligible plans the lowest rel(o) (prior 0) goes: never called counts as 0.0
    mixed = [plan(5, 5, age=100_000), plan(10, 21), plan(0, 0, age=100_000)]
    assert plan_slots(mixed, P).replaceable == 2


def test_plan_slots_replaces_lowest_prior_zero() -> None:
    a, b, c = plan(10, 21), plan(5, 30), plan(2, 8)       # rel0 0.323, 0.143; c has 10 calls
    slots = plan_slots([a, b, c], P)
    assert slots.remove == ()
    assert slots.free == 0
    assert slots.replaceable == 1
    assert slots.accepts_new
    # prior 0 and prior 1 rank these two differently:
    x, y = plan(6, 25), plan(10, 40)     # rel0 0.1935 < 0.2000; rel1 0.2121 > 0.2115
    assert x.rel() > y.rel()
    assert plan_slots([y, x, c], P).replaceable == 1


def test_plan_slots_lowest_reading_never_replaces_a_better_plan() -> None:
    """Decision 100, seed 1 of docs/results.md at step 93,999: a(Ṫ_L, [+]) held plans of 3
    successes in 22 calls, 0 in 11 and 14 in 31 (rel(o), prior 0: 0.136, 0.0, 0.452). Only the
    best has been called more than 30 times: the literal reading replaces it; "lowest" finds
    the worst plan (0 of 11) too young to go and replaces none."""
    plans = [plan(3, 19, age=78_000), plan(0, 11, age=72_000), plan(14, 17, age=8_000)]
    assert plan_slots(plans, P).replaceable == 2
    lowest = P.replace(plan_replace="lowest")
    slots = plan_slots(plans, lowest)
    assert slots.replaceable is None and not slots.accepts_new
    # once the worst has 31 calls (1 success: 1/31 = 0.032) it is the one to go
    plans[1] = plan(1, 30, age=72_000)
    assert plan_slots(plans, lowest).replaceable == 1
    # or once it is dbn_max_age (100,000) steps old, with its 11 calls
    plans[1] = plan(0, 11, age=100_000)
    assert plan_slots(plans, lowest).replaceable == 1
    # a sufficiently reliable plan is never the one (3 of 22 is then the worst, too young)
    plans[1] = plan(0, 11, reliable=True, age=72_000)
    assert plan_slots(plans, lowest).replaceable is None
    # ties at the lowest rel(o) (1 of 10 and 4 of 40: 0.1): the eligible one goes
    tied = [plan(1, 9), plan(4, 36), plan(14, 17)]
    assert plan_slots(tied, lowest).replaceable == 1
    # where both readings agree (test_plan_slots_replaces_lowest_prior_zero)
    assert plan_slots([plan(10, 21), plan(5, 30), plan(2, 8)], lowest).replaceable == 1
    with pytest.raises(ValueError, match="plan_replace"):
        P.replace(plan_replace="best")


def test_plan_slots_free_slots_and_removal() -> None:
    slots = plan_slots([plan(0, 30), plan(10, 21), plan(5, 30)], P)
    assert slots.remove == (0,)
    assert slots.free == 1
    assert slots.replaceable is None
    assert plan_slots([], P).free == 3
    assert plan_slots([plan(3, 3)], P).free == 2


def test_plan_slots_reliable_action_gets_no_new_plans() -> None:
    slots = plan_slots([plan(0, 30)], P, action=stats(8, 0))
    assert slots.remove == (0,)
    assert slots.free == 0 and slots.replaceable is None
    assert plan_slots([plan(0, 30)], P, action=stats(7, 0)).free == 3


# --- motor values (§5.5) ----------------------------------------------------------------------


def test_motor_value_ranges() -> None:
    space = QuantitySpace([Landmark(0.0, 0.0)])
    rng = np.random.default_rng(1)
    below = np.array([motor_value_for(space, 0, -1.0, 1.0, rng) for _ in range(2000)])
    above = np.array([motor_value_for(space, 2, -1.0, 1.0, rng) for _ in range(2000)])
    assert np.all((below >= -1.0) & (below < 0.0))
    assert np.all((above > 0.0) & (above <= 1.0))
    assert below.min() < -0.99 and below.max() > -0.01    # the whole range is used
    assert above.min() < 0.01 and above.max() > 0.99
    assert abs(below.mean() + 0.5) < 0.03                 # uniform: sd of mean 0.0065
    assert motor_value_for(space, 1, -1.0, 1.0, rng) == 0.0


def test_motor_value_landmark_range_and_determinism() -> None:
    space = QuantitySpace([Landmark(0.2, 0.4)])
    rng = np.random.default_rng(2)
    x = np.array([motor_value_for(space, 1, -1.0, 1.0, rng) for _ in range(2000)])
    assert np.all((x >= 0.2) & (x <= 0.4))
    assert abs(x.mean() - 0.3) < 0.01
    a = motor_value(-1.0, 1.0, 0.0, math.inf, np.random.default_rng(7))
    b = motor_value(-1.0, 1.0, 0.0, math.inf, np.random.default_rng(7))
    assert a == b
    # landmark partly outside the motor range: clipped
    y = [motor_value(-1.0, 1.0, 0.5, 3.0, rng, landmark=True) for _ in range(200)]
    assert min(y) >= 0.5 and max(y) <= 1.0


def test_motor_value_never_returns_open_interval_endpoint() -> None:
    class Stub:
        def uniform(self, a: float, b: float) -> float:
            return a

    x = motor_value(-1.0, 1.0, 0.0, math.inf, Stub())  # type: ignore[arg-type]
    assert x == 0.5


def test_motor_values_out_of_the_motor_range_are_not_reachable() -> None:
    # u_UG in [0, 1] with a landmark at 0: (−∞, 0) is out of reach, [0] and (0, +∞) are not
    space = QuantitySpace([Landmark(0.0, 0.0)])
    assert [motor_reachable(space, q, 0.0, 1.0) for q in range(3)] == [False, True, True]
    assert motor_interval(0.0, 1.0, -math.inf, 0.0) is None
    assert motor_interval(0.0, 1.0, 0.0, 0.0, landmark=True) == (0.0, 0.0)
    assert motor_interval(0.0, 1.0, 0.0, math.inf) == (0.0, 1.0)
    # unbounded motors: only bounded values (or point landmarks) are reachable
    assert not motor_reachable(space, 2, None, None)
    assert motor_reachable(space, 1, None, None)
    # rest: 0, or the nearest value of the range
    assert rest_value(-1.0, 1.0) == 0.0
    assert rest_value(0.0, 1.0) == 0.0
    assert rest_value(0.2, 1.0) == 0.2
    assert rest_value(-3.0, -1.0) == -1.0
    assert rest_value(None, None) == 0.0


def test_motor_value_errors() -> None:
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="unbounded"):
        motor_value(None, None, 0.0, math.inf, rng)
    with pytest.raises(ValueError, match="does not meet"):
        motor_value(-1.0, 1.0, 2.0, 3.0, rng, landmark=True)
    with pytest.raises(ValueError, match="does not meet"):
        motor_value(0.0, 1.0, -math.inf, 0.0, rng)


# --- the table (§5.1) -------------------------------------------------------------------------


def test_table_creates_and_remaps() -> None:
    t = ActionTable(P)
    t.sync([3, 1])
    assert len(t) == 4
    assert list(t) == [(0, 0), (0, 1), (0, 2), (1, 0)]
    t.record((0, 2), True, 4)
    t.record((0, 0), False)
    moved = t[(0, 2)]
    old = t.on_landmark(0, 0)
    assert old.failures == 1
    assert t.n_values(0) == 5
    assert t[(0, 4)] is moved and moved.successes == 1
    for q in (0, 1, 2):
        assert t[(0, q)].calls == 0
    assert t[(0, 3)].calls == 0                 # the old landmark 0 value, moved up by 2
    with pytest.raises(ValueError, match="open interval"):
        t.on_landmark(0, 1)
    with pytest.raises(KeyError, match="no action"):
        t[(0, 5)]
    t2 = ActionTable.from_json(t.to_json(), P)
    assert t2.items() == t.items()


def test_table_history_len_covers_iac() -> None:
    assert ActionTable(P).history_len == REL_HISTORY_LEN
    assert ActionTable(P.replace(iac_window=150)).history_len == 300


# --- self (§6.4, App. A) ----------------------------------------------------------------------


def test_is_self_change_variable() -> None:
    t = ActionTable(P)
    t.ensure_variable(0, 3)
    for _ in range(8):
        t.record((0, 0), True, 2)
        t.record((0, 2), True, 2)
    assert t.is_self(0, Kind.CHANGE, k=3)
    assert not t.is_self(0, Kind.CHANGE, k=2)          # mean 2 is not < 2
    assert not t.is_self(0, Kind.MAGNITUDE, k=3)
    u = ActionTable(P)
    u.ensure_variable(0, 3)
    for _ in range(8):
        u.record((0, 2), True, 1)
    for _ in range(7):
        u.record((0, 0), True, 1)                      # [−] not sufficiently reliable
    assert not u.is_self(0, Kind.CHANGE, k=3)
    u.record((0, 0), True, 1)
    assert u.is_self(0, Kind.CHANGE, k=3)


def test_is_self_nominal_needs_all_values() -> None:
    good = [stats(8, 0, steps=1) for _ in range(3)]
    assert is_self(good, 2, P)
    assert not is_self([*good[:2], stats(8, 0, steps=5)], 2, P)
    assert not is_self([], 2, P)
    t = ActionTable(P)
    t.ensure_variable(0, 3)
    for q in range(3):
        for _ in range(8):
            t.record((0, q), True, 1)
    assert t.is_self(0, Kind.NOMINAL, k=2)
    t.ensure_variable(0, 4)                            # a value never achieved
    assert not t.is_self(0, Kind.NOMINAL, k=2)


# --- targeted learning (§6.3) -----------------------------------------------------------------


def test_targeted_and_ablations() -> None:
    frac = [0.01, 0.05, 0.2, math.nan]
    assert targeted(frac, P).tolist() == [True, False, False, False]
    assert targeted(frac, P.replace(ablations=Ablations(no_targeted=True))).tolist() == [
        False] * 4
    assert targeted(frac, P.replace(ablations=Ablations(all_targeted=True))).tolist() == [
        True] * 4
    with pytest.raises(ValueError, match="mutually exclusive"):
        targeted(frac, P.replace(ablations=Ablations(no_targeted=True, all_targeted=True)))


def test_targeted_thresholds() -> None:
    assert theta_pen_for(True, P) == 0.02 and theta_pen_for(False, P) == 0.05
    assert theta_sr_for(True, P) == 0.25 and theta_sr_for(False, P) == 0.75
    mask = np.array([True, False])
    assert theta_pen_for(mask, P).tolist() == [0.02, 0.05]
    assert theta_sr_for(mask, P).tolist() == [0.25, 0.75]
