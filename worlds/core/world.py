"""The core table world of §7.1 and Table 7.1, in MuJoCo, with the variants of §7.4–7.9.

The scene (``core.xml`` beside this file): a table whose top is 10.5 above the floor, one block
(a cube whose width is drawn from [1, 3] at each placement), and a hand (a 3 × 3 × 0.5 palm) on an
orthogonal arm of three slide joints driven by force motors u_x, u_y, u_z. One agent step is 2
MuJoCo steps of 0.025 s (``step_seconds`` = 0.05).

The hand. Dry friction on the slides (``frictionloss=300``) means about 300 units of force are
needed before the hand moves; the arm's weight (250 down; the arm is gravity-compensated and the
weight is the u_z actuator's bias) means lifting needs more than 550 and lowering less than −50
(the reference learned landmarks near ±300 for u_x, u_y and 570 for u_z, Table 8.1). Above the
threshold viscous damping (75) sets the speed, (|u| − 300)/75 units per second: 0.067 units per
agent step at |u| = 400, 0.2 at 600 and 0.47 at 1000 (the reference's hand: 0.44–0.48 per step,
Table 8.9). The reach x ∈ [−2.5, 2.5], y ∈ [−2, 3], z ∈ [11, 14.5] ends in hard stops: the hand
rests exactly at a limit while pushed against it.

The block and the table. Gravity is 140 units/s² (9.8 m/s² at about 7 cm a unit: the table is
10.5 high). A block has three slide joints (it moves, never turns or tips) and rests on the table
through a small foot at the centre of its bottom, so it falls off an edge when its centre passes
the edge; its sliding friction is Coulomb friction of 0.6 × its weight (0.25 × 140) on the x and
y slides while it rests on the table (none while lifted or falling), so a push moves it about
as far as the hand travels plus ≲ 0.5 (v²/2μg at the hand's top speed). Hand–block and
block–block contacts are frictionless: a push moves the block along the normal of the face that
is pushed. The table top is rigid (a block that sank into it after a drop is put back on it).
The table spans x ∈ [−17, 4], y ∈ [−6, 4]: its left (+x) and far (+y) edges are within pushing
reach (the reference's T_L and T_T landmarks near 0, Table 8.1), and it reaches far to the
robot's right (the T_R landmarks at 12.3–21.1), so a block pushed right or towards the robot
stays on the table, out of reach, and is replaced.

Frame (the reference's, Table 8.1 and §8.1.1): **+x is the robot's left**, +y is forward (away
from the robot), +z is up.

Sticky-mitten grasp (§7.1): the block is grasped when hand and block touch and the hand's centre
is within 1.5 of the block's centre in x–y; each grasped step it is let go with probability 0.1
(or when u_UG > 0.5), and when let go it is moved to a new place with probability 0.5. The block is
replaced when it hits the floor (bang is true on that step; it is replaced at the start of the
next), when it is out of reach and still, or when it has been out of reach for 100 steps
(footnote 1). A replaced or moved block, and a hand or block placed between steps (``set_hand``,
``place_block``), make the next observation a discontinuity (``World.discontinuity``).

Variants (options of this one world, ``make("core:VARIANT[:OPTION]")``):

* ``floating`` — two balls drifting out of reach (§7.4.1): f1_x … f2_z.
* ``random1`` / ``random2`` — floating plus 3 / 6 uniform [0, 1) variables r1 … r6 (§7.6.1).
* ``relevant1`` / ``relevant2`` — the extra hand/block edge variables of §7.6.1.
* ``secondary:aligned`` / ``secondary:unaligned`` — a second block out of reach on a larger table
  (§7.8.1): x_BB, y_BB, z_BB, m_BB added; z_F, T_L, T_R, T_T and bang removed.
* ``contingent:rising`` / ``contingent:jump`` — floating, with ball 1 contingent on the hand
  (§7.9.1).
* ``transfer[:STEP]`` — bang and z_F withheld until agent step STEP (default 150000, §7.5).
"""

from __future__ import annotations

import math
from pathlib import Path
from types import MappingProxyType
from typing import Any

import mujoco
import numpy as np

from worlds.base import VariableSpec, VarKind, World, with_resolution
from worlds.core.floating import FloatingBalls
from worlds.core.geometry import (
    HAND_HALF,
    HAND_HALF_Z,
    HAND_HIGH,
    HAND_LOW,
    HAND_OFFSET,
    RESOLUTION,
)
from worlds.core.tasks import core_tasks

__all__ = ["CoreWorld", "make_core"]

XML = Path(__file__).with_name("core.xml")

TIMESTEP = 0.025
SUBSTEPS = 2

TABLE_TOP = 10.5
#: The table's edges (reference frame): x_right, x_left, y_near, y_far. The left and far edges are
#: within pushing reach (the reference's T_L and T_T landmarks near 0, Table 8.1, are the edges a
#: block falls off); the table reaches 17 beyond the hand's centre to the robot's right (its T_R
#: landmarks at 12.3–21.1 put the right edge about 21 from the left one) and 6 towards the robot.
TABLE_CORE = (-17.0, 4.0, -6.0, 4.0)
TABLE_SECONDARY = (-9.0, 9.0, -6.0, 8.0)
REACH = (
    HAND_LOW[0] - HAND_HALF,
    HAND_HIGH[0] + HAND_HALF,
    HAND_LOW[1] - HAND_HALF,
    HAND_HIGH[1] + HAND_HALF,
)
PLACE_X = (-3.0, 3.0)  # where a block's centre is placed (§7.2.1: within reach)
PLACE_Y = (-2.0, 3.0)
#: A block's centre is placed at least this far from an edge it can fall off (it falls when its
#: centre passes the edge): a push of a few steps does not drop it, a longer one can.
EDGE_MARGIN = 1.0
WIDTH = (1.0, 3.0)
BLOCK_MASS = 0.25
#: The block's sliding friction on the table: Coulomb friction of this times its weight on its x
#: and y slides (decelerating it at 0.6 × 140 = 84 units/s²; core.xml's contacts are frictionless).
BLOCK_FRICTION = 0.6
TABLE_HALF_Z = 1.0  # half the thickness of the table's top (core.xml)
FOOT_RADIUS = 0.05  # the block's foot (core.xml)
#: How deep a resting block's foot is placed into the table top, so that the contact holds it
#: from the first substep (at depth 0 MuJoCo has no contact yet and the block would drop).
REST_DEPTH = 1e-4

GRASP_DISTANCE = 1.5
LET_GO_PROB = 0.1
MOVE_ON_LET_GO_PROB = 0.5
UNGRASP_THRESHOLD = 0.5
OUT_OF_REACH_STEPS = 100
STILL_SPEED = 0.1  # units per second

FORCE = 1000.0

VARIANTS = (
    "floating",
    "random1",
    "random2",
    "relevant1",
    "relevant2",
    "secondary",
    "contingent",
    "transfer",
)


def _m(name: str, meaning: str, available_from: int = 0) -> VariableSpec:
    return VariableSpec(name, VarKind.MAGNITUDE, meaning, available_from=available_from)


def _n(name: str, meaning: str, available_from: int = 0) -> VariableSpec:
    return VariableSpec(
        name, VarKind.NOMINAL, meaning, values=("false", "true"), available_from=available_from
    )


MOTORS = (
    VariableSpec("u_x", VarKind.MOTOR, "force on the hand in x; + pushes it left", -FORCE, FORCE),
    VariableSpec(
        "u_y", VarKind.MOTOR, "force on the hand in y; + pushes it forward", -FORCE, FORCE
    ),
    VariableSpec("u_z", VarKind.MOTOR, "force on the hand in z; + pushes it up", -FORCE, FORCE),
    VariableSpec(
        "u_UG", VarKind.MOTOR, "ungrasp: a value above 0.5 lets go of the block", 0.0, 1.0
    ),
)
HAND = (
    _m("h_x", "hand centre x (global); + is the robot's left, range [-2.5, 2.5]"),
    _m("h_y", "hand centre y (global); + is forward (away from the robot), range [-2, 3]"),
    _m("h_z", "hand centre z (global, floor = 0); + is up, range [11, 14.5]"),
)
EDGES = (
    _m(
        "y_TB",
        "far (top) side of hand minus near (bottom) side of block, y; 0: touching, "
        "pushing it forward",
    ),
    _m("y_BT", "near side of hand minus far side of block, y; 0: touching, pushing it back"),
    _m("x_RL", "right side of hand minus left side of block, x; 0: touching, pushing it right"),
    _m("x_LR", "left side of hand minus right side of block, x; 0: touching, pushing it left"),
    _m("z_BT", "bottom of hand minus top of block, z; 0: resting on it, < 0: beside it"),
)
FLOOR = _m("z_F", "bottom of block above the floor; 10.5 on the table, 0 on the floor")
TABLE_EDGES = (
    _m("T_L", "block centre minus the table's left edge, x; < 0 on the table, rises moving left"),
    _m("T_R", "block centre minus the table's right edge, x; > 0 on the table, falls moving right"),
    _m("T_T", "block centre minus the table's far edge, y; < 0 on the table, rises moving forward"),
)
CENTRE = (
    _m("c_x", "hand centre minus block centre, x; + when the hand is left of the block"),
    _m("c_y", "hand centre minus block centre, y; + when the hand is beyond the block"),
)
GRASPED = _n("T", "block is grasped (touching, and hand–block centre distance in x–y < 1.5)")
BANG = _n("bang", "true on the step the block hits the floor (it is replaced on the next step)")
FLOATS = tuple(
    _m(f"f{i}_{axis}", f"floating ball {i} position in {axis} (global); out of reach")
    for i in (1, 2)
    for axis in "xyz"
)
RANDOMS = tuple(_m(f"r{i}", "uniform random in [0, 1), irrelevant (§7.6.1)") for i in range(1, 7))
RELEVANT1 = (
    _m("y_TT", "far side of hand minus far side of block, y"),
    _m("x_LL", "left side of hand minus left side of block, x"),
    _m("b_TY", "far side of block, y (global)"),
    _m("b_LX", "left side of block, x (global)"),
    _m("h_TY", "far side of hand, y (global)"),
    _m("h_LX", "left side of hand, x (global)"),
)
RELEVANT2 = (
    _m("y_BB", "near side of hand minus near side of block, y"),
    _m("x_RR", "right side of hand minus right side of block, x"),
    _m("b_BY", "near side of block, y (global)"),
    _m("b_RX", "right side of block, x (global)"),
    _m("h_BY", "near side of hand, y (global)"),
    _m("h_RX", "right side of hand, x (global)"),
)
SECONDARY = (
    _m("x_BB", "gap between the two blocks in x (|Δx| − half widths); ≤ 0 overlapping in x"),
    _m("y_BB", "gap between the two blocks in y; ≤ 0 overlapping in y"),
    _m("z_BB", "gap between the two blocks in z; ≤ 0 overlapping in z"),
    _n("m_BB", "the two blocks are touching"),
)


class CoreWorld(World):
    """The core table world; see the module docstring for the physics and the variants."""

    substeps = SUBSTEPS
    step_seconds = TIMESTEP * SUBSTEPS

    def __init__(
        self,
        variant: str | None = None,
        option: str | None = None,
        *,
        transfer_step: int = 150_000,
    ) -> None:
        if variant is not None and variant not in VARIANTS:
            raise ValueError(f"core has no variant {variant!r}; variants: {', '.join(VARIANTS)}")
        self.variant = variant
        self.secondary = variant == "secondary"
        self.placement = option or "aligned"
        if self.secondary and self.placement not in ("aligned", "unaligned"):
            raise ValueError(f"core:secondary takes 'aligned' or 'unaligned', got {option!r}")
        contingent = None
        if variant == "contingent":
            contingent = option or "rising"
            if contingent not in ("rising", "jump"):
                raise ValueError(f"core:contingent takes 'rising' or 'jump', got {option!r}")
        if variant == "transfer" and option is not None:
            try:
                transfer_step = int(option)
            except ValueError:
                transfer_step = -1
            if transfer_step < 0:
                raise ValueError(f"core:transfer takes a step number >= 0, got {option!r}")
        elif variant != "transfer" and variant not in ("secondary", "contingent") and option:
            raise ValueError(f"core:{variant} takes no option, got {option!r}")
        self.name = "core" + (f":{variant}" if variant else "") + (f":{option}" if option else "")
        floating = variant in ("floating", "random1", "random2", "contingent")
        self.balls = FloatingBalls(2, contingent) if floating else None
        self.n_random = {"random1": 3, "random2": 6}.get(variant or "", 0)
        self.relevant = {"relevant1": 1, "relevant2": 2}.get(variant or "", 0)
        self.table = TABLE_SECONDARY if self.secondary else TABLE_CORE

        late = transfer_step if variant == "transfer" else 0
        variables: list[VariableSpec] = [*MOTORS, *HAND, *EDGES]
        if not self.secondary:
            variables.append(
                VariableSpec(FLOOR.name, FLOOR.kind, FLOOR.meaning, available_from=late)
            )
            variables.extend(TABLE_EDGES)
        variables.extend(CENTRE)
        variables.append(GRASPED)
        if not self.secondary:
            variables.append(_n(BANG.name, BANG.meaning, available_from=late))
        if self.balls is not None:
            variables.extend(FLOATS)
        variables.extend(RANDOMS[: self.n_random])
        if self.relevant >= 1:
            variables.extend(RELEVANT1)
        if self.relevant >= 2:
            variables.extend(RELEVANT2)
        if self.secondary:
            variables.extend(SECONDARY)
        self._init_variables(with_resolution(tuple(variables), RESOLUTION))
        names = {v.name for v in variables}
        self.rare_variables = tuple(n for n in ("T", "bang", "m_BB") if n in names)
        self._build_model()

        self.tasks = MappingProxyType(core_tasks(self))
        self.agent_options = MappingProxyType({})
        self.reset(seed=0)

    # --- model ------------------------------------------------------------------------------

    def _build_model(self) -> None:
        spec = mujoco.MjSpec.from_file(str(XML))
        spec.option.timestep = TIMESTEP
        if not self.secondary:
            spec.delete(spec.body("block2"))
        if self.balls is None:
            spec.delete(spec.body("float1"))
            spec.delete(spec.body("float2"))
        for block in ("block", "block2") if self.secondary else ("block",):
            spec.geom(block).mass = BLOCK_MASS
        #: Coulomb friction on a block's x and y slides while its foot touches the table or the
        #: floor (switched off while it is lifted or falls).
        self._sliding_friction = BLOCK_FRICTION * BLOCK_MASS * -float(spec.option.gravity[2])
        x_right, x_left, y_near, y_far = self.table
        half_x, half_y = (x_left - x_right) / 2, (y_far - y_near) / 2
        leg = (TABLE_TOP - 2 * TABLE_HALF_Z) / 2
        table = spec.body("table")
        # MuJoCo's x is the reference's −x.
        table.pos = [-(x_left + x_right) / 2, (y_far + y_near) / 2, TABLE_TOP - TABLE_HALF_Z]
        spec.geom("table").size = [half_x, half_y, TABLE_HALF_Z]
        for name, sx, sy in (("leg1", 1, 1), ("leg2", -1, 1), ("leg3", 1, -1), ("leg4", -1, -1)):
            geom = spec.geom(name)
            geom.pos = [sx * (half_x - 0.4), sy * (half_y - 0.4), -TABLE_HALF_Z - leg]
            geom.size = [0.25, 0.25, leg]
        self.model = model = spec.compile()
        self.data = mujoco.MjData(model)
        gid = lambda name: mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, name)  # noqa: E731
        bid = lambda name: mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)  # noqa: E731
        jid = lambda name: mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)  # noqa: E731
        ng = model.ngeom
        pair = lambda a, b: min(a, b) * ng + max(a, b)  # noqa: E731
        self._g_hand, self._g_block, self._g_floor = gid("hand"), gid("block"), gid("floor")
        self._g_foot = gid("block_foot")
        self._b_hand, self._b_block = bid("hand"), bid("block")
        self._pair_hand_block = pair(self._g_hand, self._g_block)
        self._pair_floor_block = pair(self._g_floor, self._g_foot)
        self._pair_table_block = pair(gid("table"), self._g_foot)
        # The block's three slide joints x, y, z are consecutive in qpos and qvel.
        self._qadr_block = model.jnt_qposadr[jid("block_x")]
        self._vadr_block = model.jnt_dofadr[jid("block_x")]
        if self.secondary:
            self._g_block2, self._b_block2 = gid("block2"), bid("block2")
            self._g_foot2 = gid("block2_foot")
            self._pair_blocks = pair(self._g_block, self._g_block2)
            self._pair_floor_block2 = pair(self._g_floor, self._g_foot2)
            self._pair_table_block2 = pair(gid("table"), self._g_foot2)
            self._qadr_block2 = model.jnt_qposadr[jid("block2_x")]
            self._vadr_block2 = model.jnt_dofadr[jid("block2_x")]
        self._eq_grasp = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_EQUALITY, "grasp")
        self._hand_range = [
            tuple(float(r) for r in model.jnt_range[jid(name)])
            for name in ("hand_x", "hand_y", "hand_z")
        ]

    def _set_width(self, geom: int, foot: int, width: float) -> None:
        """Resize a block's box (a cube of ``width``) and keep its foot at the bottom's centre."""
        m = self.model
        half = width / 2
        m.geom_size[geom] = (half, half, half)
        m.geom_rbound[geom] = half * math.sqrt(3.0)
        m.geom_aabb[geom] = (0.0, 0.0, 0.0, half, half, half)
        m.geom_pos[foot] = (0.0, 0.0, -half + FOOT_RADIUS)

    # --- placing things ---------------------------------------------------------------------

    def set_hand(self, x: float, y: float, z: float) -> None:
        """Put the hand at (x, y, z) (reference frame), at rest. Releases a grasped block.

        A teleport: the next observation is marked as a discontinuity."""
        self._release()
        self._mark_discontinuity()
        q = self.data.qpos
        q[0] = min(max(x, HAND_LOW[0]), HAND_HIGH[0]) - HAND_OFFSET[0]
        q[1] = min(max(y, HAND_LOW[1]), HAND_HIGH[1]) - HAND_OFFSET[1]
        q[2] = min(max(z, HAND_LOW[2]), HAND_HIGH[2]) - HAND_OFFSET[2]
        self.data.qvel[:3] = 0.0
        mujoco.mj_forward(self.model, self.data)

    def random_hand(self, rng: np.random.Generator) -> None:
        """Move the hand to a random place within its limits (task set-up, §7.2.1)."""
        self.set_hand(
            *(float(rng.uniform(lo, hi)) for lo, hi in zip(HAND_LOW, HAND_HIGH, strict=True))
        )

    def _put_block(self, qadr: int, vadr: int, x: float, y: float, width: float) -> None:
        self.data.qpos[qadr : qadr + 3] = (-x, y, TABLE_TOP + width / 2 - REST_DEPTH)
        self.data.qvel[vadr : vadr + 3] = 0.0
        self._support(vadr, True)

    def _support(self, vadr: int, supported: bool) -> None:
        """Switch the block's sliding friction on (its foot is on the table or the floor) or off
        (lifted in the hand, or falling)."""
        self.model.dof_frictionloss[vadr : vadr + 2] = self._sliding_friction if supported else 0.0

    def place_block(
        self,
        rng: np.random.Generator,
        x: float | None = None,
        y: float | None = None,
        width: float | None = None,
    ) -> None:
        """Put the block at a random place within reach (or at the given one), clear of the hand.

        The centre is drawn in ``PLACE_X`` × ``PLACE_Y``, at least ``EDGE_MARGIN`` from the
        table's edges. In the secondary variant the second block is placed again too (aligned or
        unaligned). A teleport: the next observation is marked as a discontinuity.
        """
        self._release()
        self._mark_discontinuity()
        width = float(rng.uniform(*WIDTH)) if width is None else width
        hx, hy, hz = self.hand_position()
        x_right, x_left, _, y_far = self.table
        lo_x = max(PLACE_X[0], x_right + EDGE_MARGIN)
        hi_x = min(PLACE_X[1], x_left - EDGE_MARGIN)
        hi_y = min(PLACE_Y[1], y_far - EDGE_MARGIN)
        bx, by = x, y
        for _ in range(50):
            bx = float(rng.uniform(lo_x, hi_x)) if x is None else x
            by = float(rng.uniform(PLACE_Y[0], hi_y)) if y is None else y
            clear = (
                abs(bx - hx) > HAND_HALF + width / 2 + 0.05
                or abs(by - hy) > HAND_HALF + width / 2 + 0.05
                or hz - HAND_HALF_Z > TABLE_TOP + width + 0.05
            )
            if clear or (x is not None and y is not None):
                break
        else:  # no clear place found: lift the hand out of the way
            self.set_hand(hx, hy, HAND_HIGH[2])
        self.width = width
        self._set_width(self._g_block, self._g_foot, width)
        self._put_block(self._qadr_block, self._vadr_block, bx, by, width)
        if self.secondary:
            self._place_secondary(rng, bx, by)
        self._out_of_reach_steps = 0
        mujoco.mj_forward(self.model, self.data)

    def _place_secondary(self, rng: np.random.Generator, bx: float, by: float) -> None:
        """§7.8.2: aligned — same y as the block, random x between it and the table's edge, out
        of reach; unaligned — at the left or right edge of the table, random x and y there."""
        width2 = float(rng.uniform(*WIDTH))
        x_right, x_left, y_near, y_far = self.table
        side = 1.0 if rng.random() < 0.5 else -1.0
        edge = x_left if side > 0 else x_right
        inner = (REACH[1] if side > 0 else REACH[0]) + side * (width2 / 2 + 0.3)
        outer = edge - side * (width2 / 2 + 0.3)
        x2 = float(rng.uniform(min(inner, outer), max(inner, outer)))
        if self.placement == "aligned":
            y2 = by
        else:
            y2 = float(rng.uniform(y_near + width2 / 2 + 0.3, y_far - width2 / 2 - 0.3))
        self.width2 = width2
        self._set_width(self._g_block2, self._g_foot2, width2)
        self._put_block(self._qadr_block2, self._vadr_block2, x2, y2, width2)

    def hand_position(self) -> tuple[float, float, float]:
        """The hand centre (x, y, z) in the reference frame."""
        q = self.data.qpos
        return (
            float(q[0]) + HAND_OFFSET[0],
            float(q[1]) + HAND_OFFSET[1],
            float(q[2]) + HAND_OFFSET[2],
        )

    def block_position(self) -> tuple[float, float, float]:
        """The block centre (x, y, z) in the reference frame."""
        a = self._qadr_block
        x, y, z = self.data.qpos[a : a + 3].tolist()
        return -x, y, z

    # --- grasp ------------------------------------------------------------------------------

    def _grasp(self) -> None:
        m, d = self.model, self.data
        hp, hq = d.xpos[self._b_hand], d.xquat[self._b_hand]
        bp, bq = d.xpos[self._b_block], d.xquat[self._b_block]
        inv = np.empty(4)
        mujoco.mju_negQuat(inv, hq)
        rel_pos = np.empty(3)
        mujoco.mju_rotVecQuat(rel_pos, bp - hp, inv)
        rel_quat = np.empty(4)
        mujoco.mju_mulQuat(rel_quat, inv, bq)
        m.eq_data[self._eq_grasp, 3:6] = rel_pos
        m.eq_data[self._eq_grasp, 6:10] = rel_quat
        d.eq_active[self._eq_grasp] = 1
        self.grasped = True

    def _release(self) -> None:
        if getattr(self, "grasped", False):
            self.data.eq_active[self._eq_grasp] = 0
        self.grasped = False

    # --- the contract -----------------------------------------------------------------------

    def _reset(self) -> dict[str, float]:
        mujoco.mj_resetData(self.model, self.data)
        self.grasped = False
        self.bang = False
        self.touching_blocks = False
        self.block_replaced = False
        self.block_out_of_reach = False
        self._pending_replace = False
        self._out_of_reach_steps = 0
        self._last_hz = HAND_OFFSET[2]
        self.set_hand(*HAND_OFFSET)
        self.place_block(self.rng)
        if self.balls is not None:
            self.balls.reset(self.rng)
        self._randoms = self.rng.random(self.n_random).tolist() if self.n_random else []
        return self._observe()

    def _step(self, motor: list[float]) -> dict[str, float]:
        rng = self.rng
        self.block_replaced = False
        if self._pending_replace:
            self._pending_replace = False
            self.place_block(rng)
            self.block_replaced = True
        released = False
        if self.grasped and (motor[3] > UNGRASP_THRESHOLD or rng.random() < LET_GO_PROB):
            self._release()
            released = True
            if rng.random() < MOVE_ON_LET_GO_PROB:
                self.place_block(rng)
                self.block_replaced = True
        d = self.data
        ctrl = d.ctrl
        ctrl[0], ctrl[1], ctrl[2] = motor[0], motor[1], motor[2]
        mujoco.mj_step(self.model, d, SUBSTEPS)
        self._hard_stops()
        self._rest_on_table(self._qadr_block, self._vadr_block, self.width)
        if self.secondary:
            self._rest_on_table(self._qadr_block2, self._vadr_block2, self.width2)

        # Contacts of the last substep, as sorted geom-pair codes.
        pairs: set[int] = set()
        n = d.ncon
        if n:
            g = d.contact.geom[:n]
            pairs = set((g.min(axis=1) * self.model.ngeom + g.max(axis=1)).tolist())
        hx, hy, hz = self.hand_position()
        bx, by, bz = self.block_position()
        if not self.grasped and not released and self._pair_hand_block in pairs:
            if (hx - bx) ** 2 + (hy - by) ** 2 < GRASP_DISTANCE**2:
                self._grasp()
        self.bang = self._pair_floor_block in pairs
        self._support(self._vadr_block, self.bang or self._pair_table_block in pairs)
        if self.secondary:
            self.touching_blocks = self._pair_blocks in pairs
            self._support(
                self._vadr_block2,
                self._pair_floor_block2 in pairs or self._pair_table_block2 in pairs,
            )
        half = self.width / 2
        out = (
            bx - half > REACH[1]
            or bx + half < REACH[0]
            or by - half > REACH[3]
            or by + half < REACH[2]
            or bz + half < HAND_LOW[2] - HAND_HALF_Z
        )
        self.block_out_of_reach = out
        if out:
            self._out_of_reach_steps += 1
            v = self._vadr_block
            speed = math.sqrt(float(d.qvel[v] ** 2 + d.qvel[v + 1] ** 2 + d.qvel[v + 2] ** 2))
            if speed < STILL_SPEED or self._out_of_reach_steps >= OUT_OF_REACH_STEPS:
                self._pending_replace = True
        else:
            self._out_of_reach_steps = 0
        if self.bang or (self.secondary and self._pair_floor_block2 in pairs):
            self._pending_replace = True
        if self.balls is not None:
            self.balls.step(rng, hz, hz - self._last_hz)
        self._last_hz = hz
        if self.n_random:
            self._randoms = rng.random(self.n_random).tolist()
        return self._observe()

    # --- the state (exact resume) -----------------------------------------------------------

    replayable = False
    STATE_SIG = mujoco.mjtState.mjSTATE_INTEGRATION
    """What ``mj_getState`` saves: everything ``mj_step`` reads (time, qpos, qvel, act,
    controls, applied forces, equality activation, mocap, the warm start)."""

    def _get_state(self) -> dict[str, Any]:
        """mjData's integration state, the model values this world changes (block widths,
        the grasp weld's relative pose, the blocks' sliding friction) and the bookkeeping."""
        m, d = self.model, self.data
        sig = int(self.STATE_SIG)
        physics = np.empty(mujoco.mj_stateSize(m, sig))
        mujoco.mj_getState(m, d, physics, sig)
        state: dict[str, Any] = {
            "mj_state": physics.tolist(), "nq": int(m.nq), "nv": int(m.nv),
            "weld": m.eq_data[self._eq_grasp, 3:10].tolist(),
            "frictionloss": m.dof_frictionloss.tolist(),
            "width": self.width, "grasped": self.grasped, "bang": self.bang,
            "touching_blocks": self.touching_blocks, "block_replaced": self.block_replaced,
            "block_out_of_reach": self.block_out_of_reach,
            "pending_replace": self._pending_replace,
            "out_of_reach_steps": self._out_of_reach_steps, "last_hz": self._last_hz,
            "randoms": list(self._randoms),
        }
        if self.secondary:
            state["width2"] = self.width2
        if self.balls is not None:
            state["balls"] = {"pos": [list(p) for p in self.balls.pos],
                              "vel": [list(v) for v in self.balls.vel],
                              "restitution": self.balls.restitution}
        return state

    def _set_state(self, physics: Any) -> None:
        m, d = self.model, self.data
        sig = int(self.STATE_SIG)
        values = np.asarray(physics["mj_state"], dtype=float)
        size = mujoco.mj_stateSize(m, sig)
        if values.shape != (size,) or (physics["nq"], physics["nv"]) != (m.nq, m.nv):
            raise ValueError(f"{self.name}: mj_state holds {values.size} values for nq "
                             f"{physics['nq']}, nv {physics['nv']}; this model needs {size} "
                             f"(nq {m.nq}, nv {m.nv})")
        weld = np.asarray(physics["weld"], dtype=float)
        friction = np.asarray(physics["frictionloss"], dtype=float)
        if weld.shape != (7,) or friction.shape != m.dof_frictionloss.shape:
            raise ValueError(f"{self.name}: weld {weld.shape} or frictionloss "
                             f"{friction.shape} of the wrong shape")
        for name, array_ in (("mj_state", values), ("weld", weld), ("frictionloss", friction)):
            if not np.isfinite(array_).all():
                raise ValueError(f"{self.name}: {name} holds non-finite values")
        width = float(physics["width"])
        if not WIDTH[0] <= width <= WIDTH[1]:
            raise ValueError(f"{self.name}: block width {width} outside {WIDTH}")
        randoms = [float(r) for r in physics["randoms"]]
        if len(randoms) != self.n_random:
            raise ValueError(f"{self.name}: {len(randoms)} random values, expected "
                             f"{self.n_random}")
        balls = physics.get("balls")
        if (balls is None) != (self.balls is None):
            raise ValueError(f"{self.name}: floating balls in the state do not match the world")
        self.width = width
        self._set_width(self._g_block, self._g_foot, width)
        if self.secondary:
            self.width2 = float(physics["width2"])
            self._set_width(self._g_block2, self._g_foot2, self.width2)
        m.eq_data[self._eq_grasp, 3:10] = weld
        m.dof_frictionloss[:] = friction
        mujoco.mj_setState(m, d, values, sig)
        mujoco.mj_forward(m, d)
        self.grasped, self.bang = bool(physics["grasped"]), bool(physics["bang"])
        self.touching_blocks = bool(physics["touching_blocks"])
        self.block_replaced = bool(physics["block_replaced"])
        self.block_out_of_reach = bool(physics["block_out_of_reach"])
        self._pending_replace = bool(physics["pending_replace"])
        self._out_of_reach_steps = int(physics["out_of_reach_steps"])
        self._last_hz = float(physics["last_hz"])
        self._randoms = randoms
        if self.balls is not None:
            pos = [[float(v) for v in p] for p in balls["pos"]]
            vel = [[float(v) for v in p] for p in balls["vel"]]
            if len(pos) != self.balls.n or len(vel) != self.balls.n \
                    or any(len(p) != 3 for p in pos + vel):
                raise ValueError(f"{self.name}: floating balls of the wrong shape")
            self.balls.pos, self.balls.vel = pos, vel
            self.balls.restitution = float(balls["restitution"])

    def _hard_stops(self) -> None:
        """The arm's joint limits are hard stops: a hand that went past one (MuJoCo's limits are
        soft, and spring back over several steps) is put on it, its outward speed removed. So the
        hand rests exactly at a limit while pushed against it (no false ḣ → [−] after a hit)."""
        q, v = self.data.qpos, self.data.qvel
        for i in range(3):
            lo, hi = self._hand_range[i]
            if q[i] < lo:
                q[i] = lo
                v[i] = max(v[i], 0.0)
            elif q[i] > hi:
                q[i] = hi
                v[i] = min(v[i], 0.0)

    def _rest_on_table(self, qadr: int, vadr: int, width: float) -> None:
        """The table top is rigid: a block whose centre is over it and whose bottom sank into it
        (MuJoCo's soft contact lets a dropped block sink ~0.05 and rise back over several
        steps) is put on it, its downward speed removed."""
        q, v = self.data.qpos, self.data.qvel
        x, y, z = -float(q[qadr]), float(q[qadr + 1]), float(q[qadr + 2])
        x_right, x_left, y_near, y_far = self.table
        bottom = z - width / 2
        if (
            x_right <= x <= x_left
            and y_near <= y <= y_far
            and TABLE_TOP - 2 * TABLE_HALF_Z < bottom < TABLE_TOP - REST_DEPTH
        ):
            q[qadr + 2] = TABLE_TOP + width / 2 - REST_DEPTH
            v[vadr + 2] = max(float(v[vadr + 2]), 0.0)

    def restart_here(self) -> dict[str, float]:
        """:meth:`restart_from` the observation of the current state: what a task's setup
        calls after moving the hand or the block past ``reset()``."""
        return self.restart_from(self._observe())

    @property
    def replace_pending(self) -> bool:
        """The block fell, went out of reach or hit the other block: it is put back on the
        table at the next step."""
        return self._pending_replace

    def _observe(self) -> dict[str, float]:
        hx, hy, hz = self.hand_position()
        bx, by, bz = self.block_position()
        half = self.width / 2
        x_right, x_left, _, y_far = self.table
        obs = {
            "h_x": hx,
            "h_y": hy,
            "h_z": hz,
            "y_TB": (hy + HAND_HALF) - (by - half),
            "y_BT": (hy - HAND_HALF) - (by + half),
            "x_RL": (hx - HAND_HALF) - (bx + half),
            "x_LR": (hx + HAND_HALF) - (bx - half),
            "z_BT": (hz - HAND_HALF_Z) - (bz + half),
        }
        if not self.secondary:
            obs["z_F"] = bz - half
            obs["T_L"] = bx - x_left
            obs["T_R"] = bx - x_right
            obs["T_T"] = by - y_far
        obs["c_x"] = hx - bx
        obs["c_y"] = hy - by
        obs["T"] = 1.0 if self.grasped else 0.0
        if not self.secondary:
            obs["bang"] = 1.0 if self.bang else 0.0
        if self.balls is not None:
            for i, pos in enumerate(self.balls.pos, start=1):
                obs[f"f{i}_x"], obs[f"f{i}_y"], obs[f"f{i}_z"] = pos
        for i, r in enumerate(self._randoms, start=1):
            obs[f"r{i}"] = r
        if self.relevant:
            obs["y_TT"] = (hy + HAND_HALF) - (by + half)
            obs["x_LL"] = (hx + HAND_HALF) - (bx + half)
            obs["b_TY"] = by + half
            obs["b_LX"] = bx + half
            obs["h_TY"] = hy + HAND_HALF
            obs["h_LX"] = hx + HAND_HALF
            if self.relevant >= 2:
                obs["y_BB"] = (hy - HAND_HALF) - (by - half)
                obs["x_RR"] = (hx - HAND_HALF) - (bx - half)
                obs["b_BY"] = by - half
                obs["b_RX"] = bx - half
                obs["h_BY"] = hy - HAND_HALF
                obs["h_RX"] = hx - HAND_HALF
        if self.secondary:
            a = self._qadr_block2
            x2, y2, z2 = self.data.qpos[a : a + 3].tolist()
            x2 = -x2
            half2 = self.width2 / 2
            obs["x_BB"] = abs(x2 - bx) - half - half2
            obs["y_BB"] = abs(y2 - by) - half - half2
            obs["z_BB"] = abs(z2 - bz) - half - half2
            obs["m_BB"] = 1.0 if self.touching_blocks else 0.0
        return obs

    # --- pictures ---------------------------------------------------------------------------

    def sync_visuals(self) -> None:
        """Copy the kinematic floating balls into the MuJoCo scene (for pictures)."""
        if self.balls is not None:
            for i, (x, y, z) in enumerate(self.balls.pos):
                self.data.mocap_pos[i] = (-x, y, z)

    def render_text(self, width: int = 60, height: int = 20) -> str:
        """A top-down drawing: '.' table, '#' block, 'B' second block, 'H'/'h' hand (low/high:
        below or above the block's top), 'o' floating balls; left of the picture is the robot's
        left (+x), the top is the far side (+y)."""
        x_right, x_left, y_near, y_far = self.table
        x_max, x_min = x_left + 1.5, x_right - 1.5
        y_max = max(y_far, 10.0 if self.balls is not None else y_far) + 1.0
        y_min = y_near - 1.0
        rows = max(height - 2, 4)
        grid = [[" "] * width for _ in range(rows)]

        def cell(x: float, y: float) -> tuple[int, int]:
            c = int((x_max - x) / (x_max - x_min) * (width - 1) + 0.5)
            r = int((y_max - y) / (y_max - y_min) * (rows - 1) + 0.5)
            return r, c

        def fill(x0: float, x1: float, y0: float, y1: float, ch: str) -> None:
            r0, c0 = cell(x1, y1)
            r1, c1 = cell(x0, y0)
            for r in range(max(r0, 0), min(r1, rows - 1) + 1):
                for c in range(max(c0, 0), min(c1, width - 1) + 1):
                    grid[r][c] = ch

        fill(x_right, x_left, y_near, y_far, ".")
        obs = self.observation
        bx, by, bz = self.block_position()
        half = self.width / 2
        if bz > 0.5 * TABLE_TOP:
            fill(bx - half, bx + half, by - half, by + half, "#")
        if self.secondary:
            a = self._qadr_block2
            x2, y2 = -float(self.data.qpos[a]), float(self.data.qpos[a + 1])
            h2 = self.width2 / 2
            fill(x2 - h2, x2 + h2, y2 - h2, y2 + h2, "B")
        hx, hy, hz = self.hand_position()
        ch = "h" if obs.get("z_BT", 0.0) > 0 else "H"
        fill(hx - HAND_HALF, hx + HAND_HALF, hy - HAND_HALF, hy + HAND_HALF, ch)
        if self.balls is not None:
            for x, y, _ in self.balls.pos:
                r, c = cell(x, y)
                if 0 <= r < rows and 0 <= c < width:
                    grid[r][c] = "o"
        status = (
            f"{self.name} t={self.step_count} hand=({hx:.1f},{hy:.1f},{hz:.1f}) "
            f"T={int(self.grasped)} bang={int(self.bang)}"
        )
        return "\n".join([status[:width], *("".join(row) for row in grid)])

    def scene(self, values: dict[str, float] | None = None) -> list[dict[str, Any]]:
        """The bodies as boxes and spheres, for a 3D view (the recorder's foxglove.SceneUpdate).

        Each body is ``{"id", "shape": "box" | "sphere", "centre": (x, y, z), "size": (sx, sy,
        sz), "rgba": (r, g, b, a)}``, sizes being full extents, in a right-handed frame with z up:
        MuJoCo's, whose x is the reference's −x (so the hand's centre is (−h_x, h_y, h_z)). The
        table (its top and legs) comes from the variant's geometry; the hand (the 3 × 3 × 0.5
        palm), the block (a cube of its current width) and the floating balls from ``values``, an
        observation such as a recorded ``sense`` (default: the current observation): block
        centre (h_x − c_x, h_y − c_y, h_z − 0.25 − z_BT − w/2), width w = x_LR − x_RL − 3. The
        second block of ``secondary`` is not observable: it is drawn only without ``values``.
        """

        def body(name: str, centre: Any, size: Any, rgba: Any, shape: str = "box") -> dict:
            return {"id": name, "shape": shape, "centre": centre, "size": size, "rgba": rgba}

        obs = self.observation if values is None else values
        x_right, x_left, y_near, y_far = self.table
        half_x, half_y = (x_left - x_right) / 2, (y_far - y_near) / 2
        tx, ty = -(x_left + x_right) / 2, (y_far + y_near) / 2
        leg = TABLE_TOP - 2 * TABLE_HALF_Z
        top = (tx, ty, TABLE_TOP - TABLE_HALF_Z)
        bodies = [
            body("table", top, (2 * half_x, 2 * half_y, 2 * TABLE_HALF_Z), (0.62, 0.45, 0.28, 1))
        ]
        for i, (sx, sy) in enumerate(((1, 1), (-1, 1), (1, -1), (-1, -1)), start=1):
            centre = (tx + sx * (half_x - 0.4), ty + sy * (half_y - 0.4), leg / 2)
            bodies.append(body(f"table_leg{i}", centre, (0.5, 0.5, leg), (0.45, 0.32, 0.20, 1)))
        hx, hy, hz = obs["h_x"], obs["h_y"], obs["h_z"]
        palm = (2 * HAND_HALF, 2 * HAND_HALF, 2 * HAND_HALF_Z)
        bodies.append(body("hand", (-hx, hy, hz), palm, (0.95, 0.80, 0.25, 1)))
        width = obs["x_LR"] - obs["x_RL"] - 2 * HAND_HALF
        centre = (obs["c_x"] - hx, hy - obs["c_y"], hz - HAND_HALF_Z - obs["z_BT"] - width / 2)
        bodies.append(body("block", centre, (width,) * 3, (0.85, 0.15, 0.15, 1)))
        if self.secondary and values is None:
            a = self._qadr_block2
            centre = tuple(self.data.qpos[a : a + 3].tolist())
            bodies.append(body("block2", centre, (self.width2,) * 3, (0.15, 0.55, 0.85, 1)))
        for i, rgba in ((1, (0.90, 0.20, 0.60, 1)), (2, (0.30, 0.85, 0.35, 1))):
            if f"f{i}_x" in obs:
                centre = (-obs[f"f{i}_x"], obs[f"f{i}_y"], obs[f"f{i}_z"])
                bodies.append(body(f"ball{i}", centre, (1.0, 1.0, 1.0), rgba, "sphere"))
        return bodies


def make_core(variant: str | None = None, option: str | None = None, **options: Any) -> CoreWorld:
    """Registry factory for ``core[:variant[:option]]``."""
    return CoreWorld(variant, option, **options)
