"""The work of one worker: an agent run or an evaluation, JSON text in and JSON text out.

These functions run in a worker process (the local pool) or a Ray task; their messages are JSON
strings (how an executor carries a string between processes is its own business). A run writes
into its run directory (docs/outputs.md; :mod:`.sweep`), with ``progress.json`` every
:data:`PROGRESS_EVERY` steps for the sweep's progress display; an evaluation only returns its
figures: the scheduler alone writes curve.csv.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import math
import os
import shutil
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ..qlap.checkpoint import atomic_write_json
from .sweep import EvalSpec, RunSpec, run_done

__all__ = ["PROGRESS_EVERY", "eval_job", "file_lock", "run_job", "run_payload"]

PROGRESS_EVERY = 1000
"""Steps between two ``progress.json`` of a running agent."""


@contextlib.contextmanager
def file_lock(path: Path) -> Iterator[None]:
    """An exclusive ``flock`` on ``path`` (created if missing), waited for and released on
    exit — also when the holder dies, so a killed sweep leaves no stale lock."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as f:
        fcntl.flock(f.fileno(), fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f.fileno(), fcntl.LOCK_UN)


def run_payload(spec: RunSpec, run_dir: Path, root: Path) -> str:
    return json.dumps({"spec": spec.to_json(), "dir": str(run_dir), "root": str(root)})


def _progress_writer(run_dir: Path, steps: int) -> Any:
    t0 = time.time()

    path, tmp = run_dir / "progress.json", run_dir / ".progress.json.tmp"

    def write(t: int) -> None:
        if t % PROGRESS_EVERY == 0 or t == steps:       # renamed into place, not fsynced:
            tmp.write_text(json.dumps(                  # a hint for the display only
                {"step": t, "steps": steps, "elapsed_s": round(time.time() - t0, 3)}))
            os.replace(tmp, path)

    return write


def run_job(payload: str) -> str:
    """Run one agent (``{"spec", "dir", "root"}``) unless it is already done; returns
    ``{"key", "summary", "seconds", "reused"}`` as JSON."""
    d = json.loads(payload)
    spec = RunSpec.from_json(d["spec"])
    run_dir, root = Path(d["dir"]), Path(d["root"])
    # One writer per run directory, whichever sweep asks: a second waits, then reuses it.
    with file_lock(run_dir.parent / f".{run_dir.name}.lock"):
        return _run_locked(spec, run_dir, root)


def _run_locked(spec: RunSpec, run_dir: Path, root: Path) -> str:
    import worlds

    t0 = time.perf_counter()
    if run_done(run_dir, spec):
        summary = json.loads((run_dir / "summary.json").read_text())
        return json.dumps({"key": spec.key, "summary": summary, "seconds": 0.0,
                           "reused": True})
    for stale in ("checkpoints", "summary.json", "knowledge.json", "curve.csv"):
        path = run_dir / stale
        if path.is_dir():
            shutil.rmtree(path)
        elif path.exists():
            path.unlink()
    run_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_json(run_dir / "run.json", {"key": spec.key, "spec": spec.to_json()})
    progress = _progress_writer(run_dir, spec.steps)
    world = worlds.make(spec.world)
    try:
        if spec.kind == "qlap":
            summary = _run_qlap(spec, world, run_dir, progress)
        elif spec.kind == "tile":
            summary = _run_tile(spec, world, run_dir, root, progress)
        elif spec.kind == "qtable":
            summary = _run_qtable(spec, world, run_dir, root, progress)
        else:
            raise ValueError(f"unknown run kind {spec.kind!r}")
    finally:
        world.close()
    return json.dumps({"key": spec.key, "summary": summary,
                       "seconds": round(time.perf_counter() - t0, 3), "reused": False})


def _run_qlap(spec: RunSpec, world: Any, run_dir: Path, progress: Any) -> dict[str, Any]:
    from ..agent_run import run_agent
    from .spec import qlap_params

    params = qlap_params(dict(spec.params), spec.ablations)
    _, summary = run_agent(world, spec.steps, spec.seed, run_dir, params=params,
                           progress=lambda t, agent: progress(t + 1),
                           checkpoint_every=spec.checkpoint_every)
    return dict(summary)


def _baseline_summary(spec: RunSpec, run_dir: Path, summary: dict[str, Any]) -> dict[str, Any]:
    summary = {"world": spec.world, "seed": spec.seed, "kind": spec.kind, **summary}
    atomic_write_json(run_dir / "summary.json", summary)
    return summary


def _run_tile(spec: RunSpec, world: Any, run_dir: Path, root: Path,
              progress: Any) -> dict[str, Any]:
    from .baselines import common, tile_agent

    assert spec.tile is not None
    ranges = common.cached_ranges(spec.world, spec.tile.range_steps, root / "ranges")
    summary = tile_agent.train(world, spec.world, spec.tasks, spec.steps, spec.seed,
                               spec.tile, ranges, run_dir, spec.checkpoint_every, progress)
    return _baseline_summary(spec, run_dir, summary)


def _run_qtable(spec: RunSpec, world: Any, run_dir: Path, root: Path,
                progress: Any) -> dict[str, Any]:
    from ..analysis.runs import load_knowledge
    from .baselines import common, qtable

    assert spec.qtable is not None
    if spec.landmark_run is not None:
        landmarks = qtable.qlap_landmarks(load_knowledge(root / "agents" / spec.landmark_run))
    else:
        ranges = common.cached_ranges(spec.world, spec.qtable.range_steps, root / "ranges")
        landmarks = qtable.random_landmarks(world, ranges, np.random.default_rng([spec.seed, 3]),
                                            spec.qtable.max_random_landmarks)
    summary = qtable.train(world, spec.world, spec.tasks, spec.steps, spec.seed, spec.qtable,
                           landmarks, run_dir, spec.checkpoint_every, progress)
    summary["landmarks"] = sum(len(v) for v in landmarks.values())
    return _baseline_summary(spec, run_dir, summary)


def eval_job(payload: str) -> str:
    """Evaluate one checkpoint, or the random policy, on a task (§7.2): ``{"eval",
    "checkpoint"}`` in, ``{"mean_reward", "stderr", "success_rate", "trials", "seconds"}``
    out (the figures of ``qlap curve``)."""
    d = json.loads(payload)
    e = EvalSpec(**d["eval"])
    checkpoint = d.get("checkpoint")
    if e.kind in ("qlap", "random"):
        from ..analysis.curve import EvalJob, evaluate_job

        res = evaluate_job(EvalJob(checkpoint if e.kind == "qlap" else None, e.world, e.task,
                                   e.trials, e.seed))
        return json.dumps(res)
    import worlds
    from worlds.evaluate import run_trials

    from .baselines import qtable, tile_agent

    t0 = time.perf_counter()
    world = worlds.make(e.world)
    try:
        loader = tile_agent.load_policy if e.kind == "tile" else qtable.load_policy
        policy = loader(Path(checkpoint), world)
        res = run_trials(world, e.task, e.trials, e.seed, policy)
    finally:
        world.close()
    rewards = np.asarray(res["rewards"], dtype=float)
    stderr = float(rewards.std(ddof=1) / math.sqrt(len(rewards))) if len(rewards) > 1 else 0.0
    return json.dumps({"mean_reward": res["mean_reward"], "stderr": stderr,
                       "success_rate": res["successes"] / max(1, res["n_trials"]),
                       "trials": res["n_trials"], "seconds": time.perf_counter() - t0})
