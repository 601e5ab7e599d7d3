"""IAC, plan choice and the babbling schedule (§6.1, App. E)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from qlap_runtime.qlap.actions import ActionStats
from qlap_runtime.qlap.curiosity import (
    BabbleSchedule,
    IACChoice,
    action_weight,
    babble_instead,
    choose_action,
    choose_plan,
    fallback_weight,
    iac_weight,
    is_babbling_period,
    plan_weight,
)
from qlap_runtime.qlap.params import Params

P = Params()
N = 20_000


def test_iac_weight_regimes() -> None:
    rising = [0.2] * 25 + [0.5] * 25
    assert iac_weight(rising, P) == pytest.approx(0.3)
    assert iac_weight([0.5] * 25 + [0.2] * 25, P) == 0.001      # decreasing → floor
    assert iac_weight([0.4] * 50, P) == 0.001                    # flat → floor
    assert iac_weight(rising[1:], P) is None                     # 49 values
    assert iac_weight([0.9] * 10 + rising, P) == pytest.approx(0.3)   # only the last 50 count
    mixed = [0.1] * 20 + [0.3] * 5 + [0.6] * 25                  # old mean 0.14, new 0.6
    assert iac_weight(mixed, P) == pytest.approx(0.46)


def test_fallback_weight_eq_6_2() -> None:
    assert fallback_weight(0.5, 0.7) == pytest.approx(0.7)       # H(0.5) = 1
    # H(0.25) = −(0.25·log2 0.25 + 0.75·log2 0.75) = 0.5 + 0.311278 = 0.811278
    assert fallback_weight(0.25, 0.5) == pytest.approx(0.405639, abs=1e-6)
    assert fallback_weight(1.0, 0.9) == 0.0
    assert plan_weight(0.8, 0.5) == pytest.approx(0.4)


def test_action_weight_switches_regime_at_50_calls() -> None:
    a = ActionStats()
    assert action_weight(a, 0.6, P) == pytest.approx(0.6)       # rel(a) = 1/2, H = 1
    assert action_weight(a, None, P) == 0.0
    for _ in range(50):
        a.record(True, None, P)
    # history: rel = (s+1)/(s+2) for s = 1..50; old window s = 1..25, new s = 26..50
    h = [(s + 1) / (s + 2) for s in range(1, 51)]
    expected = max(0.001, np.mean(h[25:]) - np.mean(h[:25]))
    assert action_weight(a, 0.6, P) == pytest.approx(expected)
    assert expected > 0.001


def test_windowed_iac_compares_success_rates_of_the_two_windows() -> None:
    """``iac_progress="windowed"`` (docs/decisions.md 78): rel_new and rel_old of eq. 6.1 are the
    success rates of the last 25 calls and of the 25 before."""
    pw = P.replace(iac_progress="windowed")
    a = ActionStats()
    outcomes = [True] * 5 + [False] * 20 + [True] * 15 + [False] * 10   # 5/25, then 15/25
    for ok in outcomes:
        a.record(ok, None, pw)
    assert list(a.history) == [float(ok) for ok in outcomes]
    assert action_weight(a, 0.6, pw) == pytest.approx(15 / 25 - 5 / 25)    # 0.4
    # The cumulative reading of the same calls: means of rel(a) = (s + 1)/(n + 2).
    b = ActionStats()
    for ok in outcomes:
        b.record(ok, None, P)
    s = np.cumsum(outcomes)
    h = (s + 1) / (np.arange(1, 51) + 2)
    assert h[25:].mean() - h[:25].mean() == pytest.approx(-0.056097, abs=1e-6)
    # The success rate tripled, yet the cumulative reading sees no progress (the floor).
    assert action_weight(b, 0.6, P) == 0.001
    # An action that keeps failing (or keeps succeeding) makes no progress in either reading.
    c = ActionStats()
    for _ in range(50):
        c.record(False, None, pw)
    assert action_weight(c, 0.6, pw) == 0.001
    with pytest.raises(ValueError, match="iac_progress"):
        P.replace(iac_progress="outcomes")


def test_iac_can_record_practice_calls_only() -> None:
    """``iac_records="practice"`` (docs/decisions.md 79): terminations of the action as a plan's
    sub-action count in rel(a) but not in eq. 6.1's history, so the action keeps eq. 6.2's
    weight until it has been practised 2θ = 50 times."""
    pp = P.replace(iac_records="practice")
    a = ActionStats()
    for i in range(60):                       # 60 sub-action calls, one success in three
        a.record(i % 3 == 0, None, pp, practised=False)
    assert (a.calls, a.successes, len(a.history)) == (60, 20, 0)
    assert a.rel(P.prior) == pytest.approx(21 / 62)
    # Still eq. 6.2: H(21/62)·rel(o, s), not the floor of eq. 6.1.
    assert action_weight(a, 0.5, pp) == pytest.approx(0.46179, abs=1e-5)   # H = 0.92358 bits
    for _ in range(50):                       # 50 practised calls, all failures
        a.record(False, None, pp, practised=True)
    assert len(a.history) == 50 and a.history[0] == pytest.approx(21 / 63)
    assert action_weight(a, 0.5, pp) == 0.001
    # With the default "all", the same 60 sub-action calls make 60 records: eq. 6.1 already
    # (at its floor: rel(a) fell over the calls).
    b = ActionStats()
    for i in range(60):
        b.record(i % 3 == 0, None, P, practised=False)
    assert len(b.history) == 60 and action_weight(b, 0.5, P) == 0.001
    with pytest.raises(ValueError, match="iac_records"):
        P.replace(iac_records="sub")


def test_choose_action_frequencies() -> None:
    rng = np.random.default_rng(3)
    keys = [(0, 0), (4, 2)]
    picks = [choose_action(keys, [1.0, 3.0], rng)[0] for _ in range(N)]
    frac = sum(p == (4, 2) for p in picks) / N
    assert abs(frac - 0.75) < 0.015                          # sd 0.0031
    _, w = choose_action(keys, [1.0, 3.0], rng)
    assert w.tolist() == [0.25, 0.75]
    picks = [choose_action(keys, [1.0, 3.0], rng, no_iac=True)[0] for _ in range(N)]
    assert abs(sum(p == (4, 2) for p in picks) / N - 0.5) < 0.015
    _, w = choose_action(keys, [0.0, 0.0], rng)
    assert w.tolist() == [0.5, 0.5]
    picks = [choose_action(keys, [0.0, 0.0], rng)[0] for _ in range(2000)]
    assert 800 < sum(p == (0, 0) for p in picks) < 1200
    assert all(choose_action(keys, [0.0, 2.0], rng)[0] == (4, 2) for _ in range(200))


def test_choose_action_edge_cases_and_determinism() -> None:
    rng = np.random.default_rng(0)
    key, w = choose_action([], [], rng)
    assert key is None and w.size == 0
    with pytest.raises(ValueError, match=">= 0"):
        choose_action([(0, 0)], [-1.0], rng)
    with pytest.raises(ValueError, match="weights"):
        choose_action([(0, 0)], [1.0, 2.0], rng)
    keys = [(i, 0) for i in range(10)]
    ws = list(np.linspace(0.1, 1.0, 10))
    r1, r2 = np.random.default_rng(42), np.random.default_rng(42)
    a = [choose_action(keys, ws, r1)[0] for _ in range(100)]
    b = [choose_action(keys, ws, r2)[0] for _ in range(100)]
    assert a == b
    assert len(set(a)) > 3


def test_choose_plan_epsilon_greedy() -> None:
    rng = np.random.default_rng(5)
    w = [0.2, 0.9, 0.5]
    counts = np.bincount([choose_plan(w, [False] * 3, rng, 0.05) for _ in range(N)], minlength=3)
    frac = counts / N
    # best: 0.95 + 0.05/3 = 0.96667; others 0.05/3 = 0.01667 (sd 0.0009)
    assert abs(frac[1] - 0.96667) < 0.007
    assert abs(frac[0] - 0.01667) < 0.005 and abs(frac[2] - 0.01667) < 0.005
    counts = np.bincount([choose_plan(w, [False, True, False], rng, 0.05) for _ in range(N)],
                         minlength=3)
    assert counts[1] == 0
    assert abs(counts[2] / N - 0.975) < 0.007                # 0.95 + 0.05/2
    assert choose_plan(w, [True] * 3, rng, 0.05) is None
    assert choose_plan([], [], rng, 0.05) is None
    assert all(choose_plan(w, [False] * 3, rng, 0.0) == 1 for _ in range(500))


def test_choose_plan_ties_and_errors() -> None:
    rng = np.random.default_rng(6)
    picks = [choose_plan([0.5, 0.5, 0.1], [False] * 3, rng, 0.0) for _ in range(2000)]
    assert 2 not in picks
    assert 850 < picks.count(0) < 1150
    with pytest.raises(ValueError, match="exclusion"):
        choose_plan([0.5], [False, True], rng, 0.05)


def test_babbling_schedule() -> None:
    assert is_babbling_period(0, P) and is_babbling_period(19_999, P)
    assert not is_babbling_period(20_000, P)
    rng = np.random.default_rng(9)
    frac = np.mean([babble_instead(rng, P) for _ in range(N)])
    assert abs(frac - 0.1) < 0.01                             # sd 0.0021
    sched = BabbleSchedule(P)
    before = rng.bit_generator.state
    assert sched.should_babble(100, rng)
    assert rng.bit_generator.state == before                  # no draw during the period
    frac = np.mean([sched.should_babble(30_000, rng) for _ in range(N)])
    assert abs(frac - 0.1) < 0.01
    never = BabbleSchedule(P.replace(babble_probability=0.0))
    assert not any(never.should_babble(30_000, rng) for _ in range(100))


def test_iac_choice_record() -> None:
    c = IACChoice(step=25_000, action=(3, 2), weight=0.75, n_applicable=2, babbling=False,
                  weights=(0.25, 0.75))
    with pytest.raises(dataclasses.FrozenInstanceError):
        c.step = 1  # type: ignore[misc]
    assert c.to_dict() == {"step": 25_000, "action": [3, 2], "weight": 0.75,
                           "n_applicable": 2, "babbling": False, "weights": [0.25, 0.75]}
    assert IACChoice(1, None, 0.0, 0, True).to_dict()["action"] is None
