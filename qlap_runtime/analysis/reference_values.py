"""The reference's figures that ``qlap report`` prints beside a run's, as data in one place.

Every value is read from J. Mugan, *Autonomous Qualitative Learning of Distinctions and Actions
in a Developing Agent*, PhD dissertation, UT Austin, 2010 (section, table or figure in each
docstring); the targets are those issue 9 sets for a 250,000-step core agent.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType

__all__ = [
    "ABOVE_RANDOM",
    "ACTIONS",
    "CHANGE_DBNS",
    "CHANGE_DBN_LIMIT",
    "FRICTION_BAND",
    "GROWTH_AFTER",
    "GROWTH_TOLERANCE",
    "LANDMARKS_TABLE_8_1",
    "NARROW_RELATIVE",
    "SYNC_STEPS_PER_S",
    "TARGETS",
    "TASK_REWARD",
    "U_X_LANDMARKS",
    "WINDOW_K",
    "ReferenceAction",
]

WINDOW_K = 6
"""The window k of the core world: App. C learns it; §7.10.1 gives k = 6 as "the value for k
that was used in the Breve environment". Target: 4 ≤ k ≤ 8."""

CHANGE_DBNS = 250
"""Change DBNs of a core agent, about 250 and bounded over 250,000 steps (Fig. 7.9).
Target: ≤ 600 and no longer growing after 150,000 steps."""

CHANGE_DBN_LIMIT = 600
"""Target: at most this many change DBNs at the end of a 250,000-step core run."""

GROWTH_AFTER = 150_000
"""Target: the change DBNs no longer grow from this step on (Fig. 7.9: bounded, with drops
when the hand's actions become reliable and when DBNs reach the age limit of 100,000 steps)."""

GROWTH_TOLERANCE = 0.10
""""Not growing": the least-squares line through the change-DBN counts of the checkpoints from
:data:`GROWTH_AFTER` on rises, over those checkpoints, by at most this fraction of their mean
count (``qlap_runtime.analysis.timeline.growth_verdict``)."""

SYNC_STEPS_PER_S = 1500.0
"""Target (a benchmark, not a test): the synchronous loop averages at least this many steps
per second over a 250,000-step core run (summary.json's ``steps_per_s``)."""

TASK_REWARD = MappingProxyType({"move_block": 6.0, "hit_floor": 6.0, "pickup": 2.0})
"""Target: mean reward per trial at 250,000 steps, mean over 5 seeds, 100 trials each, core
world (§7.2's reward: +9.99 on success, −0.01 a step)."""

ABOVE_RANDOM = 2.0
"""Target: each task's final mean reward at least this much above the random policy's."""

LANDMARKS_TABLE_8_1 = MappingProxyType({
    "u_x": 3, "u_y": 3, "u_z": 2, "h_x": 4, "h_y": 3, "h_z": 3, "y_TB": 3, "y_BT": 2,
    "x_RL": 1, "x_LR": 2, "z_BT": 1, "z_F": 2, "T_L": 2, "T_R": 2, "T_T": 2, "c_x": 3,
    "c_y": 3,
})
"""Final landmarks per motor and magnitude variable of a typical core run (Table 8.1, the
initial landmark of a motor included): median 2, max 4. Target: median ≤ 4, max ≤ 9."""

NARROW_RELATIVE = 1e-3
"""A qualitative value narrower than this fraction of its magnitude counts as a sliver when the
variable declares no resolution. Table 8.1 has none (two decimals); target: none."""

U_X_LANDMARKS = ((-335.03, -333.53), (288.89, 331.27))
"""The landmarks on u_x besides the initial one: the force that overcomes friction, "at least
300 units to move the hand" (Table 8.1, §8.1.1)."""

FRICTION_BAND = (240.0, 360.0)
"""Issue 9's target: one u_x landmark centred in [240, 360] and one in [−360, −240]."""


TARGETS = MappingProxyType({
    "k": "4–8", "change_dbns": "≤ 600, flat after 150k", "landmarks_median": "≤ 4",
    "landmarks_max": "≤ 9", "narrow_count": "0", "u_x_band": "one each side",
})
"""Issue 9's targets for a 250,000-step core agent (5 seeds), as printed by ``qlap report``."""


@dataclass(frozen=True)
class ReferenceAction:
    """An action of §8.1.2 whose reliability rel(a) the reference reports."""

    variable: str
    """The action's variable as the agent names it (``h_x.dot`` is ḣ_x)."""
    value: str
    """The qualitative value, as knowledge.json labels it (``[+]``, ``true``)."""
    rel: float
    """rel(a) in the reference."""
    source: str
    """Where the reference gives it."""
    target: float
    """Issue 9's target for rel(a) (with a plan)."""


ACTIONS = (
    ReferenceAction("h_x.dot", "[+]", 0.97, "Table 8.2", 0.9),
    ReferenceAction("T_L.dot", "[+]", 0.28, "Table 8.4", 0.28),
    ReferenceAction("T", "true", 0.26, "Table 8.5", 0.26),
)
"""Move the hand left (Table 8.2), move the block left (Table 8.4), grab the block (Table 8.5)."""
