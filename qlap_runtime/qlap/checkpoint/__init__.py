"""Saving and loading the agent's whole state: documented JSON + npz, versioned, no pickle.

A checkpoint is a directory holding ``<name>.json`` (structure, small values, compact JSON) and
``<name>.npz`` (arrays, loaded with ``allow_pickle=False``), written atomically; the JSON's
``format`` and ``version`` are checked on load, and a missing, corrupt or foreign checkpoint
raises :class:`CheckpointError` with the path and the reason. Schema: ``docs/checkpoint.md``.

* :mod:`.files` — atomic files, the npz encoding, what a path stands for;
* :mod:`.learner_files` — the model learner (``learner.json``/``.npz``, ``stats.*``), and the
  field checks of both files (``check_learner``, ``check_agent``);
* :mod:`.agent_files` — the whole agent (``agent.json``/``.npz``) on top of the learner's;
* :mod:`.run_dirs` — a run's ``step-N`` checkpoints, retention, ``final`` and the world's state.

Version 3 (compact): every array in the npz (the plans' Q-tables too, byte-shuffled), the JSON
without indentation, the real-valued state rows stored once in a table of distinct rows, the
per-DBN and per-plan arrays grouped into one array per field. Versions 1 and 2 are still read.
"""

from __future__ import annotations

from .agent_files import (
    AGENT_FILE,
    AGENT_FORMAT,
    AGENT_READABLE_VERSIONS,
    AGENT_VERSION,
    WORLD_FILE,
    check_plan_arrays,
    checkpoint_seed,
    load_agent,
    save_agent,
)
from .files import (
    LINK_MARKER,
    ROWS,
    XZ_ARRAYS,
    CheckpointError,
    InconsistentArray,
    atomic_file,
    atomic_write_bytes,
    atomic_write_json,
    not_a_checkpoint,
    resolve_checkpoint,
)
from .learner_files import (
    FORMAT,
    READABLE_VERSIONS,
    STATS_FORMAT,
    STATS_PART,
    VERSION,
    check_agent,
    check_learner,
    learner_state,
    load_learner,
    read_checkpoint,
    restore_learner,
    save_learner,
    save_statistics,
    statistics_missing,
)
from .run_dirs import (
    final_target,
    load_world_state,
    prune_checkpoints,
    restore_world,
    save_agent_checkpoint,
    save_final_checkpoint,
    save_step_checkpoint,
    save_world_state,
    step_checkpoints,
    step_name,
    world_state_of,
    write_checkpoint_dir,
)

__all__ = [
    "AGENT_FILE",
    "AGENT_FORMAT",
    "AGENT_READABLE_VERSIONS",
    "AGENT_VERSION",
    "FORMAT",
    "LINK_MARKER",
    "READABLE_VERSIONS",
    "ROWS",
    "STATS_FORMAT",
    "STATS_PART",
    "VERSION",
    "WORLD_FILE",
    "XZ_ARRAYS",
    "CheckpointError",
    "InconsistentArray",
    "atomic_file",
    "atomic_write_bytes",
    "atomic_write_json",
    "check_agent",
    "check_learner",
    "check_plan_arrays",
    "checkpoint_seed",
    "final_target",
    "learner_state",
    "load_agent",
    "load_learner",
    "load_world_state",
    "not_a_checkpoint",
    "prune_checkpoints",
    "read_checkpoint",
    "resolve_checkpoint",
    "restore_learner",
    "restore_world",
    "save_agent",
    "save_agent_checkpoint",
    "save_final_checkpoint",
    "save_learner",
    "save_statistics",
    "save_step_checkpoint",
    "save_world_state",
    "statistics_missing",
    "step_checkpoints",
    "step_name",
    "world_state_of",
    "write_checkpoint_dir",
]
