"""The model learner end to end on the toy world of the issue, plus save/load."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from qlap_runtime.qlap import ModelLearner, Params
from qlap_runtime.qlap.checkpoint import CheckpointError, load_learner, save_learner
from qlap_runtime.qlap.variables import Kind
from tests.qlap.toyworld import SPECS, babble_stream


def learn(steps: int, seed: int = 0, params: Params | None = None) -> ModelLearner:
    learner = ModelLearner(SPECS, params or Params())
    for t, obs in babble_stream(steps, seed):
        learner.observe(t, obs)
    return learner


@pytest.fixture(scope="module")
def learned() -> ModelLearner:
    return learn(20_000)


def test_landmark_on_the_motor_threshold_and_its_mirror(learned: ModelLearner):
    u = learned.perception.spaces[learned.table.index("u")].landmarks
    pos = [m for m in u if m.lb > 0.05]
    neg = [m for m in u if m.ub < -0.05]
    assert len(pos) == 1 and 0.25 <= pos[0].lb <= pos[0].ub <= 0.35, u
    assert len(neg) == 1 and -0.35 <= neg[0].lb <= neg[0].ub <= -0.25, u


def test_landmarks_near_both_bounds_of_x(learned: ModelLearner):
    x = learned.perception.spaces[learned.table.index("x")].landmarks
    assert any(m.lb <= 1.0 and m.ub >= -0.1 and m.lb < 1.0 for m in x), x
    assert any(m.ub >= 9.0 and m.lb <= 10.1 for m in x), x


def test_reliable_dbn_from_the_motor_threshold_to_x_moving_up(learned: ModelLearner):
    u, x = learned.table.index("u"), learned.table.index("x")
    up = [d for d in learned.find_dbns("u", "x.dot")
          if d.consequent.value == 2 and d.antecedent.value % 2 == 0
          and learned.perception.spaces[u].bounds(d.antecedent.value)[0] > 0.25]
    assert len(up) == 1
    dbn = up[0]
    lo, hi = learned.perception.spaces[u].bounds(dbn.antecedent.value)
    assert 0.25 < lo < 0.36 and hi == np.inf
    assert dbn.context == (x,)
    assert dbn.ever_reliable and learned.stats(dbn).reliable
    assert learned.dbn_label(dbn).startswith("⟨{x}: u→(0.3")


def test_k_is_learned_from_motor_to_change_transitions(learned: ModelLearner):
    assert learned.k_learned and 2 <= learned.k <= 15


def test_magnitude_dbns_exist_for_every_reachable_value(learned: ModelLearner):
    x = learned.table.index("x")
    size = learned.perception.spaces[x].size
    mags = learned.find_dbns(kind="magnitude")
    keys = {(d.consequent.value, d.consequent.direction) for d in mags}
    expected = {(v, 1) for v in range(1, size)} | {(v, -1) for v in range(size - 1)}
    assert keys == expected


def test_deterministic_for_a_seed():
    a, b = learn(6000, seed=3), learn(6000, seed=3)
    assert json.dumps(a.knowledge()) == json.dumps(b.knowledge())


@pytest.mark.parametrize("lag", [0, 500])
def test_save_load_mid_run_continues_identically(tmp_path, lag):
    params = Params(batch_lag=lag)
    stream = list(babble_stream(14_000, 1))
    straight = ModelLearner(SPECS, params)
    for t, obs in stream:
        straight.observe(t, obs)
    first = ModelLearner(SPECS, params)
    for t, obs in stream[:8300]:
        first.observe(t, obs)
    save_learner(first, tmp_path / "ckpt")
    resumed = load_learner(tmp_path / "ckpt")
    for t, obs in stream[8300:]:
        resumed.observe(t, obs)
    assert json.dumps(resumed.knowledge()) == json.dumps(straight.knowledge())
    for i, d in straight.dbns.items():
        np.testing.assert_array_equal(resumed.dbns[i].cpt_s, d.cpt_s)
    np.testing.assert_array_equal(resumed.pairs.soon_given, straight.pairs.soon_given)


def test_corrupt_checkpoints_give_clear_errors(tmp_path):
    learner = learn(500)
    save_learner(learner, tmp_path)
    (tmp_path / "learner.npz").write_bytes(b"not a zip")
    with pytest.raises(CheckpointError, match="corrupt array file"):
        load_learner(tmp_path)
    (tmp_path / "learner.json").write_text("{")
    with pytest.raises(CheckpointError, match="corrupt JSON"):
        load_learner(tmp_path)
    (tmp_path / "learner.json").write_text(json.dumps({"format": "qlap-learner", "version": 99}))
    with pytest.raises(CheckpointError, match="version 99"):
        load_learner(tmp_path)
    with pytest.raises(CheckpointError, match="no such checkpoint"):
        load_learner(tmp_path / "missing")


def test_lag_delays_batches_but_keeps_learning():
    learner = learn(9000, params=Params(batch_lag=700))
    assert [a["applied_at"] - a["computed_at"] for a in learner.applied] == [700] * 4
    assert any(learner.table[d.antecedent.var].kind is Kind.MOTOR for d in learner.dbns.values())


def test_observe_rejects_bad_input_and_keeps_going():
    learner = ModelLearner(SPECS, Params())
    learner.observe(0, {"u": 0.0, "x": 1.0})
    with pytest.raises(ValueError, match="'x'"):
        learner.observe(1, {"u": 0.0, "x": float("nan")})
    learner.observe(1, {"u": 0.5, "x": 1.0})
    assert learner.step == 1


def test_all_candidates_at_once_choose_as_one_at_a_time(learned: ModelLearner):
    """Algorithm 3's vectorised round picks the option and statistics of the default."""
    import copy

    from qlap_runtime.qlap.context import StoredActivations

    rng = np.random.default_rng(0)
    learner = copy.deepcopy(learned)
    for dbn in learner.dbns.values():
        if dbn.act_n < 1:
            continue
        dbn.act_ok[: dbn.act_n] = rng.random(dbn.act_n) < 0.5
        X, ok = dbn.stored()
        acts = StoredActivations.quantized(X, ok, learner.perception.quantize_columns,
                                           range(len(learner.table)),
                                           learner.perception.events.sizes, learner.params)
        ev = learner.evaluator(dbn)
        cands = list(range(len(learner.table)))
        for ctx in [(), *((v,) for v in cands)]:
            options = [v for v in cands if v not in ctx]
            scored = [(v, ev(tuple(sorted((*ctx, v))))) for v in options]
            for by_entropy in (False, True):
                if by_entropy:
                    want = min(scored, key=lambda p: (p[1].entropy, p[0]))
                else:
                    want = max(scored, key=lambda p: (-1.0 if p[1].brel is None else p[1].brel,
                                                      -p[0]))
                assert acts.choose(ctx, options, by_entropy) == want
            assert acts.evaluate(ctx) == ev(ctx)


def test_algorithm_4_puts_no_motor_in_a_context():
    """App. D.1: context variables are magnitude or nominal; D.2: a motor may get a landmark
    from a DBN only as its antecedent. A second motor w gates whether y follows x (y rises
    when x rises and w > 0.5): before this rule Algorithm 4 put w into the context of
    ⟨ẋ→[+] ⇒ ẏ→[+]⟩ with landmarks at w ≈ 0.51 and 0.63 (docs/decisions.md 38)."""
    from qlap_runtime.qlap import VariableTable
    from qlap_runtime.qlap.babble import Babbler
    from tests.qlap.toyworld import Spec

    specs = (Spec("u", "motor", -1.0, 1.0), Spec("w", "motor", -1.0, 1.0),
             Spec("x", "magnitude"), Spec("y", "magnitude"))
    babbler = Babbler(VariableTable.from_specs(specs), Params(), np.random.default_rng(0))
    learner = ModelLearner(specs, Params())
    motors = {learner.table.index("u"), learner.table.index("w")}
    x = y = 5.0
    for t in range(30_000):
        m, _ = babbler.step()
        learner.observe(t, {"u": m["u"], "w": m["w"], "x": x, "y": y})
        if t % 2000 == 1:                                   # after each batch
            assert not [d for d in learner.dbns.values() if motors & set(d.context)]
        if abs(m["u"]) > 0.3:
            nx = float(np.clip(x + 0.5 * m["u"], 0.0, 10.0))
            if nx > x and m["w"] > 0.5:
                y = y + 0.5 if y < 9.5 else 0.0
            x = nx
    w = learner.perception.spaces[learner.table.index("w")].landmarks
    assert [m.source for m in w] == ["initial"], w
    u = learner.perception.spaces[learner.table.index("u")].landmarks
    assert any(0.25 < m.lb <= m.ub < 0.35 for m in u), u    # the threshold, via ⟨u→q ⇒ ẋ⟩



def test_cell_of_from_the_step_values_is_the_cell_of_the_real_values(learned: ModelLearner):
    """_cell_of reads an activation's context values from the qualitative values perceived
    at its step (kept while the landmarks are the same): the cell value_of gives from the
    real values, for every stored row of every DBN under every context of 0–2 variables."""
    import copy
    from itertools import pairwise

    learner = copy.deepcopy(learned)
    cands = [v.index for v in learner.table if v.kind.name in ("MAGNITUDE", "NOMINAL")]
    X = learner.perception.history()[0][-300:]
    checked = 0
    for t, x in enumerate(X, start=10**6):
        x = np.array(x)
        p = learner.perception.perceive(t, x, copy=False, remember=False)
        learner._own = p
        learner._remember_q(p)
        for dbn in list(learner.dbns.values())[:5]:
            for ctx in [(), *((v,) for v in cands), *pairwise(cands)]:
                dbn.context = ctx
                got = learner._cell_of(dbn, p.x)
                learner._x_q.clear()
                want = learner._cell_of(dbn, p.x)
                learner._remember_q(p)
                assert got == want
                checked += got >= 0
    assert checked > 100


def test_a_deep_copy_of_a_learner_goes_on_like_the_learner():
    """DBN and Event copies take a shortcut (docs/decisions.md 101): the copy shares no DBN
    or array with the learner, keeps its own internal sharing, and — fed the same stream as
    the learner it came from — learns exactly what that learner learns."""
    params = Params(batch_lag=500)
    stream = list(babble_stream(14_000, 1))
    straight = ModelLearner(SPECS, params)
    for t, obs in stream[:9000]:
        straight.observe(t, obs)
    work = copy.deepcopy(straight)      # what batch_copy does, its pending deltas kept
    assert work.dbns and set(work.dbns) == set(straight.dbns)
    for i, d in straight.dbns.items():
        c = work.dbns[i]
        assert c is not d and type(c) is type(d)
        assert set(vars(c)) == set(vars(d))
        for k, v in vars(d).items():
            if isinstance(v, np.ndarray):
                assert vars(c)[k] is not v
                np.testing.assert_array_equal(vars(c)[k], v)
        assert c.antecedent == d.antecedent and c.context == d.context
    for dbns in work._by_antecedent.values():
        assert all(work.dbns[d.id] is d for d in dbns)
    for _, dbn, _entry in work._expiry:
        assert work.dbns.get(dbn.id) is dbn
    for t, obs in stream[9000:]:
        straight.observe(t, obs)
        work.observe(t, obs)
    assert json.dumps(work.knowledge()) == json.dumps(straight.knowledge())
    for i, d in straight.dbns.items():
        np.testing.assert_array_equal(work.dbns[i].cpt_s, d.cpt_s)
        np.testing.assert_array_equal(work.dbns[i].act_x, d.act_x)


def test_a_landmark_inside_the_quantity_space_keeps_two_magnitude_dbns_per_value():
    # §4.5: two magnitude DBNs for each qualitative value (none from below for the lowest
    # value, none from above for the highest). Landmarks added below, above and between
    # existing ones: x's space grows 1 → 3 → 5 → 7 → 9 → 11 values, and after each landmark
    # every reachable (value, side) has its DBN. Before the fix the pairs' set still held
    # the old numbering while the new values' DBNs were added, and a landmark at 2.0 below 5.0
    # left values 1 and 2 without DBNs: (1, −1), (1, +1), (2, +1).
    from qlap_runtime.qlap.delta import AddLandmark, Delta, delta_version

    learner = ModelLearner(SPECS, Params())
    x = learner.table.index("x")
    for n, lb in enumerate((5.0, 2.0, 8.0, 3.5, 1.0), start=1):
        learner.apply_delta(Delta(delta_version(n, "landmarks"), n, n,
                                  (AddLandmark(x, lb, lb + 0.1, "event", n),)))
        size = learner.perception.spaces[x].size
        assert size == 1 + 2 * n
        keys = sorted((d.consequent.value, d.consequent.direction)
                      for d in learner.find_dbns(kind="magnitude") if d.consequent.var == x)
        assert keys == sorted({(v, 1) for v in range(1, size)}
                              | {(v, -1) for v in range(size - 1)})


def test_magnitude_dbns_learn_from_the_motion_observed():
    # Decisions 11 and 126 (§4.5): r± of (x, q) is activated when ẋ → [±] is observed with x on
    # the near side of q, succeeds when x reaches q, fails when ẋ leaves [±] first. x's
    # landmarks at [3, 3.1] and [6, 6.1] give values 0 (−∞, 3), 1, 2 (3.1, 6), 3, 4 (6.1, +∞).
    # x rises from 1.0 (value 0) to 3.5 (value 2) and stops, then falls from 3.5 to 2.5.
    from qlap_runtime.qlap.delta import AddLandmark, Delta, delta_version

    learner = ModelLearner(SPECS, Params())
    x = learner.table.index("x")
    for n, lb in enumerate((3.0, 6.0), start=1):
        learner.apply_delta(Delta(delta_version(n, "landmarks"), n, n,
                                  (AddLandmark(x, lb, lb + 0.1, "event", n),)))
    path = (1.0, 1.0, 1.0, 1.5, 2.0, 2.5, 3.05, 3.5, 3.5, 3.5, 3.5, 3.0, 2.5, 2.5)
    for t, value in enumerate(path):
        learner.observe(t, {"u": 0.0, "x": value})
    outcome = {(d.consequent.value, d.consequent.direction): (int(d.cpt_s.sum()),
                                                             int(d.cpt_f.sum()))
               for d in learner.find_dbns(kind="magnitude") if d.consequent.var == x}
    # The onset ẋ → [+] at step 3 (x in value 0) activates r⁺ of every value above: 1 and 2
    # are reached (successes), 3 and 4 are not before ẋ → [0] at step 8 (failures). The onset
    # ẋ → [−] at step 11 finds x at 3.0, in value 1: only r⁻ of value 0 starts, and succeeds.
    assert outcome == {(1, 1): (1, 0), (2, 1): (1, 0), (3, 1): (0, 1), (4, 1): (0, 1),
                       (0, -1): (1, 0), (1, -1): (0, 0), (2, -1): (0, 0), (3, -1): (0, 0)}
