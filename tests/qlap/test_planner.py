"""Plans (§5.2–5.4): learned Q-values survive a growth of the state space; usable actions; the
sticky brel(o) flag. Numbers are computed by hand in the comments."""

from __future__ import annotations

import numpy as np
import pytest

from qlap_runtime.qlap import Params, VariableTable
from qlap_runtime.qlap.dbn import CHANGE, DBN
from qlap_runtime.qlap.mdp import NOT_APPLICABLE, sarsa_reward
from qlap_runtime.qlap.planner import Plan, PlanGroups, closes_cycle, dbn_rel_state
from qlap_runtime.qlap.variables import Event
from tests.qlap.toyworld import SPECS

P = Params()
U, X, XDOT = 0, 1, 2           # motor u, magnitude x, its direction of change ẋ
V_STAR = 60 / 11               # Q* of a(u, (0, +∞)) in every non-goal state, see below


def rel_half(var: int, value: int) -> float:
    return 0.5


def make_plan() -> tuple[Plan, DBN, VariableTable]:
    """⟨{}: u → (0, +∞) ⇒ ẋ → [+]⟩ as a plan; S = Q(u) × Q(ẋ) = 3 × 3, one action a(u, 2)."""
    table = VariableTable.from_specs(SPECS)
    dbn = DBN(0, CHANGE, Event(U, 2, 0), Event(XDOT, 2, 0), (), 0, len(table), 200)
    plan = Plan(0, dbn, table, P, 0, len(table))
    sizes = [3, 1, 3]
    plan.build(dbn, sizes, rel_half, dbn_rel_state(dbn, sizes, 1.0), fresh=True)
    return plan, dbn, table


def test_value_iteration_of_the_toy_plan_by_hand() -> None:
    # rel(r, s) = (0 + 1)/(0 + 0 + 2) = 0.5 with no data. a(u, 2) reaches ẋ = [+] (R = 10 − 2)
    # w.p. 0.5, else s' has u = 2 and ẋ unchanged (R = −2), whose value is the same V:
    # V = 0.5·8 + 0.5·(−2 + 0.9·V) → 0.55·V = 3 → V = 60/11 = 5.4545…
    plan, _, _ = make_plan()
    assert plan.space is not None and plan.space.vars == (U, XDOT)
    for u in range(3):
        for xd in range(2):
            assert plan.q[plan.space.index((u, xd)), 0] == pytest.approx(V_STAR, abs=1e-5)
        assert plan.q[plan.space.index((u, 2)), 0] == NOT_APPLICABLE   # goal: terminal


def test_a_q_value_learned_by_sarsa_survives_state_space_growth() -> None:
    plan, dbn, _ = make_plan()
    assert plan.space is not None and plan.sarsa is not None
    s0 = plan.space.index((0, 0))
    # Sarsa: a(u, 2) in (u = 0, ẋ = [−]) reached the goal in 3 steps: r' = 10 − 0.03 = 9.97,
    # terminal. δ = 9.97 − 60/11 = 4.515455; Q = 60/11 + 0.2·δ = 6.357636
    plan.sarsa.start(s0, 0)
    plan.sarsa.update(s0, 0, sarsa_reward(True, 3, P), plan.space.index((0, 2)), None)
    learned = 60 / 11 + 0.2 * (9.97 - 60 / 11)
    assert plan.q[s0, 0] == pytest.approx(learned)
    assert learned == pytest.approx(6.357636, abs=1e-6)

    # 1. C_o gains x (3 values, §5.4.2): S = Q(x) × Q(u) × Q(ẋ); the actions a(x, 0..2) come
    # first, a(u, 2) is now column 3. Every value of x inherits the learned value.
    plan.context_o = (X,)
    sizes = [3, 3, 3]
    assert plan.build(dbn, sizes, rel_half, dbn_rel_state(dbn, sizes, 1.0))
    sp = plan.space
    assert sp.vars == (X, U, XDOT) and len(plan.actions) == 4
    for x in range(3):
        assert plan.q[sp.index((x, 0, 0)), 3] == pytest.approx(learned)
        assert plan.q[sp.index((x, 1, 0)), 3] == pytest.approx(V_STAR, abs=1e-5)
    # New pairs take value iteration on the new model: a(x, q) is applicable only where
    # x > q (rule 1; rule 2 excludes x < q, which would need ẋ = [+]); it moves x w.p. 0.5
    # and otherwise stays, reward −2, and V is still 60/11: Q = −2 + 0.9·60/11 = 2.909091
    assert plan.q[sp.index((2, 0, 0)), 0] == pytest.approx(-2 + 0.9 * V_STAR, abs=1e-5)
    assert plan.q[sp.index((0, 0, 0)), 0] == NOT_APPLICABLE
    assert plan.sarsa.q is plan.q

    # 2. A landmark splits u's interval (−∞, 0) (value 0): u has 5 values, new_to_old
    # [0, 0, 0, 1, 2]; the antecedent (0, +∞) is renumbered 2 → 4 (as the learner does).
    dbn.antecedent = Event(U, 4, 0)
    sizes = [5, 3, 3]
    maps = {U: np.array([0, 0, 0, 1, 2])}
    assert plan.build(dbn, sizes, rel_half, dbn_rel_state(dbn, sizes, 1.0), value_maps=maps)
    sp = plan.space
    assert sp.sizes == (3, 5, 3)
    for x in range(3):
        for u in range(3):                          # the three descendants of old u = 0
            assert plan.q[sp.index((x, u, 0)), 3] == pytest.approx(learned)
        assert plan.q[sp.index((x, 3, 0)), 3] == pytest.approx(V_STAR, abs=1e-5)

    # 3. Unchanged structure: Q is kept as it is; fresh: value iteration from scratch.
    assert not plan.build(dbn, sizes, rel_half, dbn_rel_state(dbn, sizes, 1.0))
    assert plan.q[sp.index((1, 1, 0)), 3] == pytest.approx(learned)
    assert plan.build(dbn, sizes, rel_half, dbn_rel_state(dbn, sizes, 1.0), fresh=True)
    assert plan.q[sp.index((1, 1, 0)), 3] == pytest.approx(V_STAR, abs=1e-5)


def test_unusable_actions_are_never_applicable() -> None:
    plan, dbn, _ = make_plan()
    plan.context_o = (X,)
    sizes = [3, 3, 3]
    plan.build(dbn, sizes, rel_half, dbn_rel_state(dbn, sizes, 1.0), fresh=True,
               usable=lambda v, q: not (v == X and q == 0))
    assert plan.actions[0].var == X and plan.actions[0].value == 0
    assert np.all(plan.q[:, 0] == NOT_APPLICABLE)
    assert plan.model is not None and not plan.model.applicable[:, 0].any()
    # the mask holds through a refresh (Dyna) as well
    plan.refresh(rel_half, dbn_rel_state(dbn, sizes, 1.0), dyna=True)
    assert not plan.model.applicable[:, 0].any()
    assert np.all(plan.q[:, 0] == NOT_APPLICABLE)


def test_sufficiently_reliable_plan_is_sticky() -> None:
    # r_o² with empty C_o has one cell; brel(o) needs 5 successes (App. B.1): with 4, ⊥.
    # With 5: brel = 6/7 = 0.857 and P(p > 0.75 | Beta(6, 1)) = 1 − 0.75⁶ = 0.822 ≥ 0.8.
    plan, _, table = make_plan()
    x = np.zeros(len(table))
    for _ in range(4):
        plan.record_call(x, True, 0)
    assert not plan.refresh_reliable()
    plan.record_call(x, True, 0)
    assert plan.refresh_reliable()
    for _ in range(20):                             # brel = 6/27 now: the flag stays set
        plan.record_call(x, False, 0)
    assert not plan.stats().reliable
    assert plan.refresh_reliable()
    assert plan.plan_stats(100).reliable and plan.plan_stats(100).age == 100


def test_plan_groups_agree_with_the_plans_one_by_one() -> None:
    # Groups by action in key order, plans by id, and known() as index_from_full tells it,
    # for plans of different spaces (one with C_o, one never built) and vectors with −1 and
    # out-of-range values.
    table = VariableTable.from_specs(SPECS)
    sizes = [3, 3, 3]
    plans: dict[int, Plan] = {}
    for pid, (ante, cons, ctx_o) in [(3, (Event(U, 0), Event(XDOT, 2), ())),
                                     (1, (Event(U, 2), Event(XDOT, 2), (X,))),
                                     (2, (Event(U, 2), Event(XDOT, 0), ())),
                                     (0, (Event(U, 0), Event(XDOT, 0), ()))]:
        dbn = DBN(pid, CHANGE, ante, cons, (), 0, len(table), 200)
        plan = Plan(pid, dbn, table, P, 0, len(table))
        plan.context_o = ctx_o
        if pid != 0:
            plan.build(dbn, sizes, rel_half, dbn_rel_state(dbn, sizes, 1.0), fresh=True)
        plans[pid] = plan
    groups, cached = PlanGroups.for_plans(plans, None)
    assert groups.keys == [(XDOT, 0), (XDOT, 2)]
    assert [[pl.id for pl in g] for g in groups.groups] == [[0, 2], [1, 3]]
    rng = np.random.default_rng(0)
    for q in [*rng.integers(-1, 4, size=(200, 3)), np.array([0, 1]), np.array([], dtype=int)]:
        known = groups.known(q)
        for group, rows in zip(groups.groups, groups.rows, strict=True):
            for pl, r in zip(group, rows, strict=True):
                want = pl.space is not None and pl.space.index_from_full(q.tolist()) is not None
                assert known[r] == want
    assert PlanGroups.for_plans(plans, cached)[0] is groups          # nothing changed
    dbn2 = DBN(2, CHANGE, Event(U, 2), Event(XDOT, 0), (), 0, len(table), 200)
    plans[2].build(dbn2, [5, 3, 3], rel_half, dbn_rel_state(dbn2, [5, 3, 3], 1.0))
    again, _ = PlanGroups.for_plans(plans, cached)
    assert again is not groups and again.known(np.array([4, 0, 0]))[1]


def test_a_recount_with_unchanged_inputs_keeps_the_cpt_a_full_recount_gives() -> None:
    plan, _, table = make_plan()
    plan.context_o = (X,)
    rng = np.random.default_rng(1)

    def quantize(x_rows: np.ndarray, cols) -> np.ndarray:
        return np.where(np.isnan(x_rows[:, list(cols)]), -1, x_rows[:, list(cols)] > 0.5)

    def fresh(sizes: list[int]) -> tuple[bytes, bytes]:
        other = Plan(9, DBN(9, CHANGE, Event(U, 2), Event(XDOT, 2), (), 0, len(table), 200),
                     table, P, 0, len(table))
        other.call_x, other.call_ok = plan.call_x, plan.call_ok
        other.call_n, other.call_head, other.context_o = plan.call_n, plan.call_head, (X,)
        other.recount(quantize, sizes)
        return other.cpt_s.tobytes(), other.cpt_f.tobytes()

    for sizes, version in [([3, 3, 3], 1), ([3, 3, 3], 1), ([3, 5, 3], 1), ([3, 5, 3], 2)]:
        for _ in range(int(rng.integers(0, 3))):
            x = rng.uniform(0.0, 1.0, len(table))
            plan.record_call(x, bool(rng.random() < 0.5), int(x[X] > 0.5))
        plan.recount(quantize, sizes, version)
        assert (plan.cpt_s.tobytes(), plan.cpt_f.tobytes()) == fresh(sizes)
    s_before = plan.cpt_s
    plan.recount(quantize, [3, 5, 3], 2)                    # nothing changed: kept as it is
    assert plan.cpt_s is s_before


def test_a_rebuild_with_an_equal_space_keeps_the_space_and_its_cached_arrays() -> None:
    plan, dbn, _ = make_plan()
    space, q = plan.space, plan.q.copy()
    assert space is not None
    vals = space.all_values()
    changed = plan.build(dbn, [3, 1, 3], rel_half, dbn_rel_state(dbn, [3, 1, 3], 1.0))
    assert not changed and plan.space is space and plan.space.all_values() is vals
    assert plan.q.tobytes() == q.tobytes()
    plan.build(dbn, [5, 1, 3], rel_half, dbn_rel_state(dbn, [5, 1, 3], 1.0))
    assert plan.space is not space and plan.space.sizes == (5, 3)


def test_cached_cell_reliabilities_are_the_scalar_formula_after_every_change() -> None:
    # The per-cell values (DBN.cell_reliabilities, Plan.rel_state) are kept until a record or
    # a recount changes the CPT, and equal the formula on one cell's numpy numbers bit for bit.
    plan, dbn, table = make_plan()
    rng = np.random.default_rng(2)
    dbn.cpt_s, dbn.cpt_f = (rng.integers(0, 40, 6).astype(float) for _ in range(2))
    plan.cpt_s, plan.cpt_f = (rng.integers(0, 9, 3).astype(float) for _ in range(2))

    def check() -> None:
        for owner, got in ((dbn, dbn.cell_reliabilities(P.prior)),
                           (plan, [plan.rel_state(c) for c in range(len(plan.cpt_s))])):
            for c, g in enumerate(got):
                s, f = owner.cpt_s[c], owner.cpt_f[c]
                want = float((s + P.prior) / (s + f + 2 * P.prior))
                assert type(g) is float and np.float64(g).tobytes() == np.float64(want).tobytes()

    for _ in range(20):
        check()
        x = rng.uniform(0.0, 1.0, len(table))
        if rng.random() < 0.5:
            dbn.record(x, bool(rng.random() < 0.5), int(rng.integers(-1, 6)))
        else:
            plan.record_call(x, bool(rng.random() < 0.5), int(rng.integers(-1, 3)))
        if rng.random() < 0.2:                              # a recount: new arrays
            dbn.cpt_s, dbn.cpt_f = dbn.cpt_s + 1.0, dbn.cpt_f.copy()
    assert plan.rel_state(-1) == plan.rel() and plan.rel_state(3) == plan.rel()


def test_plan_groups_usable_agrees_with_the_scan_one_plan_at_a_time() -> None:
    # usable() against the IAC scan's tests plan by plan: the action not achieved, the plan's
    # state known, and for an action on a magnitude the plan's goal direction the side the
    # value is reached from; a magnitude group (X, 1) with a plan from each side.
    table = VariableTable.from_specs(SPECS)
    sizes = [3, 3, 3]
    plans: dict[int, Plan] = {}
    specs = [(3, CHANGE, Event(U, 0), Event(XDOT, 2)), (1, CHANGE, Event(U, 2), Event(XDOT, 2)),
             (2, CHANGE, Event(U, 2), Event(XDOT, 0)),
             (4, "magnitude", Event(XDOT, 2), Event(X, 1, 1)),
             (5, "magnitude", Event(XDOT, 0), Event(X, 1, -1))]
    for pid, kind, ante, cons in specs:
        dbn = DBN(pid, kind, ante, cons, (), 0, len(table), 200)
        plan = Plan(pid, dbn, table, P, 0, len(table))
        plan.build(dbn, sizes, rel_half, dbn_rel_state(dbn, sizes, 1.0), fresh=True)
        plans[pid] = plan
    groups, _ = PlanGroups.for_plans(plans, None)
    magnitudes = frozenset({X})
    rng = np.random.default_rng(3)
    for q in rng.integers(-1, 3, size=(300, 3)):
        found, usable = groups.usable(q, magnitudes)
        want_found = []
        for g, (key, group, rows) in enumerate(zip(groups.keys, groups.groups, groups.rows,
                                                  strict=True)):
            ok = []
            for pl, r in zip(group, rows, strict=True):
                good = pl.space.index_from_full(q.tolist()) is not None
                if key[0] in magnitudes:
                    good &= pl.goal.direction == (1 if q[key[0]] < key[1] else -1)
                assert usable[r] == good
                ok.append(good)
            if q[key[0]] != key[1] and any(ok):
                want_found.append(g)
        assert found == want_found


def test_plan_groups_plans_of_is_the_filter_of_all_plans() -> None:
    table = VariableTable.from_specs(SPECS)
    sizes = [3, 3, 3]
    plans: dict[int, Plan] = {}
    for pid, ante, cons in [(3, Event(U, 0), Event(XDOT, 2)), (1, Event(U, 2), Event(XDOT, 2)),
                            (2, Event(U, 2), Event(XDOT, 0))]:
        dbn = DBN(pid, CHANGE, ante, cons, (), 0, len(table), 200)
        plans[pid] = Plan(pid, dbn, table, P, 0, len(table))
        plans[pid].build(dbn, sizes, rel_half, dbn_rel_state(dbn, sizes, 1.0), fresh=True)
    groups = PlanGroups(plans)
    for key in [(XDOT, 0), (XDOT, 2), (XDOT, 1), (X, 0)]:
        want = sorted((pl for pl in plans.values() if pl.action == key), key=lambda pl: pl.id)
        assert groups.plans_of(key) == want


def test_a_rebuild_of_the_same_structure_leaves_the_model_to_the_next_refresh() -> None:
    # Rebuilt with new reliabilities and the same structure, a plan keeps its model (only
    # Dyna and value iteration read p1); its next refresh gives the model and Dyna sweep of a
    # plan whose rebuild computed the model.
    lazy, dbn, _ = make_plan()
    eager, _, _ = make_plan()
    sizes = [3, 1, 3]
    rng = np.random.default_rng(6)
    for _ in range(4):
        dbn.record(np.zeros(3), bool(rng.random() < 0.7), 0)
        rel_a = float(rng.uniform(0.1, 0.9))

        def rel(var: int, value: int, r: float = rel_a) -> float:
            return r

        before = lazy.model
        assert not lazy.build(dbn, sizes, rel, dbn_rel_state(dbn, sizes, 1.0))
        assert lazy.model is before
        eager._model_cache = None                       # the rebuild computes the model
        assert not eager.build(dbn, sizes, rel, dbn_rel_state(dbn, sizes, 1.0))
        for plan in (lazy, eager):
            plan.refresh(rel, dbn_rel_state(dbn, sizes, 1.0), dyna=True)
        assert lazy.model.p1.tobytes() == eager.model.p1.tobytes()
        assert lazy.q.tobytes() == eager.q.tobytes()


def test_an_edge_closes_a_cycle_when_its_antecedent_reaches_its_consequent():
    """§6.2.2 criterion 2: with plans a → b → c in the action graph (consequent → antecedent),
    a plan whose edge is c → a closes a cycle; a → c, or an edge apart, does not; a DBN whose
    antecedent is its own consequent does."""
    a, b, c, d = (0, 1), (1, 1), (2, 1), (3, 1)
    adj = {a: [b], b: [c]}
    assert closes_cycle(adj, (c, a))
    assert not closes_cycle(adj, (a, c))
    assert not closes_cycle(adj, (d, a))
    assert closes_cycle(adj, (d, d))
