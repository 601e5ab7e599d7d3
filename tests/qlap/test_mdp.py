"""Plans' MDPs (§5.2–5.3): every number below is computed by hand in the comments."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from qlap_runtime.qlap import mdp
from qlap_runtime.qlap.mdp import (
    NOT_APPLICABLE,
    MDPAction,
    PlanSpec,
    PlanStateSpace,
    Role,
    SarsaLambda,
    TransitionModel,
    action_map,
    actions_from_state,
    actions_to_state,
    build_actions,
    compose_split_maps,
    descendant_state,
    dyna_sweep,
    greedy_action,
    greedy_policy,
    grow_q,
    q_from_state,
    q_to_state,
    remap_q,
    reward,
    sarsa_reward,
    split_value_map,
    state_values,
    value_iteration,
)
from qlap_runtime.qlap.params import Params
from qlap_runtime.qlap.variables import Event

P = Params()

# --- the toy change plan --------------------------------------------------------------------
# r = ⟨{C} : X → 1 ⇒ Y → 1⟩ with C = var 0, X = var 1, Y = var 2, all nominal with values {0, 1}.
# State (c, x, y) has index 4c + 2x + y.
# Actions: 0 = a(C, 0), 1 = a(C, 1), 2 = a(X, 1) (the antecedent action).
# rel(a(C, ·)) = 0.9; rel(r, s) = 0.8 when C = 1 and 0.2 when C = 0.
C, X, Y = 0, 1, 2
TOY_SPEC = PlanSpec(goal=Event(Y, 1), antecedent=Event(X, 1))
TOY_SPACE = PlanStateSpace.from_groups([[C], [X], [Y]], {C: 2, X: 2, Y: 2})
A_C0, A_C1, ANTE = 0, 1, 2


def toy_model(regress=None) -> TransitionModel:
    actions = build_actions(TOY_SPACE, TOY_SPEC)
    return TransitionModel.build(TOY_SPACE, actions, TOY_SPEC, [0.9, 0.9, 0.5],
                                 lambda st: 0.8 if st[C] == 1 else 0.2, regress)


def s_(c: int, x: int, y: int) -> int:
    return 4 * c + 2 * x + y


# --- state space ----------------------------------------------------------------------------


def test_state_space_mixed_radix_by_hand() -> None:
    sp = PlanStateSpace((3, 5, 7), (2, 3, 4))
    assert sp.n_states == 24
    assert sp.strides == (12, 4, 1)
    assert sp.index((1, 2, 3)) == (1 * 3 + 2) * 4 + 3 == 23
    assert sp.values(23) == (1, 2, 3)
    assert sp.values(13) == (1, 0, 1)  # 13 = 1·12 + 0·4 + 1
    assert all(sp.index(sp.values(i)) == i for i in range(24))
    np.testing.assert_array_equal(sp.all_values()[13], [1, 0, 1])
    # the agent's full vector is indexed by variable number; −1 (unavailable) gives None
    full = [0, 0, 0, 1, 0, 1, 0, 3]
    assert sp.index_from_full(full) == (1 * 3 + 1) * 4 + 3 == 19
    assert sp.index_from_full([0, 0, 0, 2, 0, 1, 0, 3]) is None  # 2 is outside Q(var 3)
    assert sp.index_from_full([0, 0, 0, 1, 0, -1, 0, 3]) is None
    with pytest.raises(ValueError, match="outside"):
        sp.index((2, 0, 0))


def test_state_space_from_groups_keeps_each_variable_once() -> None:
    # eq. 5.14: C_o = {5}, C = {3, 5}, X = 7, Y = 3 → (5, 3, 7)
    sp = PlanStateSpace.from_groups([[5], [3, 5], [7], [3]], {3: 2, 5: 4, 7: 3})
    assert sp.vars == (5, 3, 7)
    assert sp.sizes == (4, 2, 3)
    with pytest.raises(ValueError, match="twice"):
        PlanStateSpace((1, 1), (2, 2))


def test_with_variable_copies_q_to_every_value_of_the_new_variable() -> None:
    model = toy_model()
    q = value_iteration(model, P)
    new_space, state_map = TOY_SPACE.with_variable(5, 3)
    assert new_space.vars == (C, X, Y, 5)
    # (1, 0, 0, 2) → ((1·2 + 0)·2 + 0)·3 + 2 = 14, which was old state (1, 0, 0) = 4
    assert new_space.index((1, 0, 0, 2)) == 14
    assert state_map[14] == 4
    new_actions = build_actions(new_space, TOY_SPEC)
    assert new_actions == [MDPAction(C, 0), MDPAction(C, 1), MDPAction(5, 0), MDPAction(5, 1),
                           MDPAction(5, 2), MDPAction(X, 1, Role.ANTECEDENT)]
    amap = action_map(model.actions, new_actions)
    np.testing.assert_array_equal(amap, [0, 1, -1, -1, -1, 2])
    new_model = TransitionModel.build(new_space, new_actions, TOY_SPEC, np.full(6, 0.9),
                                      lambda st: 0.8 if st[C] == 1 else 0.2)
    q2 = remap_q(q, state_map, amap, new_model.applicable, fill=-1.5)
    for s_new in range(new_space.n_states):
        c, x, y, _ = new_space.values(s_new)
        old = TOY_SPACE.index((c, x, y))
        np.testing.assert_array_equal(q2[s_new, [0, 1, 5]], q[old])
        expected_new = -1.5 if y == 0 else NOT_APPLICABLE
        np.testing.assert_array_equal(q2[s_new, 2:5], expected_new)


def test_resized_splits_a_value_into_three_copies() -> None:
    # var 7 had Q(7) = {(−∞, a), [a], (a, +∞)}; a landmark splits (a, +∞) (value 2) → 5 values
    sp = PlanStateSpace((7, 2), (3, 2))
    assert split_value_map(3, 2) == [0, 1, (2, 3, 4)]
    assert split_value_map(3, 0) == [(0, 1, 2), 3, 4]
    new, state_map = sp.resized(7, 5, split_value_map(3, 2))
    assert new.sizes == (5, 2)
    # new (v7, v2) → old (min(v7, 2), v2); index = 2·v7 + v2
    np.testing.assert_array_equal(state_map, [0, 1, 2, 3, 4, 5, 4, 5, 4, 5])
    q = np.arange(12.0).reshape(6, 2)
    q2 = remap_q(q, state_map)
    np.testing.assert_array_equal(q2[new.index((3, 1))], q[sp.index((2, 1))])  # [10, 11]
    np.testing.assert_array_equal(q2[new.index((4, 0))], [8.0, 9.0])
    # a(7, q) on the resized variable continues a(7, new_to_old[q])
    old_actions = [MDPAction(7, q) for q in range(3)]
    new_actions = [MDPAction(7, q) for q in range(5)]
    np.testing.assert_array_equal(
        action_map(old_actions, new_actions, {7: [0, 1, 2, 2, 2]}), [0, 1, 2, 2, 2])
    with pytest.raises(ValueError, match="no old value"):
        sp.resized(7, 5, [0, 1, (2, 3)])
    with pytest.raises(ValueError, match="two old values"):
        sp.resized(7, 3, [0, 1, 1])


def test_compose_split_maps_by_hand() -> None:
    # var 7 had 3 values; a landmark splits value 2 (→ 5 values), then one splits value 0 of
    # that numbering (→ 7 values). First map: [0, 1, 2, 2, 2]; the second split sends new
    # 0, 1, 2 to 0 and q > 2 to q − 2: [0, 0, 0, 1, 2, 3, 4] → [0, 0, 0, 1, 2, 2, 2].
    maps = compose_split_maps([(7, 2), (7, 0), (3, 4)], {7: 7, 3: 9})
    np.testing.assert_array_equal(maps[7], [0, 0, 0, 1, 2, 2, 2])
    np.testing.assert_array_equal(maps[3], [0, 1, 2, 3, 4, 4, 4, 5, 6])
    assert compose_split_maps([(7, 6)], {7: 5}) == {}       # sizes not explained: no map


def test_grow_q_carries_values_through_a_split() -> None:
    # old: vars (7, 2), sizes (3, 2), state (v7, v2) = 2·v7 + v2; actions a(7, 0..2), a(2, 1)
    old = PlanStateSpace((7, 2), (3, 2))
    old_actions = [MDPAction(7, q) for q in range(3)] + [MDPAction(2, 1, Role.ANTECEDENT)]
    q_old = np.arange(24.0).reshape(6, 4)
    q_old[5, 1] = NOT_APPLICABLE
    # a landmark splits value 2 of var 7: new sizes (5, 2), map [0, 1, 2, 2, 2]
    new = PlanStateSpace((7, 2), (5, 2))
    new_actions = [MDPAction(7, q) for q in range(5)] + [MDPAction(2, 1, Role.ANTECEDENT)]
    base = np.full((10, 6), -1.0)
    base[new.index((3, 1)), 4] = NOT_APPLICABLE
    q = grow_q(q_old, old, old_actions, new, new_actions, {7: np.array([0, 1, 2, 2, 2])}, base)
    assert q is not None
    # new (3, 1) descends from old (2, 1) = state 5, row [20, −inf, 22, 23]; a(7, 3), a(7, 4)
    # continue a(7, 2); the −inf old pair takes base (−1); base's −inf stays.
    np.testing.assert_array_equal(q[new.index((3, 1))], [20, -1, 22, 22, NOT_APPLICABLE, 23])
    # new (1, 0) is old (1, 0) = state 2: [8, 9, 10, 10, 10, 11]
    np.testing.assert_array_equal(q[new.index((1, 0))], [8, 9, 10, 10, 10, 11])
    # a size change without a map cannot be followed
    assert grow_q(q_old, old, old_actions, new, new_actions, {}, base) is None


def test_grow_q_adds_and_drops_variables() -> None:
    # old: vars (0, 1), sizes (2, 2), state 2·v0 + v1; actions a(0, 0), a(0, 1), a(1, 1)
    old = PlanStateSpace((0, 1), (2, 2))
    old_actions = [MDPAction(0, 0), MDPAction(0, 1), MDPAction(1, 1, Role.ANTECEDENT)]
    q_old = np.zeros((4, 3))
    q_old[:, 2] = [1.0, 5.0, 3.0, NOT_APPLICABLE]
    # new: var 0 dropped, var 5 (3 values) added: vars (1, 5), state 3·v1 + v5
    new = PlanStateSpace((1, 5), (2, 3))
    new_actions = [MDPAction(5, q) for q in range(3)] + [MDPAction(1, 1, Role.ANTECEDENT)]
    base = np.full((6, 4), -1.5)
    q = grow_q(q_old, old, old_actions, new, new_actions, {}, base)
    assert q is not None
    # a(1, 1) at v1 = 0: mean of old (0, 0) and (1, 0) = (1 + 3)/2 = 2; at v1 = 1: old (0, 1)
    # = 5 and (1, 1) not applicable → 5; the same for every value of the new var 5.
    np.testing.assert_array_equal(q[:, 3], [2, 2, 2, 5, 5, 5])
    np.testing.assert_array_equal(q[:, :3], -1.5)           # new actions: base


def test_grow_q_drops_a_variable_when_no_old_action_continues() -> None:
    # Every old action is on the dropped variable 0: no column carries over, every pair takes
    # base (a reshape with no column once failed; seen in a core run with lag 500).
    old = PlanStateSpace((0, 1), (2, 2))
    old_actions = [MDPAction(0, 0), MDPAction(0, 1)]
    new = PlanStateSpace((1,), (2,))
    new_actions = [MDPAction(1, 1, Role.ANTECEDENT)]
    base = np.full((2, 1), -2.5)
    q = grow_q(np.zeros((4, 2)), old, old_actions, new, new_actions, {}, base)
    assert q is not None
    np.testing.assert_array_equal(q, base)


def test_descendant_state_prefers_the_current_values() -> None:
    old = PlanStateSpace((7, 2), (3, 2))
    new = PlanStateSpace((7, 2, 9), (5, 2, 3))             # 7 split at 2, 9 added
    maps = {7: np.array([0, 1, 2, 2, 2])}
    prefer = np.full(10, -1)
    prefer[7], prefer[2], prefer[9] = 4, 0, 2
    # old (2, 1): v7 ∈ {2, 3, 4} → 4 (preferred); v2 must stay 1; v9 → 2: (4·2 + 1)·3 + 2 = 29
    assert descendant_state(old, new, maps, old.index((2, 1)), prefer) == 29
    prefer[7] = 0                                           # not a descendant: the first, 2
    assert descendant_state(old, new, maps, old.index((2, 1)), prefer) == (2 * 2 + 1) * 3 + 2
    assert descendant_state(old, new, {}, 0, prefer) is None


# --- transitions and applicability ----------------------------------------------------------


def test_toy_transitions() -> None:
    m = toy_model()
    # context a(C, 1) from (0, 1, 0): success → (1, 1, 0) with 0.9, else stays
    assert m.applicable[s_(0, 1, 0), A_C1]
    assert (m.next1[s_(0, 1, 0), A_C1], m.next2[s_(0, 1, 0), A_C1]) == (s_(1, 1, 0), s_(0, 1, 0))
    assert m.p1[s_(0, 1, 0), A_C1] == pytest.approx(0.9)
    # antecedent from (1, 0, 0): → (1, 1, 1) with rel(r, s) = 0.8, else (1, 1, 0)
    assert (m.next1[s_(1, 0, 0), ANTE], m.next2[s_(1, 0, 0), ANTE]) == (s_(1, 1, 1), s_(1, 1, 0))
    assert m.p1[s_(1, 0, 0), ANTE] == pytest.approx(0.8)
    assert m.p1[s_(0, 0, 0), ANTE] == pytest.approx(0.2)
    # X is not a magnitude: a(X, 1) stays applicable where X = 1 already (footnote 2)
    assert m.applicable[s_(0, 1, 0), ANTE]
    # nothing is applicable in a goal state (Y = 1); everything else is
    np.testing.assert_array_equal(m.applicable.all(axis=1), [c == 0 for c in (0, 1) * 4])
    np.testing.assert_array_equal(m.applicable.any(axis=1), [y == 0 for y in (0, 1) * 4])
    np.testing.assert_array_equal(m.goal, [True if i % 2 else False for i in range(8)])
    # eq. 5.5 rewards: into the goal 10 − 2 = 8, else −2
    r1, r2 = m.rewards(P)
    assert (r1[s_(1, 0, 0), ANTE], r2[s_(1, 0, 0), ANTE]) == (8.0, -2.0)
    np.testing.assert_array_equal(reward(np.array([True, False]), P), [8.0, -2.0])


def test_rule2_regress_predicate_and_mask() -> None:
    # exclude a(C, 1) wherever C = 0 (as if it would call a(Y, 1) again)
    def regress(state, a):
        return a == MDPAction(C, 1) and state[C] == 0

    m = toy_model(regress)
    base = toy_model()
    expected = base.applicable.copy()
    for x in (0, 1):
        expected[s_(0, x, 0), A_C1] = False
    np.testing.assert_array_equal(m.applicable, expected)
    assert m.p1[s_(0, 0, 0), A_C1] == 0.0
    assert m.next1[s_(0, 0, 0), A_C1] == s_(0, 0, 0)
    mask = np.zeros((8, 3), dtype=bool)
    mask[[s_(0, 0, 0), s_(0, 1, 0)], A_C1] = True
    np.testing.assert_array_equal(toy_model(mask).applicable, expected)


# change plan with a magnitude antecedent ↑X → x: X = var 1 with values 0 = (−∞, x),
# 1 = [x], 2 = (x, +∞); Y = var 2 nominal {0, 1}; state (x, y) has index 2x + y.
# build_actions gives 0 = a(X, 0), 1 = a(X, 2), 2 = a(X, 1) (antecedent).


def magnitude_antecedent_model(direction: int) -> TransitionModel:
    spec = PlanSpec(goal=Event(Y, 1), antecedent=Event(X, 1, direction),
                    magnitude_vars=frozenset({X}))
    space = PlanStateSpace((X, Y), (3, 2))
    actions = build_actions(space, spec)
    assert actions == [MDPAction(X, 0), MDPAction(X, 2), MDPAction(X, 1, Role.ANTECEDENT)]
    return TransitionModel.build(space, actions, spec, [0.9, 0.7, 0.5], np.full(6, 0.6))


def test_wrong_side_gives_probability_zero() -> None:
    up = magnitude_antecedent_model(+1)
    # X below x: ↑X → x can happen; success (1, 1) with rel(r, s) = 0.6, else (1, 0)
    assert (up.next1[0, 2], up.p1[0, 2], up.next2[0, 2]) == (3, pytest.approx(0.6), 2)
    # X above x is the wrong side for ↑: Pr(s'1) = 0 and Pr(s'2 = (1, 0)) = 1
    assert up.applicable[4, 2]
    assert (up.p1[4, 2], up.next2[4, 2]) == (0.0, 2)
    down = magnitude_antecedent_model(-1)
    assert down.p1[0, 2] == 0.0  # X below x is the wrong side for ↓
    assert down.p1[4, 2] == pytest.approx(0.6)


def test_rule1_and_rule3_on_a_magnitude_antecedent() -> None:
    up = magnitude_antecedent_model(+1)
    # rule 1: a(X, 1) is not applicable where X = 1; rule 3 (↑): a(X, 0) only where X ≥ x
    # (moving below x makes ↑X → x achievable), a(X, 2) never
    np.testing.assert_array_equal(up.applicable[[0, 2, 4]], [[False, False, True],
                                                             [True, False, False],
                                                             [True, False, True]])
    assert (up.next1[4, 0], up.p1[4, 0], up.next2[4, 0]) == (0, pytest.approx(0.9), 4)
    down = magnitude_antecedent_model(-1)
    np.testing.assert_array_equal(down.applicable[[0, 2, 4]], [[False, True, True],
                                                               [False, True, False],
                                                               [False, False, True]])
    assert not up.applicable[[1, 3, 5]].any()  # goal states


# magnitude plan r⁺ = ⟨∅ : Ẏ → [+] ⇒ ↑Y → y⟩ (§5.3): Y = var 0 with values 0 = (−∞, y),
# 1 = [y], 2 = (y, +∞); Ẏ = var 1 with values 0 = [−], 1 = [0], 2 = [+]. State (y, ẏ) has
# index 3y + ẏ. Actions: 0 = a(Ẏ, [+]) (antecedent, rel(a) = 0.5), 1 = wait (rel(r, s) = 0.8).


def magnitude_plan_model() -> TransitionModel:
    spec = PlanSpec(goal=Event(0, 1, +1), antecedent=Event(1, 2), magnitude_plan=True,
                    magnitude_vars=frozenset({0}))
    space = PlanStateSpace((0, 1), (3, 3))
    actions = build_actions(space, spec)
    assert actions == [MDPAction(1, 2, Role.ANTECEDENT), MDPAction.wait()]
    return TransitionModel.build(space, actions, spec, [0.5, 0.0], np.full(9, 0.8))


def test_magnitude_plan_actions_and_transitions() -> None:
    m = magnitude_plan_model()
    # Y below y: a(Ẏ, [+]) where Ẏ ≠ [+], wait only where Ẏ = [+]; Y = y: goal;
    # Y above y: the wrong side of r⁺, nothing applicable
    expected = np.zeros((9, 2), dtype=bool)
    expected[[0, 1], 0] = True
    expected[2, 1] = True
    np.testing.assert_array_equal(m.applicable, expected)
    # the antecedent action is a context move with rel(a): (0, [0]) → (0, [+]) or stays
    assert (m.next1[1, 0], m.p1[1, 0], m.next2[1, 0]) == (2, pytest.approx(0.5), 1)
    # wait: (0, [+]) → (y, [+]) = 5 with rel(r, s), else stays
    assert (m.next1[2, 1], m.p1[2, 1], m.next2[2, 1]) == (5, pytest.approx(0.8), 2)


def test_magnitude_plan_value_iteration_by_hand() -> None:
    q = value_iteration(magnitude_plan_model(), P)
    # V(0,[+]) = 0.8·8 + 0.2·(−2 + 0.9·V) ⇒ 0.82·V = 6 ⇒ V = 300/41 ≈ 7.3171
    v_plus = 300 / 41
    # V(0,[0]) = 0.5·(−2 + 0.9·V(0,[+])) + 0.5·(−2 + 0.9·V(0,[0]))
    #   ⇒ 0.55·V = −2 + 0.45·300/41 = 53/41 ⇒ V = 53/22.55 ≈ 2.3503
    v_zero = 53 / 41 / 0.55
    assert q[2, 1] == pytest.approx(v_plus, abs=1e-5)
    assert q[1, 0] == pytest.approx(v_zero, abs=1e-5)
    assert q[0, 0] == pytest.approx(v_zero, abs=1e-5)
    assert q[2, 0] == NOT_APPLICABLE
    np.testing.assert_array_equal(greedy_policy(q), [0, 0, 1, -1, -1, -1, -1, -1, -1])


def test_model_validation() -> None:
    with pytest.raises(ValueError, match="direction"):
        PlanSpec(goal=Event(Y, 1), antecedent=Event(X, 1), magnitude_vars=frozenset({X}))
    with pytest.raises(ValueError, match="direction"):
        PlanSpec(goal=Event(0, 1), antecedent=Event(1, 2), magnitude_plan=True)
    with pytest.raises(ValueError, match="magnitude plans only"):
        TransitionModel.build(TOY_SPACE, [MDPAction.wait()], TOY_SPEC, [0.5], np.zeros(8))
    with pytest.raises(ValueError, match=r"rel\(r, s\)"):
        TransitionModel.build(TOY_SPACE, [MDPAction(C, 0)], TOY_SPEC, [0.5], np.full(8, 1.5))
    with pytest.raises(ValueError, match="is not"):
        TransitionModel.build(TOY_SPACE, [MDPAction(C, 1, Role.ANTECEDENT)], TOY_SPEC, [0.5],
                              np.zeros(8))


# --- value iteration, Dyna ------------------------------------------------------------------


def test_value_iteration_two_sweeps_by_hand() -> None:
    q = value_iteration(toy_model(), P.replace(value_iteration_max_sweeps=2))
    # sweep 1 (V = 0): antecedent at C = 1: 0.8·8 + 0.2·(−2) = 6.0; at C = 0: 0.2·8 + 0.8·(−2)
    # = 0.0; every context move −2. So V(C=1) = 6, V(C=0) = 0 for Y = 0.
    # sweep 2:
    for x in (0, 1):
        # antecedent at C = 1: 0.8·8 + 0.2·(−2 + 0.9·6) = 6.4 + 0.68 = 7.08
        assert q[s_(1, x, 0), ANTE] == pytest.approx(7.08)
        # antecedent at C = 0: 0.2·8 + 0.8·(−2 + 0.9·0) = 0.0
        assert q[s_(0, x, 0), ANTE] == pytest.approx(0.0)
        # a(C, 1) from C = 0: 0.9·(−2 + 0.9·6) + 0.1·(−2 + 0) = 3.06 − 0.2 = 2.86
        assert q[s_(0, x, 0), A_C1] == pytest.approx(2.86)
        # a(C, 0) from C = 1: 0.9·(−2 + 0) + 0.1·(−2 + 5.4) = −1.8 + 0.34 = −1.46
        assert q[s_(1, x, 0), A_C0] == pytest.approx(-1.46)
        # a(C, 1) from C = 1 (a self-loop): −2 + 5.4 = 3.4
        assert q[s_(1, x, 0), A_C1] == pytest.approx(3.4)
        assert q[s_(0, x, 0), A_C0] == pytest.approx(-2.0)
    assert np.all(q[[1, 3, 5, 7]] == NOT_APPLICABLE)


def test_value_iteration_fixed_point_by_hand() -> None:
    q = value_iteration(toy_model(), P)
    v = state_values(q)
    # C = 1: V = 0.8·8 + 0.2·(−2 + 0.9·V) ⇒ 0.82·V = 6 ⇒ V = 300/41 ≈ 7.3171
    v1 = 300 / 41
    # C = 0: a(C, 1): V = 0.9·(−2 + 0.9·v1) + 0.1·(−2 + 0.9·V) = −2 + 0.81·v1 + 0.09·V
    #   ⇒ 0.91·V = −2 + 243/41 = 161/41 ⇒ V ≈ 4.3152 (the antecedent there gives 0.72·V)
    v0 = 161 / 41 / 0.91
    np.testing.assert_allclose(v, [v0, 0, v0, 0, v1, 0, v1, 0], atol=1e-5)
    np.testing.assert_array_equal(greedy_policy(q), [A_C1, -1, A_C1, -1, ANTE, -1, ANTE, -1])
    # the fixed point is left alone by a Dyna sweep (eq. 5.10)
    q2 = dyna_sweep(q.copy(), toy_model(), P)
    np.testing.assert_allclose(q2, q, atol=1e-5)


def test_dyna_sweep_by_hand() -> None:
    m = toy_model()
    q = m.initial_q()
    q[s_(1, 1, 0), ANTE] = 5.0  # so V(1, 1, 0) = 5, every other V = 0
    out = dyna_sweep(q, m, P)
    assert out is q  # in place
    # antecedent at (1, 0, 0): target 0.8·8 + 0.2·(−2 + 0.9·5) = 6.9; 0.8·0 + 0.2·6.9 = 1.38
    assert q[s_(1, 0, 0), ANTE] == pytest.approx(1.38)
    # antecedent at (1, 1, 0): 0.8·5 + 0.2·6.9 = 5.38
    assert q[s_(1, 1, 0), ANTE] == pytest.approx(5.38)
    # a(C, 1) at (0, 1, 0): target 0.9·(−2 + 4.5) + 0.1·(−2) = 2.05; 0.2·2.05 = 0.41
    assert q[s_(0, 1, 0), A_C1] == pytest.approx(0.41)
    # a(C, 1) at (0, 0, 0): target −2 (V(1, 0, 0) was 0); 0.2·(−2) = −0.4
    assert q[s_(0, 0, 0), A_C1] == pytest.approx(-0.4)
    # antecedent at (0, 0, 0): target 0.2·8 + 0.8·(−2 + 0) = 0
    assert q[s_(0, 0, 0), ANTE] == pytest.approx(0.0)
    assert np.all(q[[1, 3, 5, 7]] == NOT_APPLICABLE)


# --- ε-greedy (§6.1.3) ----------------------------------------------------------------------


def test_greedy_action_none_and_greedy() -> None:
    q = np.array([[NOT_APPLICABLE, NOT_APPLICABLE], [1.0, 3.0]])
    rng = np.random.default_rng(0)
    assert greedy_action(q, 0, rng, 0.05) is None
    assert all(greedy_action(q, 1, rng, 0.0) == 1 for _ in range(50))


def test_greedy_action_is_deterministic_for_a_seed() -> None:
    q = np.array([[0.0, 2.0, NOT_APPLICABLE, 1.0]])
    a = [greedy_action(q, 0, np.random.default_rng(7), 0.5) for _ in range(2)]
    rng1, rng2 = np.random.default_rng(11), np.random.default_rng(11)
    seq1 = [greedy_action(q, 0, rng1, 0.5) for _ in range(200)]
    seq2 = [greedy_action(q, 0, rng2, 0.5) for _ in range(200)]
    assert a[0] == a[1]
    assert seq1 == seq2
    assert set(seq1) == {0, 1, 3}  # ε = 0.5 explores all applicable actions, never action 2


def test_greedy_action_frequencies() -> None:
    # ε = 0.3 over 3 applicable actions: best 0.7 + 0.3/3 = 0.8, others 0.1, inapplicable 0
    q = np.array([[0.0, NOT_APPLICABLE, 2.0, 1.0]])
    rng = np.random.default_rng(2024)
    n = 20_000
    counts = np.bincount([greedy_action(q, 0, rng, 0.3) for _ in range(n)], minlength=4) / n
    np.testing.assert_allclose(counts, [0.1, 0.0, 0.8, 0.1], atol=0.01)
    # ties are broken at random
    tie = np.array([[1.0, 1.0]])
    picks = {greedy_action(tie, 0, rng, 0.0) for _ in range(100)}
    assert picks == {0, 1}


# --- Sarsa(λ) (eq. 5.7–5.9) -----------------------------------------------------------------


def test_sarsa_reward() -> None:
    assert sarsa_reward(True, 4, P) == pytest.approx(9.96)   # 10 − 0.01·4
    assert sarsa_reward(False, 5, P) == pytest.approx(-0.05)  # 0 − 0.01·5


def test_sarsa_lambda_three_step_episode_by_hand() -> None:
    q = np.zeros((4, 2))
    q[1, 1] = 1.0
    q[3, 0] = NOT_APPLICABLE
    sarsa = SarsaLambda(q, P)
    sarsa.start(0, 0)
    # step 1: (0,0) → r' = −0.05 → (1,1). δ = −0.05 + 0.9·1 − 0 = 0.85; Q(0,0) = 0.2·0.85
    # = 0.17; then the trace of (0,0) decays 1 → λγ = 0.81
    assert sarsa.update(0, 0, sarsa_reward(False, 5, P), 1, 1) == pytest.approx(0.85)
    assert q[0, 0] == pytest.approx(0.17)
    assert sarsa.e[0, 0] == pytest.approx(0.81)
    # step 2: (1,1) → r' = −0.03 → (2,0). δ = −0.03 + 0 − 1 = −1.03;
    # Q(1,1) = 1 + 0.2·(−1.03)·1 = 0.794; Q(0,0) = 0.17 + 0.2·(−1.03)·0.81 = 0.00314
    assert sarsa.update(1, 1, sarsa_reward(False, 3, P), 2, 0) == pytest.approx(-1.03)
    assert q[1, 1] == pytest.approx(0.794)
    assert q[0, 0] == pytest.approx(0.00314)
    np.testing.assert_allclose(sarsa.e[[0, 1], [0, 1]], [0.6561, 0.81])
    # step 3: (2,0) → goal, r' = 10 − 0.04 = 9.96, terminal: δ = 9.96 − 0
    # Q(2,0) = 0.2·9.96 = 1.992; Q(1,1) = 0.794 + 1.992·0.81 = 2.40752;
    # Q(0,0) = 0.00314 + 1.992·0.6561 = 1.3100912
    assert sarsa.update(2, 0, sarsa_reward(True, 4, P), 3, None) == pytest.approx(9.96)
    assert q[2, 0] == pytest.approx(1.992)
    assert q[1, 1] == pytest.approx(2.40752)
    assert q[0, 0] == pytest.approx(1.3100912)
    assert q[3, 0] == NOT_APPLICABLE
    assert not sarsa.e.any()  # the episode ended


def test_sarsa_traces_are_replacing() -> None:
    q = np.zeros((2, 1))
    sarsa = SarsaLambda(q, P)
    sarsa.start(0, 0)
    sarsa.update(0, 0, 1.0, 0, 0)  # δ = 1 + 0.9·0 − 0 = 1: Q(0,0) = 0.2; e → 0.81
    # revisit: e(0,0) is set to 1 (accumulating would give 1.81). δ = 1 + 0.9·Q(1,0) − 0.2
    # = 0.8; Q(0,0) = 0.2 + 0.2·0.8·1 = 0.36 (accumulating: 0.2 + 0.16·1.81 = 0.4896)
    sarsa.update(0, 0, 1.0, 1, 0)
    assert q[0, 0] == pytest.approx(0.36)
    assert sarsa.e[0, 0] == pytest.approx(0.81)
    with pytest.raises(ValueError, match="not applicable"):
        SarsaLambda(np.array([[NOT_APPLICABLE]]), P).start(0, 0)


# --- serialisation --------------------------------------------------------------------------


def test_state_round_trips_through_strict_json() -> None:
    m = toy_model()
    q = value_iteration(m, P)
    sarsa = SarsaLambda(q, P)
    sarsa.start(s_(0, 0, 0), A_C1)
    sarsa.update(s_(0, 0, 0), A_C1, -0.02, s_(1, 0, 0), ANTE)
    blob = json.dumps({"space": TOY_SPACE.to_state(), "actions": actions_to_state(m.actions),
                       "sarsa": sarsa.to_state(), "q": q_to_state(q)}, allow_nan=False)
    data = json.loads(blob)
    assert PlanStateSpace.from_state(data["space"]) == TOY_SPACE
    assert actions_from_state(data["actions"]) == list(m.actions)
    back = SarsaLambda.from_state(data["sarsa"], P)
    np.testing.assert_array_equal(back.q, q)
    np.testing.assert_array_equal(back.e, sarsa.e)
    assert back.e[s_(0, 0, 0), A_C1] == pytest.approx(0.81)
    np.testing.assert_array_equal(q_from_state(data["q"]), q)
    # npz-friendly: the same dict as arrays
    as_arrays = {k: np.asarray(v) for k, v in q_to_state(q).items()}
    np.testing.assert_array_equal(q_from_state(as_arrays), q)


# --- value iteration on the bisimulation quotient ---------------------------------------------


def _unreduced_value_iteration(model: TransitionModel, params: Params) -> np.ndarray:
    """The sweeps of value_iteration over every state (no quotient)."""
    r1, r2 = model.rewards(params)
    p1 = model.p1
    p2 = 1.0 - p1
    return mdp._sweeps(model.initial_q(), p1 * r1 + p2 * r2, p1, p2, model.next1, model.next2,
                       model.applicable, params)


@pytest.mark.parametrize("seed", range(6))
def test_value_iteration_on_the_quotient_is_bit_identical(seed: int) -> None:
    # W (var 3, 3 values) and C: rel(r, s) depends on C only, so states differing in W alone
    # are bisimilar (W's own context moves aside, which every W value has the same of).
    rng = np.random.default_rng(seed)
    w_var = 3
    space = PlanStateSpace.from_groups([[w_var], [C], [X], [Y]], {w_var: 3, C: 3, X: 2, Y: 2})
    actions = build_actions(space, TOY_SPEC)
    rel_a = rng.uniform(0.05, 1.0, len(actions)).round(int(rng.integers(1, 4)))
    rel_c = rng.uniform(0.0, 1.0, 3)
    model = TransitionModel.build(space, actions, TOY_SPEC, rel_a,
                                  lambda st: float(rel_c[st[C]]))
    r1, r2 = model.rewards(P)
    er = model.p1 * r1 + (1.0 - model.p1) * r2
    cls, reps = mdp._bisimilar(model.applicable, er, model.p1, model.next1, model.next2)
    assert reps.size < space.n_states                       # something was merged
    np.testing.assert_array_equal(cls[reps], np.arange(reps.size))
    for params in (P, P.replace(value_iteration_max_sweeps=3)):
        q = value_iteration(model, params)
        assert q.tobytes() == _unreduced_value_iteration(model, params).tobytes()


def test_row_classes_survive_hash_collisions(monkeypatch: pytest.MonkeyPatch) -> None:
    rows = np.array([[1, 2], [3, 4], [1, 2], [5, 6], [3, 4]], dtype=np.int64)
    cls, first = mdp._row_classes(rows)
    np.testing.assert_array_equal(cls, [0, 1, 0, 2, 1])
    np.testing.assert_array_equal(first, [0, 1, 3])
    monkeypatch.setitem(mdp._ROW_HASH, 2, np.zeros(2, dtype=np.uint64))   # every hash equal
    cls2, first2 = mdp._row_classes(rows)
    np.testing.assert_array_equal(cls2, cls)
    np.testing.assert_array_equal(first2, first)


def test_dyna_sweep_on_applicable_pairs_is_bit_identical() -> None:
    rng = np.random.default_rng(3)
    w_var = 3
    space = PlanStateSpace.from_groups([[w_var], [C], [X], [Y]], {w_var: 3, C: 3, X: 2, Y: 2})
    actions = build_actions(space, TOY_SPEC)
    model = TransitionModel.build(space, actions, TOY_SPEC, rng.uniform(0.1, 1.0, len(actions)),
                                  rng.uniform(0.0, 1.0, space.n_states))
    q = np.where(model.applicable, rng.normal(0.0, 3.0, model.applicable.shape), NOT_APPLICABLE)
    a = P.dyna_alpha
    expected = q.copy()
    m = model.applicable
    expected[m] = (1.0 - a) * q[m] + a * model.backup(q, P)[m]
    for _ in range(2):                                      # the second sweep: cached pairs
        expected2 = expected.copy()
        expected2[m] = (1.0 - a) * expected[m] + a * model.backup(expected, P)[m]
        got = dyna_sweep(q, model, P)
        assert got is q and q.tobytes() == expected.tobytes()
        expected = expected2
    wide = np.zeros((q.shape[0], 2 * q.shape[1]))           # a non-contiguous table
    wide[:, ::2] = q
    dyna_sweep(wide[:, ::2], model, P)
    assert np.ascontiguousarray(wide[:, ::2]).tobytes() == expected.tobytes()


def test_grow_q_single_ancestor_matches_the_mean_bit_for_bit() -> None:
    # A split of C's value 0 (one ancestor per new state): each inherited value is the mean of
    # one value, 0.0 + x / 1.0, so −0.0 becomes +0.0 and every other value is kept exactly.
    actions = build_actions(TOY_SPACE, TOY_SPEC)
    model = TransitionModel.build(TOY_SPACE, actions, TOY_SPEC, [0.9, 0.9, 0.5], np.full(8, 0.5))
    q_old = np.where(model.applicable, np.random.default_rng(0).normal(0, 3, (8, 3)),
                     NOT_APPLICABLE)
    q_old[0, 0] = -0.0
    new_space, _ = TOY_SPACE.resized(C, 4, split_value_map(2, 0))
    new_actions = build_actions(new_space, TOY_SPEC)
    maps = compose_split_maps([(C, 0)], {C: 4, X: 2, Y: 2})
    out = grow_q(q_old, TOY_SPACE, actions, new_space, new_actions, maps,
                 np.zeros((new_space.n_states, len(new_actions))))
    assert out is not None
    state_map = new_space.all_values()[:, 0]
    rows = maps[C][state_map] * 4 + new_space.all_values()[:, 1] * 2 + new_space.all_values()[:, 2]
    cols = action_map(actions, new_actions, maps)
    for s_new in range(new_space.n_states):
        for j, j_old in enumerate(cols):
            x = q_old[rows[s_new], j_old] if j_old >= 0 else np.nan
            want = (0.0 + x) / 1.0 if np.isfinite(x) else 0.0
            assert np.array([out[s_new, j]]).tobytes() == np.array([want]).tobytes()
    assert np.signbit(q_old[0, 0]) and not np.signbit(out[0, 0])


@pytest.mark.parametrize("direction", [+1, -1])
def test_with_reliabilities_and_its_cached_pairs_match_a_fresh_build(direction: int) -> None:
    # The cached columns of p1 and the applicable pairs carried from the previous model give
    # the very arrays a fresh build gives (wrong-side zeros included), and the same Dyna sweep.
    spec = PlanSpec(goal=Event(Y, 1), antecedent=Event(X, 1, direction),
                    magnitude_vars=frozenset({X}))
    space = PlanStateSpace((C, X, Y), (2, 3, 2))
    actions = build_actions(space, spec)
    rng = np.random.default_rng(5)
    old = TransitionModel.build(space, actions, spec, rng.uniform(0.1, 1.0, len(actions)),
                                rng.uniform(0.0, 1.0, space.n_states))
    q = np.where(old.applicable, rng.normal(0.0, 3.0, old.applicable.shape), NOT_APPLICABLE)
    dyna_sweep(q.copy(), old, P)                            # caches the applicable pairs
    for _ in range(3):
        rel_a, rel_r = rng.uniform(0.1, 1.0, len(actions)), rng.uniform(0.0, 1.0, space.n_states)
        new = old.with_reliabilities(rel_a, rel_r)
        fresh = TransitionModel.build(space, actions, spec, rel_a, rel_r)
        assert new.p1.tobytes() == fresh.p1.tobytes()
        for a, b in zip(mdp._applicable_pairs(new, P), mdp._applicable_pairs(fresh, P),
                        strict=True):
            assert a.tobytes() == b.tobytes()
        assert dyna_sweep(q.copy(), new, P).tobytes() == dyna_sweep(q.copy(), fresh, P).tobytes()
        old = new


def test_cells_are_the_mixed_radix_cells_of_the_state_values() -> None:
    space = PlanStateSpace((4, 0, 2), (3, 2, 5))
    vals = space.all_values()
    got = space.cells((2, 4), (5, 3))
    np.testing.assert_array_equal(got, vals[:, 2] * 3 + vals[:, 0])
    assert space.cells((2, 4), (5, 3)) is got               # cached per arguments
    assert not got.flags.writeable
    np.testing.assert_array_equal(space.cells((), ()), np.zeros(space.n_states))


def _merged_reference(q_old, old, new, old_actions, new_actions, maps):
    """grow_q's merge of dropped variables, one combination of their values at a time."""
    vals = new.all_values()
    old_vals = np.zeros((new.n_states, len(old.vars)), dtype=np.int64)
    dropped = []
    for i, v in enumerate(old.vars):
        if v in new:
            col = vals[:, new.position(v)]
            old_vals[:, i] = maps[v][col] if v in maps else col
        else:
            dropped.append(i)
    cols = action_map(old_actions, new_actions, maps)
    known = np.flatnonzero(cols >= 0)
    acc = np.zeros((new.n_states, known.size))
    cnt = np.zeros((new.n_states, known.size))
    for combo in np.ndindex(*(old.sizes[i] for i in dropped)):
        for i, q in zip(dropped, combo, strict=True):
            old_vals[:, i] = q
        idx = np.ravel_multi_index(tuple(old_vals.T), old.sizes)
        block = q_old[np.ix_(idx, cols[known])]
        finite = np.isfinite(block)
        acc += np.where(finite, block, 0.0)
        cnt += finite
    return acc, cnt, known


def test_grow_q_merging_dropped_variables_matches_one_combination_at_a_time() -> None:
    # Two of four variables dropped (one of them between kept ones), one kept variable split,
    # one added; random values with −inf, −0.0 and mixed magnitudes: bit-identical sums.
    rng = np.random.default_rng(7)
    old = PlanStateSpace((3, 1, 4, 2), (3, 2, 3, 2))
    new = PlanStateSpace((4, 2, 6), (5, 2, 2))
    maps = {4: np.array([0, 1, 1, 1, 2])}
    old_actions = [MDPAction(3, 0), MDPAction(4, 2), MDPAction(1, 1), MDPAction(2, 1)]
    new_actions = [MDPAction(6, 0), MDPAction(4, 3), MDPAction(2, 1), MDPAction(4, 0)]
    for _ in range(20):
        q_old = rng.normal(0, 10, (old.n_states, len(old_actions))) * \
            10.0 ** rng.integers(-8, 8, (old.n_states, len(old_actions)))
        q_old[rng.random(q_old.shape) < 0.3] = NOT_APPLICABLE
        q_old[rng.random(q_old.shape) < 0.1] = -0.0
        acc, cnt, known = _merged_reference(q_old, old, new, old_actions, new_actions, maps)
        base = np.full((new.n_states, len(new_actions)), 7.0)
        out = grow_q(q_old, old, old_actions, new, new_actions, maps, base)
        assert out is not None
        want = base.copy()
        sub = want[:, known]
        ok = cnt > 0
        sub[ok] = acc[ok] / cnt[ok]
        want[:, known] = sub
        assert out.tobytes() == want.tobytes()


def _greedy_action_numpy(q, s, rng, epsilon):
    """greedy_action as first written, with numpy (the reference)."""
    row = np.asarray(q[s], dtype=float)
    ok = np.flatnonzero(np.isfinite(row))
    if ok.size == 0:
        return None
    if rng.random() < epsilon:
        return int(ok[rng.integers(ok.size)])
    best = ok[row[ok] == row[ok].max()]
    return int(best[0] if best.size == 1 else best[rng.integers(best.size)])


def test_greedy_action_chooses_and_draws_as_the_numpy_version() -> None:
    # Ties, −inf (not applicable), rows with nothing applicable, ε from 0 to 1: the same
    # choices and the same draws (the generators end in the same state).
    data = np.random.default_rng(2)
    q = data.integers(-2, 3, size=(300, 6)).astype(float)
    q[data.random(q.shape) < 0.3] = NOT_APPLICABLE
    q[:5] = NOT_APPLICABLE
    for eps in (0.0, 0.05, 0.5, 1.0):
        a, b = np.random.default_rng(9), np.random.default_rng(9)
        for s in range(q.shape[0]):
            assert greedy_action(q, s, a, eps) == _greedy_action_numpy(q, s, b, eps)
        assert a.random() == b.random()


def test_an_mdp_action_and_an_event_are_their_own_copies():
    """Both immutable: a copy of a plan or a learner keeps them (docs/decisions.md 101)."""
    a, e = MDPAction(3, 1, Role.ANTECEDENT), Event(2, 4, 1)
    assert copy.copy(a) is a and copy.deepcopy(a) is a and copy.deepcopy([a, a])[1] is a
    assert copy.copy(e) is e and copy.deepcopy({e: [e]}) == {e: [e]}
    with pytest.raises(AttributeError):
        a.var = 4                               # frozen
