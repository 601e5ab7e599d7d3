"""Pong (§7.10, Table 7.3): two paddles moving together in y, one ball; no physics engine.

Field x ∈ [0, 20], y ∈ [0, 12] (+x right, +y up). The left paddle's face is at l_x = 1, the right
paddle's at r_x = 19 (constant, as in Table 7.3); both paddles are 3 long and share one y. The
motor u ∈ [−1, 1] is three-valued: u < −0.05 moves the paddles down, u > 0.05 up (0.5 units a
step), otherwise they stay (the dead band is the agent's initial zero landmark on motors,
Table 8.1). The ball moves 0.4 units a step in x and reflects off the top and bottom walls and
off a paddle it meets (its y speed bent by where it hits the paddle). When it passes a paddle the
volley is over: ball and paddles start again in the middle (during evaluation the paddles start
at a random place, §7.10.1).

The world declares ``agent_options = {"k_fixed": 6, "nrp": True}``: the agent must fix its
window k at 6 and allow plans without a reliable plan for the antecedent event (§7.10.1).

Each magnitude declares its resolution (docs/decisions.md 76), the distance it moves in one
tick, so that no learned landmark or interval between two is one the motion steps over: the
x positions (b_x, c^l_x, c^r_x, and the constant l_x, r_x) the ball's x step 0.4; the paddles
(l_y, r_y) their step 0.5; b_y, c^l_y and c^r_y the ball's mean y step at a serve, 0.225 (its
y speed is drawn from [0.1, 0.35]; with the paddles at rest c^l_y and c^r_y move with it).
"""

from __future__ import annotations

from types import MappingProxyType
from typing import Any

import numpy as np

from worlds.base import Goal, Task, VariableSpec, VarKind, World

__all__ = ["PongVolley", "PongWorld", "make_pong"]

WIDTH, HEIGHT = 20.0, 12.0
L_X, R_X = 1.0, 19.0
PADDLE_HALF = 1.5
PADDLE_SPEED = 0.5
BALL_SPEED_X = 0.4
BALL_SPEED_Y = (0.1, 0.35)
MAX_SPEED_Y = 0.5
BALL_RADIUS = 0.3
DEAD_BAND = 0.05
STEP_SECONDS = 1.0
RESOLUTION_X = BALL_SPEED_X
"""Resolution of the x positions: the ball moves exactly this far in x every tick."""
RESOLUTION_PADDLE = PADDLE_SPEED
"""Resolution of the paddles' y: they move in steps of this size (or rest)."""
RESOLUTION_Y = 0.5 * (BALL_SPEED_Y[0] + BALL_SPEED_Y[1])
"""Resolution of the ball's y and of the paddles' y relative to it: the ball's mean y step at
a serve (0.225; measured over 20,000 random-motor steps, the mean |Δb_y| is 0.224)."""

_M = VarKind.MAGNITUDE


def _m(name: str, meaning: str, resolution: float) -> VariableSpec:
    return VariableSpec(name, _M, meaning, resolution=resolution)


VARIABLES = (
    VariableSpec("u", VarKind.MOTOR, "paddles: < -0.05 down, > 0.05 up, else steady", -1.0, 1.0),
    _m("l_x", "left paddle's face x (constant 1)", RESOLUTION_X),
    _m("l_y", "left paddle centre y; + is up", RESOLUTION_PADDLE),
    _m("r_x", "right paddle's face x (constant 19)", RESOLUTION_X),
    _m("r_y", "right paddle centre y; + is up", RESOLUTION_PADDLE),
    _m("b_x", "ball centre x; + is right", RESOLUTION_X),
    _m("b_y", "ball centre y; + is up", RESOLUTION_Y),
    _m("cl_x", "left paddle x minus ball x (c^l_x); < 0 while the ball is in play", RESOLUTION_X),
    _m("cl_y", "left paddle y minus ball y (c^l_y); + when the paddle is above", RESOLUTION_Y),
    _m("cr_x", "right paddle x minus ball x (c^r_x); > 0 while the ball is in play",
       RESOLUTION_X),
    _m("cr_y", "right paddle y minus ball y (c^r_y); + when the paddle is above", RESOLUTION_Y),
)


class PongVolley(Task):
    """Keep the volley going (§7.10.1): make the ball go left when it goes right, and vice versa.

    Each paddle hit earns 1 and the trial goes on (``episodic = False``); it ends when the ball
    is missed or after ``max_steps``. The mean reward is the mean number of volleys per trial.
    """

    name = "pong_volley"
    step_cost = 0.0
    success_reward = 1.0
    max_steps = 2000
    episodic = False

    def setup(self, world: World, rng: np.random.Generator) -> dict[str, float]:
        w: PongWorld = world  # type: ignore[assignment]
        w.random_paddles = True
        return w.reset(seed=int(rng.integers(2**63 - 1)))

    def goal(self, world: World, obs: Any) -> Goal:
        going_right = world.ball_v[0] > 0  # type: ignore[attr-defined]
        return Goal("b_x.dot", "-" if going_right else "+")

    def is_success(self, world: World, obs: Any) -> bool:
        return world.hit  # type: ignore[attr-defined,no-any-return]

    def is_failure(self, world: World, obs: Any) -> bool:
        return world.missed  # type: ignore[attr-defined,no-any-return]


class PongWorld(World):
    """Pong; see the module docstring."""

    name = "pong"
    substeps = 1
    step_seconds = STEP_SECONDS
    constant_variables = ("l_x", "r_x")

    def __init__(self, random_paddles: bool = False) -> None:
        self._init_variables(VARIABLES)
        self.tasks = MappingProxyType({"pong_volley": PongVolley()})
        self.agent_options = MappingProxyType({"k_fixed": 6, "nrp": True})
        self.random_paddles = random_paddles
        self.reset(seed=0)

    def _new_volley(self) -> None:
        rng = self.rng
        if self.random_paddles:
            self.paddle_y = float(rng.uniform(PADDLE_HALF, HEIGHT - PADDLE_HALF))
        else:
            self.paddle_y = HEIGHT / 2
        self.ball = [WIDTH / 2, HEIGHT / 2]
        vx = BALL_SPEED_X if rng.random() < 0.5 else -BALL_SPEED_X
        vy = float(rng.uniform(*BALL_SPEED_Y)) * (1.0 if rng.random() < 0.5 else -1.0)
        self.ball_v = [vx, vy]

    def _reset(self) -> dict[str, float]:
        self.hit = False
        self.missed = False
        self.volleys = 0
        self._new_volley()
        return self._observe()

    def _step(self, motor: list[float]) -> dict[str, float]:
        self.hit = False
        if self.missed:
            self.missed = False
            self._new_volley()
            self._mark_discontinuity()
        u = motor[0]
        move = PADDLE_SPEED if u > DEAD_BAND else (-PADDLE_SPEED if u < -DEAD_BAND else 0.0)
        self.paddle_y = min(max(self.paddle_y + move, PADDLE_HALF), HEIGHT - PADDLE_HALF)
        (x, y), (vx, vy) = self.ball, self.ball_v
        x, y = x + vx, y + vy
        if y < BALL_RADIUS:
            y, vy = 2 * BALL_RADIUS - y, -vy
        elif y > HEIGHT - BALL_RADIUS:
            y, vy = 2 * (HEIGHT - BALL_RADIUS) - y, -vy
        face_l, face_r = L_X + BALL_RADIUS, R_X - BALL_RADIUS
        crossed_l = vx < 0 and x <= face_l < x - vx
        crossed_r = vx > 0 and x - vx < face_r <= x
        if crossed_l or crossed_r:
            offset = y - self.paddle_y
            if abs(offset) <= PADDLE_HALF + BALL_RADIUS:
                face = face_l if crossed_l else face_r
                x, vx = 2 * face - x, -vx
                vy = max(-MAX_SPEED_Y, min(MAX_SPEED_Y, vy + 0.15 * offset / PADDLE_HALF))
                self.hit = True
                self.volleys += 1
        if x < 0.0 or x > WIDTH:
            self.missed = True
        self.ball, self.ball_v = [x, y], [vx, vy]
        return self._observe()

    replayable = False

    def _get_state(self) -> dict[str, Any]:
        """Paddles, ball and the volley bookkeeping (the generator is saved by the base)."""
        return {"paddle_y": self.paddle_y, "ball": list(self.ball), "ball_v": list(self.ball_v),
                "hit": self.hit, "missed": self.missed, "volleys": self.volleys,
                "random_paddles": self.random_paddles}

    def _set_state(self, physics: Any) -> None:
        ball = [float(v) for v in physics["ball"]]
        ball_v = [float(v) for v in physics["ball_v"]]
        if len(ball) != 2 or len(ball_v) != 2:
            raise ValueError(f"pong: ball {ball} and velocity {ball_v} need 2 values each")
        self.paddle_y, self.ball, self.ball_v = float(physics["paddle_y"]), ball, ball_v
        self.hit, self.missed = bool(physics["hit"]), bool(physics["missed"])
        self.volleys = int(physics["volleys"])
        self.random_paddles = bool(physics["random_paddles"])

    def _observe(self) -> dict[str, float]:
        x, y = self.ball
        p = self.paddle_y
        return {
            "l_x": L_X,
            "l_y": p,
            "r_x": R_X,
            "r_y": p,
            "b_x": x,
            "b_y": y,
            "cl_x": L_X - x,
            "cl_y": p - y,
            "cr_x": R_X - x,
            "cr_y": p - y,
        }

    def render_text(self, width: int = 60, height: int = 20) -> str:
        """The field: '|' paddles, 'o' the ball."""
        rows = max(height - 2, 4)
        grid = [[" "] * width for _ in range(rows)]

        def cell(x: float, y: float) -> tuple[int, int]:
            r = int((HEIGHT - y) / HEIGHT * (rows - 1) + 0.5)
            c = int(x / WIDTH * (width - 1) + 0.5)
            return min(max(r, 0), rows - 1), min(max(c, 0), width - 1)

        for px in (L_X, R_X):
            for k in range(-3, 4):
                r, c = cell(px, self.paddle_y + k * PADDLE_HALF / 3)
                grid[r][c] = "|"
        r, c = cell(*self.ball)
        grid[r][c] = "o"
        status = f"pong t={self.step_count} volleys={self.volleys}"
        border = "-" * width
        return "\n".join([status[:width], border, *("".join(row) for row in grid)])


def make_pong(variant: str | None = None, option: str | None = None, **options: Any) -> PongWorld:
    """Registry factory for ``pong`` (option: ``random_paddles=True``)."""
    if variant or option:
        given = ":".join(x for x in (variant, option) if x)
        raise ValueError(f"pong has no variants, got {given!r}")
    return PongWorld(**options)
