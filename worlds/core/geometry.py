"""The core world's hand geometry (§7.1): what the world builds its hand from and what its tasks
read to choose a goal (footnote 2 of §7.2.2), in one place below both."""

from __future__ import annotations

HAND_HALF = 1.5  # half the palm's width: the grasp distance of §7.1
HAND_HALF_Z = 0.25
HAND_OFFSET = (0.0, 0.5, 12.75)  # hand centre when the slide joints are at 0
HAND_LOW = (-2.5, -2.0, 11.0)
HAND_HIGH = (2.5, 3.0, 14.5)
