"""The run directory of ``qlap run``: its default name (:func:`default_run_dir`), the
files that mark a directory as holding a run (:data:`RUN_FILES`), refusing an ``--out`` that
would write over the run a resumed checkpoint comes from (:func:`resume_clash`), creating and
checking the directory before the run (:func:`prepare_out`), what a stopped run keeps
(:func:`kept_checkpoint`) and the closing lines naming what was written
(:func:`print_written`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .common import say


def default_run_dir(world: str, seed: int, root: Path = Path("runs")) -> Path:
    """``runs/<world>-<YYYYmmdd-HHMMSS>-s<seed>``, the world spec made a file name; ``-2``,
    ``-3``, … when a run of the same second has it already."""
    import re
    import time

    name = re.sub(r"[^A-Za-z0-9._-]+", "_", world).strip("._") or "world"
    base = f"{name}-{time.strftime('%Y%m%d-%H%M%S')}-s{seed}"
    path, n = root / base, 1
    while path.exists():
        n += 1
        path = root / f"{base}-{n}"
    return path


def source_run(checkpoint: Path) -> Path | None:
    """The run directory a checkpoint belongs to (``<run>/checkpoints/<name>``, links
    followed), or None for a checkpoint outside a run."""
    for path in (Path(checkpoint).absolute(), Path(checkpoint).resolve()):
        if path.parent.name == "checkpoints":
            return path.parent.parent.resolve()
    return None


def resume_clash(checkpoint: Path, out: Path | None) -> str | None:
    """Why ``--resume checkpoint --out out`` would write over the run the checkpoint comes
    from (its knowledge.json, summary.json, final/ and later checkpoints), or None. Without
    ``--out`` the run goes to a new default directory."""
    run = source_run(checkpoint)
    if run is None or out is None:
        return None
    target = Path(out).resolve()
    if target == run or target.is_relative_to(run) or run.is_relative_to(target):
        return (f"--out {out} would write over the run the checkpoint comes from ({run}): "
                "give a new --out")
    return None


RUN_FILES = ("knowledge.json", "summary.json", "metrics.jsonl", "checkpoints", "actors")
"""What a run writes into its directory (docs/outputs.md): a directory holding any of them
holds a run."""


def resume_refused(args: argparse.Namespace) -> bool:
    """``--resume`` whose checkpoint ``--out`` would write over (or lie in): said in one line."""
    clash = resume_clash(args.resume, args.out)
    if clash is not None:
        print(f"qlap run: --resume: {clash}", file=sys.stderr)
    return clash is not None


def run_files_in(out: Path) -> list[str]:
    """The names of :data:`RUN_FILES` present in ``out`` (none if it does not exist)."""
    out = Path(out)
    return [name for name in RUN_FILES if (out / name).exists()] if out.is_dir() else []


def out_refused(out: Path) -> str | None:
    """Why ``out`` cannot be a new run's directory (it holds a run, whose checkpoints and
    metrics would mix with the new one's; or it is not writable, or has no room), else None
    with ``out`` created (:func:`~qlap_runtime.runtime.outputs.check_out`)."""
    from ..runtime.outputs import OutputError, check_out

    if held := run_files_in(out):
        return (f"--out {out} already holds a run ({', '.join(held)}); a second run there "
                "would mix the two: give a new directory")
    try:
        check_out(out)
    except OutputError as exc:
        return str(exc)
    return None


def prepare_out(args: argparse.Namespace) -> Path | None:
    """The run directory (``--out`` or the default), created and checked writable with a
    probe file and for room for a checkpoint before the run starts
    (:func:`~qlap_runtime.runtime.outputs.check_out`), and refused if it already holds a run
    (its checkpoints and metrics would mix with this one's); None after a one-line error."""
    out = args.out if args.out is not None else default_run_dir(args.world, args.seed)
    if (problem := out_refused(out)) is not None:
        print(f"qlap run: {problem}", file=sys.stderr)
        return None
    args.run_dir = out
    say(f"run directory: {out}")
    return out


def kept_checkpoint(run_dir: Path | None) -> str:
    """What a failed run keeps: its newest complete periodic checkpoint (one with agent.json;
    checkpoints are written whole or not at all) and how to go on from it, or ""."""
    if run_dir is None:
        return ""
    from ..qlap.checkpoint import AGENT_FILE, WORLD_FILE

    done = sorted(d for d in (Path(run_dir) / "checkpoints").glob("step-*")
                  if (d / AGENT_FILE).is_file())
    if not done:
        return "; no checkpoint was kept"
    # A realtime run's checkpoint has no world state: only the sync loop continues it (inexactly).
    sync = "" if (done[-1] / WORLD_FILE).is_file() else " --placement sync"
    return (f"; kept: {done[-1]} (go on from it: qlap run --resume {done[-1]}{sync} "
            "--out NEW_DIR)")


def print_written(out: Path) -> None:
    from ..analysis.plot import plot_run_if_possible

    picture = plot_run_if_possible(out)
    drawn = f", {picture.name}" if picture is not None else ""
    say(f"\nwrote {out}/: knowledge.json, summary.json, metrics.jsonl{drawn}, checkpoints/ "
          f"(qlap plot {out} draws them again, with a learning curve after qlap curve)")
