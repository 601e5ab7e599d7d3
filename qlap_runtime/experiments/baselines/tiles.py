"""Hashed tile coding: Sutton's ``tiles`` (tiles.C, the coder PLASTK wrapped), in numpy.

Appendix H of J. Mugan, *Autonomous Qualitative Learning of Distinctions and Actions in a
Developing Agent*, PhD dissertation, UT Austin, 2010 uses 16 tilings and "a memory size of
65,536": every tile of every tiling is hashed into one table of that many weights, whatever the
number of inputs — the design of Sutton's tile coder (R. S. Sutton, *Tile Coding Software*,
version 2, tiles.C; Sutton & Barto 1998, §8.3.2), which PLASTK (Provost, 2008) used. The
well-kept Python coders do not fit: PyFixedReps' ``TileCoder`` and mushroom-rl's ``Tiles``
enumerate every tile (tilings × tilesᵈ features, astronomically many for the 30-odd inputs of
the core world) and have no memory size; mushroom-rl also pulls in torch. So this is tiles.C's
algorithm, vectorised:

* the inputs are already scaled so that one unit is one tile width (App. H's inputs are
  normalised to [0, 1] and divided by the generalization 0.25);
* ``q_i = ⌊x_i · n⌋`` for n tilings; tiling j's coordinate of input i is
  ``q_i − ((q_i − j·(1 + 2i)) mod n)`` — tiling j is displaced by j·(1 + 2i)/n tile widths in
  dimension i (tiles.C's asymmetric offsets);
* the coordinates of tiling j are ``[c_0 … c_{d−1}, j, ints…]`` (integer inputs, e.g. a
  discrete variable or the action, are appended unchanged);
* ``hash_UNH``: the index is ``Σ_k R[(coord_k + 449·k) mod 2048] mod memory``, R a fixed table
  of 2,048 random 32-bit numbers (tiles.C fills it from ``rand()``; here from a seeded numpy
  generator, so the same seed gives the same tiles on every machine).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["HASH_INCREMENT", "RNDSEQ_SIZE", "TileCoder"]

Floats = Sequence[float] | np.ndarray

RNDSEQ_SIZE = 2048
"""Entries of hash_UNH's random table (tiles.C)."""
HASH_INCREMENT = 449
"""hash_UNH's increment per coordinate position (tiles.C)."""


class TileCoder:
    """``tilings`` hashed tilings into ``memory`` weights (tiles.C's ``tiles``)."""

    def __init__(self, tilings: int, memory: int, seed: int = 0,
                 rndseq: Sequence[int] | None = None) -> None:
        if tilings < 1 or memory < 1:
            raise ValueError(f"tilings and memory must be positive, got {tilings}, {memory}")
        self.tilings = int(tilings)
        self.memory = int(memory)
        table = (np.random.default_rng(seed).integers(0, 2**32, RNDSEQ_SIZE, dtype=np.int64)
                 if rndseq is None else np.asarray(rndseq, dtype=np.int64))
        if table.shape != (RNDSEQ_SIZE,):
            raise ValueError(f"rndseq must hold {RNDSEQ_SIZE} numbers")
        self.rndseq = table
        self._j = np.arange(self.tilings, dtype=np.int64)

    def coordinates(self, floats: Floats, ints: Sequence[int] = ()) -> np.ndarray:
        """The coordinates of every tiling, shape (tilings, len(floats) + 1 + len(ints))."""
        n = self.tilings
        x = np.asarray(floats, dtype=float)
        q = np.floor(x * n).astype(np.int64)                      # (d,)
        i = np.arange(len(x), dtype=np.int64)
        base = self._j[:, None] * (1 + 2 * i)[None, :]            # (n, d)
        coords = q[None, :] - np.mod(q[None, :] - base, n)
        extra = np.broadcast_to(np.asarray(list(ints), dtype=np.int64), (n, len(ints)))
        return np.concatenate([coords, self._j[:, None], extra], axis=1)

    def _hash_sums(self, coords: np.ndarray) -> np.ndarray:
        k = np.arange(coords.shape[1], dtype=np.int64)
        return self.rndseq[np.mod(coords + HASH_INCREMENT * k, RNDSEQ_SIZE)].sum(axis=1)

    def tiles(self, floats: Floats, ints: Sequence[int] = ()) -> np.ndarray:
        """The active tile of each tiling: ``tilings`` indices in [0, memory)."""
        return np.mod(self._hash_sums(self.coordinates(floats, ints)), self.memory)

    def action_tiles(self, floats: Floats, ints: Sequence[int],
                     n_actions: int) -> np.ndarray:
        """The tiles of (state, a) for every action a, the action being the last integer input
        (``tiles(floats, [*ints, a])``): shape (n_actions, tilings)."""
        coords = self.coordinates(floats, ints)
        sums = self._hash_sums(coords)                            # (n,)
        pos = coords.shape[1]                                     # the action's position
        a = np.arange(n_actions, dtype=np.int64)
        extra = self.rndseq[np.mod(a + HASH_INCREMENT * pos, RNDSEQ_SIZE)]   # (A,)
        return np.mod(sums[None, :] + extra[:, None], self.memory)
