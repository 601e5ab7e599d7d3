"""Evaluation tasks of the core world (§7.2, §7.8, §7.9).

Each trial resets the world (seeded from the evaluator's generator), puts the block at a random
place within reach and the hand at a random place (§7.2.1), and names the goal. Reward: −0.01 a
step, +9.99 on the step the goal is reached; at most 300 steps. Directions of change (".dot"
goals) are judged as the agent's perception judges them, per second with the zero band ±0.05
(``World.change``); a discontinuity step (a replaced block) is no motion.

* ``move_block`` — move the block left (T_L.dot = "+"), right (T_R.dot = "-") or forward
  (T_T.dot = "+"), the goal chosen by footnote 2's rule from the block's place relative to the
  hand; ends early when the block moves the wrong way.
* ``hit_floor`` — bang = "true".
* ``pickup`` — T = "true"; ends early when the block goes out of reach (or off the table).
* ``hit_secondary`` (secondary variants) — m_BB = "true"; ends early when the primary block goes
  out of reach or off the table.
* ``contingent_up`` (contingent variants) — f1_z.dot = "+"; step cost 0.1 (§7.9.3), motors held at
  0 by an agent without a plan, the ball not bouncing (restitution 0: it should not rise
  "without the agent having to do anything", §7.9.1).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from worlds.base import Goal, Task, World
from worlds.core.geometry import HAND_HALF, HAND_HIGH, HAND_LOW

if TYPE_CHECKING:
    from worlds.core.world import CoreWorld

__all__ = [
    "ContingentUp",
    "HitFloor",
    "HitSecondary",
    "MoveBlock",
    "Pickup",
    "core_tasks",
]

#: Footnote 2's "very close to the robot": the hand cannot get behind the block to push it
#: forward when the block's near side is closer than this (the hand's far side at its nearest).
NEAR_Y = HAND_LOW[1] + HAND_HALF + 0.5
#: "Extreme left": the hand cannot get left of the block to push it right (and vice versa).
EXTREME_X = HAND_HIGH[0] - HAND_HALF - 0.5


def _setup_trial(world: CoreWorld, rng: np.random.Generator) -> dict[str, float]:
    world.reset(seed=int(rng.integers(2**63 - 1)))
    world.random_hand(rng)
    world.place_block(rng)
    return world.restart_here()


class _CoreTask(Task):
    def setup(self, world: World, rng: np.random.Generator) -> dict[str, float]:
        return _setup_trial(world, rng)  # type: ignore[arg-type]


class MoveBlock(_CoreTask):
    """Hit the block left, right or forward (§7.2.2, footnote 2)."""

    name = "move_block"
    GOALS: Mapping[str, Goal] = {
        "left": Goal("T_L.dot", "+"),
        "right": Goal("T_R.dot", "-"),
        "forward": Goal("T_T.dot", "+"),
    }

    def __init__(self) -> None:
        self.choice = "left"

    def setup(self, world: World, rng: np.random.Generator) -> dict[str, float]:
        obs = _setup_trial(world, rng)  # type: ignore[arg-type]
        self.choice = self.choose(world, rng)
        return obs

    @staticmethod
    def choose(world: World, rng: np.random.Generator) -> str:
        """Footnote 2: very close to the robot → left if the block is left of the hand, else
        right; on the extreme left → left or forward; extreme right → right or forward;
        otherwise left, right or forward."""
        hx, _, _ = world.hand_position()  # type: ignore[attr-defined]
        bx, by, _ = world.block_position()  # type: ignore[attr-defined]
        half = world.width / 2  # type: ignore[attr-defined]
        if by - half < NEAR_Y:
            return "left" if bx > hx else "right"
        if bx + half > EXTREME_X:
            options = ("left", "forward")
        elif bx - half < -EXTREME_X:
            options = ("right", "forward")
        else:
            options = ("left", "right", "forward")
        return options[int(rng.integers(len(options)))]

    def goal(self, world: World, obs: Mapping[str, float]) -> Goal:
        return self.GOALS[self.choice]

    @staticmethod
    def _moves(world: World) -> tuple[str, str] | None:
        """(Ṫ_L, Ṫ_T) as the agent perceives them; None on a discontinuity (a replaced block
        did not move). Ṫ_R is Ṫ_L: both are the block centre's x minus a fixed edge."""
        dx, dy = world.change("T_L"), world.change("T_T")
        if dx is None or dy is None:
            return None
        return dx, dy

    def is_success(self, world: World, obs: Mapping[str, float]) -> bool:
        moves = self._moves(world)
        if moves is None:
            return False
        dx, dy = moves
        return {"left": dx == "+", "right": dx == "-", "forward": dy == "+"}[self.choice]

    def is_failure(self, world: World, obs: Mapping[str, float]) -> bool:
        moves = self._moves(world)
        if moves is None:
            return False
        dx, dy = moves
        moved = dx != "0" or dy != "0"
        return moved and not self.is_success(world, obs)


class HitFloor(_CoreTask):
    """Knock the block off the table (§7.2.2)."""

    name = "hit_floor"

    def goal(self, world: World, obs: Mapping[str, float]) -> Goal:
        return Goal("bang", "true")

    def is_success(self, world: World, obs: Mapping[str, float]) -> bool:
        return world.bang  # type: ignore[attr-defined,no-any-return]


class Pickup(_CoreTask):
    """Grasp the block (§7.2.2); ends early when the block goes out of reach."""

    name = "pickup"

    def goal(self, world: World, obs: Mapping[str, float]) -> Goal:
        return Goal("T", "true")

    def is_success(self, world: World, obs: Mapping[str, float]) -> bool:
        return world.grasped  # type: ignore[attr-defined,no-any-return]

    def is_failure(self, world: World, obs: Mapping[str, float]) -> bool:
        w: CoreWorld = world  # type: ignore[assignment]
        return w.block_out_of_reach or w.bang or w.block_replaced


class HitSecondary(_CoreTask):
    """Hit the second block with the first (§7.8)."""

    name = "hit_secondary"

    def goal(self, world: World, obs: Mapping[str, float]) -> Goal:
        return Goal("m_BB", "true")

    def is_success(self, world: World, obs: Mapping[str, float]) -> bool:
        return world.touching_blocks  # type: ignore[attr-defined,no-any-return]

    def is_failure(self, world: World, obs: Mapping[str, float]) -> bool:
        w: CoreWorld = world  # type: ignore[assignment]
        return w.block_replaced or w.replace_pending


class ContingentUp(_CoreTask):
    """Make the contingent ball move up (§7.9): f1_z.dot = "+"."""

    name = "contingent_up"
    step_cost = -0.1
    hold_motors_at_zero_without_plan = True
    EVAL_RESTITUTION = 0.0  # §7.9.1: no bounce up without the agent doing anything

    def setup(self, world: World, rng: np.random.Generator) -> dict[str, float]:
        obs = _setup_trial(world, rng)  # type: ignore[arg-type]
        world.balls.restitution = self.EVAL_RESTITUTION  # type: ignore[attr-defined]
        return obs

    def goal(self, world: World, obs: Mapping[str, float]) -> Goal:
        return Goal("f1_z.dot", "+")

    def is_success(self, world: World, obs: Mapping[str, float]) -> bool:
        return world.change("f1_z") == "+"


def core_tasks(world: CoreWorld) -> dict[str, Task]:
    """The tasks that make sense in this variant of the core world."""
    tasks: list[Task] = [Pickup()]
    if world.secondary:
        tasks.append(HitSecondary())
    else:
        tasks[:0] = [MoveBlock(), HitFloor()]
    if world.balls is not None and world.balls.contingent:
        tasks.append(ContingentUp())
    return {task.name: task for task in tasks}
