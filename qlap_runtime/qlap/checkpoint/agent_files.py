"""The whole agent's checkpoint (ch. 5–6): the learner's files plus ``agent.json`` / ``agent.npz``.

``agent.json`` is written last: it makes a directory an agent checkpoint.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from .checks import (
    bad,
    check_owned,
    check_ring,
    check_shape,
    is_int,
    new_id,
    numeric_array,
    one_line,
)
from .files import (
    CheckpointError,
    InconsistentArray,
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
    except InconsistentArray as exc:
        raise bad(directory / "agent", exc.field, exc.why) from None
    except Exception as exc:
        raise CheckpointError(f"{what}: corrupt agent checkpoint ({one_line(exc)})") from None
    if not isinstance(meta, dict) or meta.get("format") != AGENT_FORMAT:
        raise CheckpointError(f"{jpath}: not a {AGENT_FORMAT} checkpoint")
    if meta.get("version") not in AGENT_READABLE_VERSIONS:
        raise CheckpointError(f"{jpath}: {AGENT_FORMAT} version {meta.get('version')!r} is "
                              f"not supported (this build reads versions "
                              f"{', '.join(map(str, AGENT_READABLE_VERSIONS))})")
    check_agent(meta, learner, jpath)
    where = directory / "agent"                     # agent.json + agent.npz, as "…/learner"
    check_plan_arrays(meta, arrays, learner, where)
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
                try:
                    q = _unpack_q(tuple(int(n) for n in d["q_shape"]),
                                  arrays[f"plan.{pid}.q_na"], arrays[f"plan.{pid}.q_values"])
                except ValueError:              # not as many values as applicable entries
                    raise bad(where, f"plan.{pid}.q_values", f"does not hold a value for "
                                                              f"each applicable entry of "
                                                              f"plan.{pid}.q_na") from None
            agent.restore_plan(pl, q)           # the saved Q-table: no value iteration
            shape = pl.model.applicable.shape if pl.model is not None else q.shape
            if q.shape != shape:
                raise bad(where, _q_field(d, arrays), f"is a Q-table of shape {q.shape}, "
                                                       f"expected {shape} (plan {pid}'s states "
                                                       f"× actions)")
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
    except CheckpointError:
        raise
    except (KeyError, ValueError, TypeError, IndexError, AttributeError) as exc:
        raise CheckpointError(f"{jpath}: inconsistent agent checkpoint in "
                              f"{part} ({type(exc).__name__}: {one_line(exc)})") from None
    return agent


def _q_field(d: dict[str, Any], arrays: dict[str, np.ndarray]) -> str:
    """The name of a saved plan's Q-table, as its checkpoint's version stores it."""
    pid = d["id"]
    if "q" in d:
        return f"plans (id {pid}).q"                       # version 1: in agent.json
    return f"plan.{pid}.q" if f"plan.{pid}.q" in arrays else f"plan.{pid}.q_values"


def check_plan_arrays(meta: dict[str, Any], arrays: dict[str, np.ndarray], learner: Any,
                      where: Path) -> None:
    """The shapes of each plan's arrays (after :func:`check_agent`), from the learner's
    quantity spaces and the plan's fields: its calls' ring (``Params.stored_activations`` rows
    of the variables, ``call_n``/``call_head`` within it), its second-order CPT (one cell per
    value combination of C_o, §5.4.1), its Q-table as stored (``q_shape``, the bit mask and
    the values) and its traces (none, or the Q-table's shape). Whether the Q-table is the
    shape of the plan's states × actions is known once the plan is rebuilt
    (:func:`load_agent`). Shapes only: no scan of a large array."""
    cap, n = learner.params.stored_activations, len(learner.table)
    sizes = learner.perception.events.sizes
    ids: set[int] = set()
    for j, d in enumerate(meta["plans"]):
        pid = new_id(where, f"plans[{j}].id", d.get("id"), ids)
        ctx = d.get("context_o")
        if not isinstance(ctx, list) or not all(is_int(v) and 0 <= v < n for v in ctx):
            raise bad(where, f"plans[{j}].context_o", f"must list variables in 0..{n - 1}, "
                                                       f"got {ctx!r}")
        check_ring(where, f"plans[{j}]", d, ("call_n", "call_head"), cap)
        cells = math.prod(sizes[v] for v in ctx)
        ctx_why = f" (plan {pid}: C_o {ctx}, {cells} cells)"
        for field, shape, why in (
                ("call_x", (cap, n), " (params.stored_activations × variables)"),
                ("call_ok", (cap,), " (params.stored_activations)"),
                ("cpt_s", (cells,), ctx_why), ("cpt_f", (cells,), ctx_why)):
            key = f"plan.{pid}.{field}"
            check_shape(where, key, numeric_array(where, arrays, key), shape, why)
        q_shape = _stored_q_shape(where, j, d, arrays)
        key = f"plan.{pid}.traces"
        traces = numeric_array(where, arrays, key)
        if traces.size and q_shape is not None:
            check_shape(where, key, traces, q_shape, " (the Q-table's)")
    check_owned(where, arrays, "plan", ids, "plan")


def _stored_q_shape(where: Path, j: int, d: dict[str, Any], arrays: dict[str, np.ndarray]
                    ) -> tuple[int, ...] | None:
    """The shape of plan ``d``'s stored Q-table, its arrays checked against it (None: a
    version 1 table in agent.json, checked when read)."""
    pid = d["id"]
    if "q" in d:
        return None
    if f"plan.{pid}.q" in arrays:                                   # version 2
        q = numeric_array(where, arrays, f"plan.{pid}.q")
        if q.ndim != 2:
            raise bad(where, f"plan.{pid}.q", f"has shape {q.shape}, expected (states, "
                                               f"actions)")
        return q.shape
    q_shape = d.get("q_shape")
    if not (isinstance(q_shape, list) and len(q_shape) == 2
            and all(is_int(v) and v >= 0 for v in q_shape)):
        raise bad(where, f"plans[{j}].q_shape", f"must be [states, actions], got {q_shape!r}")
    entries = q_shape[0] * q_shape[1]
    check_shape(where, f"plan.{pid}.q_na", numeric_array(where, arrays, f"plan.{pid}.q_na"),
                 ((entries + 7) // 8,), f" (a bit per entry of the {tuple(q_shape)} Q-table)")
    values = numeric_array(where, arrays, f"plan.{pid}.q_values")
    if values.ndim != 2 or values.shape[0] != 8 or values.shape[1] > entries:
        raise bad(where, f"plan.{pid}.q_values", f"has shape {values.shape}, expected (8, "
                                                  f"at most {entries}) (the bytes of the "
                                                  f"{tuple(q_shape)} Q-table's values)")
    return tuple(q_shape)


