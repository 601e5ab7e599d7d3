"""Floating objects (§7.4.1, §7.9.1): balls drifting in an invisible box out of the hand's reach.

They are moved kinematically (no MuJoCo body takes part in the physics; the MJCF has mocap
spheres only so that pictures show them). Each ball keeps a constant velocity that is redrawn
with probability ``TURN_PROB`` per step and reflected at the box's walls.

The *contingent* ball (ball 1 in the contingent variants) drifts in x and y like the others but
falls slowly in z (``FALL_ACCEL``) unless the hand makes it rise:

* ``rising``: while the hand rises (h_z increased by more than ``RISE_EPS`` this step) the ball
  gets an upward push (``PUSH_ACCEL``, the reference's "force of 50 units"), which reverses a
  fall only after a few steps;
* ``jump``: while h_z is within ``JUMP_BAND`` (the reference's (13.75, 14.25)) the ball jumps up
  ``JUMP_HEIGHT`` at once.

It bounces at the bottom with ``restitution`` (0.8 while learning); the contingent_up task sets
it to 0 so that the ball does not bounce up "without the agent having to do anything" (§7.9.1):
at the agent's per-second zero band (±0.05) even a bounce at restitution 0.1 reads as ḟ_z → [+].
"""

from __future__ import annotations

import numpy as np

#: The invisible box, in the reference frame (x to the robot's left, y forward, z up).
BOX_LOW = (-5.0, 6.0, 11.0)
BOX_HIGH = (5.0, 10.0, 17.0)
MAX_SPEED = 4.0  # units per second
TURN_PROB = 0.05
DT = 0.05  # seconds per agent step

FALL_ACCEL = 3.0  # units/s², the contingent ball's slow fall
MAX_FALL_SPEED = 3.0
PUSH_ACCEL = 10.0  # units/s² while the hand rises (net +7 against the fall)
RISE_EPS = 0.02  # hand rise per step that counts as "rising"
JUMP_BAND = (13.75, 14.25)
JUMP_HEIGHT = 0.6
LEARNING_RESTITUTION = 0.8


class FloatingBalls:
    """``n`` balls; ball 0 is contingent on the hand when ``contingent`` is "rising" or "jump"."""

    def __init__(self, n: int, contingent: str | None = None) -> None:
        if contingent not in (None, "rising", "jump"):
            raise ValueError(f"contingent ball mode is 'rising' or 'jump', got {contingent!r}")
        self.n = n
        self.contingent = contingent
        self.restitution = LEARNING_RESTITUTION
        self.pos = [[0.0, 0.0, 0.0] for _ in range(n)]
        self.vel = [[0.0, 0.0, 0.0] for _ in range(n)]

    def reset(self, rng: np.random.Generator) -> None:
        self.restitution = LEARNING_RESTITUTION
        for i in range(self.n):
            self.pos[i] = [
                float(rng.uniform(lo, hi)) for lo, hi in zip(BOX_LOW, BOX_HIGH, strict=True)
            ]
            self.vel[i] = self._random_velocity(rng)
            if i == 0 and self.contingent:
                self.vel[i][2] = -float(rng.uniform(0.5, MAX_FALL_SPEED))

    @staticmethod
    def _random_velocity(rng: np.random.Generator) -> list[float]:
        return [float(v) for v in rng.uniform(-MAX_SPEED, MAX_SPEED, 3)]

    def step(self, rng: np.random.Generator, hand_z: float, hand_dz: float) -> None:
        turns = rng.random(self.n)
        for i in range(self.n):
            pos, vel = self.pos[i], self.vel[i]
            contingent = i == 0 and self.contingent is not None
            if turns[i] < TURN_PROB:
                new = self._random_velocity(rng)
                vel[0], vel[1] = new[0], new[1]
                if not contingent:
                    vel[2] = new[2]
            if contingent:
                vel[2] -= FALL_ACCEL * DT
                if self.contingent == "rising" and hand_dz > RISE_EPS:
                    vel[2] += PUSH_ACCEL * DT
                vel[2] = max(vel[2], -MAX_FALL_SPEED)
                if self.contingent == "jump" and JUMP_BAND[0] < hand_z < JUMP_BAND[1]:
                    pos[2] = min(pos[2] + JUMP_HEIGHT, BOX_HIGH[2])
                    vel[2] = max(vel[2], 0.0)
            for k in range(3):
                pos[k] += vel[k] * DT
                if pos[k] < BOX_LOW[k] and contingent and k == 2:
                    # The contingent ball's bounce loses speed and height alike: with
                    # restitution 0 it stops on the bottom instead of popping back up.
                    pos[k] = BOX_LOW[k] + (BOX_LOW[k] - pos[k]) * self.restitution
                    vel[k] = -vel[k] * self.restitution
                elif pos[k] < BOX_LOW[k]:
                    pos[k] = 2 * BOX_LOW[k] - pos[k]
                    vel[k] = -vel[k]
                elif pos[k] > BOX_HIGH[k]:
                    pos[k] = 2 * BOX_HIGH[k] - pos[k]
                    vel[k] = -vel[k]
