"""Knowledge over time for Figs. 7.9, 7.21–7.25: change DBNs and calls to sets of actions.

J. Mugan, *Autonomous Qualitative Learning of Distinctions and Actions in a Developing Agent*,
PhD dissertation, UT Austin, 2010 draws the change DBNs of each condition over time (Figs. 7.9,
7.24, 7.25) and the cumulative exploratory calls to the actions that move the hand (Fig. 7.21),
move the block (Fig. 7.22) and pick it up (Fig. 7.23). Both are read from every checkpoint's
JSON files without rebuilding the agent: the DBNs by
:func:`qlap_runtime.analysis.timeline.checkpoint_counts`, the calls from ``agent.json``'s
per-action statistics (``actions``: variable index, value index, ``calls``) named by
``learner.json``'s variables. ``calls`` counts every finished call of the action — as practice
and as a step of a plan — so it bounds the reference's exploratory calls from above.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

from ..analysis.runs import find_checkpoints
from ..analysis.timeline import checkpoint_counts

__all__ = ["CALL_SETS", "action_calls", "call_series", "dbn_series"]

CALL_SETS: Mapping[str, tuple[str, ...]] = {
    "move the hand (Fig. 7.21)": ("h_x.dot=+", "h_x.dot=-", "h_y.dot=+", "h_y.dot=-",
                                  "h_z.dot=+", "h_z.dot=-"),
    "move the block (Fig. 7.22)": ("T_L.dot=+", "T_L.dot=-", "T_R.dot=+", "T_R.dot=-",
                                   "T_T.dot=+", "T_T.dot=-"),
    "pick up the block (Fig. 7.23)": ("T=true",),
}
"""The action sets of Figs. 7.21–7.23, as ``variable=value`` (change values ``+``/``-``)."""


def action_calls(checkpoint: Path) -> dict[str, int]:
    """Calls of every action of a checkpoint, by ``variable=value``."""
    agent = json.loads((Path(checkpoint) / "agent.json").read_text())
    learner = json.loads((Path(checkpoint) / "learner.json").read_text())
    variables = learner["variables"]
    out: dict[str, int] = {}
    for var, value, stats in agent["actions"]["actions"]:
        v = variables[int(var)]
        values = v.get("values") or []
        label = values[int(value)] if int(value) < len(values) else str(value)
        out[f"{v['name']}={label}"] = int(stats["calls"])
    return out


def dbn_series(run_dir: Path) -> dict[int, float]:
    """Change DBNs at every checkpoint of a run, by step."""
    return {c.step: float(checkpoint_counts(c.path, c.step, c.name).change_dbns)
            for c in find_checkpoints(Path(run_dir), Path(run_dir).name)}


def call_series(run_dir: Path,
                sets: Mapping[str, tuple[str, ...]] = CALL_SETS) -> dict[str, dict[int, float]]:
    """Calls to each action set at every checkpoint of a run: {set: {step: calls}}."""
    out: dict[str, dict[int, float]] = {name: {} for name in sets}
    for c in find_checkpoints(Path(run_dir), Path(run_dir).name):
        calls = action_calls(c.path)
        for name, labels in sets.items():
            out[name][c.step] = float(sum(calls.get(label, 0) for label in labels))
    return out
