"""The compiled loops (kernels.py) give bit for bit the numbers of the numpy code they replace:
value iteration, Dyna and Sarsa(λ) on random plans, and small cases by hand."""

from __future__ import annotations

import numpy as np
import pytest

from qlap_runtime.qlap import mdp
from qlap_runtime.qlap.kernels import kernels
from qlap_runtime.qlap.mdp import (
    NOT_APPLICABLE,
    PlanSpec,
    PlanStateSpace,
    SarsaLambda,
    TransitionModel,
    build_actions,
    dyna_sweep,
    value_iteration,
)
from qlap_runtime.qlap.params import Params
from qlap_runtime.qlap.variables import Event

pytestmark = pytest.mark.skipif(kernels() is None, reason="numba is not installed")
P = Params()
C, X, Y, W = 0, 1, 2, 3


def _random_model(rng: np.random.Generator) -> TransitionModel:
    sizes = {W: int(rng.integers(1, 5)), C: int(rng.integers(1, 6)), X: 3, Y: 3}
    spec = PlanSpec(goal=Event(Y, int(rng.integers(0, 3))), antecedent=Event(X, 1))
    space = PlanStateSpace.from_groups([[W], [C], [X], [Y]], sizes)
    actions = build_actions(space, spec)
    rel_a = rng.uniform(0.0, 1.0, len(actions)).round(int(rng.integers(1, 4)))
    rel_r = rng.uniform(0.0, 1.0, space.n_states).round(int(rng.integers(1, 4)))
    regress = rng.random((space.n_states, len(actions))) < 0.1
    return TransitionModel.build(space, actions, spec, rel_a, rel_r, regress)


def _numpy(monkeypatch: pytest.MonkeyPatch, fn, *args):
    """``fn(*args)`` with the numpy code (no kernels)."""
    with monkeypatch.context() as m:
        m.setattr(mdp, "kernels", lambda: None)
        return fn(*args)


@pytest.mark.parametrize("seed", range(20))
def test_value_iteration_compiled_is_the_numpy_one(seed: int,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(seed)
    model = _random_model(rng)
    for params in (P, P.replace(value_iteration_max_sweeps=2), P.replace(gamma=0.99)):
        got = value_iteration(model, params)
        want = _numpy(monkeypatch, value_iteration, model, params)
        assert got.tobytes() == want.tobytes()


def test_value_iteration_compiled_by_hand() -> None:
    # One state, one action that reaches the goal with p1 = 0.5: E[R] = 0.5·8 + 0.5·(−2) = 3,
    # its next states are terminal (V = 0) and itself; sweeps: 3, 3 + 0.9·0.5·3 = 4.35, …
    k = kernels()
    assert k is not None
    q = k.vi_sweeps(np.zeros(1), np.array([3.0]), np.array([0.5]), np.array([0.5]),
                    np.array([1]), np.array([0]), np.array([0]), np.array([0]), 2, 0.9,
                    1e-6, 2)
    assert q.tolist() == [3.0 + 0.9 * 0.5 * 3.0]


@pytest.mark.parametrize("seed", range(20))
def test_dyna_and_sarsa_compiled_are_the_numpy_ones(seed: int,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(100 + seed)
    model = _random_model(rng)
    q0 = np.where(model.applicable, rng.normal(0.0, 3.0, model.applicable.shape),
                  NOT_APPLICABLE)
    got, want = q0.copy(), q0.copy()
    for _ in range(3):
        dyna_sweep(got, model, P)
        _numpy(monkeypatch, dyna_sweep, want, model, P)
        assert got.tobytes() == want.tobytes()
    pairs = np.argwhere(model.applicable)
    if not len(pairs):
        return
    sg, sw = SarsaLambda(got, P), SarsaLambda(want, P)
    for _ in range(12):
        s, a = pairs[int(rng.integers(len(pairs)))].tolist()
        s2, a2 = pairs[int(rng.integers(len(pairs)))].tolist()
        nxt = None if rng.random() < 0.3 else a2
        r = float(rng.normal())
        d1 = sg.update(s, a, r, s2, nxt)
        d2 = _numpy(monkeypatch, sw.update, s, a, r, s2, nxt)
        assert d1 == d2
        assert got.tobytes() == want.tobytes() and sg.e.tobytes() == sw.e.tobytes()


def test_sarsa_compiled_by_hand() -> None:
    # Traces 0.5 and 0 on two pairs: e(0, 1) = 1, Q += 0.1·e where e > 0, then e·0.81.
    k = kernels()
    assert k is not None
    q = np.array([[1.0, 2.0, 3.0]])
    e = np.array([[0.5, 0.0, 0.0]])
    k.sarsa(q, e, 0, 1, 0.1, 0.81, False)
    assert q.tolist() == [[1.05, 2.1, 3.0]]
    assert e.tolist() == [[0.5 * 0.81, 0.81, 0.0]]
    k.sarsa(q, e, 0, 2, 1.0, 0.81, True)
    assert e.tolist() == [[0.0, 0.0, 0.0]]


@pytest.mark.parametrize("seed", range(20))
def test_bisimilar_compiled_is_the_numpy_one(seed: int) -> None:
    rng = np.random.default_rng(200 + seed)
    model = _random_model(rng)
    r1, r2 = model.rewards(P)
    er = model.p1 * r1 + (1.0 - model.p1) * r2
    args = (model.applicable, er, model.p1, model.next1, model.next2)
    got = mdp._bisimilar(*args)
    with pytest.MonkeyPatch.context() as m:
        m.setattr(mdp, "kernels", lambda: None)
        want = mdp._bisimilar(*args)
    assert got[0].tobytes() == want[0].tobytes() and got[1].tobytes() == want[1].tobytes()


def test_row_classes_compiled_by_hand() -> None:
    # Rows 0 and 2 equal, 1 and 4 equal: classes by first row 0, 1, 0, 2, 1.
    k = kernels()
    assert k is not None
    from qlap_runtime.qlap import kernels as kmod

    rows = np.array([[1, 2], [3, 4], [1, 2], [5, 6], [3, 4]], dtype=np.int64)
    cls, first = kmod._row_classes(rows)
    assert cls.tolist() == [0, 1, 0, 2, 1] and first.tolist() == [0, 1, 3]
    with np.errstate(over="ignore"):                       # the loop run by Python
        cls2, first2 = kmod.row_classes(rows)
    assert cls2.tolist() == [0, 1, 0, 2, 1] and first2.tolist() == [0, 1, 3]


@pytest.mark.parametrize("seed", range(10))
def test_sequence_bounds_compiled_is_the_numpy_one(seed: int,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    # Algorithm 4's gain bounds (§4.4.1): the compiled loop with the entropy table gives
    # numpy's bounds bit for bit (ties in the values, NaNs, Q not monotone, labels 0/1).
    from qlap_runtime.qlap import landmarks

    rng = np.random.default_rng(300 + seed)
    C, R = int(rng.integers(1, 40)), int(rng.integers(1, 260))
    X = np.round(rng.normal(size=(C, R)), int(rng.integers(0, 3)))
    X[rng.random(X.shape) < 0.05] = np.nan
    Y = (rng.random((C, R)) < rng.random()).astype(float)
    Q = np.where(np.isnan(X), -1, (X > -0.5).astype(np.int64) * 2 + (X > 0.5) * 2)
    if seed % 3 == 0:
        Q = rng.integers(-1, 6, size=(C, R))                  # any labels, runs split
    got = landmarks._sequence_bounds(X, Y, Q, 5)
    monkeypatch.setattr(landmarks, "kernels", lambda: None)
    want = landmarks._sequence_bounds(X, Y, Q, 5)
    assert got.tobytes() == want.tobytes()


def test_perceive_compiled_is_the_numpy_one(monkeypatch: pytest.MonkeyPatch) -> None:
    # Perception (§3.1–3.2) with the compiled quantization and events: the same percepts
    # (values, events, ids) on a stream with a nominal variable, landmarks and
    # discontinuities (no direction of change on the step after one).
    from qlap_runtime.qlap import perception as per
    from qlap_runtime.qlap.quantity import Landmark
    from qlap_runtime.qlap.variables import VariableTable
    from tests.qlap.toyworld import Spec

    table = VariableTable.from_specs([
        Spec("u", "motor", -1.0, 1.0), Spec("x", "magnitude"), Spec("y", "magnitude"),
        Spec("n", "nominal", values=("a", "b", "c"))])

    def run(compiled: bool) -> list:
        with monkeypatch.context() as m:
            if not compiled:
                m.setattr(per, "loaded_kernels", lambda: None)
            p = per.Perception(table, P)
            p.add_landmark(table.index("x"), Landmark(0.0, 0.5))
            p.add_landmark(table.index("x"), Landmark(2.0, 2.0))
            p.add_landmark(table.index("y"), Landmark(-1.0, 1.0))
            rng = np.random.default_rng(0)
            out = []
            for t in range(400):
                obs = {"u": float(rng.uniform(-1, 1)), "x": float(rng.normal(1, 1.5)),
                       "y": float(rng.normal(0, 2)),
                       "n": float(rng.integers(0, 3))}
                pc = p.perceive(t, p.vector(obs), discontinuity=t % 97 == 0)
                out.append((pc.x.tobytes(), pc.q.tobytes(), pc.q.dtype, pc.events,
                            pc.event_ids.tobytes(), pc.event_ids.dtype))
            return out

    assert run(True) == run(False)


def test_pair_statistics_compiled_are_the_numpy_ones(monkeypatch: pytest.MonkeyPatch) -> None:
    # The pairwise contingency counts (§4.1.2) with the compiled update: the same arrays
    # after a random event stream (bursts, quiet steps, consequents without antecedents).
    from qlap_runtime.qlap import contingency
    from qlap_runtime.qlap.perception import EventIndex
    from qlap_runtime.qlap.variables import VariableTable
    from tests.qlap.toyworld import Spec

    table = VariableTable.from_specs([
        Spec("u", "motor", -1.0, 1.0), Spec("x", "magnitude"),
        Spec("n", "nominal", values=("a", "b", "c"))])
    index = EventIndex(table, [5 if v.kind.name == "MAGNITUDE" else 3 for v in table])

    def run(compiled: bool) -> list:
        with monkeypatch.context() as m:
            if not compiled:
                m.setattr(contingency, "loaded_kernels", lambda: None)
            ps = contingency.PairStatistics(index, 4)
            rng = np.random.default_rng(1)
            for t in range(3, 600):
                n = int(rng.choice([0, 0, 1, 2, 3]))
                ids = np.sort(rng.choice(index.n_events, size=n, replace=False)).astype(np.int64)
                ps.update(t, ids)
            return [a.tobytes() for a in (ps.occurrences, ps.soon_given, ps.soon_steps,
                                          ps.last_cons, ps.win_t, ps.win_ids)] + [ps.steps]

    assert run(True) == run(False)


def test_warm_kernels_load_every_signature_a_run_calls() -> None:
    """decision 95: after :func:`warm_kernels` (in a fresh process, as an actor process
    calls it) a run of core through babbling, batches and plans calls no kernel with a
    signature it did not load."""
    import subprocess
    import sys
    from pathlib import Path

    code = """
import worlds
from qlap_runtime.agent_run import params_for_world, run_agent
from qlap_runtime.qlap import Params
from qlap_runtime.qlap.kernels import kernel_signatures, kernels, warm_kernels
n = warm_kernels()
warm = {name: set(d.signatures) for name, d in vars(kernels()).items()}
world = worlds.make("core")
run_agent(world, 8000, 0, params=params_for_world(world, Params(babble_steps=6000)))
used = {name: set(d.signatures) for name, d in vars(kernels()).items()}
assert n == sum(len(s) for s in kernel_signatures().values()), n
assert used == warm, {k: used[k] - warm[k] for k in used if used[k] != warm[k]}
print("ok", n)
"""
    root = Path(__file__).resolve().parents[2]
    out = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.startswith("ok 10")
