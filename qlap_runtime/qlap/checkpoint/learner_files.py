"""The model learner's checkpoint: ``learner.json`` + ``learner.npz`` (ch. 4), checked on load.

A missing, corrupt or foreign file raises :class:`~.files.CheckpointError` naming the path and
the field; ``stats.json``/``stats.npz`` hold the DBN search's statistics an actor placement's
contingency actor writes beside the executor's checkpoint (:func:`save_statistics`).
"""

from __future__ import annotations

import json
import math
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..dbn import DBN
from ..delta import Delta
from ..learner import ModelLearner
from ..params import Params
from ..perception import EventIndex
from ..quantity import QuantitySpace
from ..variables import Event, Kind, VariableTable
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
    arrays = _read_arrays(npath, directory / name, lambda a: unpack_rows(ungroup_arrays(a)))
    return meta, arrays


def _read_arrays(npath: Path, where: Path,
                 then: Callable[[dict[str, np.ndarray]], dict[str, np.ndarray]] = lambda a: a
                 ) -> dict[str, np.ndarray]:
    """The arrays of a checkpoint's ``.npz`` (passed through ``then``); a missing or corrupt
    file is a :class:`CheckpointError` naming it, a grouped or row-indexed array that does not
    fit the arrays it goes with (:class:`~.files.InconsistentArray`) one naming ``where`` and
    the array."""
    try:
        return then(read_npz(npath))
    except FileNotFoundError:
        raise CheckpointError(f"{npath}: no such checkpoint file") from None
    except InconsistentArray as exc:
        raise bad(where, exc.field, exc.why) from None
    except Exception as exc:  # zipfile/np errors on corrupt data
        raise CheckpointError(f"{npath}: corrupt array file ({one_line(exc)})") from None


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
                      arrays: dict[str, np.ndarray]) -> bool:
    """Put ``stats.json``/``stats.npz`` (when present) into a learner checkpoint read from
    ``directory``: they replace its pair and window statistics. True when they did."""
    jpath, npath = directory / f"{STATS_PART}.json", directory / f"{STATS_PART}.npz"
    try:
        stats = json.loads(jpath.read_text())
    except FileNotFoundError:
        return False
    except (OSError, ValueError) as exc:
        raise CheckpointError(f"{jpath}: corrupt statistics ({exc})") from None
    if not isinstance(stats, dict) or stats.get("format") != STATS_FORMAT \
            or stats.get("version") != 1:
        raise CheckpointError(f"{jpath}: not a {STATS_FORMAT} version 1 file")
    if stats.get("step") != meta.get("step"):
        raise CheckpointError(f"{jpath}: statistics of step {stats.get('step')!r}, the "
                              f"learner's step is {meta.get('step')!r}")
    extra = _read_arrays(npath, directory / STATS_PART)
    for key in [k for k in arrays if k.startswith("pairs.")]:
        del arrays[key]
    arrays.update(extra)
    meta["pairs"], meta["window"] = stats.get("pairs"), stats.get("window")
    meta.pop("follower", None)
    return True


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
    directory = resolve_checkpoint(directory)
    where = directory / name
    merged = name == "learner" and _merge_statistics(directory, meta, arrays)
    check_learner(meta, arrays, where, pairs_where=directory / STATS_PART if merged else None)
    try:
        return restore_learner(meta, arrays)
    except (KeyError, ValueError, TypeError, IndexError, AttributeError) as exc:
        raise CheckpointError(f"{where}: inconsistent checkpoint "
                              f"({type(exc).__name__}: {one_line(exc)})") from None


def _check_event(where: Path, field: str, ev: Any, n: int) -> None:
    if not (isinstance(ev, list | tuple) and len(ev) == 3 and all(map(is_int, ev))):
        raise bad(where, field, f"is not an event [variable, value, direction]: {ev!r}")
    if not 0 <= ev[0] < n:
        raise bad(where, field, f"names variable {ev[0]}, not one of the {n} variables")


def check_learner(meta: dict[str, Any], arrays: dict[str, np.ndarray], where: Path,
                  pairs_where: Path | None = None) -> None:
    """The semantic checks of a learner checkpoint (variables named by index exist, scalars
    in range, array shapes): a :class:`CheckpointError` naming the field, not an IndexError
    or a broadcast error later. Every array the learner is restored from must be there, of
    the shape the rest of the state implies: the number of variables, of events and
    consequent candidates (from the quantity spaces), of stored activations, each DBN's
    context cells and pending activations (shapes only: no scan of a large array).
    ``pairs_where``: the file the ``pairs.*`` arrays come from, when not ``where`` (the
    ``stats`` part, :data:`STATS_PART`)."""
    variables = meta.get("variables")
    if not (isinstance(variables, list) and all(isinstance(v, dict) for v in variables)):
        raise bad(where, "variables", f"must be a list of variable records, got "
                                       f"{str(variables)[:60]!r}")
    try:
        n = len(variables)
        params = Params.from_dict(meta["params"])
    except (KeyError, TypeError, ValueError) as exc:
        raise bad(where, "variables/params", f"unreadable ({type(exc).__name__}: {exc})"
                   ) from None
    k = meta.get("k")
    if not is_int(k) or not 1 <= k <= params.event_history:
        raise bad(where, "k", f"must be an integer in 1..{params.event_history} "
                               f"(params.event_history), got {k!r}")
    for field, least in (("step", -1), ("next_id", 0)):
        if not is_int(meta.get(field)) or meta[field] < least:
            raise bad(where, field, f"must be an integer ≥ {least}, got {meta.get(field)!r}")
    shapes = {"perception.prev_x": (n,), "perception.prev_q": (n,)}
    for key, shape in shapes.items():
        check_shape(where, key, numeric_array(where, arrays, key), shape)
    hx = numeric_array(where, arrays, "perception.hist_x")
    hq = numeric_array(where, arrays, "perception.hist_q")
    for key, a in (("perception.hist_x", hx), ("perception.hist_q", hq)):
        if a.ndim != 2 or a.shape[1] != n:
            raise bad(where, key, f"has shape {a.shape}, expected (rows, {n})")
    if hx.shape != hq.shape:        # name the one whose rows are not the usual history's
        key, a, other = ("perception.hist_x", hx, hq) if hq.shape[0] == params.event_history \
            else ("perception.hist_q", hq, hx)
        raise bad(where, key, f"has shape {a.shape}, expected {other.shape} (as "
                               f"perception.hist_{'q' if key.endswith('x') else 'x'})")
    per = meta.get("perception")
    if not isinstance(per, dict):
        raise bad(where, "perception", "is not an object")
    rows = hx.shape[0]
    for field, top in (("hist_len", rows), ("hist_head", rows - 1)):
        v = per.get(field)
        if not is_int(v) or not 0 <= v <= max(top, 0):
            raise bad(where, f"perception.{field}", f"must be an integer in 0..{max(top, 0)} "
                                                     f"(perception.hist_x has {rows} rows), "
                                                     f"got {v!r}")
    table, sizes = _value_counts(where, variables, per.get("spaces"))
    _check_values(where, arrays, sizes)
    _check_pairs(pairs_where or where, arrays, EventIndex(table, sizes))
    dbns = meta.get("dbns")
    if not isinstance(dbns, list):
        raise bad(where, "dbns", "is not a list")
    for j, d in enumerate(dbns):
        if not isinstance(d, dict):
            raise bad(where, f"dbns[{j}]", "is not an object")
        _check_event(where, f"dbns[{j}].antecedent", d.get("antecedent"), n)
        _check_event(where, f"dbns[{j}].consequent", d.get("consequent"), n)
        ctx = d.get("context")
        if not isinstance(ctx, list | tuple) or not all(is_int(c) and 0 <= c < n for c in ctx):
            raise bad(where, f"dbns[{j}].context", f"must list variables in 0..{n - 1}, got "
                                                    f"{ctx!r}")
    _check_dbn_arrays(where, dbns, arrays, sizes, params.stored_activations, n)


def _value_counts(where: Path, variables: list[dict], spaces: Any
                  ) -> tuple[VariableTable, list[int]]:
    """The variable table and |Q(v)| of every variable (its values for a nominal one, else
    its quantity space's 2n + 1), as the learner's event index counts them."""
    n = len(variables)
    if not isinstance(spaces, list) or len(spaces) != n:
        got = len(spaces) if isinstance(spaces, list) else repr(spaces)[:40]
        raise bad(where, "perception.spaces", f"must list the quantity spaces of the {n} "
                                               f"variables, got {got}")
    try:
        table = VariableTable.from_json(variables)
        qs = [QuantitySpace.from_json(sp) for sp in spaces]
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise bad(where, "variables/perception.spaces", f"unreadable ({type(exc).__name__}: "
                                                         f"{one_line(exc)})") from None
    return table, [len(v.values) if v.kind is Kind.NOMINAL else qs[v.index].size
                   for v in table]


def _check_values(where: Path, arrays: dict[str, np.ndarray], sizes: list[int]) -> None:
    """The qualitative values the perception remembers (the last step's and its history's,
    small arrays): each −1 (unknown) or a value of its variable's quantity space."""
    top = np.asarray(sizes)
    for key in ("perception.prev_q", "perception.hist_q"):
        q = arrays[key]
        wrong = (q < -1) | (q >= top)
        if wrong.any():
            at = np.argwhere(wrong)[0]
            var = int(at[-1])
            raise bad(where, key, f"holds {int(q[tuple(at)])} for variable {var}, whose values are "
                                  f"0..{sizes[var] - 1} (or −1: unknown)")


def _check_pairs(where: Path, arrays: dict[str, np.ndarray], index: EventIndex) -> None:
    """The pair statistics (§4.1.2): one row per event, one column per consequent candidate
    of the event index the quantity spaces give; the open window's (step, event) lists."""
    e, c = index.n_events, index.n_cons
    why = f" ({e} events, {c} consequent candidates)"
    for key, shape in (("occurrences", (e,)), ("soon_given", (e, c)), ("soon_steps", (c,)),
                       ("last_cons", (c,))):
        a = numeric_array(where, arrays, f"pairs.{key}")
        check_shape(where, f"pairs.{key}", a, shape, why)
        if key != "last_cons" and a.size and float(a.min()) < 0:
            raise bad(where, f"pairs.{key}", f"holds a negative count ({a.min().item()})")
    win_t = numeric_array(where, arrays, "pairs.win_t")
    win_ids = numeric_array(where, arrays, "pairs.win_ids")
    if win_t.ndim != 1:
        raise bad(where, "pairs.win_t", f"has shape {win_t.shape}, expected (events,)")
    check_shape(where, "pairs.win_ids", win_ids, win_t.shape, " (as pairs.win_t)")
    # The open window holds the events of the last k steps: a few, checked by value.
    if win_ids.size and not (0 <= int(win_ids.min()) and int(win_ids.max()) < e):
        raise bad(where, "pairs.win_ids", f"names events outside 0..{e - 1}")


def _check_dbn_arrays(where: Path, dbns: list[dict], arrays: dict[str, np.ndarray],
                      sizes: list[int], cap: int, n: int) -> None:
    """Each DBN's arrays: its activation ring (``Params.stored_activations`` rows of the
    ``n`` variables), its CPT (one cell per value combination of its context variables,
    §4.2.1) and the states of its pending activations (one row each)."""
    ids: set[int] = set()
    for j, d in enumerate(dbns):
        i = new_id(where, f"dbns[{j}].id", d.get("id"), ids)
        check_ring(where, f"dbns[{j}]", d, ("act_n", "act_head"), cap)
        pending = d.get("pending")
        if not isinstance(pending, list) or not all(
                isinstance(e, list) and len(e) == 2 for e in pending):
            raise bad(where, f"dbns[{j}].pending", "must be a list of [step, resolved]")
        cells = math.prod(sizes[v] for v in d["context"])
        shapes = [("act_x", (cap, n)), ("act_ok", (cap,)), ("cpt_s", (cells,)),
                  ("cpt_f", (cells,))]
        if pending:
            shapes.append(("pending_x", (len(pending), n)))
        for field, shape in shapes:
            key = f"dbn.{i}.{field}"
            a = numeric_array(where, arrays, key)
            if a.shape != shape:                    # the message only for a mismatch
                why = {"act_x": "params.stored_activations × variables",
                       "act_ok": "params.stored_activations",
                       "pending_x": f"DBN {i}: {len(pending)} pending activations × "
                                    f"variables"}.get(field, f"DBN {i}: context "
                                                             f"{list(d['context'])}, {cells} "
                                                             f"cells")
                raise bad(where, key, f"has shape {a.shape}, expected {shape} ({why})")
    check_owned(where, arrays, "dbn", ids, "DBN")


def check_agent(meta: dict[str, Any], learner: ModelLearner, where: Path) -> None:
    """The semantic checks of an agent checkpoint (see :func:`check_learner`)."""
    motor = meta.get("motor")
    names = {v.name for v in learner.table if getattr(v.kind, "value", v.kind) == "motor"}
    if not isinstance(motor, dict):
        raise bad(where, "motor", f"must map motor names to numbers, got {motor!r}")
    for k, v in motor.items():
        if k not in names:
            raise bad(where, "motor", f"names {k!r}, not a motor ({', '.join(sorted(names))})")
        if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v):
            raise bad(where, f"motor.{k}", f"must be a finite number, got {v!r}")
    plans = meta.get("plans")
    if not isinstance(plans, list):
        raise bad(where, "plans", "is not a list")
    for j, d in enumerate(plans):
        dbn_id = d.get("dbn_id") if isinstance(d, dict) else None
        if dbn_id not in learner.dbns:
            raise bad(where, f"plans[{j}].dbn_id", f"names no DBN of the learner: {dbn_id!r}")
    world = meta.get("world")
    if world is not None and (not isinstance(world, str) or not world.strip()):
        raise bad(where, "world", f"must be a world spec such as 'core', got {world!r}")
    for field in ("step_count", "next_plan_id", "hold_until"):
        if not is_int(meta.get(field)):
            raise bad(where, field, f"must be an integer, got {meta.get(field)!r}")
    # The agent's last step is its learner's, or the one before it (a plan request's agent
    # has observed step t), or later (evaluation steps do not reach the learner).
    if meta["step_count"] < learner.step - 1:
        raise bad(where, "step_count", f"is {meta['step_count']}, before its learner's step "
                                        f"{learner.step}")
    n = len(learner.table)

    def n_values(var: int) -> int:
        v = learner.table[var]
        return len(v.values) if v.values else learner.perception.spaces[var].size

    goal = meta.get("goal")
    if goal is not None and not (isinstance(goal, list) and len(goal) == 2
                                 and all(is_int(g) for g in goal) and 0 <= goal[0] < n
                                 and 0 <= goal[1] < n_values(goal[0])):
        raise bad(where, "goal", f"must be null or [variable index, value index], got {goal!r}")
    selfs = meta.get("self_vars")
    if not (isinstance(selfs, list) and all(is_int(v) and 0 <= v < n for v in selfs)):
        raise bad(where, "self_vars", f"must be a list of variable indices, got {selfs!r}")
    for field, allowed in (("mode", ("babble", "command", "practice", "hold", "goal", "idle")),
                           ("goal_idle", ("babble", "zero"))):
        if meta.get(field) not in allowed:
            raise bad(where, field, f"must be one of {', '.join(allowed)}, got "
                                     f"{meta.get(field)!r}")
    if not isinstance(meta.get("learning"), bool):
        raise bad(where, "learning", f"must be true or false, got {meta.get('learning')!r}")


def restore_learner(meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> ModelLearner:
    """The learner of a checkpoint's (meta, arrays), unchecked (:func:`check_learner`)."""
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


