"""Linear, gradient-descent Sarsa(λ) with binary features (Sutton & Barto 1998, Fig. 8.8).

The learner of Appendix H of J. Mugan, *Autonomous Qualitative Learning of Distinctions and
Actions in a Developing Agent*, PhD dissertation, UT Austin, 2010: Q(s, a) = Σ_{i∈F(s,a)} θ_i
over the tiles F(s, a) of the hashed tile coder, ε-greedy, replacing traces. One episode:

* :meth:`SarsaLambda.start` — e ← 0; choose a in s ε-greedily;
* :meth:`SarsaLambda.step` with the reward r and the next state's tiles — e_i ← 1 for
  i ∈ F(s, a) (replacing traces); δ ← r − Q(s, a); choose a' in s' ε-greedily;
  δ ← δ + γ Q(s', a'); θ ← θ + (α/m) δ e; e ← γλ e;
* :meth:`SarsaLambda.end` with the last reward (a terminal state has value 0):
  e_i ← 1 for i ∈ F(s, a); θ ← θ + (α/m) δ e with δ = r − Q(s, a).

The step size α is shared by the m active tiles of a (state, action) (α/m per weight, the
usual convention with tile coding: one update moves Q(s, a) by about α·δ). Ties of the greedy
choice are broken at random, so an untrained learner does not always pick action 0.
"""

from __future__ import annotations

import numpy as np

__all__ = ["SarsaLambda", "epsilon_greedy"]


def epsilon_greedy(q: np.ndarray, epsilon: float, rng: np.random.Generator) -> int:
    """A random action with probability ε, else a greedy one (ties broken at random)."""
    if rng.random() < epsilon:
        return int(rng.integers(len(q)))
    best = np.flatnonzero(q == q.max())
    return int(best[0] if len(best) == 1 else best[rng.integers(len(best))])


class SarsaLambda:
    """Sarsa(λ) over hashed binary features; ``features`` arrays are (actions, tilings)."""

    def __init__(self, memory: int, alpha: float, lam: float, gamma: float, epsilon: float,
                 rng: np.random.Generator, tilings: int,
                 theta: np.ndarray | None = None) -> None:
        self.alpha, self.lam, self.gamma, self.epsilon = alpha, lam, gamma, epsilon
        self.rng = rng
        self.step_size = alpha / tilings
        self.theta = np.zeros(memory) if theta is None else np.asarray(theta, dtype=float)
        if self.theta.shape != (memory,):
            raise ValueError(f"theta must have {memory} weights, got {self.theta.shape}")
        self.e = np.zeros(memory)
        self._tiles: np.ndarray | None = None      # F(s, a) of the action being taken

    def values(self, features: np.ndarray) -> np.ndarray:
        """Q(s, a) of every action: the sum of its tiles' weights."""
        return self.theta[features].sum(axis=1)

    def choose(self, features: np.ndarray, epsilon: float | None = None) -> int:
        """An ε-greedy action for the state with these features (no learning)."""
        return epsilon_greedy(self.values(features), self.epsilon if epsilon is None
                              else epsilon, self.rng)

    def _take(self, features: np.ndarray) -> int:
        a = epsilon_greedy(self.values(features), self.epsilon, self.rng)
        self._tiles = features[a]
        return a

    def start(self, features: np.ndarray) -> int:
        """A new episode in the state with these features: the first action."""
        self.e[:] = 0.0
        return self._take(features)

    def step(self, reward: float, features: np.ndarray) -> int:
        """The reward of the action taken and the next state's features: update, and return
        the next action."""
        if self._tiles is None:
            raise RuntimeError("SarsaLambda.step before start")
        self.e[self._tiles] = 1.0
        delta = reward - float(self.theta[self._tiles].sum())
        a = self._take(features)
        delta += self.gamma * float(self.theta[self._tiles].sum())
        self.theta += self.step_size * delta * self.e
        self.e *= self.gamma * self.lam
        return a

    def end(self, reward: float) -> None:
        """The reward of the last action; the episode ends (terminal value 0)."""
        if self._tiles is None:
            raise RuntimeError("SarsaLambda.end before start")
        self.e[self._tiles] = 1.0
        delta = reward - float(self.theta[self._tiles].sum())
        self.theta += self.step_size * delta * self.e
        self._tiles = None
