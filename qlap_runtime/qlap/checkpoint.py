"""Saving and loading the learner's whole state: documented JSON + npz, versioned, no pickle.

A checkpoint is a directory holding ``<name>.json`` (structure, small values, compact JSON) and
``<name>.npz`` (arrays, loaded with ``allow_pickle=False``). Both are written to temporary files
and renamed, so a crash never leaves a half-written checkpoint. The JSON's ``format`` and
``version`` fields are checked on load; a missing, corrupt or foreign checkpoint raises
:class:`CheckpointError` with the path and the reason. Schema: ``docs/checkpoint.md``.

Version 3 (compact): every array is in the npz (the plans' Q-tables too, byte-shuffled), the
JSON has no indentation, the real-valued state rows (DBN activations, plan calls, the
perception history) are stored once in a table of distinct rows (byte-for-byte, so NaN and
-0.0 survive) with an index per array — the same world state is shared by many DBNs activated
at one step — and the per-DBN and per-plan arrays are grouped into one array per field.
Versions 1 and 2 are still read.

A run directory's ``checkpoints/`` holds ``step-NNNNNNN/`` every 10,000 steps (§7.2) and
``final``: a directory, or, when the last ``step-N`` holds exactly the final state, a symbolic
link to it (a small marker file naming it where links cannot be made);
:func:`resolve_checkpoint` follows both. :func:`prune_checkpoints` keeps the newest N.
"""

from __future__ import annotations

import contextlib
import io
import json
import lzma
import os
import re
import shutil
import tempfile
import time
import zipfile
from collections import deque
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from .dbn import DBN
from .delta import Delta
from .learner import ModelLearner
from .params import Params
from .variables import Event, VariableTable

FORMAT = "qlap-learner"
VERSION = 3
READABLE_VERSIONS = (1, 2, 3)
"""Versions :func:`read_checkpoint` reads (1: indented JSON, an npz entry per array; 2: compact
JSON, distinct rows; 3: as 2, the per-DBN arrays grouped into one array per field)."""

ROWS = "_rows"
"""The npz entry (version 2) holding the distinct state rows; an array ``K`` stored as rows is
written as ``K@rows``, the int32 index of each of its rows in that table."""
LINK_MARKER = "qlap-checkpoint-link"
"""First word of a marker file that stands for a checkpoint directory (``final`` where symbolic
links cannot be made): ``qlap-checkpoint-link step-0250000``."""


WORLD_FILE = "world.json"
"""The world's state in a checkpoint (``World.get_state``), for an exact ``--resume``."""
AGENT_FILE = "agent.json"
"""The file that makes a directory an agent checkpoint; written last."""
STATS_PART = "stats"
"""``stats.json``/``stats.npz``: the pair and window statistics of DBN search (§4.1,
Appendix C), written beside an actor placement's checkpoint by the contingency actor: the
executor's learner is a follower that does not keep them, and :func:`load_learner` puts them
in, so the checkpoint is the synchronous loop's."""
STATS_FORMAT = "qlap-learner-stats"


class CheckpointError(ValueError):
    """A checkpoint that cannot be read (missing, corrupt, wrong format or version)."""


@contextlib.contextmanager
def atomic_file(path: Path) -> Iterator[BinaryIO]:
    """A binary file that becomes ``path`` when the block ends without an error: written as a
    temporary file in the same directory, flushed to disk, then renamed over ``path``; on an
    error the temporary file is removed and ``path`` is left as it was. The file gets the
    permissions an ``open(path, "w")`` would (0666 less the umask), not mkstemp's 0600: results
    are for other users too."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, 0o666 & ~_UMASK)
        with os.fdopen(fd, "wb") as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _read_umask() -> int:
    """The process's umask, read once at import (setting it back at once; later threads never
    see it changed)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


_UMASK = _read_umask()


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temporary file in the same directory and a rename."""
    with atomic_file(path) as f:
        f.write(data)


def atomic_write_json(path: Path, obj: Any) -> None:
    """Human-readable JSON (indented, sorted keys): summary.json, knowledge.json."""
    atomic_write_bytes(path, json.dumps(obj, indent=1, sort_keys=True).encode())


def _write_compact_json(path: Path, obj: Any) -> None:
    atomic_write_bytes(path, json.dumps(obj, separators=(",", ":")).encode())


def _pack_rows(arrays: dict[str, np.ndarray], keys: list[str]) -> dict[str, np.ndarray]:
    """Store the 2-D float arrays ``keys`` as indices into one table of distinct rows."""
    keys = [k for k in keys if arrays[k].ndim == 2 and arrays[k].size]
    if not keys:
        return arrays
    width = arrays[keys[0]].shape[1]
    keys = [k for k in keys if arrays[k].shape[1] == width and arrays[k].dtype == np.float64]
    stacked = np.ascontiguousarray(np.concatenate([arrays[k] for k in keys]))
    rows = stacked.view(np.dtype((np.void, stacked.dtype.itemsize * width))).ravel()
    distinct, index = np.unique(rows, return_inverse=True)
    out = {k: v for k, v in arrays.items() if k not in keys}
    out[ROWS] = distinct.view(np.float64).reshape(len(distinct), width)
    index = index.astype(np.int32).ravel()
    at = 0
    for k in keys:
        n = arrays[k].shape[0]
        out[f"{k}@rows"] = index[at:at + n]
        at += n
    return out


def _unpack_rows(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Inverse of :func:`_pack_rows`."""
    table = arrays.pop(ROWS, None)
    for k in [k for k in arrays if k.endswith("@rows")]:
        if table is None:
            raise ValueError(f"{k} without the {ROWS} table")
        arrays[k[:-5]] = table[arrays.pop(k)]
    return arrays


def _group(arrays: dict[str, np.ndarray], prefix: str) -> dict[str, np.ndarray]:
    """Store the per-object arrays ``<prefix>.<id>.<field>`` (one per DBN or plan) as one
    array per field: ``<prefix>.*.<field>`` (their values, flattened and concatenated in id
    order), ``….ids`` and ``….shapes``. Thousands of small npz entries cost more in headers
    than in data, and deflate does better on one long array."""
    fields: dict[str, list[tuple[int, np.ndarray]]] = {}
    rest = {}
    for k, v in arrays.items():
        parts = k.split(".", 2)
        if len(parts) == 3 and parts[0] == prefix and parts[1].isdigit():
            fields.setdefault(parts[2], []).append((int(parts[1]), np.asarray(v)))
        else:
            rest[k] = v
    for field, items in fields.items():
        items.sort(key=lambda item: item[0])
        dtype = np.result_type(*(a.dtype for _, a in items))
        if len({a.ndim for _, a in items}) > 1 or not all(
                a.dtype == dtype or np.array_equal(a.astype(dtype).astype(a.dtype), a)
                for _, a in items):
            rest.update({f"{prefix}.{i}.{field}": a for i, a in items})   # kept apart
            continue
        items = [(i, a.astype(dtype, copy=False)) for i, a in items]   # e.g. counts as float
        key = f"{prefix}.*.{field}"
        rest[key] = np.concatenate([a.ravel() for _, a in items])
        rest[f"{key}.ids"] = np.array([i for i, _ in items], dtype=np.int64)
        rest[f"{key}.shapes"] = np.array([a.shape for _, a in items], dtype=np.int64
                                         ).reshape(len(items), items[0][1].ndim)
    return rest


def _ungroup(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Inverse of :func:`_group` (for every prefix)."""
    for key in [k for k in arrays if ".*." in k and not k.endswith((".ids", ".shapes"))]:
        prefix, field = key.split(".*.", 1)
        data = arrays.pop(key)
        ids, shapes = arrays.pop(f"{key}.ids"), arrays.pop(f"{key}.shapes")
        at = 0
        for i, shape in zip(ids, shapes, strict=True):
            n = int(np.prod(shape))
            arrays[f"{prefix}.{int(i)}.{field}"] = data[at:at + n].reshape(tuple(shape))
            at += n
        if at != len(data):
            raise ValueError(f"{key}: {len(data)} values for shapes totalling {at}")
    return arrays


XZ_ARRAYS = (ROWS, "plan.*.q_values")
"""The large tables of full-precision floats (the distinct state rows, the Q-values), stored
as ``K.npy.xz``: their ``.npy`` compressed with xz (LZMA, preset 0), about a fifth smaller than
deflate for a second or two per checkpoint."""


def _write_npz(path: Path, arrays: dict[str, np.ndarray], fast: bool = False) -> None:
    """An npz (a zip of ``.npy`` files, deflated, as ``np.savez_compressed`` writes it), with
    the :data:`XZ_ARRAYS` stored as ``.npy.xz`` entries instead; ``fast``: stored, not
    compressed (``np.savez``). Each array is streamed into its entry, compressed on the way,
    into the file itself (:func:`atomic_file`): no copy of it is held in memory, neither
    plain nor compressed (docs/decisions.md 108)."""
    with atomic_file(path) as f, zipfile.ZipFile(f, "w", allowZip64=True) as zf:
        for key, value in arrays.items():
            array = np.asanyarray(value)
            xz = not fast and key in XZ_ARRAYS
            info = zipfile.ZipInfo(f"{key}.npy.xz" if xz else f"{key}.npy",
                                   date_time=time.localtime()[:6])
            info.compress_type = zipfile.ZIP_STORED if fast or xz else zipfile.ZIP_DEFLATED
            info.external_attr = 0o600 << 16            # as ZipFile.writestr gives an entry
            big = array.nbytes > zipfile.ZIP64_LIMIT // 2   # its size is not known up front
            with zf.open(info, "w", force_zip64=big) as entry:
                if xz:
                    with lzma.LZMAFile(entry, "w", preset=0) as packed:
                        np.lib.format.write_array(packed, array, allow_pickle=False)
                else:
                    np.lib.format.write_array(entry, array, allow_pickle=False)


def _read_npz(path: Path) -> dict[str, np.ndarray]:
    """Every array of an npz written by :func:`_write_npz` or ``np.savez`` (no pickle)."""
    out = {}
    with zipfile.ZipFile(path) as zf:
        for name in zf.namelist():
            if name.endswith(".npy.xz"):
                data = io.BytesIO(lzma.decompress(zf.read(name)))
                out[name[:-7]] = np.lib.format.read_array(data, allow_pickle=False)
            elif name.endswith(".npy"):
                with zf.open(name) as f:
                    out[name[:-4]] = np.lib.format.read_array(f, allow_pickle=False)
    return out


def resolve_checkpoint(path: str | Path) -> Path:
    """The checkpoint directory ``path`` stands for: itself, or the directory a marker file
    (``qlap-checkpoint-link NAME``, NAME beside it) names. Symbolic links need no help."""
    path = Path(path)
    if path.is_file() and path.stat().st_size < 256:
        text = path.read_text(errors="replace").split()
        if len(text) == 2 and text[0] == LINK_MARKER and "/" not in text[1] \
                and text[1] not in (".", ".."):
            return path.parent / text[1]
    return path


def not_a_checkpoint(directory: Path) -> str | None:
    """Why ``directory`` (resolved) cannot be a checkpoint at all — a file, or a run
    directory given for one of its checkpoints — or None."""
    if directory.is_file():
        return f"{directory}: a file, not a checkpoint directory"
    if not directory.exists():
        return f"{directory}: no such checkpoint directory"
    if (directory / "checkpoints").is_dir() and not (directory / "learner.json").exists():
        return (f"{directory} is a run directory, not a checkpoint: give "
                f"{directory / 'checkpoints' / 'final'} (or one of its step-… directories)")
    return None


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
        arrays = _group(_pack_rows(arrays, rows), "dbn")
    _write_npz(directory / f"{name}.npz", arrays, fast)
    _write_compact_json(directory / f"{name}.json", meta)
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
    arrays = _read_arrays(npath, lambda a: _unpack_rows(_ungroup(a)))
    return meta, arrays


def _read_arrays(npath: Path, then: Callable[[dict[str, np.ndarray]], dict[str, np.ndarray]]
                 = lambda a: a) -> dict[str, np.ndarray]:
    """The arrays of a checkpoint's ``.npz`` (passed through ``then``); a missing or corrupt
    file is a :class:`CheckpointError` naming it."""
    try:
        return then(_read_npz(npath))
    except FileNotFoundError:
        raise CheckpointError(f"{npath}: no such checkpoint file") from None
    except Exception as exc:  # zipfile/np errors on corrupt data
        raise CheckpointError(f"{npath}: corrupt array file ({exc})") from None


def save_statistics(learner: ModelLearner, directory: str | Path) -> Path:
    """Write the learner's pair and window statistics as ``stats.json``/``stats.npz`` (each
    atomically): the part of a learner an actor placement's follower learner lacks."""
    directory = Path(directory)
    pairs_meta, pairs_arrays = learner.pairs.to_state()
    _write_npz(directory / f"{STATS_PART}.npz", {f"pairs.{k}": v for k, v in pairs_arrays.items()})
    _write_compact_json(directory / f"{STATS_PART}.json", {
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


# ---------------------------------------------------------------------------------------------
# The whole agent (ch. 5–6): the learner's files plus agent.json / agent.npz
# ---------------------------------------------------------------------------------------------
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
    from .mdp import NOT_APPLICABLE

    q = np.ascontiguousarray(q, dtype=np.float64)
    na = q == NOT_APPLICABLE
    values = np.ascontiguousarray(q[~na], dtype="<f8")          # little-endian on any host
    return np.packbits(na.ravel()), np.ascontiguousarray(values.view(np.uint8)
                                                         .reshape(-1, 8).T)


def _unpack_q(shape: tuple[int, ...], na_bits: np.ndarray, shuffled: np.ndarray) -> np.ndarray:
    """Inverse of :func:`_pack_q`."""
    from .mdp import NOT_APPLICABLE

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
    _write_npz(directory / "agent.npz", arrays if fast else
               _group(_pack_rows(arrays, [k for k in arrays if k.endswith(".call_x")]),
                      "plan"), fast)
    _write_compact_json(directory / AGENT_FILE, meta)
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
    from .actions import ActionTable
    from .agent import Agent, AgentCounters, Frame
    from .curiosity import IACChoice
    from .mdp import NOT_APPLICABLE, SarsaLambda, q_from_state
    from .planner import Plan

    directory = resolve_checkpoint(directory)
    learner = load_learner(directory)
    jpath = directory / "agent.json"
    what = jpath
    try:
        meta = json.loads(jpath.read_text())
        what = directory / "agent.npz"
        arrays = _unpack_rows(_ungroup(_read_npz(what)))
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
    try:
        agent = Agent(learner.table, learner.params)
        agent.learner = learner
        agent.rng.bit_generator.state = meta["seed_state"]
        agent.seed = meta.get("seed")              # older checkpoints: not recorded
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
        agent.load_state(meta)                      # seen_applied
    except (KeyError, ValueError, TypeError, IndexError, AttributeError) as exc:
        raise CheckpointError(f"{directory}: inconsistent agent checkpoint "
                              f"({type(exc).__name__}: {exc})") from None
    return agent


# ---------------------------------------------------------------------------------------------
# A run's checkpoints: step-NNNNNNN every N steps, retention, and final
# ---------------------------------------------------------------------------------------------
_STEP_DIR = re.compile(r"step-(\d+)")


def step_name(step: int) -> str:
    """``step-NNNNNNN``: the checkpoint taken when the agent has observed ``step`` steps."""
    return f"step-{int(step):07d}"


def step_checkpoints(checkpoints: str | Path) -> list[tuple[int, Path]]:
    """The ``step-N`` directories of a run's ``checkpoints/``, by step."""
    root = Path(checkpoints)
    found = []
    for d in root.glob("step-*") if root.is_dir() else ():
        m = _STEP_DIR.fullmatch(d.name)
        if m and d.is_dir() and not d.is_symlink():
            found.append((int(m[1]), d))
    return sorted(found)


def final_target(checkpoints: str | Path) -> Path | None:
    """The directory ``checkpoints/final`` stands for (None when there is no final)."""
    final = Path(checkpoints) / "final"
    if not final.exists():
        return None
    return resolve_checkpoint(final).resolve()


def prune_checkpoints(checkpoints: str | Path, keep: int | None) -> list[Path]:
    """Remove all but the newest ``keep`` ``step-N`` directories (None: keep all); the one
    ``final`` stands for is never removed. Returns the removed directories."""
    if keep is None:
        return []
    target = final_target(checkpoints)
    steps = step_checkpoints(checkpoints)
    doomed = steps[:max(0, len(steps) - keep)]
    removed = []
    for _, d in doomed:
        if target is not None and d.resolve() == target:
            continue
        shutil.rmtree(d, ignore_errors=True)
        removed.append(d)
    return removed


def save_world_state(directory: str | Path, state: Any) -> None:
    """Write ``world.json`` (a ``World.get_state()``; None writes nothing) atomically."""
    if state is not None:
        _write_compact_json(Path(directory) / WORLD_FILE, state)


def load_world_state(directory: str | Path) -> dict[str, Any] | None:
    """The world state a checkpoint holds (None: it has none, e.g. written before world
    states were saved). A corrupt file raises :class:`CheckpointError` naming it."""
    path = resolve_checkpoint(directory) / WORLD_FILE
    try:
        state = json.loads(path.read_text())
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        raise CheckpointError(f"{path}: corrupt world state ({exc})") from None
    if not isinstance(state, dict) or state.get("format") != "qlap-world-state":
        raise CheckpointError(f"{path}: not a qlap-world-state file")
    return state


def world_state_of(world: Any) -> dict[str, Any] | None:
    """``world.get_state()`` for a checkpoint, or None for a world that cannot save one (a
    plug-in world without the method, a replayed world whose caller moved things)."""
    get = getattr(world, "get_state", None)
    if get is None:
        return None
    try:
        return get()
    except (ValueError, NotImplementedError):
        return None


def restore_world(world: Any, state: dict[str, Any], where: str | Path) -> dict[str, float]:
    """``world.set_state(state)``, any failure a one-line :class:`CheckpointError` naming
    ``where``; returns the observation the agent sees now."""
    try:
        return world.set_state(state)
    except (ValueError, KeyError, TypeError, IndexError, AttributeError, OverflowError) as exc:
        what = f"{type(exc).__name__}: {exc}" if not isinstance(exc, ValueError) else str(exc)
        raise CheckpointError(f"{where}: the world state cannot be restored ({what})") from None


def save_step_checkpoint(agent: Any, checkpoints: str | Path, step: int,
                         world: str | None = None, keep: int | None = None,
                         world_state: Any = None) -> Path | None:
    """The periodic checkpoint ``checkpoints/step-NNNNNNN`` (``step``: steps observed), with
    the world's state when given, then the retention of ``keep`` (None: keep all; 0: write
    none). Returns its path (None with ``keep == 0``)."""
    if keep == 0:
        return None
    path = save_agent_checkpoint(agent, Path(checkpoints) / step_name(step), world, world_state)
    prune_checkpoints(checkpoints, keep)
    return path


def save_agent_checkpoint(agent: Any, target: str | Path, world: str | None = None,
                          world_state: Any = None, merge: bool = True) -> Path:
    """The agent (and the world's state, when given) as one checkpoint directory ``target``,
    written whole or not at all (:func:`write_checkpoint_dir`)."""

    def write(d: Path) -> None:
        save_agent(agent, d, world)
        save_world_state(d, world_state)

    return write_checkpoint_dir(target, write, merge)


def write_checkpoint_dir(target: str | Path, write: Callable[[Path], None],
                         merge: bool = True) -> Path:
    """A checkpoint directory written whole or not at all: ``write`` fills a hidden sibling
    (``.NAME.PID.tmp``), which is then renamed to ``target``. Where ``target`` already exists
    as a directory it is replaced, or with ``merge`` (the actor placements' world and
    statistics parts are written into it first; a second save at one step) the files move in
    one by one, ``agent.json`` — what makes a directory a checkpoint — last. If ``write``
    fails (a full disk), the sibling is removed and the error raised: no half-written
    checkpoint is left under a checkpoint's name."""
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.parent / f".{target.name}.{os.getpid()}.tmp"
    _remove(tmp)
    try:
        tmp.mkdir()
        write(tmp)
        if target.is_dir() and not target.is_symlink() and merge:
            for name in sorted((p.name for p in tmp.iterdir()),
                               key=lambda n: (n == AGENT_FILE, n)):
                os.replace(tmp / name, target / name)
            tmp.rmdir()
        else:
            _remove(target)             # rename(2) puts a directory only where none is
            os.replace(tmp, target)
    except BaseException:
        _remove(tmp)
        raise
    return target


def _remove(path: Path) -> None:
    if path.is_symlink() or path.is_file():
        path.unlink()
    elif path.is_dir():
        shutil.rmtree(path)


def save_final_checkpoint(agent: Any, checkpoints: str | Path, world: str | None = None,
                          same_as: str | Path | None = None, world_state: Any = None) -> Path:
    """Write ``checkpoints/final`` (with the world's state when given). ``same_as``: a
    ``step-N`` directory beside it that holds exactly this agent's state (saved at this step,
    nothing changed since); ``final`` is then a relative symbolic link to it (a marker file
    where links cannot be made), not a copy."""
    root = Path(checkpoints)
    root.mkdir(parents=True, exist_ok=True)
    final = root / "final"
    same = Path(same_as) if same_as is not None else None
    if same is None or same.parent.resolve() != root.resolve() \
            or not (same / AGENT_FILE).is_file():
        return save_agent_checkpoint(agent, final, world, world_state, merge=False)
    tmp = root / f".final-{os.getpid()}.tmp"
    _remove(tmp)
    try:
        os.symlink(same.name, tmp, target_is_directory=True)
    except OSError:                                         # no links here: a marker file
        tmp.write_text(f"{LINK_MARKER} {same.name}\n")
    if final.is_dir() and not final.is_symlink():
        shutil.rmtree(final)
    os.replace(tmp, final)
    return final
