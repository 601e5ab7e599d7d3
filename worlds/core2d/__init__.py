"""The 2D core world of §7.7 (pymunk)."""
