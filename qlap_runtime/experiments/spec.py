"""Experiments as data: small frozen dataclasses that say what chapter 7 runs and plots.

An :class:`Experiment` (one per section of §7.4–7.11 of J. Mugan, *Autonomous Qualitative
Learning of Distinctions and Actions in a Developing Agent*, PhD dissertation, UT Austin, 2010)
has *arms* — a world (or world variant) and a :class:`Condition` (QLAP with parameter changes
and §7.11 ablations, or a baseline: Sarsa(λ) with tile coding, App. H; tabular Q-learning on
landmarks, §7.7) — the tasks every arm is evaluated on (§7.2), the number of agents, steps,
trials and checkpoints, the panels to draw and the reference's statistics to print beside the
measured ones. :func:`configure` applies the command line (``--agents``, ``--steps``,
``--set``, ``--ablation``, ``--quick``) and validates it, with one-line errors.
"""

from __future__ import annotations

import dataclasses
import difflib
import types
import typing
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

from ..qlap.params import Ablations, Params

__all__ = [
    "ABLATIONS",
    "Arm",
    "Condition",
    "Experiment",
    "ExperimentError",
    "Panel",
    "Preset",
    "QTableConfig",
    "ReferenceStat",
    "TileConfig",
    "configure",
    "parse_set",
    "qlap_params",
    "versus",
]

ABLATIONS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(Ablations))
"""The switches of §7.11.1 (``--ablation NAME``), fields of :class:`~qlap_runtime.qlap.params.
Ablations`."""

CONFLICTING: tuple[tuple[str, str], ...] = (("no_targeted", "all_targeted"),)
"""Ablation switches that contradict each other (§7.11.1: targeted learning for no event and
for every event)."""

Kind = Literal["qlap", "tile", "qtable"]


class ExperimentError(ValueError):
    """An experiment or option that cannot be used; the message (one line) says why."""


@dataclass(frozen=True)
class TileConfig:
    """Linear, gradient-descent Sarsa(λ) on hashed tile coding, as Appendix H sets it up."""

    decision_every: int = 1
    """World steps per decision: 1 for Tile-1, 10 for Tile-10 (§7.4.2)."""
    decision_cost: float | None = None
    """Reward of a decision that does not reach the goal; None: the task's step cost (−0.01).
    Tile-10: −0.1 "every 10th timestep it does not reach the goal" (§7.4.2)."""
    tilings: int = 16
    """16 tilings (App. H)."""
    memory: int = 65_536
    """Memory size of the hashed tiles: 65,536 weights (App. H)."""
    motors: tuple[str, ...] = ("u_x", "u_y")
    """Motors that actions set; the others stay at rest (App. H: u_x and u_y)."""
    motor_bins: int = 10
    """Each motor's range in this many equal-width bins; an action sets one motor to the
    centre of one bin: 2 × 10 = 20 actions (App. H)."""
    change_band: float = 0.05
    """Change variables in 3 bins (−∞, −0.05), [−0.05, 0.05], (0.05, ∞), per second (App. H;
    the agent's derivatives, ``World.change``)."""
    generalization: float = 0.25
    """Tile width in the [0, 1]-normalised inputs (App. H: "the generalization was 0.25")."""
    lam: float = 0.9
    """λ of the replacing traces (App. H)."""
    gamma: float = 1.0
    """Discount γ (App. H)."""
    alpha: float = 0.2
    """Step size α (App. H), shared by the active tiles: each of the ``tilings`` weights of a
    (state, action) moves by α/``tilings`` · δ (Sutton & Barto's convention for tile coding)."""
    epsilon: float = 0.05
    """ε of the ε-greedy choice while learning (App. H)."""
    eval_epsilon: float = 0.05
    """ε during evaluation (learning off): the agent acts as it learned to (our choice; the
    reference does not say)."""
    range_steps: int = 20_000
    """Steps of motor babbling (App. E) whose minimum and maximum normalise each magnitude to
    [0, 1]: "the minimum and maximum values observed during a typical run of QLAP", whose
    first 20,000 steps are babbling (§6.1)."""


@dataclass(frozen=True)
class QTableConfig:
    """Tabular Q-learning on a qualitative state (§7.7): QLAP's landmarks or random ones."""

    landmarks: Literal["qlap", "random"]
    """``qlap``: the landmarks of a QLAP run of ``landmark_steps`` in the same world (the agent
    with the same seed); ``random``: for each magnitude or motor variable 0–5 landmarks drawn
    uniformly within its observed range (motors keep their landmark at 0) (§7.7.2)."""
    landmark_steps: int | None = None
    """Steps of the QLAP run that provides the landmarks (§7.7.2: 100,000); None: the
    experiment's steps."""
    max_random_landmarks: int = 5
    """Random landmarks per variable: uniformly 0 to this many (§7.7.2)."""
    alpha: float = 0.2
    """Step size (not stated in §7.7; App. H's α)."""
    gamma: float = 1.0
    """Discount (not stated in §7.7; App. H's γ)."""
    epsilon: float = 0.05
    """ε-greedy while learning (not stated in §7.7; App. H's ε)."""
    eval_epsilon: float = 0.05
    """ε during evaluation (learning off)."""
    change_band: float = 0.05
    """Change variables in 3 bins, as the agent's (Table 8.1)."""
    range_steps: int = 20_000
    """Motor babbling whose minimum and maximum bound the random landmarks (§7.7.2: "the
    minimum and maximum range observed for v during a typical run of QLAP")."""


@dataclass(frozen=True)
class Condition:
    """How an agent learns: QLAP (with parameter changes and ablations) or a baseline."""

    name: str
    kind: Kind = "qlap"
    params: tuple[tuple[str, Any], ...] = ()
    """Changes to :class:`~qlap_runtime.qlap.params.Params` (QLAP, and the QLAP run that
    gives a Q-learner its landmarks)."""
    ablations: tuple[str, ...] = ()
    """Switches of §7.11.1 that are on."""
    tile: TileConfig | None = None
    qtable: QTableConfig | None = None
    description: str = ""

    def params_dict(self) -> dict[str, Any]:
        return dict(self.params)


@dataclass(frozen=True)
class Arm:
    """One line of a figure: a condition learning in a world."""

    label: str
    """The name in figures and tables (the reference's condition name)."""
    world: str
    """World spec; ``{half}`` is replaced by half the experiment's steps (transfer, §7.5)."""
    condition: Condition
    steps_fraction: float = 1.0
    """This arm's agents learn for this fraction of the experiment's steps."""
    eval_world: str | None = None
    """World of the evaluation trials (default: ``world``): the transfer agent learned with
    variables withheld, and is evaluated with all of them (§7.5)."""
    eval_from_fraction: float = 0.0
    """Evaluate the checkpoints from this fraction of the experiment's steps on."""
    offset_fraction: float = 0.0
    """Drawn at step − offset_fraction × steps (the transfer agent's second half, §7.5.3)."""

    def world_spec(self, steps: int) -> str:
        return self.world.format(half=steps // 2)

    def evaluation_world(self, steps: int) -> str:
        return (self.eval_world or self.world).format(half=steps // 2)

    def steps(self, steps: int) -> int:
        return round(self.steps_fraction * steps)

    def offset(self, steps: int) -> int:
        return round(self.offset_fraction * steps)


@dataclass(frozen=True)
class Panel:
    """A sub-figure: curves of some arms and a bar graph of their averages after the excluded
    start, with F tests between pairs of arms (§7.3)."""

    key: str
    """The sub-figure's letter, as in the reference (a, b, c)."""
    title: str
    arms: tuple[str, ...]
    tests: tuple[tuple[str, str], ...] = ()
    """(arm, versus) pairs compared by ANOVA (§7.3)."""
    expect: str = ""
    """What the reference reports for this panel."""


def versus(arms: tuple[str, ...], base: str) -> tuple[tuple[str, str], ...]:
    """Every arm of ``arms`` but ``base`` compared with ``base`` (Tables 7.2 and 7.4)."""
    return tuple((a, base) for a in arms if a != base)


@dataclass(frozen=True)
class ReferenceStat:
    """An F test the reference reports (a caption or Table 7.2/7.4)."""

    task: str
    arm: str
    versus: str
    F: float
    sig: float
    source: str


@dataclass(frozen=True)
class Preset:
    """The ``--quick`` preset: every experiment end to end in minutes (not a measurement)."""

    agents: int = 2
    steps: int = 30_000
    trials: int = 20
    every: int = 10_000


@dataclass(frozen=True)
class Experiment:
    """One experiment of chapter 7."""

    name: str
    section: str
    title: str
    claim: str
    """The reference's claim, quoted or closely paraphrased."""
    arms: tuple[Arm, ...]
    tasks: tuple[str, ...]
    """Evaluation tasks (§7.2); none for an experiment that only counts knowledge."""
    panels: tuple[Panel, ...] = ()
    figures: tuple[str, ...] = ("curves", "bars")
    """What to draw: ``curves``, ``bars`` (per task), ``dbn_count`` (Figs. 7.9, 7.24),
    ``calls`` (cumulative exploratory calls, Figs. 7.21–7.23)."""
    agents: int = 20
    """Agents per arm (§7.3: twenty, except for pong)."""
    steps: int = 250_000
    """Steps of autonomous learning (§7.2)."""
    trials: int = 100
    """Evaluation trials per checkpoint and task (§7.2.1)."""
    checkpoint_every: int = 10_000
    """A checkpoint every 10,000 steps (§7.2)."""
    eval_every: int = 10_000
    """Evaluate the checkpoints whose step is a multiple of this (and each run's last)."""
    exclude_fraction: float = 0.4
    """Bar graphs and ANOVA use the checkpoints after this fraction of the steps: "the first
    100,000 timesteps are excluded" of 250,000 (§7.3)."""
    reference: tuple[ReferenceStat, ...] = ()
    notes: tuple[str, ...] = ()
    """The reference's statements about the results, printed in RESULTS.md."""
    figure_refs: str = ""
    """The reference's figures and tables of this experiment."""
    reference_protocol: tuple[tuple[str, str], ...] = (
        ("agents", "20 (§7.3)"), ("steps", "250,000 (§7.2)"))
    """What the reference used, where it differs from 20 agents and 250,000 steps."""
    quick: Preset = field(default_factory=Preset)
    quick_mode: bool = False
    """Set by :func:`configure` when ``--quick`` is given."""

    def arm(self, label: str) -> Arm:
        for a in self.arms:
            if a.label == label:
                return a
        raise ExperimentError(f"{self.name} has no arm {label!r}")

    def anova_from(self) -> int:
        """Checkpoints (on the drawn axis) after this step enter the bars and the ANOVA."""
        span = max(a.steps(self.steps) - a.offset(self.steps) for a in self.arms)
        return int(self.exclude_fraction * span)

    def summary(self) -> str:
        """One line for ``qlap experiment --list``."""
        return f"{self.name:<20}{self.section:<7}{self.title} ({self.figure_refs})"

    def to_json(self) -> dict[str, Any]:
        return _jsonable(dataclasses.asdict(self))


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, Mapping):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    return obj


# ---------------------------------------------------------------------------------------------
# Parameters and ablations from the command line
# ---------------------------------------------------------------------------------------------
def _field_types() -> dict[str, Any]:
    hints = typing.get_type_hints(Params)
    return {f.name: hints[f.name] for f in dataclasses.fields(Params) if f.name != "ablations"}


def _convert(name: str, text: str, typ: Any) -> Any:
    args = typing.get_args(typ)
    if isinstance(typ, types.UnionType) or typing.get_origin(typ) is typing.Union:
        if type(None) in args and text.strip().lower() in ("none", "null"):
            return None
        inner = [a for a in args if a is not type(None)]
        typ = inner[0] if len(inner) == 1 else str
    try:
        if typ is bool:
            low = text.strip().lower()
            if low in ("1", "true", "yes", "on"):
                return True
            if low in ("0", "false", "no", "off"):
                return False
            raise ValueError
        if typ is int:
            value = float(text)
            if not value.is_integer():
                raise ValueError
            return int(value)
        if typ is float:
            return float(text)
    except ValueError:
        raise ExperimentError(f"--set {name}={text}: expected {getattr(typ, '__name__', typ)}"
                              ) from None
    return text


def parse_set(text: str) -> tuple[str, Any]:
    """``name=value`` of ``--set``: a :class:`Params` field and its value, typed as the field
    is (``none`` for an optional field). Raises :class:`ExperimentError`."""
    name, sep, value = text.partition("=")
    name = name.strip()
    if not sep or not name:
        raise ExperimentError(f"--set {text!r}: expected name=value")
    types_ = _field_types()
    if name == "ablations":
        raise ExperimentError("--set ablations=…: use --ablation NAME for the switches of §7.11")
    if name in ABLATIONS:
        raise ExperimentError(f"--set {name}: a switch of §7.11, not a Params field; use "
                              f"--ablation {name}")
    if name not in types_:
        close = difflib.get_close_matches(name, list(types_), n=1)
        hint = f"did you mean {close[0]}? " if close else ""
        raise ExperimentError(f"--set {name}: unknown Params field ({hint}see "
                              "qlap_runtime/qlap/params.py)")
    return name, _convert(name, value.strip(), types_[name])


def qlap_params(params: Mapping[str, Any], ablations: Iterable[str]) -> Params:
    """The validated :class:`Params` of these changes and switches."""
    ablations = tuple(ablations)
    unknown = [a for a in ablations if a not in ABLATIONS]
    if unknown:
        raise ExperimentError(f"unknown ablation {unknown[0]!r}; ablations: "
                              f"{', '.join(ABLATIONS)}")
    for a, b in CONFLICTING:
        if a in ablations and b in ablations:
            raise ExperimentError(f"ablations {a} and {b} contradict each other (§7.11.1)")
    try:
        return Params(**dict(params), ablations=Ablations(**dict.fromkeys(ablations, True)))
    except (TypeError, ValueError) as exc:
        raise ExperimentError(str(exc).splitlines()[0]) from None


def configure(exp: Experiment, *, agents: int | None = None, steps: int | None = None,
              trials: int | None = None, every: int | None = None, quick: bool = False,
              sets: Mapping[str, Any] | None = None,
              ablations: Iterable[str] = ()) -> Experiment:
    """``exp`` with the command line applied: the ``--quick`` preset first, then ``--agents``,
    ``--steps``, ``--trials``, ``--every``; ``--set`` and ``--ablation`` go into every QLAP
    condition (and the QLAP runs that give a Q-learner its landmarks). Raises
    :class:`ExperimentError` for a bad value or a contradiction."""
    changes: dict[str, Any] = {}
    if quick:
        p = exp.quick
        changes.update(agents=p.agents, steps=p.steps, trials=p.trials, eval_every=p.every,
                       quick_mode=True)
        if p.every < exp.checkpoint_every:
            changes["checkpoint_every"] = p.every
    for name, value in (("agents", agents), ("steps", steps), ("trials", trials),
                        ("eval_every", every)):
        if value is not None:
            if int(value) != value or value < 1:
                raise ExperimentError(f"--{name.replace('eval_', '')} must be a positive "
                                      f"integer, got {value!r}")
            changes[name] = int(value)
    out = dataclasses.replace(exp, **changes)
    if out.eval_every % out.checkpoint_every:
        raise ExperimentError(f"--every {out.eval_every} must be a multiple of the checkpoint "
                              f"interval {out.checkpoint_every:,}")
    sets = dict(sets or {})
    ablations = tuple(dict.fromkeys(ablations))
    qlap_params(sets, ablations)                    # the options alone
    arms = []
    for arm in out.arms:
        cond = arm.condition
        if cond.kind == "qlap" or (cond.qtable is not None and cond.qtable.landmarks == "qlap"):
            merged = {**cond.params_dict(), **sets}
            switches = tuple(dict.fromkeys((*cond.ablations, *ablations)))
            try:
                qlap_params(merged, switches)
            except ExperimentError as exc:
                raise ExperimentError(f"arm {arm.label!r}: {exc}") from None
            cond = dataclasses.replace(cond, params=tuple(sorted(merged.items())),
                                       ablations=switches)
        arms.append(dataclasses.replace(arm, condition=cond))
    out = dataclasses.replace(out, arms=tuple(arms))
    for arm in out.arms:
        if arm.steps(out.steps) < out.checkpoint_every:
            raise ExperimentError(f"--steps {out.steps}: arm {arm.label!r} would learn for "
                                  f"{arm.steps(out.steps)} steps, fewer than one checkpoint "
                                  f"interval ({out.checkpoint_every:,})")
    return out
