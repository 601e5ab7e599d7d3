"""Saving and loading the learner's whole state: documented JSON + npz, versioned, no pickle.

A checkpoint is a directory holding ``<name>.json`` (structure, small values) and ``<name>.npz``
(arrays, loaded with ``allow_pickle=False``). Both are written to temporary files and renamed, so
a crash never leaves a half-written checkpoint. The JSON's ``format`` and ``version`` fields are
checked on load; a missing, corrupt or foreign checkpoint raises :class:`CheckpointError` with
the path and the reason. Schema: ``docs/checkpoint.md``.
"""

from __future__ import annotations

import io
import json
import os
import tempfile
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np

from .dbn import DBN
from .delta import Delta
from .learner import ModelLearner
from .params import Params
from .quantity import QuantitySpace
from .variables import Event, VariableTable

FORMAT = "qlap-learner"
VERSION = 1


class CheckpointError(ValueError):
    """A checkpoint that cannot be read (missing, corrupt, wrong format or version)."""


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temporary file in the same directory and a rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_write_json(path: Path, obj: Any) -> None:
    atomic_write_bytes(path, json.dumps(obj, indent=1, sort_keys=True).encode())


def learner_state(learner: ModelLearner) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The learner's complete state as (JSON object, arrays)."""
    per = learner.perception
    arrays: dict[str, np.ndarray] = {
        "perception.prev_x": per.prev_x, "perception.prev_q": per.prev_q,
        "perception.hist_x": per.hist_x, "perception.hist_q": per.hist_q}
    pairs_meta, pairs_arrays = learner.pairs.to_state()
    arrays.update({f"pairs.{k}": v for k, v in pairs_arrays.items()})
    dbns = []
    pos: dict[int, dict[int, int]] = {}
    for dbn_id in sorted(learner.dbns):
        d = learner.dbns[dbn_id]
        pos[dbn_id] = {id(e): i for i, e in enumerate(d.pending)}
        dbns.append({"id": d.id, "kind": d.kind, "antecedent": list(d.antecedent),
                     "consequent": list(d.consequent), "context": list(d.context),
                     "created": d.created, "ever_reliable": d.ever_reliable,
                     "is_plan": d.is_plan, "act_n": d.act_n, "act_head": d.act_head,
                     "total": d.total, "pending": [[e[0], e[2]] for e in d.pending]})
        arrays[f"dbn.{dbn_id}.act_x"] = d.act_x
        arrays[f"dbn.{dbn_id}.act_ok"] = d.act_ok
        arrays[f"dbn.{dbn_id}.cpt_s"] = d.cpt_s
        arrays[f"dbn.{dbn_id}.cpt_f"] = d.cpt_f
        if d.pending:
            arrays[f"dbn.{dbn_id}.pending_x"] = np.stack([e[1] for e in d.pending])
    expiry = [[t, d.id, pos[d.id][id(e)]] for t, d, e in learner._expiry
              if d.id in pos and id(e) in pos[d.id]]
    meta = {
        "format": FORMAT, "version": VERSION,
        "params": learner.params.to_dict(), "variables": learner.table.to_json(),
        "step": learner.step, "k": learner.k, "k_learned": learner.k_learned,
        "next_id": learner.next_id, "delta_version": learner.version,
        "perception": {"spaces": [s.to_json() for s in per.spaces],
                       "hist_len": per.hist_len, "hist_head": per.hist_head,
                       "steps_seen": per.steps_seen, "all_seen": per._all_seen},
        "pairs": pairs_meta, "window": learner.window.to_state(), "dbns": dbns,
        "expiry": expiry,
        "mag_active": [[y, [d.id for d in ds]] for y, ds in learner._mag_active.items()],
        "pending_deltas": [dict(d.to_json(), applied=d.applied)
                           for d in learner.pending_deltas],
        "applied": learner.applied, "applied_count": learner.applied_count,
        "splits": [list(x) for x in learner.splits],
        "reliable_actions": sorted([list(a) for a in learner.reliable_actions]),
    }
    return meta, arrays


def save_learner(learner: ModelLearner, directory: str | Path, name: str = "learner") -> Path:
    """Write the learner's state to ``directory/name.{json,npz}`` atomically."""
    directory = Path(directory)
    meta, arrays = learner_state(learner)
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    atomic_write_bytes(directory / f"{name}.npz", buf.getvalue())
    atomic_write_json(directory / f"{name}.json", meta)
    return directory


def read_checkpoint(directory: str | Path, name: str = "learner"
                    ) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    directory = Path(directory)
    jpath, npath = directory / f"{name}.json", directory / f"{name}.npz"
    try:
        meta = json.loads(jpath.read_text())
    except FileNotFoundError:
        raise CheckpointError(f"{jpath}: no such checkpoint file") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise CheckpointError(f"{jpath}: corrupt JSON ({exc})") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise CheckpointError(f"{jpath}: not a {FORMAT} checkpoint")
    if meta.get("version") != VERSION:
        raise CheckpointError(f"{jpath}: version {meta.get('version')!r} is not supported "
                              f"(this build reads version {VERSION})")
    try:
        with np.load(npath, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except FileNotFoundError:
        raise CheckpointError(f"{npath}: no such checkpoint file") from None
    except Exception as exc:  # zipfile/np errors on corrupt data
        raise CheckpointError(f"{npath}: corrupt array file ({exc})") from None
    return meta, arrays


def load_learner(directory: str | Path, name: str = "learner") -> ModelLearner:
    """Rebuild a learner that continues exactly as the saved one would."""
    meta, arrays = read_checkpoint(directory, name)
    try:
        return restore_learner(meta, arrays)
    except (KeyError, ValueError, TypeError, IndexError) as exc:
        raise CheckpointError(f"{Path(directory) / name}: inconsistent checkpoint "
                              f"({type(exc).__name__}: {exc})") from None


def restore_learner(meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> ModelLearner:
    params = Params.from_dict(meta["params"])
    learner = ModelLearner(VariableTable.from_json(meta["variables"]), params)
    per = learner.perception
    per.spaces = [QuantitySpace.from_json(s) for s in meta["perception"]["spaces"]]
    per._rebuild()
    per.prev_x = arrays["perception.prev_x"].astype(float)
    per.prev_q = arrays["perception.prev_q"].astype(np.int64)
    per.hist_x = arrays["perception.hist_x"].astype(float)
    per.hist_q = arrays["perception.hist_q"].astype(np.int16)
    pm = meta["perception"]
    per.hist_len, per.hist_head = int(pm["hist_len"]), int(pm["hist_head"])
    per.steps_seen, per._all_seen = int(pm["steps_seen"]), bool(pm["all_seen"])
    learner.step, learner.k, learner.k_learned = int(meta["step"]), int(meta["k"]), \
        bool(meta["k_learned"])
    learner.next_id, learner.version = int(meta["next_id"]), int(meta["delta_version"])
    learner.pairs.reset(per.events)
    learner.pairs.load_state(meta["pairs"], {k[6:]: v for k, v in arrays.items()
                                             if k.startswith("pairs.")})
    learner.window.load_state(meta["window"])
    cap, n = params.stored_activations, len(learner.table)
    for d in meta["dbns"]:
        i = int(d["id"])
        dbn = DBN(i, d["kind"], Event(*d["antecedent"]), Event(*d["consequent"]),
                  tuple(d["context"]), int(d["created"]), n, cap)
        dbn.ever_reliable, dbn.is_plan = bool(d["ever_reliable"]), bool(d["is_plan"])
        dbn.act_n, dbn.act_head, dbn.total = int(d["act_n"]), int(d["act_head"]), int(d["total"])
        dbn.act_x = arrays[f"dbn.{i}.act_x"].astype(float)
        dbn.act_ok = arrays[f"dbn.{i}.act_ok"].astype(bool)
        dbn.cpt_s = arrays[f"dbn.{i}.cpt_s"].astype(float)
        dbn.cpt_f = arrays[f"dbn.{i}.cpt_f"].astype(float)
        px = arrays.get(f"dbn.{i}.pending_x")
        dbn.pending = [[int(t), px[j].astype(float), bool(res)]
                       for j, (t, res) in enumerate(d["pending"])]
        learner.dbns[i] = dbn
    learner._expiry = deque((int(t), learner.dbns[int(i)], learner.dbns[int(i)].pending[int(j)])
                            for t, i, j in meta["expiry"])
    learner._mag_active = {int(y): [learner.dbns[int(i)] for i in ids]
                           for y, ids in meta["mag_active"]}
    learner.pending_deltas = deque(
        Delta.from_json(d).mark_applied() if d.get("applied") else Delta.from_json(d)
        for d in meta["pending_deltas"])
    learner.applied = list(meta["applied"])
    learner.applied_count = int(meta.get("applied_count", 0))
    learner.splits = [(int(a), int(b)) for a, b in meta.get("splits", [])]
    learner.reliable_actions = {(int(a), int(b)) for a, b in meta["reliable_actions"]}
    learner._reindex()
    return learner


# ---------------------------------------------------------------------------------------------
# The whole agent (ch. 5–6): the learner's files plus agent.json / agent.npz
# ---------------------------------------------------------------------------------------------
AGENT_FORMAT = "qlap-agent"
AGENT_VERSION = 1


def save_agent(agent: Any, directory: str | Path, world: str | None = None) -> Path:
    """Write the agent's full state (learner, actions, plans, call list, RNG) atomically.

    ``world``: the spec of the world the agent learned in (``qlap eval``/``qlap curve`` read it
    so that an evaluation needs no ``--world``)."""
    from .mdp import q_to_state

    directory = Path(directory)
    save_learner(agent.learner, directory)
    arrays: dict[str, np.ndarray] = {}
    plans = []
    for pid in sorted(agent.plans):
        pl = agent.plans[pid]
        plans.append({"id": pl.id, "dbn_id": pl.dbn_id, "kind": pl.kind, "created": pl.created,
                      "context_o": list(pl.context_o), "call_n": pl.call_n,
                      "call_head": pl.call_head, "calls": pl.calls,
                      "successes": pl.successes, "ever_reliable": bool(pl.ever_reliable),
                      "q": q_to_state(pl.q)})
        arrays[f"plan.{pid}.call_x"] = pl.call_x
        arrays[f"plan.{pid}.call_ok"] = pl.call_ok
        arrays[f"plan.{pid}.cpt_s"] = pl.cpt_s
        arrays[f"plan.{pid}.cpt_f"] = pl.cpt_f
        arrays[f"plan.{pid}.traces"] = pl.sarsa.e if pl.sarsa is not None else np.zeros(0)
    c = agent.counters
    meta = {
        "format": AGENT_FORMAT, "version": AGENT_VERSION,
        "seed_state": agent.rng.bit_generator.state,
        "babbler": agent.babbler.to_state(), "actions": agent.actions.to_json(),
        "plans": plans, "next_plan_id": agent.next_plan_id,
        "call_list": [f.to_json() for f in agent.call_list], "motor": agent.motor,
        "mode": agent.mode, "hold_until": agent.hold_until,
        "goal": list(agent.goal) if agent.goal is not None else None,
        "goal_idle": agent.goal_idle, "learning": agent.learning,
        "iac_log": [ch.to_dict() for ch in agent.iac_log],
        "counters": {k: v for k, v in c.__dict__.items()},
        "self_vars": sorted(agent.self_vars), "step_count": agent.step_count,
        "seen_applied": agent._seen_applied,
    }
    if world is not None:
        meta["world"] = str(world)
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    atomic_write_bytes(directory / "agent.npz", buf.getvalue())
    atomic_write_json(directory / "agent.json", meta)
    return directory


def load_agent(directory: str | Path) -> Any:
    """Rebuild an agent that continues exactly as the saved one would."""
    from .actions import ActionTable
    from .agent import Agent, AgentCounters, Frame
    from .curiosity import IACChoice
    from .mdp import SarsaLambda, q_from_state
    from .planner import Plan

    directory = Path(directory)
    learner = load_learner(directory)
    jpath = directory / "agent.json"
    try:
        meta = json.loads(jpath.read_text())
        with np.load(directory / "agent.npz", allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except FileNotFoundError as exc:
        raise CheckpointError(f"{directory}: not an agent checkpoint ({exc.filename} missing)"
                              ) from None
    except Exception as exc:
        raise CheckpointError(f"{directory}: corrupt agent checkpoint ({exc})") from None
    if meta.get("format") != AGENT_FORMAT or meta.get("version") != AGENT_VERSION:
        raise CheckpointError(f"{jpath}: not a {AGENT_FORMAT} v{AGENT_VERSION} checkpoint")
    try:
        agent = Agent(learner.table, learner.params)
        agent.learner = learner
        agent.rng.bit_generator.state = meta["seed_state"]
        agent.babbler.load_state(meta["babbler"])
        agent.actions = ActionTable.from_json(meta["actions"], learner.params)
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
            agent.plans[pid] = pl
            agent._rebuild(pl, fresh=True)
            pl.q = q_from_state(d["q"])
            traces = arrays[f"plan.{pid}.traces"]
            pl.sarsa = SarsaLambda(pl.q, learner.params,
                                   traces.astype(float) if traces.size else None)
        agent.next_plan_id = int(meta["next_plan_id"])
        agent.call_list = [Frame.from_json(f) for f in meta["call_list"]]
        agent.motor = {k: float(v) for k, v in meta["motor"].items()}
        agent.mode, agent.hold_until = meta["mode"], int(meta["hold_until"])
        agent.goal = tuple(meta["goal"]) if meta["goal"] is not None else None
        agent.goal_idle, agent.learning = meta["goal_idle"], bool(meta["learning"])
        agent.iac_log.extend(
            IACChoice(c["step"], tuple(c["action"]) if c["action"] else None, c["weight"],
                      c["n_applicable"], c["babbling"], tuple(c["weights"]))
            for c in meta["iac_log"])
        agent.counters = AgentCounters(**meta["counters"])
        agent.self_vars = set(meta["self_vars"])
        agent.step_count = int(meta["step_count"])
        agent._seen_applied = int(meta["seen_applied"])
    except (KeyError, ValueError, TypeError, IndexError) as exc:
        raise CheckpointError(f"{directory}: inconsistent agent checkpoint "
                              f"({type(exc).__name__}: {exc})") from None
    return agent
