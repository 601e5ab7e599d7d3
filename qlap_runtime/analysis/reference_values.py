"""The reference's figures that ``qlap report`` prints beside a run's, as data in one place.

Every value is read from J. Mugan, *Autonomous Qualitative Learning of Distinctions and Actions
in a Developing Agent*, PhD dissertation, UT Austin, 2010 (section, table or figure in each
docstring); the targets are the project's own (docs/results.md) for a 250,000-step core agent,
and, beyond core, for a 100,000-step pong agent (§7.10). The results page judges a world by its
:class:`WorldTargets` (:func:`targets_for`): :data:`CORE_TARGETS` or :data:`PONG_TARGETS`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

__all__ = [
    "ABOVE_RANDOM",
    "ACTIONS",
    "CHANGE_DBNS",
    "CHANGE_DBN_LIMIT",
    "CORE_TARGETS",
    "FRICTION_BAND",
    "GROWTH_AFTER",
    "GROWTH_TOLERANCE",
    "LANDMARKS_TABLE_8_1",
    "NARROW_RELATIVE",
    "PONG_GROWTH_AFTER",
    "PONG_TARGETS",
    "SYNC_STEPS_PER_S",
    "TARGETS",
    "TASK_REWARD",
    "U_X_LANDMARKS",
    "WINDOW_K",
    "WORLD_TARGETS",
    "ReferenceAction",
    "WorldTargets",
    "targets_for",
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
"""The project's target (docs/results.md): one u_x landmark centred in [240, 360] and one in
[−360, −240]."""


TARGETS = MappingProxyType({
    "k": "4–8", "change_dbns": "≤ 600, flat after 150k", "landmarks_median": "≤ 4",
    "landmarks_max": "≤ 9", "narrow_count": "0", "u_x_band": "one each side",
})
"""The project's targets (docs/results.md) for a 250,000-step core agent (5 seeds), as printed
by ``qlap report``."""


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
    """The project's target for rel(a) (with a plan; docs/results.md)."""


ACTIONS = (
    ReferenceAction("h_x.dot", "[+]", 0.97, "Table 8.2", 0.9),
    ReferenceAction("T_L.dot", "[+]", 0.28, "Table 8.4", 0.28),
    ReferenceAction("T", "true", 0.26, "Table 8.5", 0.26),
)
"""Move the hand left (Table 8.2), move the block left (Table 8.4), grab the block (Table 8.5)."""


PONG_GROWTH_AFTER = 50_000
"""Pong's change DBNs no longer grow from this step on: half of a 100,000-step run, as
150,000 is three fifths of core's 250,000 (and at least six checkpoints to fit the line)."""


@dataclass(frozen=True)
class WorldTargets:
    """What the results page (``scripts/learning_results.py``) judges a world's runs against.

    A target set to None is not judged (the page shows the figure, marked n/a, or leaves the
    row out). Core's values are the project's targets (docs/results.md) for a 250,000-step core
    agent (the constants above); pong's those it sets beyond core: volleys clearly above the
    random policy with bounded knowledge, "plays somewhat well" (§7.10)."""

    world: str
    """The world (spec before any ``:variant``) these targets are set for."""
    steps: int
    """The protocol: agent steps of each run."""
    seeds: int
    """The protocol: at least this many seeds."""
    trials: int
    """The protocol: evaluation trials per checkpoint (§7.2)."""
    reward: str
    """What a task's mean reward per trial counts, for the page."""
    task_reward: Mapping[str, float] = field(default_factory=dict)
    """Final mean reward per task, mean over the seeds (core only: :data:`TASK_REWARD`)."""
    above_random: float | None = None
    """The final mean over the seeds at least this much above the random policy's mean."""
    clearly_above_random: float | None = None
    """"Clearly above the random policy": the final mean over the seeds above the random
    policy's mean by more than this many standard errors of the difference,
    √(s.e.² across seeds + s.e.² of the random policy over its trials), and every seed's
    final mean above the random policy's mean."""
    rise_from: int = 20_000
    """Each of the last three evaluated checkpoints above the mean at this step (the end of
    babbling)."""
    k_range: tuple[int, int] | None = (4, 8)
    """The window k (App. C) within these bounds."""
    change_dbn_limit: int = CHANGE_DBN_LIMIT
    growth_after: int = GROWTH_AFTER
    growth_tolerance: float = GROWTH_TOLERANCE
    landmarks_median: float | None = 4
    landmarks_max: int | None = 9
    chapter_8: bool = True
    """The core world's chapter-8 figures apply: the reference columns of Table 8.1 and
    Fig. 7.9, the u_x friction-threshold landmarks and the rel(a) of :data:`ACTIONS`."""
    steps_per_s: float | None = SYNC_STEPS_PER_S
    """Mean ``steps_per_s`` of the sync loop over the runs."""
    timeline_every: int = 50_000
    """The page's table of DBNs over time shows the checkpoints at multiples of this step
    (and the one at :attr:`rise_from`, and the last)."""
    note: str = ""
    """One paragraph on the page saying what the task targets are."""

    @property
    def actions(self) -> tuple[ReferenceAction, ...]:
        """The actions whose reliability is judged."""
        return ACTIONS if self.chapter_8 else ()


CORE_TARGETS = WorldTargets(
    world="core", steps=250_000, seeds=5, trials=100,
    reward="+9.99 on success, −0.01 a step, at most 300 steps; §7.2",
    task_reward=TASK_REWARD, above_random=ABOVE_RANDOM,
    note="Targets (for the core world at 250,000 steps): the final mean reward at least 6 on "
         "move_block and hit_floor and at least 2 on pickup; on every task at least 2 above "
         "the random policy; and a curve that rises: each of its last three checkpoints above "
         "its 20k value.")
"""The project's targets (docs/results.md) for 5 seeds × 250,000 steps of core (and the
core-like worlds: core2d and the variants, without the absolute rewards, which are core's)."""

PONG_TARGETS = WorldTargets(
    world="pong", steps=100_000, seeds=5, trials=100,
    reward="volleys per trial: +1 for each paddle hit, the trial ends at the first miss or "
           "after 2,000 steps; §7.10",
    clearly_above_random=2.0, growth_after=PONG_GROWTH_AFTER, landmarks_median=None,
    chapter_8=False, steps_per_s=None, timeline_every=10_000,
    note="Targets (for pong at 100,000 steps; the reference reports no figure but that QLAP "
         "\"plays somewhat well\", §7.10): the final volleys per trial *clearly* above the "
         "random policy's — the mean over the seeds above the random policy's mean by more "
         "than 2 standard errors of the difference, √(s.e.² across seeds + s.e.² of the "
         "random policy over its trials), and every seed above the random policy's mean; and "
         "a curve that rises: each of its last three checkpoints above its 20k value (the end "
         "of babbling).")
"""The project's targets (docs/results.md) beyond core, for 5 seeds × 100,000 steps of pong:
volleys clearly above the random policy, the curve rising, k, change DBNs ≤ 600 and not growing
from 50,000 steps, at most 9 landmarks per variable and none narrower than the resolution. Pong
fixes k = 6 (``agent_options``, §7.10.1); the chapter-8 figures and the speed target are core's."""

WORLD_TARGETS = MappingProxyType({"core": CORE_TARGETS, "pong": PONG_TARGETS})
"""The worlds with targets of their own; any other world is judged by core's."""


def targets_for(world: str) -> WorldTargets:
    """The targets of a world spec: pong's for ``pong`` (any variant), core's otherwise."""
    return WORLD_TARGETS.get(world.split(":", 1)[0], CORE_TARGETS)
