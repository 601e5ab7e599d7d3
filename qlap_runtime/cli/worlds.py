"""The ``qlap worlds`` command: each registered world spec, variants too, with its
description and its tasks (as lines or as JSON)."""

from __future__ import annotations

import argparse
import json

from ..errors import expected_error, one_line


def cmd_worlds(args: argparse.Namespace) -> int:
    """``qlap worlds``: each registered spec (variants too) with its description and tasks."""
    import worlds
    from worlds.registry import describe

    rows = []
    for spec in worlds.registered():
        try:
            world = worlds.make(spec)
        except Exception as exc:       # e.g. an optional engine missing: still list the spec
            if expected_error(exc) is None and not isinstance(exc, ImportError | ValueError):
                raise
            tasks, note = [], f"(cannot be made here: {one_line(exc)})"
        else:
            tasks, note = sorted(world.tasks), ""
            world.close()
        description = describe(spec) or describe(spec.split(":", 1)[0])
        rows.append({"spec": spec, "description": " ".join(filter(None, (description, note))),
                     "tasks": tasks})
    if args.json:
        print(json.dumps(rows))
        return 0
    width = max(len(r["spec"]) for r in rows)
    for r in rows:
        tasks = ", ".join(r["tasks"]) or "none (no evaluation task)"
        print(f"{r['spec']:{width}}  {r['description']}; tasks: {tasks}")
    print("any module:Factory is a world too, e.g. mypackage.worlds:make_world")
    return 0
