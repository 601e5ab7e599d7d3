"""The baselines' pieces: App. H's inputs and actions, Tile-10's decisions, the Q-learner's
qualitative states (§7.7), checkpoints without pickle, evaluation with the §7.2 protocol."""

import json

import numpy as np
import pytest

import worlds
from qlap_runtime.experiments.baselines import common, qtable, tile_agent
from qlap_runtime.experiments.spec import QTableConfig, TileConfig
from worlds.evaluate import run_trials


@pytest.fixture(scope="module")
def core2d():
    w = worlds.make("core2d")
    yield w
    w.close()


def test_app_h_actions_and_inputs(core2d):
    actions = common.bin_actions(core2d, ("u_x", "u_y"), 10)
    assert len(actions) == 20
    assert [a["u_x"] for a in actions[:10]] == pytest.approx(
        [-900, -700, -500, -300, -100, 100, 300, 500, 700, 900])
    assert actions[10] == {"u_y": -900.0}
    ranges = {n: (0.0, 10.0) for n in common.magnitudes(core2d)}
    agent = tile_agent.TileAgent(core2d, TileConfig(), ranges, np.random.default_rng(0))
    obs = core2d.reset(seed=1)
    obs = core2d.step({"u_x": 1000.0})
    goal = worlds.Goal("T_L.dot", "+")
    floats, ints = agent.inputs(core2d, obs, goal)
    h_x = agent.names.index("h_x")
    # normalised by the range and divided by the generalization 0.25: tile width 0.25
    assert floats[h_x] == pytest.approx(np.clip(obs["h_x"] / 10, 0, 1) / 0.25)
    assert floats.max() <= 4.0 and floats.min() >= 0.0
    n = len(agent.names)
    assert ints[h_x] == 2                                  # ḣ_x > 0.05 per second: bin (+)
    assert set(ints[:n]) <= {0, 1, 2} and ints[-1] == common.goal_code(goal)
    assert agent.encode(core2d, obs, goal).shape == (20, 16)


def test_change_bins_are_per_second(core2d):
    core2d.reset(seed=0)
    assert common.change_bin(core2d, "h_x", 0.05) == 1      # a reset is a discontinuity
    obs = core2d.step({})
    d = (obs["h_x"] - core2d.previous_observation["h_x"]) / core2d.step_seconds
    assert common.change_bin(core2d, "h_x", 0.05) == (0 if d < -0.05 else 2 if d > 0.05
                                                        else 1)


class Recorder:
    """An agent that records the rewards it gets and always takes action 0."""

    def __init__(self):
        self.actions = [{"u_x": 900.0}]
        self.rewards, self.ends = [], []

    def encode(self, world, obs, goal):
        return None

    def start(self, state):
        return 0

    def step(self, reward, state):
        self.rewards.append(reward)
        return 0

    def end(self, reward):
        self.ends.append(reward)

    def act(self, state, rng):
        return 0


def test_tile_10_decisions_cost_a_tenth(core2d):
    rec = Recorder()
    saved = []
    out = common.practice(core2d, ("move_block",), 95, 0, rec, 10, -0.1, saved.append)
    assert out["steps"] == 95 and saved == list(range(1, 96))
    assert set(rec.rewards) <= {-0.1}
    assert all(r in (-0.1, 9.99) for r in rec.ends)
    rec1 = Recorder()
    common.practice(core2d, ("move_block",), 30, 0, rec1, 1, None, lambda t: None)
    assert set(rec1.rewards) <= {-0.01}


def test_tile_checkpoints_round_trip(core2d, tmp_path):
    ranges = common.babble_ranges(core2d, 300)
    cfg = TileConfig(decision_every=10, decision_cost=-0.1)
    summary = tile_agent.train(core2d, "core2d", ("move_block",), 1500, 1, cfg, ranges,
                               tmp_path, 1000)
    assert summary["steps"] == 1500
    names = sorted(p.name for p in (tmp_path / "checkpoints").iterdir())
    assert names == ["final", "step-0001000"]
    meta = json.loads((tmp_path / "checkpoints" / "final" / "meta.json").read_text())
    assert meta["step"] == 1500 and meta["config"]["decision_every"] == 10
    theta = np.load(tmp_path / "checkpoints" / "final" / "theta.npy", allow_pickle=False)
    assert theta.shape == (65_536,) and np.any(theta != 0)
    policy = tile_agent.load_policy(tmp_path / "checkpoints" / "final", core2d)
    assert np.array_equal(policy.agent.learner.theta, theta)
    res = run_trials(core2d, "move_block", 2, 0, policy)
    assert res["n_trials"] == 2


def test_qualitative_states_and_actions(core2d):
    lms = [(-1.0, -1.0), (2.0, 3.0)]
    assert [qtable.qualitative_index(x, lms) for x in (-5, -1, 0, 2.5, 3, 4)] == \
        [0, 1, 2, 3, 3, 4]
    acts = qtable.landmark_actions(core2d, {"u_x": [(0.0, 0.0), (300.0, 320.0)],
                                            "u_y": [(0.0, 0.0)]})
    assert acts == [{"u_x": -500.0}, {"u_x": 0.0}, {"u_x": 150.0}, {"u_x": 310.0},
                    {"u_x": 660.0}, {"u_y": -500.0}, {"u_y": 500.0}]   # one rest action


def test_random_landmarks_of_7_7(core2d):
    ranges = {n: (0.0, 1.0) for n in common.magnitudes(core2d)}
    counts = []
    for seed in range(30):
        lms = qtable.random_landmarks(core2d, ranges, np.random.default_rng(seed))
        assert set(lms) == {"u_x", "u_y", *ranges}
        for name in ("u_x", "u_y"):
            assert (0.0, 0.0) in lms[name] and 1 <= len(lms[name]) <= 6
        for name in ranges:
            assert all(0.0 <= lb == ub <= 1.0 for lb, ub in lms[name])
            counts.append(len(lms[name]))
    assert set(counts) == {0, 1, 2, 3, 4, 5}


def test_qtable_checkpoints_round_trip(core2d, tmp_path):
    ranges = common.babble_ranges(core2d, 300)
    lms = qtable.random_landmarks(core2d, ranges, np.random.default_rng(4))
    summary = qtable.train(core2d, "core2d", ("move_block",), 1000, 2, QTableConfig("random"),
                           lms, tmp_path, 1000)
    assert summary["states"] > 1
    policy = qtable.load_policy(tmp_path / "checkpoints" / "step-0001000", core2d)
    assert len(policy.agent.q) == summary["states"]
    assert run_trials(core2d, "move_block", 2, 0, policy)["n_trials"] == 2


def test_ranges_are_cached(tmp_path):
    a = common.cached_ranges("core2d", 200, tmp_path)
    (path,) = tmp_path.iterdir()
    assert json.loads(path.read_text())["steps"] == 200
    assert common.cached_ranges("core2d", 200, tmp_path) == a
