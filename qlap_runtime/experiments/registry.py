"""The experiments of chapter 7 (§7.4–7.11), by the names of issue 11.

Every experiment is a :class:`~.spec.Experiment` built from the reference's text: J. Mugan,
*Autonomous Qualitative Learning of Distinctions and Actions in a Developing Agent*, PhD
dissertation, UT Austin, 2010. The F tests of its captions and of Tables 7.2 and 7.4 are
:class:`~.spec.ReferenceStat` rows, printed beside the measured ones.
"""

from __future__ import annotations

from types import MappingProxyType

from .spec import (
    Arm,
    Condition,
    Experiment,
    ExperimentError,
    Panel,
    Preset,
    QTableConfig,
    ReferenceStat,
    TileConfig,
    versus,
)

__all__ = ["EXPERIMENTS", "get", "names"]

CORE_TASKS = ("move_block", "hit_floor", "pickup")
"""The core tasks (§7.2.2)."""

QLAP = Condition("QLAP", "qlap", description="the QLAP algorithm, exploring autonomously")
TILE_1 = Condition("Tile-1", "tile", tile=TileConfig(decision_every=1),
                   description="Sarsa(λ) with tile coding, an action every step (App. H)")
TILE_10 = Condition("Tile-10", "tile", tile=TileConfig(decision_every=10, decision_cost=-0.1),
                    description="Sarsa(λ) with tile coding, an action every 10 steps, −0.1 a "
                                "decision (§7.4.2, App. H)")


def _panel(key: str, title: str, arms: tuple[str, ...], base: str | None = None,
           tests: tuple[tuple[str, str], ...] = (), expect: str = "") -> Panel:
    """A panel whose arms are each compared with ``base`` (or the explicit ``tests``)."""
    return Panel(key, title, arms, versus(arms, base) if base else tests, expect)


def _ablation(name: str, switch: str, what: str) -> Condition:
    return Condition(name, "qlap", ablations=(switch,), description=what)


# ---------------------------------------------------------------------------------------------
# §7.4 QLAP against supervised learning (Figs. 7.2–7.4)
# ---------------------------------------------------------------------------------------------
_TASK_FIG = {"move_block": "7.2", "hit_floor": "7.3", "pickup": "7.4"}
_CORE_F = {  # (d), (e), (f) of Figs. 7.2–7.4
    "move_block": ((71.740, 0.000), (94.142, 0.000), (2.358, 0.133)),
    "hit_floor": ((49.703, 0.000), (0.583, 0.450), (19.779, 0.000)),
    "pickup": ((18.403, 0.000), (3.144, 0.084), (10.531, 0.002)),
}
CORE_TASKS_EXPERIMENT = Experiment(
    name="core-tasks", section="§7.4",
    title="QLAP against Sarsa(λ) with tile coding on the core tasks",
    claim="QLAP, doing undirected exploration and creating high-level actions on low-level "
          "foundations, performs as well or better than a supervised learning method with a "
          "performance goal pre-specified.",
    arms=(Arm("QLAP", "core", QLAP), Arm("Tile-1", "core", TILE_1),
          Arm("Tile-10", "core", TILE_10),
          Arm("QLAP float", "core:floating", QLAP),
          Arm("Tile-10 float", "core:floating", TILE_10)),
    tasks=CORE_TASKS,
    panels=(_panel("a", "QLAP and Tile-1 (core)", ("QLAP", "Tile-1"), base="QLAP",
                  expect="Tile-1 was not able to do any of the tasks well compared to QLAP "
                         "(high task diameter)"),
            _panel("b", "QLAP and Tile-10 (core)", ("QLAP", "Tile-10"), base="QLAP",
                  expect="Tile-10 does better on moving the block, about equal on hitting it "
                         "to the floor, QLAP better on picking it up"),
            _panel("c", "with the floating objects", ("QLAP", "Tile-10", "QLAP float",
                                                     "Tile-10 float"),
                  tests=(("Tile-10 float", "QLAP float"),),
                  expect="tile coding degrades with the distractors; QLAP does not, or only "
                         "slightly; (f) tests QLAP against Tile-10 with the floating objects")),
    reference=tuple(
        ReferenceStat(task, arm, versus, f, sig, f"Fig. {_TASK_FIG[task]}({letter})")
        for task, rows in _CORE_F.items()
        for (f, sig), letter, arm, versus in zip(
            rows, "def", ("Tile-1", "Tile-10", "Tile-10 float"),
            ("QLAP", "QLAP", "QLAP float"), strict=True)),
    notes=("Tile-1 was not able to do any of the tasks well compared to QLAP due to the high "
           "task diameter (Figs. 7.2–7.4 (a)).",
           "On the easiest task of hitting the block, Tile-10 does better. They do almost "
           "equally well on the task of making the block hit the floor, and QLAP does better "
           "on the task of picking up the block (Figs. 7.2–7.4 (b)).",
           "The performance of tile coding degrades when the distractor objects are added, but "
           "the performance of QLAP does not degrade, or degrades only slightly (Figs. 7.2–7.4 "
           "(c))."),
    figure_refs="Figs. 7.2–7.4")


# ---------------------------------------------------------------------------------------------
# §7.5 Transfer (Fig. 7.5)
# ---------------------------------------------------------------------------------------------
TRANSFER = Experiment(
    name="transfer", section="§7.5", title="transfer: actions learned without bang and z_F",
    claim="QLAP can do transfer learning by learning actions that can later be treated as "
          "primitive actions to build yet higher-level actions.",
    arms=(Arm("transfer", "core:transfer:{half}", QLAP, steps_fraction=1.0,
              eval_world="core", eval_from_fraction=0.5, offset_fraction=0.5),
          Arm("from scratch", "core", QLAP, steps_fraction=0.5)),
    tasks=("hit_floor",),
    panels=(_panel("a", "transfer and from scratch", ("transfer", "from scratch"),
                  base="from scratch",
                  expect="the transfer agent reuses the skills learned with the limited "
                         "variables to learn the task faster"),),
    steps=300_000, exclude_fraction=0.0,
    reference_protocol=(("agents", "20 (§7.5.2)"),
                        ("steps", "300,000: 150,000 + 150,000 (§7.5.2)")),
    reference=(ReferenceStat("hit_floor", "transfer", "from scratch", 6.739, 0.013,
                             "Fig. 7.5(b), over all 150,000 timesteps"),),
    notes=("The transfer agent learns 150,000 steps without bang and z_F, then 150,000 with "
           "them; it is drawn and tested over its second half against an agent learning "
           "150,000 steps from scratch (§7.5.2). The statistics are over all 150,000 "
           "timesteps (§7.5.3).",),
    figure_refs="Fig. 7.5",
    quick=Preset(steps=30_000, every=5_000))


# ---------------------------------------------------------------------------------------------
# §7.6 Extraneous variables (Figs. 7.6–7.9, Table 7.2) and the DBN count (Fig. 7.9)
# ---------------------------------------------------------------------------------------------
_EXTRA = (("no extra", "core"), ("float", "core:floating"), ("random 1", "core:random1"),
          ("random 2", "core:random2"), ("relevant 1", "core:relevant1"),
          ("relevant 2", "core:relevant2"))
_TABLE_7_2 = {
    "float": ((0.303, 0.585), (0.038, 0.847), (1.002, 0.323)),
    "random 1": ((2.447, 0.126), (0.465, 0.499), (0.578, 0.452)),
    "random 2": ((7.648, 0.009), (0.713, 0.404), (1.862, 0.180)),
    "relevant 1": ((1.595, 0.214), (0.337, 0.565), (0.382, 0.540)),
    "relevant 2": ((5.597, 0.023), (0.453, 0.505), (0.730, 0.398)),
}
_DBN_NOTE = ("Fig. 7.9: the number of change DBNs does not increase without bound (about 250 "
             "in the core world); relevant variables increase it, irrelevant ones do not. Two "
             "drops: the hand's actions becoming sufficiently reliable, and DBNs deleted after "
             "100,000 steps.")
EXTRANEOUS = Experiment(
    name="extraneous", section="§7.6", title="extraneous variables: irrelevant and relevant",
    claim="Because of its bottom-up construction of DBNs and plans, QLAP can ignore extraneous "
          "variables: performance degrades gracefully.",
    arms=tuple(Arm(label, world, QLAP) for label, world in _EXTRA),
    tasks=CORE_TASKS,
    panels=(_panel("a", "irrelevant variables", ("no extra", "float", "random 1", "random 2"),
                  base="no extra", expect="adding irrelevant variables reduces performance, "
                                            "but not by much"),
            _panel("b", "relevant variables", ("no extra", "relevant 1", "relevant 2"),
                  base="no extra", expect="performance degrades significantly but "
                                            "gracefully for the move task under random 2 and "
                                            "relevant 2")),
    figures=("curves", "bars", "dbn_count"),
    reference=tuple(ReferenceStat(task, arm, "no extra", f, sig, "Table 7.2")
                    for arm, rows in _TABLE_7_2.items()
                    for task, (f, sig) in zip(CORE_TASKS, rows, strict=True)),
    notes=("Adding irrelevant variables reduces performance, but not by much; the move task "
           "degrades significantly but gracefully under random 2 and relevant 2 (Table 7.2).",
           _DBN_NOTE),
    figure_refs="Figs. 7.6–7.9, Table 7.2")

DBN_COUNT = Experiment(
    name="dbn-count", section="§7.6.3",
    title="change DBNs over time with extraneous variables",
    claim="The number of change DBNs does not increase without bound; relevant variables "
          "increase it, irrelevant variables do not.",
    arms=tuple(Arm(label, world, QLAP) for label, world in _EXTRA),
    tasks=(), figures=("dbn_count",), notes=(_DBN_NOTE,), figure_refs="Fig. 7.9")


# ---------------------------------------------------------------------------------------------
# §7.7 Landmarks against random landmarks (Fig. 7.10)
# ---------------------------------------------------------------------------------------------
LANDMARKS = Experiment(
    name="landmarks-vs-random", section="§7.7",
    title="tabular Q-learning on QLAP's landmarks and on random landmarks (core2d)",
    claim="QLAP learns landmarks that are generally useful: tabular Q-learning does better "
          "with them than with random landmarks.",
    arms=(Arm("QLAP landmarks", "core2d",
              Condition("QLAP landmarks", "qtable", qtable=QTableConfig("qlap"),
                        description="tabular Q-learning on the landmarks of a QLAP run "
                                    "(§7.7.2)")),
          Arm("random landmarks", "core2d",
              Condition("random landmarks", "qtable", qtable=QTableConfig("random"),
                        description="tabular Q-learning on 0–5 random landmarks per variable "
                                    "(§7.7.2)"))),
    tasks=("move_block",),
    panels=(_panel("a", "QLAP landmarks and random landmarks",
                  ("QLAP landmarks", "random landmarks"), base="QLAP landmarks",
                  expect="tabular Q-learning works much better using the learned landmarks "
                         "than using the random ones"),),
    steps=100_000,
    reference_protocol=(("agents", "20 (§7.3)"),
                        ("steps", "landmarks of a 100,000-step QLAP run; the Q-learner's "
                                  "length is not stated (§7.7.2)")),
    reference=(ReferenceStat("move_block", "random landmarks", "QLAP landmarks", 39.210, 0.000,
                             "Fig. 7.10(b)"),),
    notes=("The landmarks come from a QLAP run of 100,000 steps in core2d (§7.7.2); the "
           "Q-learner's own length, step size, discount and exploration are not stated: here "
           "it learns for the experiment's steps with App. H's α = 0.2, γ = 1, ε = 0.05.",),
    figure_refs="Fig. 7.10")


# ---------------------------------------------------------------------------------------------
# §7.8 Two blocks, §7.9 contingent ball, §7.10 pong
# ---------------------------------------------------------------------------------------------
TWO_BLOCKS = Experiment(
    name="two-blocks", section="§7.8", title="hitting one block with another (aligned or not)",
    claim="QLAP can learn to use one block to hit another when they are aligned, but not when "
          "it first has to align them.",
    arms=(Arm("aligned", "core:secondary:aligned", QLAP),
          Arm("unaligned", "core:secondary:unaligned", QLAP)),
    tasks=("hit_secondary",),
    panels=(_panel("a", "aligned and unaligned", ("aligned", "unaligned"), base="aligned",
                  expect="QLAP learns the task when the blocks are aligned, not when they are "
                         "unaligned"),),
    notes=("In the unaligned case the agent learned no sufficiently reliable DBN that led to a "
           "plan (§7.8.3; no F test is given).",),
    figure_refs="Fig. 7.11")

CONTINGENT = Experiment(
    name="contingent", section="§7.9", title="making the contingent ball rise",
    claim="QLAP can learn to perform a task that does not match a human's notion of intuitive "
          "physics.",
    arms=(Arm("continuous rising", "core:contingent:rising", QLAP),
          Arm("jump up", "core:contingent:jump", QLAP)),
    tasks=("contingent_up",),
    panels=(_panel("a", "continuous rising and jump up", ("continuous rising", "jump up"),
                  base="jump up",
                  expect="in both cases the agent learns the task; the reward is lower with "
                         "continuous rising (momentum)"),),
    notes=("Step cost 0.1 (§7.9.3); an agent without a plan holds its motors at 0 during "
           "evaluation (§7.9.1). No F test is given.",),
    figure_refs="Fig. 7.12")

PONG = Experiment(
    name="pong", section="§7.10", title="QLAP learns to play pong",
    claim="QLAP is not specific to a particular environment: it learns to hit the ball back "
          "and forth in pong, autonomously.",
    arms=(Arm("QLAP", "pong", QLAP),),
    tasks=("pong_volley",),
    panels=(_panel("a", "volleys per trial", ("QLAP",),
                  expect="the agent learns to play pong somewhat well (average volleys of four "
                         "agents)"),),
    agents=4,
    reference_protocol=(("agents", "4 (§7.10.2)"), ("steps", "not stated (§7.10)")),
    notes=("Four agents (§7.10.2); k fixed at 6 and plans allowed without a reliable plan for "
           "the antecedent (§7.10.1, the world's agent options). The reward is volleys per "
           "trial.",),
    figure_refs="Fig. 7.14")


# ---------------------------------------------------------------------------------------------
# §7.11 Ablations (Figs. 7.15–7.25, Table 7.4)
# ---------------------------------------------------------------------------------------------
_ABLATED = (
    ("no IAC", "no_iac", "actions to practice chosen at random instead of by IAC"),
    ("no Dyna", "no_dyna", "no Dyna update of the plans (ch. 5)"),
    ("no Sarsa", "no_sarsa", "no Sarsa update of the plans (ch. 5)"),
    ("entropy", "entropy_only", "hill climbing on entropy only (ch. 4)"),
    ("no targeted", "no_targeted", "no targeted learning (ch. 6)"),
    ("all targeted", "all_targeted", "targeted learning for all actions (ch. 6)"),
    ("NRC", "nrc", "no restriction on contingencies (ch. 6)"),
    ("NRP", "nrp", "no restriction on plans (ch. 6)"),
)
_TABLE_7_4 = {
    "no IAC": ((0.251, 0.619), (0.232, 0.633), (1.128, 0.295)),
    "no Dyna": ((2.355, 0.133), (1.131, 0.294), (0.530, 0.471)),
    "no Sarsa": ((0.398, 0.532), (0.022, 0.870), (0.332, 0.568)),
    "entropy": ((0.009, 0.927), (2.812, 0.102), (18.455, 0.000)),
    "no targeted": ((2.185, 0.148), (0.427, 0.517), (8.227, 0.007)),
    "all targeted": ((2.183, 0.148), (0.055, 0.816), (1.295, 0.262)),
    "NRC": ((0.774, 0.384), (2.178, 0.148), (0.002, 0.964)),
    "NRP": ((1.491, 0.230), (0.441, 0.511), (0.149, 0.702)),
}
ABLATIONS = Experiment(
    name="ablations", section="§7.11", title="the eight ablations of §7.11 on the core tasks",
    claim="Exploration by IAC, hill climbing on best reliability and targeted learning matter "
          "(for picking up the block); the developmental restrictions do not hinder "
          "performance and save DBNs.",
    arms=(Arm("QLAP", "core", QLAP),
          *(Arm(label, "core", _ablation(label, switch, what))
            for label, switch, what in _ABLATED)),
    tasks=CORE_TASKS,
    panels=(_panel("a", "exploration, planning, hill climbing",
                  ("QLAP", "no IAC", "no Dyna", "no Sarsa", "entropy"), base="QLAP",
                  expect="no IAC and entropy hurt picking up the block (Figs. 7.15–7.17)"),
            _panel("b", "targeted learning and restrictions",
                  ("QLAP", "no targeted", "all targeted", "NRC", "NRP"), base="QLAP",
                  expect="targeted learning is important for picking up the block "
                         "(Figs. 7.18–7.20)")),
    figures=("curves", "bars", "calls", "dbn_count"),
    reference=tuple(ReferenceStat(task, arm, "QLAP", f, sig, "Table 7.4")
                    for arm, rows in _TABLE_7_4.items()
                    for task, (f, sig) in zip(CORE_TASKS, rows, strict=True)),
    notes=("no IAC makes the most calls to moving the hand and learns more DBNs (Figs. 7.21, "
           "7.24, 7.25).",
           "NRC uses more resources in the form of DBNs; the restrictions do not hinder "
           "performance.",
           "entropy is significantly diminished in picking up the block; no targeted makes "
           "fewer exploratory calls to moving the hand and picking up the block, and is "
           "significantly worse at picking it up; all targeted uses more DBNs without "
           "improving performance.",),
    figure_refs="Figs. 7.15–7.25, Table 7.4")


EXPERIMENTS = MappingProxyType({e.name: e for e in (
    CORE_TASKS_EXPERIMENT, TRANSFER, EXTRANEOUS, DBN_COUNT, LANDMARKS, TWO_BLOCKS, CONTINGENT,
    PONG, ABLATIONS)})
"""Every experiment by name, in the reference's order."""


def names() -> list[str]:
    return list(EXPERIMENTS)


def get(name: str) -> Experiment:
    """The experiment ``name``; raises :class:`ExperimentError` naming the known ones."""
    try:
        return EXPERIMENTS[name]
    except KeyError:
        raise ExperimentError(f"unknown experiment {name!r}; experiments: "
                              f"{', '.join(EXPERIMENTS)}") from None
