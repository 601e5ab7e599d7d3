"""The core world's hand geometry (§7.1): what the world builds its hand from and what its tasks
read to choose a goal (footnote 2 of §7.2.2), in one place below both; and the resolution its
hand's motion gives the position-like magnitudes, which core2d's same hand declares too."""

from __future__ import annotations

HAND_HALF = 1.5  # half the palm's width: the grasp distance of §7.1
HAND_HALF_Z = 0.25
HAND_OFFSET = (0.0, 0.5, 12.75)  # hand centre when the slide joints are at 0
HAND_LOW = (-2.5, -2.0, 11.0)
HAND_HIGH = (2.5, 3.0, 14.5)

RESOLUTION = 0.16
"""Resolution of every position-like magnitude: the hand's mean step in one tick while it moves
(motor babbling, App. E: 0.15–0.18 for h_x, h_y, h_z and the hand–block distances; the block's
T_L and T_T 0.20–0.21). No landmark is narrower or closer: a value narrower than the motion of
one tick is one the motion steps over (docs/decisions.md 76 and 114)."""
