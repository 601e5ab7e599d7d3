"""The supervisor of the processes placement: restarts a dead process, and the run goes on.

See docs/architecture.md §2 (processes). The launcher starts one ``spawn`` process per process
group (a tuple of actors, ``placements.groups``: by default the step chain with the planner, and
the two learners; with ``each``, one actor a process) and polls them here. A process that dies
(any non-zero exit: a crash, SIGKILL, the OOM killer) is started again with ``ctx.restarted``
and each actor's snapshot in ``ctx.resumes``: the newest step at which every actor of the group
has one (``snapshot.common_snapshot``; none yet: from the start). The new process loads the
snapshots, fetches from the writers' replay logs what it missed, catches up and continues live
(docs/runtime.md, Faults). Because the lockstep clock makes each actor's state a function of
its input stream, the run's knowledge is the one of a run without the fault.

Not restarted, and the run stops with :class:`ActorFailed` saying why: a group with the world
(its physics state is not snapshotted), any process under the realtime clock (its state depends
on arrival times, so there is nothing exact to resume), and a process that died
``max_restarts`` times.
"""

from __future__ import annotations

import json
import logging
import multiprocessing as mp
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from ..errors import ActorFailed
from .snapshot import common_snapshot
from .watchdog import DEFAULT_STALL_S, SIZE, Board, Watchdog

log = logging.getLogger("qlap.supervisor")

RESTARTABLE = frozenset({"perception", "contingency", "landmarks", "planner", "executor"})
MAX_RESTARTS = 3
"""Restarts allowed per process in one run."""


def group_name(group: tuple[str, ...]) -> str:
    """A process group's name: its actors joined by ``+`` (one actor: its name)."""
    return "+".join(group)


@dataclass(frozen=True)
class Restart:
    """One restart of a process, as reported in summary.json's ``restarted``."""

    actor: str
    """The process's name: its actors joined by ``+`` (``contingency+landmarks``; the actor's
    name for a process of one)."""
    actors: list[str]
    """The actors restarted with it."""
    attempt: int
    """1 for the process's first restart."""
    exit_code: int | None
    """The dead process's exit code (−9: SIGKILL)."""
    from_step: int | None
    """The step of the snapshots its actors resumed from (None: from the start of the run)."""


class Supervisor:
    """Starts the group processes and restarts those that die (see the module docstring).

    ``groups``: the actors of each process. ``target(actors, ctx_json, endpoint, result_path,
    slots, password)`` is a process's entry point (``actors`` a tuple, ``slots`` each actor's
    progress slot); ``ctx`` must have a ``snapshot_dir`` for restarts to resume from snapshots.
    ``passwords``: each process's password on the router, by process name.
    """

    def __init__(self, ctx: Any, endpoint: str, workdir: Path,
                 groups: tuple[tuple[str, ...], ...], target: Callable[..., None], *,
                 max_restarts: int = MAX_RESTARTS,
                 passwords: dict[str, str] | None = None) -> None:
        self.ctx = ctx
        self.endpoint = endpoint
        self.workdir = Path(workdir)
        self.groups = {group_name(g): tuple(g) for g in groups}
        """Each process's actors, by process name."""
        self.names = tuple(a for g in groups for a in g)
        """Every actor."""
        self.target = target
        self.max_restarts = max_restarts
        self.passwords = dict(passwords or {})
        """Each process's password on the router (given to its process, never written)."""
        self.snapshot_dir = ctx.snapshots
        """None under the realtime clock (no snapshots): a dead process stops the run."""
        self.procs: dict[str, Any] = {}
        """The running (or last) process of each group, by process name."""
        self.attempts: dict[str, int] = dict.fromkeys(self.groups, 0)
        self.restarts: list[Restart] = []
        self._spawn = mp.get_context("spawn")
        # The progress board in shared memory: each incarnation of an actor gets its slot.
        self.shared = {n: self._spawn.RawArray("d", SIZE) for n in self.names}
        self.board = Board(self.names, self.shared)
        self.watchdog = Watchdog(self.board, ctx.stall_s or DEFAULT_STALL_S)

    def group_of(self, actor: str) -> str:
        """The name of the process that runs ``actor``."""
        for name, actors in self.groups.items():
            if actor in actors:
                return name
        raise KeyError(f"no process runs actor {actor!r}")

    def process_of(self, actor: str) -> Any:
        """The process (``multiprocessing.Process``) that runs ``actor`` now."""
        return self.procs[self.group_of(actor)]

    def result_path(self, name: str) -> Path:
        return self.workdir / f"{name}.json"

    def start(self, name: str, resumes: dict[str, Path] | None = None, *,
              restarted: bool = False) -> None:
        """Start (or start again, ``restarted``, each actor from its snapshot in ``resumes``)
        the process ``name``."""
        actors = self.groups[name]
        paths = None if resumes is None else {a: str(p) for a, p in resumes.items()}
        ctx_json = self.ctx.with_(restarted=restarted, resumes=paths).to_json()
        for actor in actors:
            self.board.slot(actor).restarted()
        p = self._spawn.Process(target=self.target, name=f"qlap-{name}",
                                args=(actors, json.dumps(ctx_json), self.endpoint,
                                      str(self.result_path(name)),
                                      {a: self.shared[a] for a in actors},
                                      self.passwords.get(name)))
        p.start()
        self.procs[name] = p
        self.watchdog.reset()

    def start_all(self) -> None:
        for name in self.groups:
            self.start(name)

    def check(self) -> bool:
        """Restart the processes that died since the last call; True while any is running.
        Raises :class:`ActorFailed` for a death that cannot be recovered, and
        :class:`~.watchdog.RunStalled` for a run that makes no progress."""
        for name, p in list(self.procs.items()):
            if p.is_alive() or p.exitcode in (0, None):
                continue
            self._restart(name, p.exitcode)
        running = any(p.is_alive() for p in self.procs.values())
        if running:
            self.watchdog.check()
        return running

    def error_of(self, name: str) -> dict[str, str] | None:
        """The one-line error the process wrote before dying, if any."""
        path = self.result_path(name).with_suffix(".error.json")
        try:
            err = json.loads(path.read_text())
            path.unlink()
        except (OSError, ValueError):
            return None
        return err if isinstance(err, dict) else None

    def _restart(self, name: str, code: int) -> None:
        self.procs[name].join(1)
        actors = self.groups[name]
        err = self.error_of(name)
        why = f" ({err.get('message')})" if err else ""
        what = f"actor {name}" if len(actors) == 1 else \
            f"process {name} (actors {', '.join(actors)})"
        world = self.procs.get(self.group_of("world")) if "world" in self.names else None
        if err is not None and err.get("type") == "OSError":
            raise ActorFailed(f"{what} exited with code {code}{why}; a restart cannot "
                              "help: run stopped")
        if "world" not in actors and world is not None and world.exitcode == 0:
            raise ActorFailed(f"{what} exited with code {code}{why} after the world "
                              "finished; its inputs cannot be replayed: run stopped")
        for actor in actors:
            if actor not in RESTARTABLE:
                raise ActorFailed(f"{what} exited with code {code}{why}; the {actor} actor "
                                  "cannot be restarted (its physics state is not "
                                  "snapshotted): run stopped")
        if self.snapshot_dir is None:
            raise ActorFailed(f"{what} exited with code {code}; restarting an actor needs "
                              "the lockstep clock and a snapshot directory: run stopped")
        if self.attempts[name] >= self.max_restarts:
            raise ActorFailed(f"{what} exited with code {code} after "
                              f"{self.attempts[name]} restarts: run stopped")
        self.attempts[name] += 1
        attempt = self.attempts[name]
        found = common_snapshot(self.snapshot_dir, actors)
        step = None if found is None else found[0]
        if found is None:
            log.warning("%s exited with code %s; restarting %s from the start (no "
                        "snapshot yet) (attempt %d)", what, code, name, attempt)
        else:
            log.warning("%s exited with code %s; restarting %s from snapshot at step %d "
                        "(attempt %d)", what, code, name, step, attempt)
        self.restarts.append(Restart(name, list(actors), attempt, code, step))
        self.start(name, None if found is None else found[1], restarted=True)

    def stop(self, timeout: float = 10.0) -> None:
        """Terminate (SIGTERM: each closes its session) and reap every process still running."""
        import os
        import signal

        for p in self.procs.values():
            if p.is_alive():
                p.terminate()
                try:
                    os.kill(p.pid, signal.SIGCONT)  # a stopped process gets its SIGTERM too
                except (ProcessLookupError, TypeError):
                    pass
        for p in self.procs.values():
            p.join(timeout)
            if p.is_alive():                # pragma: no cover - a stuck actor
                p.kill()
                p.join(1)

    def results(self) -> dict[str, Any]:
        """Every actor's result (its last process's: ``{actor: result}``), once all have
        exited with 0."""
        out = {}
        for name, p in self.procs.items():
            if p.exitcode != 0:
                raise ActorFailed(f"actor {name} exited with code {p.exitcode}")
            out.update(json.loads(self.result_path(name).read_text()))
        return out

    def report(self) -> dict[str, Any]:
        """summary.json's ``restarts`` (how many process restarts) and ``restarted`` (which
        process and actors, attempt, exit code, from which snapshot step: :class:`Restart`)."""
        return {"restarts": len(self.restarts),
                "restarted": [asdict(r) for r in self.restarts]}
