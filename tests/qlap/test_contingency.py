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
        wl.update(t + 2, [], [3])
        t += 10
    wl.update(t, [(0, 7)], [])                        # closes the 40th episode
    found = wl.learnable(30, 0.05, 1.0, 0.8)
    assert len(found) == 1
    e1, e2, k_r = found[0]
    assert (e1, e2) == (7, 3)
    assert k_r == 3.0                                   # t' - t + 1
