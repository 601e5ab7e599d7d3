"""The 2D core world of §7.7, in pymunk: the core world seen from above, the hand moving in x, y.

Same frame, table, hand and block sizes as ``core`` (+x is the robot's left, +y forward; the hand
is a 3 × 3 palm with centre in x ∈ [−2.5, 2.5], y ∈ [−2, 3], its limits hard stops; the block a
square of width 1–3; the table x ∈ [−17, 4], y ∈ [−6, 4]). Removed from Table 7.1 (§7.7.1): u_z,
u_UG, h_z, z_BT, c_x, c_y, T and bang. Table friction is a top-down pivot joint with a bounded
force on each body (pymunk's usual trick): 300 units of force on the hand before it moves, then
a viscous drag of 75 per unit of speed, (|u| − 300) / 75 units/s (0.47 units per step at
|u| = 1000), as in ``core``; the block (mass 0.25) has the friction of ``core``'s, 0.6 × its
weight at gravity 140, so a push moves it about as far as the hand travels.

A block whose centre leaves the table falls: z_F drops from 10.5 under gravity, and when it
reaches 0 the block is replaced (at the start of the next step, a discontinuity). It is also
replaced when out of reach and still, or out of reach for 100 steps. One agent step is 2 × 0.025
s = 0.05 s (``step_seconds``).
"""

from __future__ import annotations

import math
from types import MappingProxyType
from typing import Any

import numpy as np
import pymunk

from worlds.base import Goal, Task, VariableSpec, VarKind, World, with_resolution
from worlds.core.geometry import RESOLUTION  # the same hand: its mean step, 0.14–0.18 here

__all__ = ["Core2DWorld", "make_core2d"]

DT = 0.025
SUBSTEPS = 2
HAND_HALF = 1.5
HAND_LOW = (-2.5, -2.0)
HAND_HIGH = (2.5, 3.0)
HAND_MASS = 2.2
FRICTION = 300.0
DRAG = 75.0
FORCE = 1000.0
GRAVITY = 140.0  # units/s², as in core (9.8 m/s² at about 7 cm a unit)
BLOCK_MASS = 0.25
BLOCK_FRICTION = 0.6 * BLOCK_MASS * GRAVITY
TABLE = (-17.0, 4.0, -6.0, 4.0)  # x_right, x_left, y_near, y_far, as in core
TABLE_TOP = 10.5
REACH = (-4.0, 4.0, -3.5, 4.5)
PLACE_X = (-3.0, 3.0)
PLACE_Y = (-2.0, 3.0)
EDGE_MARGIN = 1.0  # a block's centre is placed at least this far from the table's edges
WIDTH = (1.0, 3.0)
STILL_SPEED = 0.1
OUT_OF_REACH_STEPS = 100

_M = VarKind.MAGNITUDE
VARIABLES = (
    VariableSpec("u_x", VarKind.MOTOR, "force on the hand in x; + pushes it left", -FORCE, FORCE),
    VariableSpec(
        "u_y", VarKind.MOTOR, "force on the hand in y; + pushes it forward", -FORCE, FORCE
    ),
    VariableSpec("h_x", _M, "hand centre x; + is the robot's left, range [-2.5, 2.5]"),
    VariableSpec("h_y", _M, "hand centre y; + is forward, range [-2, 3]"),
    VariableSpec("y_TB", _M, "far side of hand minus near side of block, y; 0: pushing forward"),
    VariableSpec("y_BT", _M, "near side of hand minus far side of block, y; 0: pushing back"),
    VariableSpec("x_RL", _M, "right side of hand minus left side of block, x; 0: pushing right"),
    VariableSpec("x_LR", _M, "left side of hand minus right side of block, x; 0: pushing left"),
    VariableSpec("z_F", _M, "bottom of block above the floor; 10.5 on the table, falls to 0"),
    VariableSpec("T_L", _M, "block centre minus the table's left edge, x; < 0 on the table"),
    VariableSpec("T_R", _M, "block centre minus the table's right edge, x; > 0 on the table"),
    VariableSpec("T_T", _M, "block centre minus the table's far edge, y; < 0 on the table"),
)


class MoveBlock2D(Task):
    """Move the block left, right or forward (§7.7's task is the core move task)."""

    name = "move_block"
    GOALS = MappingProxyType(
        {
            "left": Goal("T_L.dot", "+"),
            "right": Goal("T_R.dot", "-"),
            "forward": Goal("T_T.dot", "+"),
        }
    )

    def __init__(self) -> None:
        self.choice = "left"

    def setup(self, world: World, rng: np.random.Generator) -> dict[str, float]:
        w: Core2DWorld = world  # type: ignore[assignment]
        w.reset(seed=int(rng.integers(2**63 - 1)))
        w.set_hand(
            float(rng.uniform(HAND_LOW[0], HAND_HIGH[0])),
            float(rng.uniform(HAND_LOW[1], HAND_HIGH[1])),
        )
        w.place_block(rng)
        obs = w.restart_from(w._observe())
        hx = w.hand.position.x
        bx, by = w.block.position
        half = w.width / 2
        if by - half < HAND_LOW[1] + HAND_HALF + 0.5:
            self.choice = "left" if bx > hx else "right"
        else:
            extreme = HAND_HIGH[0] - HAND_HALF - 0.5
            options = (
                ("left", "forward")
                if bx + half > extreme
                else (
                    ("right", "forward") if bx - half < -extreme else ("left", "right", "forward")
                )
            )
            self.choice = options[int(rng.integers(len(options)))]
        return obs

    def goal(self, world: World, obs: Any) -> Goal:
        return self.GOALS[self.choice]

    @staticmethod
    def _moves(world: World) -> tuple[str, str] | None:
        """(Ṫ_L, Ṫ_T) as the agent perceives them; None on a discontinuity."""
        dx, dy = world.change("T_L"), world.change("T_T")
        if dx is None or dy is None:
            return None
        return dx, dy

    def is_success(self, world: World, obs: Any) -> bool:
        moves = self._moves(world)
        if moves is None:
            return False
        dx, dy = moves
        return {"left": dx == "+", "right": dx == "-", "forward": dy == "+"}[self.choice]

    def is_failure(self, world: World, obs: Any) -> bool:
        moves = self._moves(world)
        return moves is not None and moves != ("0", "0") and not self.is_success(world, obs)


class Core2DWorld(World):
    """The 2D core world; see the module docstring."""

    name = "core2d"
    substeps = SUBSTEPS
    step_seconds = DT * SUBSTEPS

    def __init__(self) -> None:
        self._init_variables(with_resolution(VARIABLES, RESOLUTION))
        self.tasks = MappingProxyType({"move_block": MoveBlock2D()})
        self.agent_options = MappingProxyType({})
        self.reset(seed=0)

    def _build(self) -> None:
        space = pymunk.Space()
        space.gravity = (0.0, 0.0)
        self.space = space
        ground = space.static_body
        self.hand = pymunk.Body(HAND_MASS, math.inf)
        shape = pymunk.Poly.create_box(self.hand, (2 * HAND_HALF, 2 * HAND_HALF))
        shape.friction = 0.2
        space.add(self.hand, shape)
        pivot = pymunk.PivotJoint(ground, self.hand, (0, 0), (0, 0))
        pivot.max_bias = 0.0
        pivot.max_force = FRICTION
        space.add(pivot)
        self.block = None
        self._block_parts: tuple[Any, ...] = ()

    def _new_block(self, width: float) -> None:
        if self._block_parts:
            self.space.remove(*self._block_parts)
        body = pymunk.Body(BLOCK_MASS, pymunk.moment_for_box(BLOCK_MASS, (width, width)))
        shape = pymunk.Poly.create_box(body, (width, width))
        shape.friction = 0.2
        pivot = pymunk.PivotJoint(self.space.static_body, body, (0, 0), (0, 0))
        pivot.max_bias = 0.0
        pivot.max_force = BLOCK_FRICTION
        gear = pymunk.GearJoint(self.space.static_body, body, 0.0, 1.0)
        gear.max_bias = 0.0
        gear.max_force = BLOCK_FRICTION * width / 2
        self.space.add(body, shape, pivot, gear)
        self._block_parts = (body, shape, pivot, gear)
        self._friction_parts = (pivot, gear)
        self.block = body
        self.width = width

    def set_hand(self, x: float, y: float) -> None:
        """Put the hand at (x, y), at rest (a teleport: the next step is a discontinuity)."""
        self._mark_discontinuity()
        self.hand.position = (
            min(max(x, HAND_LOW[0]), HAND_HIGH[0]),
            min(max(y, HAND_LOW[1]), HAND_HIGH[1]),
        )
        self.hand.velocity = (0.0, 0.0)

    def place_block(self, rng: np.random.Generator) -> None:
        """Put a new block (random width) at a random place within reach, clear of the hand (a
        teleport: the next step is a discontinuity)."""
        self._mark_discontinuity()
        width = float(rng.uniform(*WIDTH))
        hx, hy = self.hand.position
        lo_x = max(PLACE_X[0], TABLE[0] + EDGE_MARGIN)
        hi_x = min(PLACE_X[1], TABLE[1] - EDGE_MARGIN)
        hi_y = min(PLACE_Y[1], TABLE[3] - EDGE_MARGIN)
        for _ in range(50):
            bx, by = float(rng.uniform(lo_x, hi_x)), float(rng.uniform(PLACE_Y[0], hi_y))
            if (
                abs(bx - hx) > HAND_HALF + width / 2 + 0.05
                or abs(by - hy) > HAND_HALF + width / 2 + 0.05
            ):
                break
        else:  # pragma: no cover - the placement region is much larger than the hand
            bx, by = (hi_x, hi_y) if hy < 0.5 else (lo_x, PLACE_Y[0])
        self._new_block(width)
        assert self.block is not None
        self.block.position = (bx, by)
        self.z_f = TABLE_TOP
        self.v_z = 0.0
        self.falling = False
        self._out_of_reach_steps = 0

    def _reset(self) -> dict[str, float]:
        self._build()
        self.set_hand(0.0, 0.5)
        self.place_block(self.rng)
        self.block_replaced = False
        self.block_out_of_reach = False
        self._pending_replace = False
        return self._observe()

    def _step(self, motor: list[float]) -> dict[str, float]:
        self.block_replaced = False
        if self._pending_replace:
            self._pending_replace = False
            self.place_block(self.rng)
            self.block_replaced = True
        fx, fy = motor[0], motor[1]
        hand, block, space = self.hand, self.block, self.space
        assert block is not None
        for _ in range(SUBSTEPS):
            vx, vy = hand.velocity
            hand.force = (fx - DRAG * vx, fy - DRAG * vy)
            space.step(DT)
            x, y = hand.position
            if not (HAND_LOW[0] <= x <= HAND_HIGH[0] and HAND_LOW[1] <= y <= HAND_HIGH[1]):
                vx, vy = hand.velocity
                if x < HAND_LOW[0] or x > HAND_HIGH[0]:
                    x, vx = min(max(x, HAND_LOW[0]), HAND_HIGH[0]), 0.0
                if y < HAND_LOW[1] or y > HAND_HIGH[1]:
                    y, vy = min(max(y, HAND_LOW[1]), HAND_HIGH[1]), 0.0
                hand.position, hand.velocity = (x, y), (vx, vy)
        bx, by = block.position
        on_table = TABLE[0] <= bx <= TABLE[1] and TABLE[2] <= by <= TABLE[3]
        if not on_table and not self.falling:
            self.falling = True
            space.remove(*self._friction_parts)
            self._block_parts = self._block_parts[:2]
        if self.falling:
            self.v_z -= GRAVITY * DT * SUBSTEPS
            self.z_f = max(0.0, self.z_f + self.v_z * DT * SUBSTEPS)
            if self.z_f <= 0.0:
                self._pending_replace = True
        half = self.width / 2
        out = (
            bx - half > REACH[1]
            or bx + half < REACH[0]
            or by - half > REACH[3]
            or by + half < REACH[2]
        )
        self.block_out_of_reach = out
        if out:
            self._out_of_reach_steps += 1
            if (
                block.velocity.length < STILL_SPEED
                or self._out_of_reach_steps >= OUT_OF_REACH_STEPS
            ):
                self._pending_replace = True
        else:
            self._out_of_reach_steps = 0
        return self._observe()

    def _observe(self) -> dict[str, float]:
        hx, hy = self.hand.position
        assert self.block is not None
        bx, by = self.block.position
        half = self.width / 2
        return {
            "h_x": float(hx),
            "h_y": float(hy),
            "y_TB": float((hy + HAND_HALF) - (by - half)),
            "y_BT": float((hy - HAND_HALF) - (by + half)),
            "x_RL": float((hx - HAND_HALF) - (bx + half)),
            "x_LR": float((hx + HAND_HALF) - (bx - half)),
            "z_F": float(self.z_f),
            "T_L": float(bx - TABLE[1]),
            "T_R": float(bx - TABLE[0]),
            "T_T": float(by - TABLE[3]),
        }

    def render_text(self, width: int = 60, height: int = 20) -> str:
        """Top-down: '.' table, '#' block, 'H' hand; left of the picture is +x (robot's left)."""
        x_max, x_min, y_max, y_min = TABLE[1] + 1.5, TABLE[0] - 1.5, TABLE[3] + 1.0, TABLE[2] - 1.0
        rows = max(height - 2, 4)
        grid = [[" "] * width for _ in range(rows)]

        def fill(x0: float, x1: float, y0: float, y1: float, ch: str) -> None:
            c0 = int((x_max - x1) / (x_max - x_min) * (width - 1) + 0.5)
            c1 = int((x_max - x0) / (x_max - x_min) * (width - 1) + 0.5)
            r0 = int((y_max - y1) / (y_max - y_min) * (rows - 1) + 0.5)
            r1 = int((y_max - y0) / (y_max - y_min) * (rows - 1) + 0.5)
            for r in range(max(r0, 0), min(r1, rows - 1) + 1):
                for c in range(max(c0, 0), min(c1, width - 1) + 1):
                    grid[r][c] = ch

        fill(TABLE[0], TABLE[1], TABLE[2], TABLE[3], ".")
        assert self.block is not None
        bx, by = self.block.position
        h = self.width / 2
        fill(bx - h, bx + h, by - h, by + h, "#")
        hx, hy = self.hand.position
        fill(hx - HAND_HALF, hx + HAND_HALF, hy - HAND_HALF, hy + HAND_HALF, "H")
        status = f"core2d t={self.step_count} hand=({hx:.1f},{hy:.1f}) z_F={self.z_f:.1f}"
        return "\n".join([status[:width], *("".join(row) for row in grid)])

    def scene(self, values: dict[str, float] | None = None) -> list[dict[str, Any]]:
        """The bodies as boxes, for a 3D view (the recorder's foxglove.SceneUpdate), as
        :meth:`worlds.core.world.CoreWorld.scene` gives them: ``{"id", "shape": "box", "centre",
        "size", "rgba"}`` in MuJoCo's right-handed frame (x = the reference's −x, z up). The
        table top is 10.5 above the floor; the hand, a 3 × 3 × 0.5 palm, at height 11 (its
        lowest in ``core``, level with the block); the block, a cube of its current width,
        from ``values`` (default: the current observation): centre (T_L + 4, T_T + 4), bottom
        at z_F (10.5 on the table, lower while it falls), width x_LR − x_RL − 3.
        """
        obs = self.observation if values is None else values
        x_right, x_left, y_near, y_far = TABLE
        top = (-(x_left + x_right) / 2, (y_far + y_near) / 2, TABLE_TOP - 1.0)
        width = obs["x_LR"] - obs["x_RL"] - 2 * HAND_HALF
        bx, by = obs["T_L"] + x_left, obs["T_T"] + y_far
        return [
            {
                "id": "table",
                "shape": "box",
                "centre": top,
                "size": (x_left - x_right, y_far - y_near, 2.0),
                "rgba": (0.62, 0.45, 0.28, 1),
            },
            {
                "id": "hand",
                "shape": "box",
                "centre": (-obs["h_x"], obs["h_y"], 11.0),
                "size": (2 * HAND_HALF, 2 * HAND_HALF, 0.5),
                "rgba": (0.95, 0.80, 0.25, 1),
            },
            {
                "id": "block",
                "shape": "box",
                "centre": (-bx, by, obs["z_F"] + width / 2),
                "size": (width, width, width),
                "rgba": (0.85, 0.15, 0.15, 1),
            },
        ]


def make_core2d(
    variant: str | None = None, option: str | None = None, **options: Any
) -> Core2DWorld:
    """Registry factory for ``core2d`` (no variants)."""
    if variant or option or options:
        given = [repr(":".join(x for x in (variant, option) if x))] if variant or option else []
        given += [f"{k}={v!r}" for k, v in options.items()]
        raise ValueError(f"core2d takes no variant or options, got {', '.join(given)}")
    return Core2DWorld()
