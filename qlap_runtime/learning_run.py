"""A headless learning run: a world, motor babbling (App. E) and the model learner (ch. 4).

This is the main job until the acting side (ch. 5–6) drives the motors: the agent babbles for
the whole run while :class:`~qlap_runtime.qlap.ModelLearner` learns landmarks and DBNs. Outputs
under ``--out``: ``checkpoints/step-N/`` every 10,000 steps (§7.2), ``knowledge.json`` and
``summary.json`` (schemas in docs/outputs.md).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from .qlap import ModelLearner, Params
from .qlap.babble import Babbler
from .qlap.checkpoint import atomic_write_json, save_learner
from .qlap.perception import InvalidObservation

ProgressFn = Callable[[int, ModelLearner], None]


def params_for_world(world: Any, base: Params | None = None) -> Params:
    """Apply the options a world declares for the agent (e.g. pong's k = 6, §7.10.1)."""
    params = base or Params()
    opts = dict(getattr(world, "agent_options", {}) or {})
    changes: dict[str, Any] = {}
    if "k_fixed" in opts:
        changes["k_fixed"] = int(opts["k_fixed"])
    if opts.get("nrp"):
        changes["ablations"] = params.ablations.__class__(
            **{**params.ablations.__dict__, "nrp": True})
    if "derivative_zero_band" in opts:
        changes["derivative_zero_band"] = float(opts["derivative_zero_band"])
    return params.replace(**changes) if changes else params


def run_learning(world: Any, steps: int, seed: int, out: Path | None = None,
                 params: Params | None = None, progress: ProgressFn | None = None,
                 checkpoint_every: int = 10_000) -> tuple[ModelLearner, dict[str, Any]]:
    """Babble in ``world`` for ``steps`` steps while learning; returns the learner and a summary.

    An observation the learner rejects (NaN, unknown variable) is counted and logged in the
    summary; the run goes on.
    """
    params = params_for_world(world, params)
    learner = ModelLearner(world.variables, params)
    rng = np.random.default_rng(seed)
    babbler = Babbler(learner.table, params, rng)
    obs = world.reset(seed=seed)
    rejected: list[str] = []
    t0 = time.perf_counter()
    for t in range(steps):
        motor, _ = babbler.step()
        full = dict(obs)
        full.update(motor)
        try:
            learner.observe(t, full)
        except InvalidObservation as exc:
            rejected.append(f"step {t}: {exc}")
        obs = world.step(motor)
        if progress is not None:
            progress(t, learner)
        if out is not None and (t + 1) % checkpoint_every == 0:
            save_learner(learner, Path(out) / "checkpoints" / f"step-{t + 1:07d}")
    wall = time.perf_counter() - t0
    knowledge = learner.knowledge()
    summary = {
        "world": getattr(world, "name", type(world).__name__), "seed": seed, "steps": steps,
        "wall_time_s": round(wall, 3), "steps_per_s": round(steps / wall, 1) if wall else None,
        "k": learner.k, "dbns": len(knowledge["dbns"]),
        "reliable_dbns": sum(d["sufficiently_reliable"] for d in knowledge["dbns"]),
        "landmarks": sum(len(v) for v in knowledge["landmarks"].values()),
        "rejected_observations": len(rejected), "rejected_examples": rejected[:20],
    }
    if out is not None:
        out = Path(out)
        atomic_write_json(out / "knowledge.json", knowledge)
        atomic_write_json(out / "summary.json", summary)
    return learner, summary
