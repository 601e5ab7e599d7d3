"""Placements: the same actors in one process (embedded) or in process groups (processes).

``embedded`` opens one Zenoh session with no sockets and runs every actor as a trio task of one
nursery. ``processes`` opens a Zenoh router in this process on a free loopback port and starts
each process group (:mod:`.groups`: by default the step chain with the planner, and the two
learners; ``each``: one process per actor) in its own process (``spawn``), each with a client
session to the router; a supervisor (:mod:`~qlap_runtime.runtime.supervisor`) restarts a group
that dies from its actors' latest snapshots and the run goes on. What the actors of a process
share — the step chain in one task, one learner for both learners, ``planreq`` in memory —
follows from ``RunContext.groups`` (:func:`_run_group`). In every placement the run is in
lockstep and the results are those of the synchronous loop with the same seed and parameters.
"""

from __future__ import annotations

import json
import os
import socket
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import trio
import zenoh

from ..bus.bridge import AliveWatcher, cancel_when
from ..bus.config import client_config, embedded_config, router_config
from ..qlap.checkpoint import atomic_write_json
from ..qlap.kernels import warm_kernels
from ..runtime.interrupt import heeded
from ..runtime.outputs import check_out
from ..runtime.supervisor import Supervisor, group_name
from .groups import ACTORS, DEFAULT_GROUPS, LEARNERS, Layout, parse_groups

CHAIN = ("world", "perception", "executor")
"""The step chain: when its actors share a process, one task runs their steps in turn (the
world's hosts the others', ``actors.world.run``), so a step needs no wake-up between them."""
# LEARNERS (.groups): when they share a process, both run in one task on one learner
# (``learning_pair.run_pair``).


def _units(names: tuple[str, ...], ctx: Any) -> list[str]:
    """The tasks of a process running the actors ``names``: ``chain`` for the step chain and
    ``learners`` for the pair when ``ctx.groups`` puts them together, the others one each."""
    units, rest = [], list(names)
    for unit, members in (("chain", CHAIN), ("learners", LEARNERS)):
        if set(members) <= set(rest) and ctx.together(*members):
            units.append(unit)
            rest = [n for n in rest if n not in members]
    return units + rest


async def _run_unit(unit: str, session: Any, ctx: Any,
                    ready: trio.Event | None = None) -> dict[str, Any]:
    """One task of a process (:func:`_units`); returns ``{actor: result}``."""
    from actors import executor, learning, learning_pair, perception, planner, world
    from actors.chain import Chain

    if unit == "chain":                     # world, perception, executor: one task
        chain = Chain()                     # their hops in memory, one perception a step
        with executor.ExecutorActor(session, ctx.for_actor("executor"), chain=chain) as ex, \
                perception.PerceptionActor(session, ctx.for_actor("perception"), chain,
                                           shared=ex.agent.learner.perception) as per:
            async with trio.open_nursery() as nursery:
                nursery.start_soon(ex.between_steps)
                result = await world.run(session, ctx, ready, perception=per, executor=ex,
                                         chain=chain)
                nursery.cancel_scope.cancel()
            return {"world": result, "perception": per.result, "executor": ex.result}
    if unit == "learners":                  # both learners on one learner
        return await learning_pair.run_pair(session, ctx)
    actor_ctx = ctx.for_actor(unit)
    if unit == "world":
        return {unit: await world.run(session, actor_ctx, ready)}
    if unit == "perception":
        return {unit: await perception.run(session, actor_ctx)}
    if unit in LEARNERS:
        return {unit: await learning.run(session, actor_ctx, unit)}
    if unit == "executor":
        return {unit: await executor.run(session, actor_ctx)}
    if unit == "planner":
        return {unit: await planner.run(session, actor_ctx)}
    raise ValueError(f"unknown actor {unit!r}; known: {', '.join(ACTORS)}")


async def _run_group(names: tuple[str, ...], session: Any, ctx: Any,
                     ready: trio.Event | None) -> dict[str, Any]:
    """The actors ``names`` of one process on one session, a task per unit (:func:`_units`);
    ``ready`` lets the world step. Returns ``{actor: result}``."""
    results: dict[str, Any] = {}
    if "world" in names:
        # A process with the world is never restarted: its actors write no snapshots (an
        # executor's took 0.3 s on the chain every snapshot_every steps).
        ctx = ctx.with_(snapshot_dir=None)
    if set(names) - {"world"}:
        # Numba's kernels loaded before the world's clock starts, not on the step chain at
        # their first call (docs/decisions.md 95).
        warm_kernels()

    async def one(unit: str) -> None:
        results.update(await _run_unit(unit, session, ctx, ready))

    async with trio.open_nursery() as nursery:
        for unit in _units(names, ctx):
            nursery.start_soon(one, unit)
    return results


async def _wait_alive(session: Any, run_id: str, names: set[str], limit_s: float) -> None:
    with AliveWatcher(session, run_id) as watcher, trio.fail_after(limit_s):
        await watcher.wait_until(lambda alive: names <= alive)


async def run_embedded_async(ctx: Any, listen: tuple[str, ...] = (),
                             record: Path | None = None, extra: tuple = (),
                             watchers: tuple = ()) -> dict[str, Any]:
    """Every actor in this process on one socket-less session (or listening on ``listen``);
    with ``record``, the recorder actor writes every message of the run to an MCAP file;
    ``extra`` coroutines ``task(session, ctx)`` run beside the actors (tests, tools);
    ``watchers`` coroutines ``task(session, ctx, stop)`` (e.g. the progress bar) run until
    the actors are done and ``stop`` is set."""
    from ..runtime.watchdog import DEFAULT_STALL_S, Board, Watchdog

    results: dict[str, Any] = {}
    ctx = ctx.with_(placement=ctx.placement or "embedded", board=Board(ACTORS),
                    groups=(ACTORS,))
    if ctx.out is not None:
        check_out(Path(ctx.out))
    ctx, auth = _listen_auth(ctx, listen)
    watchdog = Watchdog(ctx.board, ctx.stall_s or DEFAULT_STALL_S)
    t0 = time.perf_counter()
    recording: dict[str, Any] = {}
    try:
        await _embedded_actors(ctx, listen, auth, record, extra, watchers, watchdog, results,
                               recording)
    except BaseException:
        if ctx.out is not None:
            from actors.checkpoint_parts import discard_incomplete, place_final_parts

            place_final_parts(Path(ctx.out) / "checkpoints")   # the world's, into final
            discard_incomplete(Path(ctx.out) / "checkpoints")  # only whole checkpoints stay
        raise
    return _finish(ctx, "embedded", results, time.perf_counter() - t0,
                   {"recording": recording} if recording else None)


async def _embedded_actors(ctx: Any, listen: tuple[str, ...], auth: dict[str, Any],
                           record: Path | None, extra: tuple, watchers: tuple, watchdog: Any,
                           results: dict[str, Any], recording: dict[str, Any]) -> None:
    """The body of :func:`run_embedded_async`: the actors' nursery on one session; what the
    recorder wrote goes into ``recording`` (:func:`recording_summary`)."""
    from ..bus.recorder import record as record_bus

    async def recorder(session: Any, stop: trio.Event,
                       task_status: trio.TaskStatus[None] = trio.TASK_STATUS_IGNORED) -> None:
        written = await record_bus(session, ctx.run_id, record, stop, info=ctx.to_json(),
                                   task_status=task_status)
        recording.update(recording_summary(written))

    with zenoh.open(embedded_config(listen, **auth)) as session:
        ready = trio.Event()
        stop = trio.Event()

        async def actors() -> None:
            results.update(await _run_group(ACTORS, session, ctx, ready))

        async with trio.open_nursery() as outer:
            if record is not None:
                await outer.start(recorder, session, stop)
            for watcher in watchers:
                outer.start_soon(watcher, session, ctx, stop)
            outer.start_soon(_watch_stalls, watchdog, stop)
            async with trio.open_nursery() as nursery:
                nursery.start_soon(actors)
                await _wait_alive(session, ctx.run_id, set(ACTORS) - {"world"}, 120)
                ready.set()
                for task in extra:                 # e.g. a test's fuzzer on the same session
                    nursery.start_soon(task, session, ctx)
            stop.set()


def quit_on_signals(fired: list[int]) -> Callable[..., Any]:
    """A watcher (``run_embedded(watchers=...)``) that turns the first Ctrl-C, SIGTERM or
    SIGHUP into the ``quit`` a viewer would send: every actor ends at the world's last step
    and the run's outputs are written, as after its last step (docs/runtime.md, "Stopping").
    A Ctrl-C after that cancels the actors at once. ``fired`` gets the signal's number."""
    import signal

    from ..bus.keys import key
    from ..bus.schema import Control, encode

    async def watch(session: Any, ctx: Any, stop: trio.Event) -> None:
        signals = heeded((signal.SIGINT, signal.SIGTERM, signal.SIGHUP))
        if not signals:                     # every one ignored (nohup, started with &)
            return
        with trio.open_signal_receiver(*signals) as sigs:
            async with trio.open_nursery() as nursery:
                nursery.start_soon(cancel_when, stop, nursery.cancel_scope)
                async for signum in sigs:
                    if fired and signum == signal.SIGINT:
                        raise KeyboardInterrupt
                    if not fired:
                        fired.append(int(signum))
                        session.put(key(ctx.run_id, "control"), encode(Control("quit")))

    return watch


def _listen_auth(ctx: Any, listen: tuple[str, ...]) -> tuple[Any, dict[str, Any]]:
    """Authorisation by default for an embedded run that listens (docs/security.md): fresh
    ``tui`` and ``viewer`` credentials and the run's ACL; the credentials go to
    ``<out>/bus-credentials.json`` (mode 0600), or ``ctx.credentials``."""
    if not listen:
        return ctx, {}
    from ..bus.auth import CREDENTIALS_FILE, run_acl, run_users, write_credentials

    users = run_users()
    where = ctx.credentials or (
        Path(ctx.out) / CREDENTIALS_FILE if ctx.out is not None else None)
    if where is None:
        import tempfile

        where = Path(tempfile.mkdtemp(prefix=f"qlap-{ctx.run_id}-")) / CREDENTIALS_FILE
    ctx = ctx.with_(credentials=write_credentials(Path(where), listen, users))
    return ctx, {"users": users, "acl": run_acl(users)}


async def _watch_stalls(watchdog: Any, stop: trio.Event) -> None:
    """The embedded placement's watchdog: raises RunStalled (ending the run) on no progress."""
    while not stop.is_set():
        with trio.move_on_after(1.0):
            await stop.wait()
        if not stop.is_set():
            watchdog.check()


async def _connected_group(names: tuple[str, ...], config: zenoh.Config, ctx: Any,
                           watcher: Any, alive_limit_s: float) -> dict[str, Any] | None:
    """The actors ``names`` (:func:`_run_group`) on one client session, stopped early when
    ``watcher(cancel_scope)`` cancels them (signals, launcher gone); returns ``{actor:
    result}``, or None if stopped before the end. The world steps once every other actor of
    the run is alive."""
    results = None
    with zenoh.open(config) as session:
        async with trio.open_nursery() as nursery:
            nursery.start_soon(watcher, nursery.cancel_scope)
            ready = trio.Event() if "world" in names else None

            async def run() -> None:
                nonlocal results
                results = await _run_group(names, session, ctx, ready)
                nursery.cancel_scope.cancel()

            nursery.start_soon(run)
            if ready is not None:
                await _wait_alive(session, ctx.run_id, set(ACTORS) - {"world"}, alive_limit_s)
                ready.set()
    return results


def run_embedded(ctx: Any, listen: tuple[str, ...] = (), record: Path | None = None,
                 watchers: tuple = ()) -> dict[str, Any]:
    """:func:`run_embedded_async` under trio; Ctrl-C cancels every actor at its next
    checkpoint (sessions closed) and surfaces as a plain KeyboardInterrupt."""
    try:
        return trio.run(run_embedded_async, ctx, listen, record, (), watchers,
                        restrict_keyboard_interrupt_to_checkpoints=True)
    except BaseExceptionGroup as group:
        if group.subgroup(KeyboardInterrupt) is not None:
            raise KeyboardInterrupt from None
        raise


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


BATCH_NICENESS = 10
"""Under the realtime clock a process without the world (the learners' batches) runs this much
nicer than the step chain's, so that the kernel gives a core to the chain first."""


def niceness_for(names: tuple[str, ...], ctx: Any) -> int:
    """How much nicer the process of the actors ``names`` runs (docs/decisions.md 111): under the
    realtime clock a process without the world yields the cores to the step chain's; in
    lockstep every process is on the chain's path (a batch's delta is waited for), so none."""
    return BATCH_NICENESS if ctx.realtime and "world" not in names else 0


def _actor_process(names: tuple[str, ...], ctx_json: str, endpoint: str, result_path: str,
                   slots: dict[str, Any] | None = None, password: str | None = None) -> None:
    """Entry point of a process group's process (spawned: no state inherited): the actors
    ``names`` on one session, their results as ``{actor: result}`` in ``result_path``.

    Ctrl-C is the launcher's business (it stops every actor): SIGINT is ignored here; SIGTERM,
    or the launcher's death, cancels the actors, whose session is then closed.
    """
    import os
    import signal

    from ..runtime.context import RunContext

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    names = tuple(names)
    ctx = RunContext.from_json(json.loads(ctx_json))
    if slots is not None:                           # the supervisor's progress board
        from ..runtime.watchdog import Board

        ctx = ctx.with_(board=Board(names, slots))
    parent = os.getppid()
    niceness = os.nice(niceness_for(names, ctx))

    async def watch(cancel: trio.CancelScope) -> None:
        with trio.open_signal_receiver(signal.SIGTERM) as signals:
            while os.getppid() == parent:
                with trio.move_on_after(0.5):
                    async for _ in signals:
                        cancel.cancel()
                        return
        cancel.cancel()                             # the launcher died: stop, close the session

    try:
        auth = {"user": group_name(names), "password": password} if password else {}
        result = trio.run(_connected_group, names, client_config([endpoint], **auth), ctx,
                          watch, 60)
        if result is None:
            raise SystemExit(143)                   # stopped before the end of the run
        for actor in result.values():
            actor["niceness"] = niceness
        atomic_write_json(Path(result_path), result)
    except Exception as exc:
        # One line for the supervisor (it decides whether a restart can help, and says why
        # the run stopped); the traceback of a bug still goes to stderr.
        from ..errors import expected_error

        _write_error(Path(result_path), exc)
        if expected_error(exc) is not None:
            raise SystemExit(1) from None
        raise


def _write_error(result_path: Path, exc: BaseException) -> None:
    from ..errors import expected_error, one_line

    leaf = expected_error(exc) or exc
    kind = "OSError" if isinstance(leaf, OSError) else type(leaf).__name__
    try:
        atomic_write_json(result_path.with_suffix(".error.json"),
                          {"type": kind, "message": f"{type(leaf).__name__}: "
                                                    f"{one_line(leaf)}"[:500]})
    except OSError:
        pass


def run_processes(ctx: Any, listen_port: int | None = None, poll: float = 0.05, *,
                  record: Path | None = None,
                  on_poll: Callable[[Supervisor], None] | None = None,
                  groups: str | Layout = DEFAULT_GROUPS) -> dict[str, Any]:
    """One process per process group around a router opened here (docs/architecture.md §2,
    processes); a dead group is restarted from its actors' latest snapshots
    (:mod:`~qlap_runtime.runtime.supervisor`).

    ``groups``: the layout (:mod:`.groups`): ``two`` (default: the step chain and the
    planner, and the learners), ``each`` (one process per actor), or a layout spelled out;
    :class:`~.groups.GroupsError` names a wrong one. ``record``: the router's session records
    every message of the run to an MCAP file (in a thread of this process).
    ``on_poll(supervisor)`` is called at every poll (tests, tools).
    Ctrl-C or SIGTERM stops every actor (SIGTERM to each, which closes its session) and
    raises KeyboardInterrupt here once they are gone.
    """
    import signal

    def on_term(signum, frame):                     # SIGTERM: stop the actors like Ctrl-C
        raise KeyboardInterrupt

    layout = parse_groups(groups)
    previous = signal.signal(signal.SIGTERM, on_term)
    try:
        return _run_processes(ctx.with_(groups=layout), listen_port, poll, record, on_poll)
    except BaseException:
        if ctx.out is not None:
            from actors.checkpoint_parts import discard_incomplete, place_final_parts

            place_final_parts(Path(ctx.out) / "checkpoints")
            discard_incomplete(Path(ctx.out) / "checkpoints")  # only whole checkpoints stay
        raise
    finally:
        signal.signal(signal.SIGTERM, previous)
        _reap_children()


def _reap_children() -> None:
    """Leave no process behind in the launcher's group: every actor process was joined by the
    supervisor; multiprocessing's resource tracker (started with the first spawn) is stopped and
    reaped here too (it is started again if this process spawns later)."""
    import multiprocessing as mp
    from multiprocessing import resource_tracker

    mp.active_children()
    try:
        resource_tracker._resource_tracker._stop()   # type: ignore[attr-defined]
    except Exception:                                # pragma: no cover - older/newer Pythons
        pass


def _run_processes(ctx: Any, listen_port: int | None, poll: float, record: Path | None,
                   on_poll: Callable[[Supervisor], None] | None) -> dict[str, Any]:
    import tempfile

    port = listen_port or free_port()
    ctx = ctx.with_(placement=ctx.placement or "processes")
    if ctx.out is not None:
        check_out(Path(ctx.out))
    endpoint = f"tcp/127.0.0.1:{port}"
    t0 = time.perf_counter()
    remove_stale_run_dirs()
    # Authorisation by default (docs/security.md): a password per actor, the UI and a viewer,
    # and the ACL of examples/router.json5; the UI's and viewer's in <out>/bus-credentials.json.
    from ..bus.auth import CREDENTIALS_FILE, run_acl, run_users, write_credentials

    names = tuple(group_name(g) for g in ctx.groups)
    users = run_users(names)
    if ctx.out is not None:
        ctx = ctx.with_(credentials=write_credentials(Path(ctx.out) / CREDENTIALS_FILE,
                                                      [endpoint], users))
    with zenoh.open(router_config([endpoint], users=users, acl=run_acl(users))) as router, \
            tempfile.TemporaryDirectory(prefix=RUN_DIR_PREFIX) as tmp:
        (Path(tmp) / OWNER_FILE).write_text(f"{os.getpid()}\n")
        run_ctx = ctx.with_(snapshot_dir=ctx.snapshot_dir or Path(tmp) / "snapshots")
        recorder = _Recorder(router, ctx.run_id, record, ctx.to_json()) \
            if record is not None else None
        sup = Supervisor(run_ctx, endpoint, Path(tmp), ctx.groups, _actor_process,
                         passwords={n: users[n] for n in names})
        try:
            sup.start_all()
            while sup.check():
                if on_poll is not None:
                    on_poll(sup)
                time.sleep(poll)
        finally:
            sup.stop()
            if recorder is not None:
                recorder.stop()
        results = sup.results()
    report = {**sup.report(), "groups": list(sup.groups)}
    if recorder is not None and recorder.summary is not None:
        report["recording"] = recording_summary(recorder.summary)
    return _finish(ctx, "processes", results, time.perf_counter() - t0, report)


RUN_DIR_PREFIX = "qlap-run-"
OWNER_FILE = "launcher.pid"


def remove_stale_run_dirs(root: Path | None = None) -> list[Path]:
    """Remove the temporary directories (snapshots, results) of processes runs whose launcher
    died without cleaning up (SIGKILL): those whose ``launcher.pid`` names no live process, or
    that have none and are over a day old. Returns what was removed."""
    import shutil
    import tempfile

    root = Path(root) if root is not None else Path(tempfile.gettempdir())
    removed = []
    for d in root.glob(f"{RUN_DIR_PREFIX}*"):
        try:
            if not d.is_dir() or d.is_symlink() or d.stat().st_uid != os.getuid():
                continue
            owner = d / OWNER_FILE
            if owner.exists():
                pid = int(owner.read_text().split()[0])
                try:
                    os.kill(pid, 0)
                    continue                        # its launcher is running
                except ProcessLookupError:
                    pass
                except PermissionError:
                    continue
            elif time.time() - d.stat().st_mtime < 86400:
                continue
            shutil.rmtree(d, ignore_errors=True)
            removed.append(d)
        except (OSError, ValueError, IndexError):
            continue
    return removed


def recording_summary(written: Any) -> dict[str, Any]:
    """``summary.json``'s ``recording``: the MCAP file, the messages written and, when the
    recording stopped early (a full disk), why (the run itself went on)."""
    return {"path": str(written.path), "messages": written.messages, "error": written.error}


class _Recorder:
    """The recorder (:func:`~qlap_runtime.bus.recorder.record`) on the router's session, in a
    thread with its own trio run, so that the launcher's polling loop and its signal handling
    stay as they are. Subscribed when the constructor returns."""

    def __init__(self, session: Any, run_id: str, path: Path,
                 info: dict[str, Any] | None = None) -> None:
        self.session, self.run_id, self.path = session, run_id, Path(path)
        self.info = info
        self.summary: Any = None
        self._ready = threading.Event()
        self._token: Any = None
        self._stop: trio.Event | None = None
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="qlap-recorder", daemon=True)
        self._thread.start()
        if not self._ready.wait(30) or self.error is not None:
            raise RuntimeError(f"the recorder did not start: {self.error!r}")

    def _run(self) -> None:
        try:
            trio.run(self._main)
        except BaseException as exc:       # e.g. the MCAP file cannot be opened
            self.error = exc
            self._ready.set()

    async def _main(self) -> None:
        from ..bus.recorder import record

        self._token = trio.lowlevel.current_trio_token()
        self._stop = trio.Event()

        async def go(task_status=trio.TASK_STATUS_IGNORED) -> None:
            self.summary = await record(self.session, self.run_id, self.path, self._stop,
                                        info=self.info, task_status=task_status)

        async with trio.open_nursery() as nursery:
            await nursery.start(go)
            self._ready.set()

    def stop(self) -> None:
        """Write what has arrived and finish the file."""
        if self._stop is not None and self._thread.is_alive():
            try:
                trio.from_thread.run_sync(self._stop.set, trio_token=self._token)
            except trio.RunFinishedError:
                pass
        self._thread.join(30)


def _finish(ctx: Any, placement: str, results: dict[str, Any], wall: float,
            restarts: dict[str, Any] | None = None) -> dict[str, Any]:
    clock = ctx.clock
    steps = int(results.get("world", {}).get("steps", ctx.steps))   # fewer after a quit
    summary: dict[str, Any] = {"placement": placement, "clock": clock,
                               "world": ctx.world, "seed": ctx.seed, "steps": steps,
                               "wall_time_s": round(wall, 3),
                               "steps_per_s": round(steps / wall, 1) if wall else None,
                               "actors": results,
                               "waits": sum(r.get("waits", 0) for r in results.values()),
                               "rejected_messages": sum(r.get("rejected", 0)
                                                        for r in results.values()),
                               "restarts": 0, "restarted": []}
    summary.update(restarts or {})
    world = results.get("world", {})
    if world.get("loop_s"):
        # Start-up excluded (spawning, imports, sessions): the rate of the step chain itself.
        summary["loop_s"] = world["loop_s"]
        summary["loop_steps_per_s"] = round(world.get("steps", ctx.steps) / world["loop_s"], 1)
    for key in ("hz", "late_ticks", "missed_ticks", "missed_at", "lateness_p50_ms",
                "lateness_p99_ms", "lateness_max_ms"):
        if key in world:
            summary[key] = world[key]
    if ctx.out is not None:
        out = Path(ctx.out)
        from actors.checkpoint_parts import place_final_parts

        place_final_parts(out / "checkpoints")          # world.json and stats of final
        executor = out / "actors" / "executor.json"
        if executor.exists():
            base = json.loads(executor.read_text())
            base.update(summary)
            summary = base
        atomic_write_json(out / "summary.json", summary)
    return summary


def run_actor(name: str, ctx: Any, config: zenoh.Config) -> dict[str, Any]:
    """One actor of a distributed run, in this process, with a client session (``qlap actor``).

    Every actor of the run must be started with the same run id, world, steps, seed and
    parameters; the world actor starts stepping once the four others are alive. Ctrl-C or
    SIGTERM stops it (session closed).
    """
    import signal

    if name not in ACTORS:
        raise ValueError(f"unknown actor {name!r}; known: {', '.join(ACTORS)}")
    ctx = ctx.with_(placement=ctx.placement or "distributed")

    async def until_signal(cancel: trio.CancelScope) -> None:
        heard = heeded((signal.SIGINT, signal.SIGTERM))
        if not heard:
            return
        with trio.open_signal_receiver(*heard) as signals:
            async for _ in signals:
                cancel.cancel()
                return

    results = trio.run(_connected_group, (name,), config, ctx, until_signal, 3600)
    if results is None:
        raise KeyboardInterrupt
    return results[name]
