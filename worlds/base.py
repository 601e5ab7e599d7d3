"""The world contract: what every world (core, core2d, pong, a wrapped Gymnasium env) offers.

A world is a continuous environment seen through named variables (§2 of the reference):

* **motor** variables are set by the agent at each step (a float within ``[low, high]``);
* **magnitude** variables are sensed real values;
* **nominal** variables are sensed labels, carried in the observation as the label's index
  written as a float (``0.0``, ``1.0``, ...).

Worlds never compute derivatives: the direction of change of a magnitude ``v`` (written
``v.dot``) is the perception side's business, per second: (ṽ(t) − ṽ(t−1)) / ``step_seconds``
with the zero band ±:data:`DOT_BAND` (the reference's [−0.05, 0.05], Table 8.1). Tasks that
need it judge it exactly that way (:meth:`World.change`, :func:`direction`).

One agent step is ``World.substeps`` physics substeps and lasts ``World.step_seconds`` seconds.
When a world teleports something (a block replaced, a ball re-centred, an episode restarted) the
observation after it is not continuous with the one before: ``World.discontinuity`` says so, and
the agent breaks its histories there (no derivative, event or window spans the jump).
Everything random in a world comes from ``World.rng``, a :class:`numpy.random.Generator` seeded
by ``reset(seed)``: the same seed and the same motor sequence give identical observations.
"""

from __future__ import annotations

import abc
import base64
import dataclasses
import enum
import math
import zlib
from array import array
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np

__all__ = [
    "DOT_BAND",
    "STATE_FORMAT",
    "Goal",
    "Task",
    "VarKind",
    "VariableSpec",
    "World",
    "direction",
    "with_resolution",
]

#: The zero band of the agent's directions of change, per second: a derivative
#: (ṽ(t) − ṽ(t−1)) / step_seconds within [−DOT_BAND, DOT_BAND] is "0" (Table 8.1's landmark
#: [−0.05, 0.05] on every change variable; the reference's derivatives are per second, Tables
#: 8.7–8.10). Tasks use it to judge ".dot" goals.
DOT_BAND = 0.05

STATE_FORMAT = "qlap-world-state"
"""The ``format`` of :meth:`World.get_state`'s dictionary (version 1)."""


class VarKind(enum.StrEnum):
    """The kind of a world variable."""

    MOTOR = "motor"
    """Set by the agent; a float within [low, high]."""
    MAGNITUDE = "magnitude"
    """A sensed real value."""
    NOMINAL = "nominal"
    """A sensed label; the observation carries the label's index as a float."""


@dataclass(frozen=True)
class VariableSpec:
    """One variable of a world's variable table."""

    name: str
    """Unique within the world, e.g. ``"h_x"``, ``"u_x"``, ``"T"``."""
    kind: VarKind
    """Motor, magnitude or nominal."""
    meaning: str
    """One line, including the sign convention."""
    low: float | None = None
    """Motors: the lowest motor value accepted (required for motors)."""
    high: float | None = None
    """Motors: the highest motor value accepted (required for motors)."""
    values: tuple[str, ...] = ()
    """Nominal: the labels; the observation carries the index as a float (0.0, 1.0, ...)."""
    available_from: int = 0
    """The agent step at which the variable first appears in observations (transfer variant)."""
    resolution: float | None = None
    """Motors and magnitudes: the smallest difference worth a distinction (the precision of the
    sensor or actuator). No learned landmark is narrower, and none closer to another. None: the
    agent's default (1 % of a motor's range; a magnitude's average change per step)."""


@dataclass(frozen=True)
class Goal:
    """A qualitative value of a variable (§7.2.1), given to the agent at the start of a trial."""

    variable: str
    """A world variable, or its direction of change written ``"<name>.dot"``."""
    value: str
    """For ``.dot`` variables one of ``"+"``, ``"0"``, ``"-"``; for nominal a label."""


def with_resolution(specs: tuple[VariableSpec, ...],
                    resolution: float) -> tuple[VariableSpec, ...]:
    """``specs`` with ``resolution`` given to every magnitude that has none."""
    return tuple(dataclasses.replace(v, resolution=resolution)
                 if v.kind is VarKind.MAGNITUDE and v.resolution is None else v for v in specs)


def direction(previous: float, current: float, band: float = DOT_BAND, *, dt: float = 1.0) -> str:
    """The qualitative direction of change between two consecutive values: "+", "0" or "-".

    The derivative is ``(current − previous) / dt`` (``dt``: the world's ``step_seconds``); it is
    "0" within the closed band ``[−band, band]``, as the agent's perception judges it.
    """
    change = (current - previous) / dt
    if change > band:
        return "+"
    if change < -band:
        return "-"
    return "0"


class Task(abc.ABC):
    """One evaluation task of a world (§7.2.2).

    A trial: ``obs = task.setup(world, rng)``; then, at each step, the agent pursues
    ``task.goal(world, obs)``; a step earns ``success_reward`` when ``is_success`` holds (and the
    trial ends), else ``step_cost``; the trial also ends early when ``is_failure`` holds or after
    ``max_steps`` steps. A task may read ``world.previous_observation`` (the observation before the
    latest step) to judge ``.dot`` goals.
    """

    name: str
    step_cost: float = -0.01
    success_reward: float = 9.99
    max_steps: int = 300
    hold_motors_at_zero_without_plan: bool = False
    """During evaluation an agent with no plan sets its motors to 0 instead of random (§7.9.1)."""
    episodic: bool = True
    """False for tasks that count successes (pong volleys): a success earns ``success_reward``
    and the trial goes on with a new goal until ``is_failure`` or ``max_steps``."""

    @abc.abstractmethod
    def setup(self, world: World, rng: np.random.Generator) -> dict[str, float]:
        """Set up a trial (reset the world and place things) and return its first observation."""

    @abc.abstractmethod
    def goal(self, world: World, obs: Mapping[str, float]) -> Goal:
        """The goal to pursue given the current observation."""

    @abc.abstractmethod
    def is_success(self, world: World, obs: Mapping[str, float]) -> bool:
        """Whether the goal was achieved at the latest step."""

    def is_failure(self, world: World, obs: Mapping[str, float]) -> bool:
        """Whether the trial ends early (block hit the wrong way, out of reach, ball missed)."""
        return False


class World(abc.ABC):
    """A continuous world seen through named variables.

    Subclasses set ``name``, ``variables`` (motors first), ``substeps``, ``step_seconds``,
    ``tasks`` and optionally ``agent_options`` and ``constant_variables``, call
    :meth:`_init_variables`, and implement :meth:`_reset` and :meth:`_step`, which return the full
    observation (every sensed variable, available or not) and call :meth:`_mark_discontinuity`
    when they teleport something; this base class validates motors, counts steps, sets
    ``discontinuity`` on every step and withholds variables before their ``available_from`` step.
    """

    name: str
    variables: tuple[VariableSpec, ...]
    substeps: int
    step_seconds: float
    """The physical duration of one agent step, in seconds (core: 2 × 0.025 = 0.05). The agent's
    directions of change are per second: (ṽ(t) − ṽ(t−1)) / step_seconds, zero band ±DOT_BAND.
    A world with no physical time (a game) says how long its step is meant to last."""
    discontinuity: bool = True
    """True when the latest observation is not continuous with the one before it: the world
    teleported something between them (a block replaced or moved after a let-go, a ball and
    paddles re-centred, an episode restarted, or the caller placed the hand or block between
    steps). True after ``reset()``; set by every ``step()``. The agent breaks its histories on
    such a step: no derivative, event or soon-window spans the jump."""
    agent_options: Mapping[str, Any] = MappingProxyType({})
    tasks: Mapping[str, Task]
    constant_variables: ClassVar[tuple[str, ...]] = ()
    """Sensed variables that are constant by design (e.g. pong's l_x, r_x, Table 7.3);
    ``check_world`` exempts them from its no-constant-variable rule."""
    rare_variables: ClassVar[tuple[str, ...]] = ()
    """Nominal event variables that a short random-motor run may leave unchanged (core's T needs
    the hand lowered onto the block's top, bang the block knocked off the table); ``check_world``
    exempts them from its no-constant-variable rule, and physics tests show that they fire."""
    step_count: int = 0
    """Agent steps since the last reset."""
    observation: dict[str, float]
    """The latest observation (all sensed variables, including withheld ones)."""
    previous_observation: dict[str, float]
    """The observation before the latest step (equal to ``observation`` just after reset)."""
    rng: np.random.Generator

    # --- set-up helpers for subclasses ------------------------------------------------------

    def _init_variables(self, variables: tuple[VariableSpec, ...]) -> None:
        self.variables = variables
        motors = [v for v in variables if v.kind is VarKind.MOTOR]
        self._motor_names = tuple(v.name for v in motors)
        self._motor_index = {name: i for i, name in enumerate(self._motor_names)}
        self._motor_low = tuple(float(v.low) if v.low is not None else -math.inf for v in motors)
        self._motor_high = tuple(float(v.high) if v.high is not None else math.inf for v in motors)
        # Missing motors default to 0, or to the nearest value in range when 0 is not in range.
        self._motor_default = tuple(
            min(max(0.0, lo), hi) for lo, hi in zip(self._motor_low, self._motor_high, strict=True)
        )
        self._late = tuple(
            sorted({v.available_from for v in variables if v.kind is not VarKind.MOTOR} - {0})
        )
        self._withheld: frozenset[str] = frozenset()
        self._jumped = False
        self._in_physics = False
        self._replay_start: dict[str, Any] | None = None
        self._replay_motors = array("d")
        self.discontinuity = True
        self.step_count = 0
        self.observation = {}
        self.previous_observation = {}
        if not hasattr(self, "rng"):
            self.rng = np.random.default_rng(0)         # reset(seed=...) gives a run its own

    @property
    def motor_names(self) -> tuple[str, ...]:
        """The motor variables' names, in table order."""
        return self._motor_names

    def available_names(self, step: int | None = None) -> list[str]:
        """The sensed variables present in observations at ``step`` (default: the current one)."""
        step = self.step_count if step is None else step
        return [
            v.name
            for v in self.variables
            if v.kind is not VarKind.MOTOR and v.available_from <= step
        ]

    # --- the contract ---------------------------------------------------------------------

    def reset(self, seed: int | None = None) -> dict[str, float]:
        """Start over and return the first observation: with ``seed``, the world's generator
        seeded from it; without, the generator goes on (Gymnasium's convention; a world is
        built with a generator seeded 0), so no reset draws from the OS's entropy.

        The observation maps each sensed variable (magnitude and nominal, not motors) available
        at step 0 to a finite float.
        """
        return self._start(self.rng if seed is None else np.random.default_rng(seed))

    def _start(self, rng: np.random.Generator) -> dict[str, float]:
        """Reset with the generator ``rng`` (a new seed, or a replay's saved start)."""
        self.rng = rng
        self.step_count = 0
        self._replay_start = dict(rng.bit_generator.state) if self.replayable else None
        self._replay_motors = array("d")
        self._in_physics = True
        try:
            obs = self._reset()
        finally:
            self._in_physics = False
        return self._begin_stream(obs)

    def step(self, motor: Mapping[str, float]) -> dict[str, float]:
        """Apply the motor values for one agent step (``substeps`` physics steps).

        ``motor`` maps motor names to values; missing motors are 0 (or the nearest in-range
        value). Raises ValueError for an unknown motor name, a NaN or infinite value, or a value
        outside the motor's range. Returns the observation after the step; ``discontinuity`` says
        whether it is continuous with the previous one.
        """
        values = self._motor_values(motor)
        return self._advance(values)

    def _advance(self, values: list[float]) -> dict[str, float]:
        """One step with validated motor values in table order (``step`` and replay)."""
        self.step_count += 1
        if self._replay_start is not None:
            self._replay_motors.extend(values)
        self._in_physics = True
        try:
            obs = self._step(values)
        finally:
            self._in_physics = False
        self.previous_observation = self.observation
        self.observation = obs
        self.discontinuity = self._jumped
        self._jumped = False
        return self._publish(obs)

    def restart_from(self, obs: dict[str, float]) -> dict[str, float]:
        """Start a fresh stream at ``obs``, the full observation of the current state.

        As after ``reset()``: ``observation`` and ``previous_observation`` become ``obs``,
        ``discontinuity`` is True, and the observation is returned with only the variables
        available now. ``reset()`` ends with it; a task's ``setup`` that moves things after
        ``reset()`` calls it with the observation of the state it set up.
        """
        self._replay_start = None           # a caller set this state up: no longer replayable
        return self._begin_stream(obs)

    def _begin_stream(self, obs: dict[str, float]) -> dict[str, float]:
        self.previous_observation = obs
        self.observation = obs
        self.discontinuity = True
        self._jumped = False
        return self._publish(obs)

    def observe(self) -> dict[str, float]:
        """The latest observation as the agent sees it (only the variables available now): what
        ``reset``, ``step`` or ``set_state`` returned last."""
        return self._publish(self.observation)

    def change(self, name: str) -> str | None:
        """The direction of change of magnitude ``name`` at the latest step, as the agent's
        perception judges it: ``direction(previous, current, DOT_BAND, dt=step_seconds)``, i.e.
        "+", "0" or "-"; None on a discontinuity step (no derivative spans a jump)."""
        if self.discontinuity:
            return None
        return direction(
            self.previous_observation[name], self.observation[name], dt=self.step_seconds
        )

    def render_text(self, width: int = 60, height: int = 20) -> str:
        """A cheap drawing of the world for the terminal UI (default: the variable values)."""
        lines = [f"{self.name}  step {self.step_count}"]
        lines += [f"{k:>10} {v: .3f}" for k, v in list(self.observation.items())[: height - 1]]
        return "\n".join(line[:width] for line in lines)

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release resources (renderers, wrapped environments)."""

    # --- for subclasses -------------------------------------------------------------------

    @abc.abstractmethod
    def _reset(self) -> dict[str, float]:
        """Reset the physics using ``self.rng``; return the full observation."""

    @abc.abstractmethod
    def _step(self, motor: list[float]) -> dict[str, float]:
        """Advance one agent step with motor values in table order; return the full observation.

        Call :meth:`_mark_discontinuity` when the step teleports something."""

    def _mark_discontinuity(self) -> None:
        """The next observation will not be continuous with the latest one (a teleport during
        ``_step``, or between steps by a caller placing things)."""
        self._jumped = True
        if not getattr(self, "_in_physics", False):
            self._replay_start = None       # a caller moved things: no longer replayable

    # --- saving and restoring the state (exact resume) ------------------------------------

    replayable: ClassVar[bool] = True
    """True: :meth:`get_state` records the generator's state at ``reset`` and every motor
    command since, and :meth:`set_state` replays them (exact for any deterministic world, at
    the cost of re-simulating). A world that saves its physics directly (MuJoCo's
    ``mj_getState``, a pure-Python game) sets False and implements :meth:`_get_state` and
    :meth:`_set_state`."""

    def get_state(self) -> dict[str, Any]:
        """The world's whole state as a JSON-able dict (no pickle): :meth:`set_state` on a world
        made with the same spec continues exactly as this one would (same observations and
        discontinuity flags for the same motors).

        Raises ValueError when the state cannot be saved: a replayed world whose caller moved
        things since ``reset`` (a task set-up), or a world that keeps no state."""
        state: dict[str, Any] = {
            "format": STATE_FORMAT, "version": 1, "world": self.name,
            "step_count": self.step_count, "observation": dict(self.observation),
            "previous_observation": dict(self.previous_observation),
            "discontinuity": bool(self.discontinuity), "jumped": bool(self._jumped),
            "rng": self.rng.bit_generator.state,
        }
        if self.replayable:
            if self._replay_start is None:
                raise ValueError(f"{self.name}: its state cannot be saved: things were placed "
                                 "by a caller since reset (only a run from reset replays)")
            raw = np.asarray(self._replay_motors, dtype="<f8").tobytes()
            state["replay"] = {"rng": self._replay_start, "n_motors": len(self._motor_names),
                               "motors": base64.b64encode(zlib.compress(raw, 6)).decode()}
        else:
            state["physics"] = self._get_state()
        return state

    def set_state(self, state: Mapping[str, Any]) -> dict[str, float]:
        """Restore a state from :meth:`get_state` (of a world made with the same spec) and
        return the observation the agent sees now, as ``reset`` does.

        Raises ValueError (KeyError, TypeError) naming what is wrong for a state of another
        world or a corrupt one; a replay whose end does not match the saved observation is
        an error too."""
        if not isinstance(state, Mapping) or state.get("format") != STATE_FORMAT:
            raise ValueError(f"{self.name}: not a world state (format "
                             f"{state.get('format') if isinstance(state, Mapping) else state!r})")
        if state.get("version") != 1:
            raise ValueError(f"{self.name}: world state version {state.get('version')!r} is "
                             "not supported (this build reads version 1)")
        if state.get("world") != self.name:
            raise ValueError(f"the world state is of {state.get('world')!r}, not {self.name!r}")
        observation = {str(k): float(v) for k, v in dict(state["observation"]).items()}
        previous = {str(k): float(v) for k, v in dict(state["previous_observation"]).items()}
        step_count = int(state["step_count"])
        if step_count < 0:
            raise ValueError(f"{self.name}: world state step_count {step_count} is negative")
        if self.replayable:
            self._replay(state.get("replay"), step_count)
            for what, got, saved in (("observation", self.observation, observation),
                                     ("generator", self.rng.bit_generator.state,
                                      state["rng"])):
                if got != saved:
                    raise ValueError(f"{self.name}: the replay of {step_count} steps does not "
                                     f"reach the saved {what} (is the world deterministic?)")
        else:
            if "physics" not in state:
                raise ValueError(f"{self.name}: the world state has no 'physics'")
            rng = np.random.default_rng(0)               # its state is set next
            rng.bit_generator.state = dict(state["rng"])
            self.rng = rng
            self._set_state(state["physics"])
            self._replay_start = None
        self.step_count = step_count
        self.observation, self.previous_observation = observation, previous
        self.discontinuity = bool(state["discontinuity"])
        self._jumped = bool(state["jumped"])
        return self._publish(observation)

    def _replay(self, replay: Any, step_count: int) -> None:
        """Reset to the saved generator state and apply the saved motor commands again."""
        if not isinstance(replay, Mapping):
            raise ValueError(f"{self.name}: the world state has no 'replay'")
        n = len(self._motor_names)
        if replay.get("n_motors") != n:
            raise ValueError(f"{self.name}: the replay has {replay.get('n_motors')!r} motors "
                             f"per step, the world {n}")
        try:
            raw = zlib.decompress(base64.b64decode(str(replay["motors"]), validate=True))
        except (ValueError, zlib.error) as exc:
            raise ValueError(f"{self.name}: corrupt replay motors ({exc})") from None
        motors = np.frombuffer(raw, dtype="<f8")
        if motors.size != n * step_count:
            raise ValueError(f"{self.name}: the replay holds {motors.size // max(n, 1)} steps, "
                             f"the state says {step_count}")
        if not np.isfinite(motors).all():
            raise ValueError(f"{self.name}: the replay holds non-finite motor values")
        rng = np.random.default_rng(0)               # its state is set next
        rng.bit_generator.state = dict(replay["rng"])
        self._start(rng)
        for row in motors.reshape(step_count, n).tolist():
            self._advance(self._motor_values(dict(zip(self._motor_names, row, strict=True))))

    def _get_state(self) -> Any:
        """The physics and bookkeeping of a world that is not ``replayable`` (JSON-able)."""
        raise ValueError(f"{self.name}: this world keeps no state (set replayable or "
                         "implement _get_state/_set_state)")

    def _set_state(self, physics: Any) -> None:
        """Restore what :meth:`_get_state` returned."""
        raise ValueError(f"{self.name}: this world keeps no state")

    # --- internals ------------------------------------------------------------------------

    def _motor_values(self, motor: Mapping[str, float]) -> list[float]:
        values = list(self._motor_default)
        index = self._motor_index
        for name, raw in motor.items():
            i = index.get(name)
            if i is None:
                raise ValueError(
                    f"{self.name}: unknown motor {name!r}; the motors are {list(self._motor_names)}"
                )
            try:
                value = float(raw)
            except (TypeError, ValueError):
                raise ValueError(f"{self.name}: motor {name!r} got a non-number {raw!r}") from None
            if not math.isfinite(value):
                raise ValueError(f"{self.name}: motor {name!r} got {value!r} (not finite)")
            lo, hi = self._motor_low[i], self._motor_high[i]
            if value < lo or value > hi:
                raise ValueError(
                    f"{self.name}: motor {name!r} got {value!r}, outside its range [{lo}, {hi}]"
                )
            values[i] = value
        return values

    def _publish(self, obs: dict[str, float]) -> dict[str, float]:
        if self._late:
            self._withheld = frozenset(
                v.name for v in self.variables if v.available_from > self.step_count
            )
            if self._withheld:
                return {k: v for k, v in obs.items() if k not in self._withheld}
        return dict(obs)
