"""The whole agent's checkpoint (ch. 5–6): the learner's files plus ``agent.json`` / ``agent.npz``.

``agent.json`` is written last: it makes a directory an agent checkpoint.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from .files import (
    CheckpointError,
    group_arrays,
    pack_rows,
    read_npz,
    resolve_checkpoint,
    ungroup_arrays,
    unpack_rows,
    write_compact_json,
    write_npz,
)
from .learner_files import check_agent, load_learner, save_learner

WORLD_FILE = "world.json"
"""The world's state in a checkpoint (``World.get_state``), for an exact ``--resume``."""
AGENT_FILE = "agent.json"
"""The file that makes a directory an agent checkpoint; written last."""

AGENT_FORMAT = "qlap-agent"
AGENT_VERSION = 3
AGENT_READABLE_VERSIONS = (1, 2, 3)
"""1: Q-tables in agent.json (indented); 2: Q-tables in agent.npz as they are, compact JSON;
3: Q-tables in agent.npz as the mask of their not-applicable entries and their other values
byte-shuffled (:func:`_pack_q`), the per-plan arrays grouped into one array per field."""


def _pack_q(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A Q-table as (packed bit mask of its not-applicable entries, row-major; the other values
    as an (8, n) uint8 array: byte k of every value, little-endian float64, in row k). The
    Q-values of one plan share their sign and exponent bytes, which deflate then finds together
    (a third smaller than the plain array); the round trip is byte-exact."""
    from ..mdp import NOT_APPLICABLE

    q = np.ascontiguousarray(q, dtype=np.float64)
    na = q == NOT_APPLICABLE
    values = np.ascontiguousarray(q[~na], dtype="<f8")          # little-endian on any host
    return np.packbits(na.ravel()), np.ascontiguousarray(values.view(np.uint8)
                                                         .reshape(-1, 8).T)


def _unpack_q(shape: tuple[int, ...], na_bits: np.ndarray, shuffled: np.ndarray) -> np.ndarray:
    """Inverse of :func:`_pack_q`."""
    from ..mdp import NOT_APPLICABLE

    n = int(np.prod(shape))
    na = np.unpackbits(na_bits, count=n).astype(bool).reshape(shape)
    q = np.full(shape, NOT_APPLICABLE, dtype=np.float64)
    q[~na] = np.ascontiguousarray(shuffled.T).view("<f8").ravel()
    return q


def save_agent(agent: Any, directory: str | Path, world: str | None = None,
               fast: bool = False) -> Path:
    """Write the agent's full state (learner, actions, plans, call list, RNG) atomically.

    ``world``: the spec of the world the agent learned in (``qlap eval``/``qlap curve`` read it
    so that an evaluation needs no ``--world``). ``fast``: plain arrays, uncompressed (see
    :func:`save_learner`)."""
    directory = Path(directory)
    save_learner(agent.learner, directory, fast=fast)
    arrays: dict[str, np.ndarray] = {}
    plans = []
    for pid in sorted(agent.plans):
        pl = agent.plans[pid]
        plans.append({"id": pl.id, "dbn_id": pl.dbn_id, "kind": pl.kind, "created": pl.created,
                      "context_o": list(pl.context_o), "call_n": pl.call_n,
                      "call_head": pl.call_head, "calls": pl.calls,
                      "successes": pl.successes, "ever_reliable": bool(pl.ever_reliable),
                      "q_shape": list(np.shape(pl.q))})
        arrays[f"plan.{pid}.q_na"], arrays[f"plan.{pid}.q_values"] = _pack_q(pl.q)
        arrays[f"plan.{pid}.call_x"] = pl.call_x
        arrays[f"plan.{pid}.call_ok"] = pl.call_ok
        arrays[f"plan.{pid}.cpt_s"] = pl.cpt_s
        arrays[f"plan.{pid}.cpt_f"] = pl.cpt_f
        arrays[f"plan.{pid}.traces"] = pl.sarsa.e if pl.sarsa is not None else np.zeros(0)
    c = agent.counters
    meta = {
        "format": AGENT_FORMAT, "version": AGENT_VERSION,
        "seed_state": agent.rng.bit_generator.state, "seed": agent.seed,
        "babbler": agent.babbler.to_state(), "actions": agent.actions.to_json(),
        "plans": plans, "next_plan_id": agent.next_plan_id,
        "call_list": [f.to_json() for f in agent.call_list], "motor": agent.motor,
        "mode": agent.mode, "hold_until": agent.hold_until,
        "goal": list(agent.goal) if agent.goal is not None else None,
        "goal_idle": agent.goal_idle, "learning": agent.learning,
        "iac_log": [ch.to_dict() for ch in agent.iac_log],
        "counters": {k: v for k, v in c.__dict__.items()},
        "self_vars": sorted(agent.self_vars), "step_count": agent.step_count,
        **agent.to_state(),                         # seen_applied
    }
    if world is not None:
        meta["world"] = str(world)
    write_npz(directory / "agent.npz", arrays if fast else
               group_arrays(pack_rows(arrays, [k for k in arrays if k.endswith(".call_x")]),
                      "plan"), fast)
    write_compact_json(directory / AGENT_FILE, meta)
    return directory


def checkpoint_seed(directory: str | Path) -> int | None:
    """The seed of the run an agent checkpoint comes from (``agent.json``'s ``seed``), or
    None when the checkpoint does not record it (older ones) or cannot be read (loading it
    says why)."""
    try:
        seed = json.loads((resolve_checkpoint(directory) / "agent.json").read_text()).get("seed")
    except (OSError, ValueError, AttributeError, CheckpointError):
        return None
    return seed if isinstance(seed, int) and not isinstance(seed, bool) else None


def load_agent(directory: str | Path) -> Any:
    """Rebuild an agent that continues exactly as the saved one would."""
    from ..actions import ActionTable
    from ..agent import Agent, AgentCounters, Frame
    from ..curiosity import IACChoice
    from ..mdp import NOT_APPLICABLE, SarsaLambda, q_from_state
    from ..planner import Plan

    directory = resolve_checkpoint(directory)
    learner = load_learner(directory)
    jpath = directory / "agent.json"
    what = jpath
    try:
        meta = json.loads(jpath.read_text())
        what = directory / "agent.npz"
        arrays = unpack_rows(ungroup_arrays(read_npz(what)))
    except FileNotFoundError as exc:
        raise CheckpointError(f"{directory}: not an agent checkpoint ({exc.filename} missing)"
                              ) from None
    except Exception as exc:
        raise CheckpointError(f"{what}: corrupt agent checkpoint ({exc})") from None
    if not isinstance(meta, dict) or meta.get("format") != AGENT_FORMAT:
        raise CheckpointError(f"{jpath}: not a {AGENT_FORMAT} checkpoint")
    if meta.get("version") not in AGENT_READABLE_VERSIONS:
        raise CheckpointError(f"{jpath}: {AGENT_FORMAT} version {meta.get('version')!r} is "
                              f"not supported (this build reads versions "
                              f"{', '.join(map(str, AGENT_READABLE_VERSIONS))})")
    check_agent(meta, learner, jpath)
    part = "seed_state"                             # the field being read, for the error
    try:
        agent = Agent(learner.table, learner.params)
        agent.learner = learner
        agent.rng.bit_generator.state = meta["seed_state"]
        agent.seed = meta.get("seed")              # older checkpoints: not recorded
        part = "babbler"
        agent.babbler.load_state(meta["babbler"])
        part = "actions"
        agent.actions = ActionTable.from_json(meta["actions"], learner.params)
        part = "plans"
        for d in meta["plans"]:
            dbn = learner.dbns[int(d["dbn_id"])]
            pl = Plan(int(d["id"]), dbn, learner.table, learner.params, int(d["created"]),
                      len(learner.table))
            pid = pl.id
            pl.context_o = tuple(d["context_o"])
            pl.call_n, pl.call_head = int(d["call_n"]), int(d["call_head"])
            pl.calls, pl.successes = int(d["calls"]), int(d["successes"])
            pl.ever_reliable = bool(d.get("ever_reliable", False))
            pl.call_x = arrays[f"plan.{pid}.call_x"].astype(float)
            pl.call_ok = arrays[f"plan.{pid}.call_ok"].astype(bool)
            pl.cpt_s = arrays[f"plan.{pid}.cpt_s"].astype(float)
            pl.cpt_f = arrays[f"plan.{pid}.cpt_f"].astype(float)
            if "q" in d:                                        # version 1
                q = q_from_state(d["q"])
            elif f"plan.{pid}.q" in arrays:                    # version 2
                q = arrays[f"plan.{pid}.q"].astype(float)
                q = np.where(np.isfinite(q), q, NOT_APPLICABLE)
            else:
                q = _unpack_q(tuple(int(n) for n in d["q_shape"]),
                              arrays[f"plan.{pid}.q_na"], arrays[f"plan.{pid}.q_values"])
            agent.restore_plan(pl, q)           # the saved Q-table: no value iteration
            pl.q = q
            traces = arrays[f"plan.{pid}.traces"]
            pl.sarsa = SarsaLambda(pl.q, learner.params,
                                   traces.astype(float) if traces.size else None)
        part = "next_plan_id"
        agent.next_plan_id = int(meta["next_plan_id"])
        part = "call_list"
        agent.call_list = [Frame.from_json(f) for f in meta["call_list"]]
        part = "motor"
        agent.motor = {k: float(v) for k, v in meta["motor"].items()}
        part = "mode, hold_until, goal, goal_idle or learning"
        agent.mode, agent.hold_until = meta["mode"], int(meta["hold_until"])
        agent.goal = tuple(meta["goal"]) if meta["goal"] is not None else None
        agent.goal_idle, agent.learning = meta["goal_idle"], bool(meta["learning"])
        part = "iac_log"
        agent.iac_log.extend(
            IACChoice(c["step"], tuple(c["action"]) if c["action"] else None, c["weight"],
                      c["n_applicable"], c["babbling"], tuple(c["weights"]))
            for c in meta["iac_log"])
        part = "counters"
        agent.counters = AgentCounters(**meta["counters"])
        part = "self_vars, step_count or seen_applied"
        agent.self_vars = set(meta["self_vars"])
        agent.step_count = int(meta["step_count"])
        agent.load_state(meta)                      # seen_applied
    except (KeyError, ValueError, TypeError, IndexError, AttributeError) as exc:
        raise CheckpointError(f"{jpath}: inconsistent agent checkpoint in "
                              f"{part} ({type(exc).__name__}: {exc})") from None
    return agent


