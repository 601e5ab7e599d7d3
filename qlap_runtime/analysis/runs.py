"""Run directories as ``qlap run --out`` leaves them: their checkpoints, world and knowledge.

A run directory holds ``checkpoints/step-NNNNNNN/`` every 10,000 steps (§7.2 of J. Mugan,
*Autonomous Qualitative Learning of Distinctions and Actions in a Developing Agent*, PhD
dissertation, UT Austin, 2010), ``checkpoints/final`` (a directory, or a link or marker file
naming the last ``step-N`` when that is the final state), ``knowledge.json`` and
``summary.json`` (docs/outputs.md). A checkpoint taken after agent step t is named
``step-(t+1)``: its agent has ``step_count`` t and has observed t + 1 steps.
"""

from __future__ import annotations

import io
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = [
    "AnalysisError",
    "Checkpoint",
    "checkpoint_step",
    "find_checkpoints",
    "load_knowledge",
    "recorded_world",
    "run_labels",
    "run_world",
]

_STEP_DIR = re.compile(r"step-(\d+)")


class AnalysisError(ValueError):
    """A run directory or option the analysis cannot use; the message says why."""


@dataclass(frozen=True)
class Checkpoint:
    """One agent checkpoint of a run."""

    run: str
    """The run's label (see :func:`run_labels`)."""
    path: Path
    """The checkpoint directory (holds ``agent.json``)."""
    step: int
    """Steps the agent had observed when it was saved (the N of ``step-N``)."""
    name: str
    """``step-NNNNNNN`` or ``final``."""


def read_summary(run_dir: Path) -> dict[str, Any] | None:
    """A run's ``summary.json`` (written when the run ended), or None while it has none."""
    try:
        data = json.loads((Path(run_dir) / "summary.json").read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def save_png(fig: Any, path: str | Path, dpi: int = 110) -> Path:
    """Write a matplotlib figure to ``path`` as PNG, atomically (temp file + rename)."""
    from ..qlap.checkpoint import atomic_write_bytes

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    atomic_write_bytes(Path(path), buf.getvalue())
    return Path(path)


def _resolve(path: str | Path) -> Path:
    """A checkpoint path with a marker file (``final`` where no link could be made) followed
    (:func:`~qlap_runtime.qlap.checkpoint.resolve_checkpoint`)."""
    from ..qlap.checkpoint import resolve_checkpoint

    return resolve_checkpoint(path)


def _read_json(path: Path) -> dict[str, Any] | None:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def checkpoint_step(path: Path) -> int:
    """Steps observed by the agent of checkpoint ``path`` (``step_count`` + 1)."""
    meta = _read_json(_resolve(path) / "agent.json")
    if meta is None or "step_count" not in meta:
        raise AnalysisError(f"{path}: no readable agent.json with a step_count")
    return int(meta["step_count"]) + 1


def find_checkpoints(run_dir: Path, run: str) -> list[Checkpoint]:
    """The agent checkpoints of ``run_dir`` by step; ``final`` only when no ``step-N`` has its
    step (a run of a multiple of 10,000 steps ends with ``final`` a link to its last
    ``step-N``; older runs with a copy).

    Directories without ``agent.json`` (being written, or learner-only) are skipped.
    """
    root = Path(run_dir) / "checkpoints"
    found: list[Checkpoint] = []
    for d in sorted(root.glob("step-*")):
        m = _STEP_DIR.fullmatch(d.name)
        if m and (d / "agent.json").is_file():
            found.append(Checkpoint(run, d, int(m[1]), d.name))
    final = _resolve(root / "final")
    if (final / "agent.json").is_file():
        step = checkpoint_step(final)
        if step not in {c.step for c in found}:
            found.append(Checkpoint(run, final, step, "final"))
    return sorted(found, key=lambda c: c.step)


def run_labels(run_dirs: list[Path]) -> list[str]:
    """A label per run: its directory name, or its path when two runs share a name."""
    resolved = [Path(d).resolve() for d in run_dirs]
    if len(set(resolved)) != len(resolved):
        raise AnalysisError("the same run directory is given twice")
    names = [p.name for p in resolved]
    if len(set(names)) == len(names):
        return names
    return [str(Path(d)) for d in run_dirs]


def recorded_world(checkpoint: Path) -> str | None:
    """The world spec a checkpoint records (``world`` in agent.json or learner.json), if any.

    Checkpoints of version 1 record none (docs/checkpoint.md); this reads it once they do.
    """
    for name in ("agent.json", "learner.json"):
        meta = _read_json(_resolve(checkpoint) / name)
        if meta is not None and isinstance(meta.get("world"), str):
            return str(meta["world"])
    return None


def run_world(run_dir: Path, checkpoints: list[Checkpoint], override: str | None) -> str:
    """The world spec of a run: what its checkpoints record, else ``override`` (``--world``),
    else ``world`` of its summary.json."""
    recorded = {w for c in checkpoints if (w := recorded_world(c.path)) is not None}
    if len(recorded) > 1:
        raise AnalysisError(f"{run_dir}: checkpoints record different worlds {sorted(recorded)}")
    if recorded:
        world = recorded.pop()
        if override is not None and override != world:
            raise AnalysisError(f"{run_dir}: its checkpoints record world {world!r}, "
                                f"not --world {override!r}")
        return world
    if override is not None:
        return override
    summary = _read_json(Path(run_dir) / "summary.json")
    if summary is not None and isinstance(summary.get("world"), str):
        return str(summary["world"])
    raise AnalysisError(f"{run_dir}: its checkpoints record no world and it has no "
                        "summary.json naming one; give --world")


KNOWLEDGE_FIELDS: dict[str, type] = {
    "step": int, "k": int, "landmarks": dict, "dbns": list, "actions": list}
"""The fields of knowledge.json that ``qlap show`` and ``qlap report`` read (docs/outputs.md)."""


def knowledge_problem(knowledge: dict[str, Any]) -> str | None:
    """What is wrong with the shape of a ``knowledge.json`` object (a missing field, a field
    of the wrong type, an entry that is not an object), or None."""
    for name, kind in KNOWLEDGE_FIELDS.items():
        if name not in knowledge:
            return f"no field {name!r}"
        value = knowledge[name]
        if not isinstance(value, kind) or isinstance(value, bool):
            return f"{name!r} is {type(value).__name__}, not {kind.__name__}"
    for name, lms in knowledge["landmarks"].items():
        if not isinstance(lms, list) or not all(isinstance(m, dict) for m in lms):
            return f"landmarks of {name!r} are not a list of objects"
    for field in ("dbns", "actions"):
        if not all(isinstance(d, dict) for d in knowledge[field]):
            return f"an entry of {field!r} is not an object"
    return None


def load_knowledge(path: Path) -> dict[str, Any]:
    """The knowledge (docs/outputs.md) of a run directory or of an agent checkpoint.

    A run directory gives its ``knowledge.json``, or, while the run is still going, that of its
    latest checkpoint; a checkpoint directory gives its agent's ``knowledge()``.
    """
    from ..qlap.checkpoint import CheckpointError, load_agent

    path = _resolve(path)
    if path.is_file() and path.name == "knowledge.json":
        path = path.parent                  # the file itself: its run directory
    if (path / "knowledge.json").is_file():
        knowledge = _read_json(path / "knowledge.json")
        if knowledge is None:
            raise AnalysisError(f"{path / 'knowledge.json'}: not a JSON object")
        problem = knowledge_problem(knowledge)
        if problem:
            raise AnalysisError(f"{path / 'knowledge.json'}: not a run's knowledge ({problem})")
        return knowledge
    target = path if (path / "agent.json").is_file() else None
    if target is None and (_resolve(path / "checkpoints" / "final") / "agent.json").is_file():
        target = _resolve(path / "checkpoints" / "final")
    if target is None and (path / "checkpoints").is_dir():
        ckpts = find_checkpoints(path, path.name)
        target = ckpts[-1].path if ckpts else None
    if target is None:
        if not path.exists():
            raise AnalysisError(f"{path}: no such directory")
        raise AnalysisError(f"{path} holds neither knowledge.json nor an agent checkpoint")
    try:
        return load_agent(target).knowledge()
    except CheckpointError as exc:
        raise AnalysisError(str(exc)) from None
