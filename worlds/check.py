"""``check_world``: does a world keep the contract of :mod:`worlds.base`?

Like Gymnasium's env checker: run it on any world (registered or not). It raises AssertionError
with a message naming the world and the broken rule.
"""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Iterator, Mapping

import numpy as np

from worlds.base import Task, VariableSpec, VarKind, World

__all__ = [
    "JUMP_MEAN_FACTOR",
    "JUMP_RANGE_FRACTION",
    "JUMP_SCALE_FRACTION",
    "check_world",
    "random_motor",
]

#: A magnitude's change over one step is a *jump* when it exceeds this fraction of the
#: variable's range over the check's run, :data:`JUMP_MEAN_FACTOR` times its mean change per step
#: and :data:`JUMP_SCALE_FRACTION` of its largest magnitude; jumps must fall on steps the world
#: marks as discontinuities.
JUMP_RANGE_FRACTION = 0.4
JUMP_MEAN_FACTOR = 8.0
JUMP_SCALE_FRACTION = 0.01
#: The check's random policy holds each motor's random value for 0..MAX_HOLD steps (like the
#: agent's motor babbling, Appendix E), so that the hand travels and meets the block.
MAX_HOLD = 20


def _require(condition: object, message: str) -> None:
    """Like ``assert`` but not stripped by ``python -O``."""
    if not condition:
        raise AssertionError(message)


def random_motor(world: World, rng: np.random.Generator) -> dict[str, float]:
    """A uniformly random value for each motor within its range (the random policy)."""
    out = {}
    for v in world.variables:
        if v.kind is VarKind.MOTOR:
            assert v.low is not None
            assert v.high is not None
            out[v.name] = float(rng.uniform(v.low, v.high))
    return out


def held_motors(world: World, rng: np.random.Generator) -> Iterator[dict[str, float]]:
    """Motor commands as the agent babbles them: each motor holds a uniform random value for
    0–``MAX_HOLD`` steps (one command per step, for ever)."""
    motor = random_motor(world, rng)
    hold = dict.fromkeys(motor, 0)
    while True:
        fresh = random_motor(world, rng)
        for name in motor:
            if hold[name] <= 0:
                motor[name] = fresh[name]
                hold[name] = int(rng.integers(0, MAX_HOLD + 1))
            hold[name] -= 1
        yield dict(motor)


def _check_spec(world: World) -> None:
    name = getattr(world, "name", None)
    _require(isinstance(name, str) and name, f"{world!r}: name must be a non-empty str")
    where = f"world {name!r}"
    variables = world.variables
    _require(isinstance(variables, tuple) and variables, f"{where}: variables must be a tuple")
    names = [v.name for v in variables]
    _require(len(set(names)) == len(names), f"{where}: duplicate variable names {names}")
    seen_sensed = False
    for v in variables:
        _require(isinstance(v, VariableSpec), f"{where}: {v!r} is not a VariableSpec")
        _require(isinstance(v.kind, VarKind), f"{where}: {v.name}: kind {v.kind!r}")
        _require(v.meaning.strip(), f"{where}: {v.name}: empty meaning")
        _require("." not in v.name, f"{where}: {v.name}: '.' is reserved for '.dot'")
        if v.kind is VarKind.MOTOR:
            _require(not seen_sensed, f"{where}: motor {v.name} comes after a sensed variable")
            _require(v.low is not None and v.high is not None, f"{where}: motor {v.name}: no range")
            _require(
                math.isfinite(v.low) and math.isfinite(v.high) and v.low < v.high,
                (f"{where}: motor {v.name}: bad range [{v.low}, {v.high}]"),
            )
            _require(v.available_from == 0, f"{where}: motor {v.name} must be available from 0")
        else:
            seen_sensed = True
        if v.kind is VarKind.NOMINAL:
            _require(len(v.values) >= 2, f"{where}: nominal {v.name} needs at least two labels")
        _require(v.available_from >= 0, f"{where}: {v.name}: negative available_from")
    _require(any(v.kind is VarKind.MOTOR for v in variables), f"{where}: no motor")
    _require(isinstance(world.substeps, int) and world.substeps >= 1, f"{where}: substeps")
    seconds = getattr(world, "step_seconds", None)
    _require(
        isinstance(seconds, (int, float))
        and not isinstance(seconds, bool)
        and math.isfinite(seconds)
        and seconds > 0,
        f"{where}: step_seconds must be a positive finite number of seconds, got {seconds!r}",
    )
    _require(isinstance(world.agent_options, Mapping), f"{where}: agent_options not a Mapping")
    _require(isinstance(world.tasks, Mapping), f"{where}: tasks not a Mapping")
    for key, task in world.tasks.items():
        _require(isinstance(task, Task), f"{where}: task {key!r} is not a Task")
        _require(task.name == key, f"{where}: task {key!r} is named {task.name!r}")
        _require(task.max_steps > 0, f"{where}: task {key!r}: max_steps")
    for c in (*world.constant_variables, *world.rare_variables):
        _require(c in names, f"{where}: exempted variable {c!r} is not a variable")


def _check_obs(world: World, obs: object, step: int) -> None:
    where = f"world {world.name!r} at step {step}"
    _require(isinstance(obs, dict), f"{where}: observation is {type(obs).__name__}, not dict")
    expected = set(world.available_names(step))
    got = set(obs)
    _require(
        got == expected,
        (
            f"{where}: observation keys differ from the available variables: "
            f"missing {sorted(expected - got)}, unexpected {sorted(got - expected)}"
        ),
    )
    specs = {v.name: v for v in world.variables}
    for key, value in obs.items():
        _require(isinstance(value, float), f"{where}: {key} is {type(value).__name__}, not float")
        _require(math.isfinite(value), f"{where}: {key} = {value} is not finite")
        spec = specs[key]
        if spec.kind is VarKind.NOMINAL:
            _require(
                value == int(value) and 0 <= value < len(spec.values),
                (f"{where}: nominal {key} = {value} is not an index into {spec.values}"),
            )


def _check_flag(world: World, step: int) -> bool:
    flag = getattr(world, "discontinuity", None)
    _require(
        type(flag) is bool,
        f"world {world.name!r} at step {step}: discontinuity is {flag!r}, not a bool",
    )
    return flag  # type: ignore[return-value]


def _run(world: World, steps: int, seed: int) -> tuple[list[dict[str, float]], list[bool]]:
    """A random-motor run: each motor holds a uniform random value for 0..MAX_HOLD steps."""
    rng = np.random.default_rng(seed + 1)
    obs = world.reset(seed=seed)
    _require(world.step_count == 0, f"world {world.name!r}: step_count after reset is not 0")
    _check_obs(world, obs, 0)
    _require(_check_flag(world, 0), f"world {world.name!r}: discontinuity is False after reset")
    trace, flags = [obs], [True]
    motors = held_motors(world, rng)
    for t in range(1, steps + 1):
        obs = world.step(next(motors))
        _require(
            world.step_count == t, f"world {world.name!r}: step_count {world.step_count} != {t}"
        )
        _check_obs(world, obs, t)
        trace.append(obs)
        flags.append(_check_flag(world, t))
    return trace, flags


def _check_state(world: World, steps: int, seed: int) -> None:
    """``get_state``/``set_state`` round-trip through JSON: step ``steps // 2``, save, step the
    rest; restore, step the same motors again: identical observations and flags."""
    where = f"world {world.name!r}"
    rng = np.random.default_rng(seed + 2)
    world.reset(seed=seed)
    held = held_motors(world, rng)
    half = max(1, steps // 2)
    obs = {}
    for _ in range(half):
        obs = world.step(next(held))
    try:
        text = json.dumps(world.get_state(), allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise AssertionError(f"{where}: get_state() is not JSON-able: {exc}") from None
    saved_flag = world.discontinuity
    motors = [next(held) for _ in range(max(1, steps - half))]
    first = [(world.step(m), world.discontinuity) for m in motors]
    restored = world.set_state(json.loads(text))
    _require(restored == obs and world.discontinuity == saved_flag
             and world.step_count == half,
             f"{where}: set_state() does not give back the observation, flag and step count "
             f"saved at step {half}")
    again = [(world.step(m), world.discontinuity) for m in motors]
    for t, (a, b) in enumerate(zip(first, again, strict=True), start=half + 1):
        _require(a == b, f"{where}: after set_state the run differs at step {t}: "
                         f"{ {k: (a[0][k], b[0].get(k)) for k in a[0] if a[0][k] != b[0].get(k)} }"
                         f" (discontinuity {a[1]} vs {b[1]})")
    try:
        world.set_state({**json.loads(text), "world": "no such world"})
    except ValueError:
        pass
    else:
        raise AssertionError(f"{where}: set_state() accepted the state of another world")


def _check_jumps(world: World, trace: list[dict[str, float]], flags: list[bool]) -> None:
    """Large changes of a magnitude happen only on steps marked as discontinuities."""
    magnitudes = [v.name for v in world.variables if v.kind is VarKind.MAGNITUDE]
    for name in magnitudes:
        values = [obs[name] for obs in trace if name in obs]
        if len(values) < 2:
            continue
        span = max(values) - min(values)
        changes = [
            (t, abs(cur[name] - prev[name]))
            for t, (prev, cur) in enumerate(itertools.pairwise(trace), start=1)
            if name in prev and name in cur and not flags[t]
        ]
        if span == 0 or not changes:
            continue
        mean = sum(c for _, c in changes) / len(changes)
        scale = max(abs(v) for v in values)
        limit = max(
            JUMP_RANGE_FRACTION * span, JUMP_MEAN_FACTOR * mean, JUMP_SCALE_FRACTION * scale
        )
        for t, change in changes:
            _require(
                change <= limit,
                (
                    f"world {world.name!r}: {name} jumped by {change:.4g} at step {t} "
                    f"({trace[t - 1][name]:.4g} -> {trace[t][name]:.4g}; range over the run "
                    f"{span:.4g}, mean change {mean:.4g}) but discontinuity was False"
                ),
            )


def check_world(world: World, steps: int = 300, seed: int = 0) -> None:
    """Check ``world`` against the contract; raise AssertionError naming what is wrong.

    Checked: the variable table (names unique, motors first with finite ranges, nominal labels),
    ``substeps``, ``step_seconds`` (a positive number), ``tasks``, ``agent_options``; that
    ``reset`` and every ``step`` of a random-motor run of ``steps`` steps (each motor holding a
    uniform random value for 0..``MAX_HOLD`` steps) return exactly the variables available at
    that step, as finite floats (nominal ones as label indices); that ``discontinuity`` is a bool
    after every step and True after ``reset``; that no magnitude jumps on a step not marked as a
    discontinuity (a jump: a change larger than ``JUMP_RANGE_FRACTION`` of the variable's range
    over the run, ``JUMP_MEAN_FACTOR`` times its mean change per step and
    ``JUMP_SCALE_FRACTION`` of its largest magnitude); that the run,
    discontinuity flags included, is identical when repeated with the same seed; that no sensed
    variable stays constant over the run, except the world's declared ``constant_variables``
    (which must be constant) and ``rare_variables`` (rare events); that ``get_state`` is
    JSON-able and ``set_state`` continues exactly (same observations and flags for the same
    motors); and that bad motor input raises ValueError.
    """
    _check_spec(world)
    _check_state(world, steps, seed)
    first, first_flags = _run(world, steps, seed)
    second, second_flags = _run(world, steps, seed)
    _require(
        first_flags == second_flags,
        f"world {world.name!r}: discontinuity flags not deterministic for seed {seed}",
    )
    _check_jumps(world, first, first_flags)
    for t, (a, b) in enumerate(zip(first, second, strict=True)):
        _require(
            a == b,
            (
                f"world {world.name!r}: not deterministic for seed {seed}: step {t} differs: "
                f"{ {k: (a[k], b.get(k)) for k in a if a[k] != b.get(k)} }"
            ),
        )
    seen: dict[str, set[float]] = {}
    for obs in first:
        for key, value in obs.items():
            seen.setdefault(key, set()).add(value)
    for key, values in seen.items():
        if key in world.constant_variables:
            _require(
                len(values) == 1, f"world {world.name!r}: {key} is declared constant but varies"
            )
        elif key not in world.rare_variables:
            _require(
                len(values) > 1,
                (
                    f"world {world.name!r}: {key} stayed at {next(iter(values))} for {steps} "
                    f"random-motor steps (seed {seed})"
                ),
            )
    motor = world.motor_names[0]
    spec = next(v for v in world.variables if v.name == motor)
    assert spec.high is not None
    for bad, fragment in (
        ({"no_such_motor": 0.0}, "no_such_motor"),
        ({motor: math.nan}, motor),
        ({motor: spec.high + abs(spec.high) + 1.0}, motor),
    ):
        try:
            world.step(bad)
        except ValueError as error:
            message = str(error)
        else:
            raise AssertionError(f"world {world.name!r}: step({bad}) did not raise ValueError")
        _require(fragment in message, f"world {world.name!r}: unclear error {message}")
