"""The model learner's checkpoint: ``learner.json`` + ``learner.npz`` (ch. 4), checked on load.

A missing, corrupt or foreign file raises :class:`~.files.CheckpointError` naming the path and
the field; ``stats.json``/``stats.npz`` hold the DBN search's statistics an actor placement's
contingency actor writes beside the executor's checkpoint (:func:`save_statistics`).
"""

from __future__ import annotations

import json
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..dbn import DBN
from ..delta import Delta
from ..learner import ModelLearner
from ..params import Params
from ..variables import Event, VariableTable
from .files import (
    CheckpointError,
    group_arrays,
    not_a_checkpoint,
    pack_rows,
    read_npz,
    resolve_checkpoint,
    ungroup_arrays,
    unpack_rows,
    write_compact_json,
    write_npz,
)

FORMAT = "qlap-learner"
VERSION = 3
READABLE_VERSIONS = (1, 2, 3)
"""Versions :func:`read_checkpoint` reads (1: indented JSON, an npz entry per array; 2: compact
JSON, distinct rows; 3: as 2, the per-DBN arrays grouped into one array per field)."""

STATS_PART = "stats"
"""``stats.json``/``stats.npz``: the pair and window statistics of DBN search (§4.1,
Appendix C), written beside an actor placement's checkpoint by the contingency actor: the
executor's learner is a follower that does not keep them, and :func:`load_learner` puts them
in, so the checkpoint is the synchronous loop's."""
STATS_FORMAT = "qlap-learner-stats"


def learner_state(learner: ModelLearner) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The learner's complete state as (JSON object, arrays)."""
    per_meta, per_arrays = learner.perception.to_state()
    arrays: dict[str, np.ndarray] = {f"perception.{k}": v for k, v in per_arrays.items()}
    pairs_meta, pairs_arrays = learner.pairs.to_state()
    arrays.update({f"pairs.{k}": v for k, v in pairs_arrays.items()})
    dbns = []
    for dbn_id in sorted(learner.dbns):
        d = learner.dbns[dbn_id]
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
    meta = {
        "format": FORMAT, "version": VERSION,
        "params": learner.params.to_dict(), "variables": learner.table.to_json(),
        "step": learner.step, "k": learner.k, "k_learned": learner.k_learned,
        "next_id": learner.next_id, "delta_version": learner.version,
        "perception": per_meta,
        "pairs": pairs_meta, "window": learner.window.to_state(), "dbns": dbns,
        **learner.to_state(),                       # expiry, mag_active
        "pending_deltas": [dict(d.to_json(), applied=d.applied)
                           for d in learner.pending_deltas],
        "applied": learner.applied, "applied_count": learner.applied_count,
        "splits": [list(x) for x in learner.splits],
        "reliable_actions": sorted([list(a) for a in learner.reliable_actions]),
    }
    if learner.follower:                # no pair statistics: see STATS_PART
        meta["follower"] = True
    return meta, arrays


def save_learner(learner: ModelLearner, directory: str | Path, name: str = "learner",
                 fast: bool = False) -> Path:
    """Write the learner's state to ``directory/name.{json,npz}`` atomically; ``fast``: as
    plain arrays, uncompressed (a copy for another process, read once: the planner's)."""
    directory = Path(directory)
    meta, arrays = learner_state(learner)
    if not fast:
        rows = ["perception.hist_x"] + [k for k in arrays if k.startswith("dbn.")
                                        and k.endswith(("act_x", "pending_x"))]
        arrays = group_arrays(pack_rows(arrays, rows), "dbn")
    write_npz(directory / f"{name}.npz", arrays, fast)
    write_compact_json(directory / f"{name}.json", meta)
    return directory


def read_checkpoint(directory: str | Path, name: str = "learner"
                    ) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    directory = resolve_checkpoint(directory)
    jpath, npath = directory / f"{name}.json", directory / f"{name}.npz"
    not_one = not_a_checkpoint(directory)
    if not_one:
        raise CheckpointError(not_one)
    try:
        meta = json.loads(jpath.read_text())
    except FileNotFoundError:
        raise CheckpointError(f"{jpath}: no such checkpoint file") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise CheckpointError(f"{jpath}: corrupt JSON ({exc})") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise CheckpointError(f"{jpath}: not a {FORMAT} checkpoint")
    if meta.get("version") not in READABLE_VERSIONS:
        raise CheckpointError(f"{jpath}: {FORMAT} version {meta.get('version')!r} is not "
                              f"supported (this build reads versions "
                              f"{', '.join(map(str, READABLE_VERSIONS))})")
    arrays = _read_arrays(npath, lambda a: unpack_rows(ungroup_arrays(a)))
    return meta, arrays


def _read_arrays(npath: Path, then: Callable[[dict[str, np.ndarray]], dict[str, np.ndarray]]
                 = lambda a: a) -> dict[str, np.ndarray]:
    """The arrays of a checkpoint's ``.npz`` (passed through ``then``); a missing or corrupt
    file is a :class:`CheckpointError` naming it."""
    try:
        return then(read_npz(npath))
    except FileNotFoundError:
        raise CheckpointError(f"{npath}: no such checkpoint file") from None
    except Exception as exc:  # zipfile/np errors on corrupt data
        raise CheckpointError(f"{npath}: corrupt array file ({exc})") from None


def save_statistics(learner: ModelLearner, directory: str | Path) -> Path:
    """Write the learner's pair and window statistics as ``stats.json``/``stats.npz`` (each
    atomically): the part of a learner an actor placement's follower learner lacks."""
    directory = Path(directory)
    pairs_meta, pairs_arrays = learner.pairs.to_state()
    write_npz(directory / f"{STATS_PART}.npz", {f"pairs.{k}": v for k, v in pairs_arrays.items()})
    write_compact_json(directory / f"{STATS_PART}.json", {
        "format": STATS_FORMAT, "version": 1, "step": learner.step, "pairs": pairs_meta,
        "window": learner.window.to_state()})
    return directory


def _merge_statistics(directory: Path, meta: dict[str, Any],
                      arrays: dict[str, np.ndarray]) -> None:
    """Put ``stats.json``/``stats.npz`` (when present) into a learner checkpoint read from
    ``directory``: they replace its pair and window statistics."""
    jpath, npath = directory / f"{STATS_PART}.json", directory / f"{STATS_PART}.npz"
    try:
        stats = json.loads(jpath.read_text())
    except FileNotFoundError:
        return
    except (OSError, ValueError) as exc:
        raise CheckpointError(f"{jpath}: corrupt statistics ({exc})") from None
    if not isinstance(stats, dict) or stats.get("format") != STATS_FORMAT \
            or stats.get("version") != 1:
        raise CheckpointError(f"{jpath}: not a {STATS_FORMAT} version 1 file")
    if stats.get("step") != meta.get("step"):
        raise CheckpointError(f"{jpath}: statistics of step {stats.get('step')!r}, the "
                              f"learner's step is {meta.get('step')!r}")
    extra = _read_arrays(npath)
    for key in [k for k in arrays if k.startswith("pairs.")]:
        del arrays[key]
    arrays.update(extra)
    meta["pairs"], meta["window"] = stats.get("pairs"), stats.get("window")
    meta.pop("follower", None)


def statistics_missing(directory: str | Path) -> bool:
    """True for a checkpoint whose learner is an actor placement's follower (no pair
    statistics) with no ``stats`` part beside it: resuming it cannot be exact."""
    directory = resolve_checkpoint(directory)
    try:
        follower = json.loads((directory / "learner.json").read_text()).get("follower", False)
    except (OSError, ValueError, AttributeError):
        return False
    return bool(follower) and not (directory / f"{STATS_PART}.json").exists()


def load_learner(directory: str | Path, name: str = "learner") -> ModelLearner:
    """Rebuild a learner that continues exactly as the saved one would (with the ``stats``
    part of an actor placement's checkpoint put in, :data:`STATS_PART`)."""
    meta, arrays = read_checkpoint(directory, name)
    if name == "learner":
        _merge_statistics(resolve_checkpoint(directory), meta, arrays)
    check_learner(meta, arrays, Path(directory) / name)
    try:
        return restore_learner(meta, arrays)
    except (KeyError, ValueError, TypeError, IndexError, AttributeError) as exc:
        raise CheckpointError(f"{Path(directory) / name}: inconsistent checkpoint "
                              f"({type(exc).__name__}: {exc})") from None


def _bad(where: Path, field: str, why: str) -> CheckpointError:
    return CheckpointError(f"{where}: inconsistent checkpoint: {field} {why}")


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _check_event(where: Path, field: str, ev: Any, n: int) -> None:
    if not (isinstance(ev, list | tuple) and len(ev) == 3 and all(map(_is_int, ev))):
        raise _bad(where, field, f"is not an event [variable, value, direction]: {ev!r}")
    if not 0 <= ev[0] < n:
        raise _bad(where, field, f"names variable {ev[0]}, not one of the {n} variables")


def check_learner(meta: dict[str, Any], arrays: dict[str, np.ndarray], where: Path) -> None:
    """The semantic checks of a learner checkpoint (variables named by index exist, scalars
    in range, array shapes): a :class:`CheckpointError` naming the field, not an IndexError
    later."""
    variables = meta.get("variables")
    if not (isinstance(variables, list) and all(isinstance(v, dict) for v in variables)):
        raise _bad(where, "variables", f"must be a list of variable records, got "
                                       f"{str(variables)[:60]!r}")
    try:
        n = len(variables)
        params = Params.from_dict(meta["params"])
    except (KeyError, TypeError, ValueError) as exc:
        raise _bad(where, "variables/params", f"unreadable ({type(exc).__name__}: {exc})"
                   ) from None
    k = meta.get("k")
    if not _is_int(k) or not 1 <= k <= params.event_history:
        raise _bad(where, "k", f"must be an integer in 1..{params.event_history} "
                               f"(params.event_history), got {k!r}")
    for field in ("step", "next_id"):
        if not _is_int(meta.get(field)):
            raise _bad(where, field, f"must be an integer, got {meta.get(field)!r}")
    shapes = {"perception.prev_x": (n,), "perception.prev_q": (n,)}
    for key, shape in shapes.items():
        if key in arrays and arrays[key].shape != shape:
            raise _bad(where, key, f"has shape {arrays[key].shape}, expected {shape}")
    hx, hq = arrays.get("perception.hist_x"), arrays.get("perception.hist_q")
    for key, a in (("perception.hist_x", hx), ("perception.hist_q", hq)):
        if a is not None and (a.ndim != 2 or a.shape[1] != n):
            raise _bad(where, key, f"has shape {a.shape}, expected (rows, {n})")
    if hx is not None and hq is not None and hx.shape != hq.shape:
        raise _bad(where, "perception.hist_q", f"has shape {hq.shape}, hist_x {hx.shape}")
    dbns = meta.get("dbns")
    if not isinstance(dbns, list):
        raise _bad(where, "dbns", "is not a list")
    for j, d in enumerate(dbns):
        if not isinstance(d, dict):
            raise _bad(where, f"dbns[{j}]", "is not an object")
        _check_event(where, f"dbns[{j}].antecedent", d.get("antecedent"), n)
        _check_event(where, f"dbns[{j}].consequent", d.get("consequent"), n)
        ctx = d.get("context")
        if not isinstance(ctx, list | tuple) or not all(_is_int(c) and 0 <= c < n for c in ctx):
            raise _bad(where, f"dbns[{j}].context", f"must list variables in 0..{n - 1}, got "
                                                    f"{ctx!r}")


def check_agent(meta: dict[str, Any], learner: ModelLearner, where: Path) -> None:
    """The semantic checks of an agent checkpoint (see :func:`check_learner`)."""
    motor = meta.get("motor")
    names = {v.name for v in learner.table if getattr(v.kind, "value", v.kind) == "motor"}
    if not isinstance(motor, dict):
        raise _bad(where, "motor", f"must map motor names to numbers, got {motor!r}")
    for k, v in motor.items():
        if k not in names:
            raise _bad(where, "motor", f"names {k!r}, not a motor ({', '.join(sorted(names))})")
        if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v):
            raise _bad(where, f"motor.{k}", f"must be a finite number, got {v!r}")
    plans = meta.get("plans")
    if not isinstance(plans, list):
        raise _bad(where, "plans", "is not a list")
    for j, d in enumerate(plans):
        dbn_id = d.get("dbn_id") if isinstance(d, dict) else None
        if dbn_id not in learner.dbns:
            raise _bad(where, f"plans[{j}].dbn_id", f"names no DBN of the learner: {dbn_id!r}")
    world = meta.get("world")
    if world is not None and (not isinstance(world, str) or not world.strip()):
        raise _bad(where, "world", f"must be a world spec such as 'core', got {world!r}")
    for field in ("step_count", "next_plan_id", "hold_until"):
        if not _is_int(meta.get(field)):
            raise _bad(where, field, f"must be an integer, got {meta.get(field)!r}")
    # The agent's last step is its learner's, or the one before it (a plan request's agent
    # has observed step t), or later (evaluation steps do not reach the learner).
    if meta["step_count"] < learner.step - 1:
        raise _bad(where, "step_count", f"is {meta['step_count']}, before its learner's step "
                                        f"{learner.step}")
    n = len(learner.table)

    def n_values(var: int) -> int:
        v = learner.table[var]
        return len(v.values) if v.values else learner.perception.spaces[var].size

    goal = meta.get("goal")
    if goal is not None and not (isinstance(goal, list) and len(goal) == 2
                                 and all(_is_int(g) for g in goal) and 0 <= goal[0] < n
                                 and 0 <= goal[1] < n_values(goal[0])):
        raise _bad(where, "goal", f"must be null or [variable index, value index], got {goal!r}")
    selfs = meta.get("self_vars")
    if not (isinstance(selfs, list) and all(_is_int(v) and 0 <= v < n for v in selfs)):
        raise _bad(where, "self_vars", f"must be a list of variable indices, got {selfs!r}")
    for field, allowed in (("mode", ("babble", "command", "practice", "hold", "goal", "idle")),
                           ("goal_idle", ("babble", "zero"))):
        if meta.get(field) not in allowed:
            raise _bad(where, field, f"must be one of {', '.join(allowed)}, got "
                                     f"{meta.get(field)!r}")
    if not isinstance(meta.get("learning"), bool):
        raise _bad(where, "learning", f"must be true or false, got {meta.get('learning')!r}")


def restore_learner(meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> ModelLearner:
    params = Params.from_dict(meta["params"])
    learner = ModelLearner(VariableTable.from_json(meta["variables"]), params)
    per = learner.perception
    per.load_state(meta["perception"], {k[len("perception."):]: v for k, v in arrays.items()
                                        if k.startswith("perception.")})
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
    learner.load_state(meta)                        # expiry, mag_active; the indexes
    learner.pending_deltas = deque(
        Delta.from_json(d).mark_applied() if d.get("applied") else Delta.from_json(d)
        for d in meta["pending_deltas"])
    learner.applied = list(meta["applied"])
    learner.applied_count = int(meta.get("applied_count", 0))
    learner.splits = [(int(a), int(b)) for a, b in meta.get("splits", [])]
    learner.reliable_actions = {(int(a), int(b)) for a, b in meta["reliable_actions"]}
    return learner


