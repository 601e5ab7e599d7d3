"""Test worlds: core2d with NaN, ±inf, huge and non-numeric values and an unknown variable at
chosen steps, or raising at a step."""

from __future__ import annotations

import worlds

BAD = {300: float("nan"), 1000: 1e308, 1001: float("-inf"), 1700: float("inf"), 2000: 1e13,
       2200: "abc", 2400: ("zzz", 1.0)}
"""Step → the bad value of the first non-motor variable, or (name, value) of a variable the
world never declared."""
RAISE_AT = 900


def bad_world(bad: dict[int, object], raise_at: int | None = None):
    """core2d whose observation of agent step t gets ``bad[t]`` on its first non-motor
    variable, and whose ``step`` raises when it would return the observation of ``raise_at``."""
    w = worlds.make("core2d")
    var = next(v.name for v in w.variables if getattr(v.kind, "value", v.kind) != "motor")
    reset, step = w.reset, w.step
    state = {"t": 0}

    def obs_of(obs):
        if state["t"] in bad:
            obs, value = dict(obs), bad[state["t"]]
            if isinstance(value, tuple):
                obs[value[0]] = value[1]
            else:
                obs[var] = value
        return obs

    def bad_reset(seed=None, **kw):
        state["t"] = 0
        return obs_of(reset(seed=seed, **kw))

    def bad_step(motor):
        obs = step(motor)
        state["t"] += 1
        if raise_at is not None and state["t"] >= raise_at:
            raise RuntimeError("the physics exploded")
        return obs_of(obs)

    w.reset, w.step = bad_reset, bad_step
    return w


def bad_values():
    return bad_world(BAD)


def raising():
    return bad_world({}, RAISE_AT)
