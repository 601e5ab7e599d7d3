"""``qlap run`` in each of its ways of running the agent: the synchronous loop
(:func:`run_sync`, Algorithm 2 in this process, with the world restored from a checkpoint), the
actor placements embedded and processes (:func:`run_actors`), and the terminal UI on its own
agent process (:func:`run_tui`)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from .common import say
from .run_dir import kept_checkpoint, prepare_out, print_written, resume_refused


def run_sync(args: argparse.Namespace, world: Any, params: Any) -> int:
    """``qlap run --placement sync``: Algorithm 2 in this process, with a progress bar."""
    from ..agent_run import run_agent
    from ..metrics import PlainProgress
    from ..placements.resume import in_flight_problem
    from ..qlap.checkpoint import CheckpointError, load_agent

    agent = None
    restored = False
    if args.resume is not None:
        if resume_refused(args):
            return 2
        try:
            agent = load_agent(args.resume)
            problem = in_flight_problem(args.resume, agent.learner.params,
                                        agent.step_count + 1, "sync")
            if problem is not None:
                raise CheckpointError(problem)
            restored = _restore_world(world, args.resume)
        except CheckpointError as exc:
            print(f"qlap run: --resume: {exc}", file=sys.stderr)
            return 2
    out = prepare_out(args)
    if out is None:
        return 2
    progress_cb = None
    bar = None
    plain = None
    if not args.quiet and not sys.stdout.isatty():
        plain = PlainProgress(args.steps, start=agent.step_count + 1 if agent else 0)
    elif not args.quiet:
        import time

        from ..runtime.progress import progress_bar

        bar = progress_bar(args.steps)
        task = bar.task_ids[0]
        state = {"t0": time.perf_counter(), "first": None}

        def progress_cb(t: int, agent) -> None:
            if state["first"] is None:
                state["first"] = t
            done = t - state["first"] + 1
            if done % 500 == 0 or done == args.steps:
                from ..metrics import knowledge_counts

                el = time.perf_counter() - state["t0"]
                n = knowledge_counts(agent)          # as in summary.json
                bar.update(task, completed=done, rate=f"{done / el:,.0f}",
                           dbns=n["dbns"], plans=n["plans"], lms=n["landmarks"])

        bar.start()
    from ..runtime.interrupt import stop_on_signals

    try:
        with stop_on_signals() as stop:
            agent, summary = run_agent(world, args.steps, args.seed, out, params=params,
                                       progress=progress_cb, agent=agent,
                                       keep_checkpoints=args.keep_checkpoints,
                                       on_metrics=plain, restored=restored, stop=stop)
    finally:
        if bar is not None:
            bar.stop()
    if plain is not None:
        plain.final(summary)
    say(f"\n{summary['steps']} steps in {summary['wall_time_s']} s "
          f"({summary['steps_per_s']} steps/s); k = {summary['k']}, {summary['dbns']} DBNs, "
          f"{summary['plans']} plans, {summary['landmarks']} landmarks, "
          f"{summary['reliable_actions']} sufficiently reliable actions")
    if summary["rejected_observations"]:
        say(f"rejected observations: {summary['rejected_observations']} "
              f"(first: {summary['rejected_examples'][0]})")
    from ..analysis.show import format_knowledge

    say(format_knowledge(agent.knowledge(), limit=25))
    print_written(out)
    if "interrupted_at" in summary:
        print(f"qlap run: interrupted after {summary['steps']:,} steps; what was "
              f"learned is written — go on from it: qlap run --resume {out}/checkpoints/final "
              "--placement sync --out NEW_DIR", file=sys.stderr)
        return 130
    return 0


def _restore_world(world, checkpoint: Path) -> bool:
    """Put ``world`` in the state a checkpoint saved (``world.json``): True when it holds one;
    a checkpoint without one (written before world states were saved, or by a world that
    cannot save its state) leaves the world to ``reset(seed)``, which ``qlap`` says."""
    from ..qlap.checkpoint import (
        load_world_state,
        resolve_checkpoint,
        restore_world,
        statistics_missing,
    )

    state = load_world_state(checkpoint)
    if state is None:
        print("qlap run: --resume: the checkpoint holds no world state; the world starts "
              "again from reset(seed), so the run will differ from an uninterrupted one",
              file=sys.stderr)
        return False
    restore_world(world, state, resolve_checkpoint(checkpoint) / "world.json")
    if statistics_missing(checkpoint):
        from ..placements.resume import why_no_stats

        print("qlap run: --resume: the checkpoint's learner has no pair statistics "
              f"({why_no_stats(resolve_checkpoint(checkpoint))}); the run will differ from an "
              "uninterrupted one", file=sys.stderr)
    return True


def run_tui(args: argparse.Namespace) -> int:
    """``qlap run`` in a terminal: the agent in its own process, the UI here (docs/tui.md)."""
    from tui import DriverProcess, run_process

    out = prepare_out(args)
    if out is None:
        return 2
    overrides: dict = {}
    if args.babble_steps is not None:
        overrides["babble_steps"] = args.babble_steps
    if args.lag:
        overrides["batch_lag"] = args.lag
    proc = DriverProcess(args.world, params=overrides, seed=args.seed, steps=args.steps,
                         out=out, listen=args.listen, checkpoint_dir=out / "checkpoints",
                         keep_checkpoints=args.keep_checkpoints)
    run_process(proc)
    print_written(out)
    return 0 if proc.exitcode in (0, None) else 1


def run_actors(args: argparse.Namespace, world, params) -> int:
    """``qlap run --placement embedded|processes``: the actor runtime in lockstep."""
    import threading

    from ..agent_run import params_for_world
    from ..bus import keys
    from ..metrics import METRICS_FILE, PlainProgress, follow_metrics
    from ..placements.launcher import run_embedded, run_processes
    from ..runtime.context import RunContext

    params = params_for_world(world, params)
    world.close()
    if args.placement == "processes" and args.listen:
        print("qlap run: --listen goes with --placement embedded; with processes, outside "
              "subscribers connect to the router's endpoint, printed at the start",
              file=sys.stderr)
        return 2
    groups = None
    if args.groups is not None:
        from ..placements.groups import GroupsError, parse_groups

        try:
            groups = parse_groups(args.groups)
        except GroupsError as exc:
            print(f"qlap run: --groups: {exc}", file=sys.stderr)
            return 2
    ctx = RunContext(keys.new_run_id(), args.world, args.steps, args.seed, params,
                     clock=args.clock, hz=args.hz, keep_checkpoints=args.keep_checkpoints,
                     placement=args.placement)
    if args.resume is not None:
        # Exact or refused (one line, with what to use instead), before anything is written.
        from ..placements.resume import ResumeRefused, resume_context
        from ..qlap.checkpoint import CheckpointError

        if resume_refused(args):
            return 2
        try:
            ctx = resume_context(ctx, args.resume)
        except (ResumeRefused, CheckpointError) as exc:
            print(f"qlap run: --resume: {exc}", file=sys.stderr)
            return 2
    params = ctx.params
    out = prepare_out(args)
    if out is None:
        return 2
    ctx = ctx.with_(out=out)
    resumed = f", from step {ctx.start} of {ctx.resume_checkpoint}" \
        if ctx.resume_checkpoint is not None else ""
    from ..placements.groups import DEFAULT_GROUPS

    layout = f" (groups {args.groups or DEFAULT_GROUPS})" if args.placement == "processes" \
        else ""
    print(f"run {ctx.run_id}: {args.steps} steps of {args.world}, placement "
          f"{args.placement}{layout}, {args.clock}, lag {params.batch_lag}{resumed}",
          file=sys.stderr)
    from ..bus.auth import CREDENTIALS_FILE

    credentials = out / CREDENTIALS_FILE
    if args.listen:
        print(f"listening on {', '.join(args.listen)} with authentication: qlap tui --connect "
              f"{args.listen[0]} --credentials {credentials}", file=sys.stderr)
    # Progress: the rich bar fed from the bus in a terminal (embedded); otherwise plain lines
    # from the metrics log the executor writes (the same counts as the summary).
    plain = None
    if not args.quiet and (args.placement == "processes" or not sys.stdout.isatty()):
        plain = PlainProgress(args.steps, start=ctx.start)
        stop = threading.Event()
        follower = follow_metrics(out / METRICS_FILE, plain, stop)
    signalled: list[int] = []
    try:
        if args.placement == "embedded":
            from ..placements.launcher import quit_on_signals
            from ..runtime.progress import watch_progress

            watchers = () if args.quiet or plain is not None else (watch_progress,)
            summary = run_embedded(ctx, tuple(args.listen), record=args.record,
                                   watchers=(*watchers, quit_on_signals(signalled)))
        else:
            from ..placements.launcher import free_port

            port = free_port()
            print(f"router on tcp/127.0.0.1:{port} with authentication (qlap tui/record/echo "
                  f"--connect tcp/127.0.0.1:{port} --credentials {credentials})",
                  file=sys.stderr)
            summary = run_processes(ctx, port, record=args.record,
                                    **({} if groups is None else {"groups": groups}))
    finally:
        if plain is not None:
            stop.set()
            follower.join(5)
    if plain is not None:
        plain.final(summary)
    knowledge = json.loads((out / "knowledge.json").read_text())
    say(f"\n{summary['steps']} steps in {summary['wall_time_s']} s "
          f"({summary['steps_per_s']} steps/s); k = {summary.get('k')}, "
          f"{summary.get('dbns')} DBNs, {summary.get('plans')} plans, "
          f"{summary.get('landmarks')} landmarks, {summary.get('reliable_actions')} "
          f"sufficiently reliable actions; waits {summary['waits']}, rejected messages "
          f"{summary['rejected_messages']}, restarts {summary.get('restarts', 0)}")
    if args.clock == "realtime":
        say(f"realtime {summary.get('hz')} Hz: late ticks {summary.get('late_ticks')}, "
              f"missed ticks {summary.get('missed_ticks')}, lateness p50 "
              f"{summary.get('lateness_p50_ms')} ms, p99 {summary.get('lateness_p99_ms')} ms")
    from ..analysis.show import format_knowledge

    say(format_knowledge(knowledge, limit=25))
    print_written(out)
    if signalled:
        final = out / "checkpoints" / "final"
        go_on = (f" — go on from it: qlap run --resume {final} --out NEW_DIR"
                 if _resumes_exactly(final, summary["steps"]) else
                 " (checkpoints/final has a batch in flight)" + kept_checkpoint(out))
        print(f"qlap run: interrupted after {summary['steps']:,} steps; what was learned is "
              f"written{go_on}", file=sys.stderr)
        return 130
    recording = summary.get("recording") or {}
    if recording.get("error"):
        print(f"qlap run: --record {args.record}: the recording stopped after "
              f"{recording['messages']:,} messages ({recording['error']}); they are in "
              f"{args.record}.part; the run went on and its outputs are written",
              file=sys.stderr)
        return 1
    return 0


def _resumes_exactly(checkpoint: Path, steps_done: int) -> bool:
    """Whether an actor placement's checkpoint after ``steps_done`` steps resumes exactly (no
    batch in flight, placements/resume.py)."""
    from ..placements.resume import in_flight_problem
    from ..qlap.checkpoint import CheckpointError, load_agent

    try:
        params = load_agent(checkpoint).learner.params
    except CheckpointError:
        return False
    return in_flight_problem(checkpoint, params, steps_done, "embedded") is None
