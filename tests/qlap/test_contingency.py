"""Pairwise contingency statistics (§4.1) and the window k (Appendix C), by hand."""

import numpy as np

from qlap_runtime.qlap import Params
from qlap_runtime.qlap.contingency import PairStatistics, WindowLearner, soon_fraction
from qlap_runtime.qlap.perception import Perception
from qlap_runtime.qlap.variables import Event, VariableTable
from tests.qlap.toyworld import Spec


def setup():
    table = VariableTable.from_specs([Spec("u", "motor", -1, 1), Spec("x", "magnitude")])
    per = Perception(table, Params())
    return per, per.events


def test_event_index_excludes_invalid_consequents():
    _, idx = setup()
    # u: 3 values (motor), x: 1 value x2 directions, x.dot: 3 values -> 3 + 2 + 3 = 8 events
    assert idx.n_events == 8
    # consequents: only x.dot -> [-] and [+] (not [0], not magnitudes, not motors)
    cons = [idx.decode(int(e)) for e in idx.event_of_cons]
    assert cons == [Event(2, 0, 0), Event(2, 2, 0)]


def test_soon_counts_by_hand():
    _, idx = setup()
    up = idx.encode(Event(0, 2))          # u -> (0, +inf)
    xp = idx.encode(Event(2, 2))          # x.dot -> [+]
    c = idx.cons_of_event[xp]
    ps = PairStatistics(idx, k=3)
    # steps 0..9; E1 at 1 and 5; E2 at 2 (within [1,3]) and 9 (not within [5,7])
    for t in range(10):
        ev = []
        if t in (1, 5):
            ev.append(up)
        if t in (2, 9):
            ev.append(xp)
        ps.update(t, np.array(ev, dtype=np.int64))
    assert ps.occurrences[up] == 2                     # both windows closed by step 9
    assert ps.soon_given[up, c] == 1
    # soon(t, E2) holds for t in {0, 1, 2} (E2 at 2) and {7, 8, 9} (E2 at 9): 6 steps
    assert ps.soon_steps[c] == 6
    assert ps.resolved_steps() == 8                    # 10 - 3 + 1
    # Pr(soon|E1) = 1/2, Pr(soon) = 6/8: not a contingency
    assert ps.contingencies(np.full(idx.n_cons, 0.05), 1, 1.0, 0.8) == []


def test_contingency_found_when_e2_follows_e1():
    _, idx = setup()
    up, xp = idx.encode(Event(0, 2)), idx.encode(Event(2, 2))
    ps = PairStatistics(idx, k=2)
    for t in range(400):
        ev = []
        if t % 10 == 0:
            ev.append(up)
        if t % 10 == 1:
            ev.append(xp)
        ps.update(t, np.array(ev, dtype=np.int64))
    found = ps.contingencies(np.full(idx.n_cons, 0.05), 30, 1.0, 0.8)
    # Pr(soon|E1) = 1 (40 of 40), Pr(soon) = 2/10
    assert [(e1, e2) for e1, e2, _, _ in found] == [(up, xp)]
    assert found[0][2] == 1.0
    assert abs(found[0][3] - 0.2) < 0.01


def test_soon_fraction_union_of_windows():
    # occurrences at 5 and 6 with k=3: windows [3,5] and [4,6] -> union [3,6] = 4 of 10 steps
    assert soon_fraction(np.array([5, 6]), 3, 0, 9) == 0.4
    assert soon_fraction(np.array([], dtype=np.int64), 3, 0, 9) == 0.0


def test_window_learner_average_delay():
    wl = WindowLearner([0], history=1000)
    # 40 episodes of u -> q (E1 id 7), each followed by E2 (id 3) after 2 steps (delay 3)
    t = 0
    for _ in range(40):
        wl.update(t, [(0, 7)], [])
        wl.update(t + 2, [], [(5, 3)])
        t += 10
    wl.update(t, [(0, 7)], [])                        # closes the 40th episode
    found = wl.learnable(30, 0.05, 1.0, 0.8)
    assert len(found) == 1
    e1, e2, k_r = found[0]
    assert (e1, e2) == (7, 3)
    assert k_r == 3.0                                   # t' - t + 1


def test_window_learner_credits_only_the_first_change_of_a_variable():
    """A reversal later in the hold (the hand bouncing at its limit) is not the command's
    transition: E2 = x.dot→[+] (id 4) at delay 2, then x.dot→[−] (id 3) at delay 9 of the same
    variable (5); the reversal pair gets no success."""
    wl = WindowLearner([0], history=1000)
    t = 0
    for _ in range(40):
        wl.update(t, [(0, 7)], [])
        wl.update(t + 1, [], [(5, 4)])
        wl.update(t + 8, [], [(5, 3)])
        t += 20
    wl.update(t, [(0, 7)], [])
    assert sum(wl.delays[(7, 4)]) == 40 and (7, 3) not in wl.delays
    assert [(e1, e2, k) for e1, e2, k in wl.learnable(30, 0.05, 1.0, 0.8)] == [(7, 4, 2.0)]


def test_window_learner_change_to_zero_marks_the_variable():
    """x.dot→[0] (−1) is a change of the variable but not a consequent: a later [+] on the same
    variable in the same episode is not credited."""
    wl = WindowLearner([0], history=1000)
    wl.update(0, [(0, 7)], [])
    wl.update(1, [], [(5, -1)])
    wl.update(3, [], [(5, 4)])
    assert wl.delays == {}


def test_window_learner_late_successes_do_not_count_against_a_k_r_window():
    """Appendix C: the pair is tested with k_r as its window. E2 happens every 8 steps whatever
    the motor does; holds last 40 steps, so the first E2 of a hold comes at delays 1..8
    (mean 4.5 -> k_r = 4 with round-half-even, 5 of 8 phases within it... computed below).
    Counting every hold as a success (40 of 40 against a base rate of k_r/8) passed the test
    before; counting only successes within k_r gives Pr(soon | E1) = base rate: not learnable."""
    wl = WindowLearner([0], history=10_000)
    t = 0
    for i in range(64):                       # hold starts at every phase of the 8-step cycle
        wl.update(t, [(0, 7)], [])
        for tt in range(t, t + 40):
            if tt % 8 == 7:
                wl.update(tt, [], [(5, 4)])
        t += 40 + (i % 8) + 1
    wl.update(t, [(0, 7)], [])
    hist = wl.delays[(7, 4)]
    assert sum(hist) == 64 and len(hist) == 8 and min(hist) > 0       # delays 1..8 all seen
    mean = sum((d + 1) * c for d, c in enumerate(hist)) / 64
    k_r = round(mean)
    within = sum(hist[:k_r]) / 64
    assert abs(within - k_r / 8) < 0.1          # about the base rate: no contingency
    assert wl.learnable(30, 0.05, 1.0, 0.8) == []


def test_learner_learns_k_from_a_delayed_effect_in_a_two_motor_world():
    """A toy world with two motors: u1 moves x three steps after it is set (delay t' − t + 1 = 4),
    u2 does nothing. Babbling (App. E) on both; Appendix C must give k = 4, not a window
    stretched by u2's chance pairs or by the holds."""
    from qlap_runtime.qlap.babble import Babbler
    from qlap_runtime.qlap.learner import ModelLearner

    specs = [Spec("u1", "motor", -1.0, 1.0), Spec("u2", "motor", -1.0, 1.0),
             Spec("x", "magnitude")]
    params = Params()
    learner = ModelLearner(specs, params)
    babbler = Babbler(learner.table, params, np.random.default_rng(3))
    x, pending = 0.0, [0.0, 0.0, 0.0]                # u1 acts on x three steps later
    motor = {"u1": 0.0, "u2": 0.0}
    for t in range(4001):
        learner.observe(t, {"u1": motor["u1"], "u2": motor["u2"], "x": x})
        motor, _ = babbler.step()
        pending.append(motor["u1"])
        x += 0.5 * pending.pop(0)
    assert learner.k_learned
    assert learner.k == 4
