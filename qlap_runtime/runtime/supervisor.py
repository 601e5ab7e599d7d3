"""The supervisor of the processes placement: restarts a dead actor, and the run goes on.

See docs/architecture.md §2 (processes). The launcher starts one ``spawn`` process per actor and
polls them here. An actor that dies (any non-zero exit: a crash, SIGKILL, the OOM killer) is
started again with ``ctx.restarted`` and ``ctx.resume_from`` = its latest
snapshot (``snapshot.latest_snapshot``; none yet: from the start). The new process loads the
snapshot, fetches from the writers' replay logs what it missed, catches up and continues live
(docs/runtime.md, Faults). Because the lockstep clock makes each actor's state a function of its
input stream, the run's knowledge is the one of a run without the fault.

Not restarted, and the run stops with :class:`ActorFailed` saying why: the world (its physics
state is not snapshotted), any actor under the realtime clock (its state depends on arrival
times, so there is nothing exact to resume), and an actor that died ``max_restarts`` times.
"""

from __future__ import annotations

import json
import logging
import multiprocessing as mp
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from .snapshot import latest_snapshot

log = logging.getLogger("qlap.supervisor")

RESTARTABLE = frozenset({"perception", "contingency", "landmarks", "planner", "executor"})
MAX_RESTARTS = 3
"""Restarts allowed per actor in one run."""


class ActorFailed(RuntimeError):
    """An actor died and could not be restarted: the run is stopped."""


def _default_stall() -> float:
    from .watchdog import DEFAULT_STALL_S

    return DEFAULT_STALL_S


@dataclass(frozen=True)
class Restart:
    """One restart, as reported in summary.json's ``restarted``."""

    actor: str
    attempt: int
    """1 for the actor's first restart."""
    exit_code: int | None
    """The dead process's exit code (−9: SIGKILL)."""
    from_step: int | None
    """The step of the snapshot it resumed from (None: from the start of the run)."""


class Supervisor:
    """Starts the actor processes and restarts those that die (see the module docstring).

    ``target(name, ctx_json, endpoint, result_path)`` is an actor process's entry point;
    ``ctx`` must have a ``snapshot_dir`` for restarts to resume from snapshots.
    """

    def __init__(self, ctx: Any, endpoint: str, workdir: Path, names: tuple[str, ...],
                 target: Callable[..., None], *,
                 max_restarts: int = MAX_RESTARTS,
                 passwords: dict[str, str] | None = None) -> None:
        self.ctx = ctx
        self.endpoint = endpoint
        self.workdir = Path(workdir)
        self.names = names
        self.target = target
        self.max_restarts = max_restarts
        self.passwords = dict(passwords or {})
        """Each actor's password on the router (given to its process, never written)."""
        self.snapshot_dir = ctx.snapshots
        """None under the realtime clock (no snapshots): a dead actor stops the run."""
        self.procs: dict[str, Any] = {}
        self.attempts: dict[str, int] = dict.fromkeys(names, 0)
        self.restarts: list[Restart] = []
        self._spawn = mp.get_context("spawn")
        from .watchdog import SIZE, Board, Watchdog
        # The progress board in shared memory: each incarnation of an actor gets its slot.
        self.shared = {n: self._spawn.RawArray("d", SIZE) for n in names}
        self.board = Board(names, self.shared)
        self.watchdog = Watchdog(self.board, ctx.stall_s or _default_stall())

    def result_path(self, name: str) -> Path:
        return self.workdir / f"{name}.json"

    def start(self, name: str, resume_from: Path | None = None, *,
              restarted: bool = False) -> None:
        """Start (or start again, ``restarted`` from the snapshot ``resume_from``) one
        actor's process."""
        ctx_json = self.ctx.with_(restarted=restarted, resume_from=resume_from).to_json()
        self.board.slot(name).restarted()
        p = self._spawn.Process(target=self.target, name=f"qlap-{name}",
                                args=(name, json.dumps(ctx_json), self.endpoint,
                                      str(self.result_path(name)), self.shared[name],
                                      self.passwords.get(name)))
        p.start()
        self.procs[name] = p
        self.watchdog.reset()

    def start_all(self) -> None:
        for name in self.names:
            self.start(name)

    def check(self) -> bool:
        """Restart the actors that died since the last call; True while any is running.
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
        """The one-line error the actor's process wrote before dying, if any."""
        path = self.result_path(name).with_suffix(".error.json")
        try:
            err = json.loads(path.read_text())
            path.unlink()
        except (OSError, ValueError):
            return None
        return err if isinstance(err, dict) else None

    def _restart(self, name: str, code: int) -> None:
        self.procs[name].join(1)
        err = self.error_of(name)
        why = f" ({err.get('message')})" if err else ""
        world = self.procs.get("world")
        if err is not None and err.get("type") == "OSError":
            raise ActorFailed(f"actor {name} exited with code {code}{why}; a restart cannot "
                              "help: run stopped")
        if name != "world" and world is not None and world.exitcode == 0:
            raise ActorFailed(f"actor {name} exited with code {code}{why} after the world "
                              "finished; its inputs cannot be replayed: run stopped")
        if name not in RESTARTABLE:
            raise ActorFailed(f"actor {name} exited with code {code}{why}; the {name} actor cannot "
                              "be restarted (its physics state is not snapshotted): run stopped")
        if self.snapshot_dir is None:
            raise ActorFailed(f"actor {name} exited with code {code}; restarting an actor needs "
                              "the lockstep clock and a snapshot directory: run stopped")
        if self.attempts[name] >= self.max_restarts:
            raise ActorFailed(f"actor {name} exited with code {code} after "
                              f"{self.attempts[name]} restarts: run stopped")
        self.attempts[name] += 1
        attempt = self.attempts[name]
        latest = latest_snapshot(self.snapshot_dir, name)
        step = None if latest is None else latest[0]
        if latest is None:
            log.warning("actor %s exited with code %s; restarting %s from the start (no "
                        "snapshot yet) (attempt %d)", name, code, name, attempt)
        else:
            log.warning("actor %s exited with code %s; restarting %s from snapshot at step %d "
                        "(attempt %d)", name, code, name, step, attempt)
        self.restarts.append(Restart(name, attempt, code, step))
        self.start(name, None if latest is None else latest[1], restarted=True)

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
        """Every actor's result (its last process's), once all have exited with 0."""
        out = {}
        for name, p in self.procs.items():
            if p.exitcode != 0:
                raise ActorFailed(f"actor {name} exited with code {p.exitcode}")
            out[name] = json.loads(self.result_path(name).read_text())
        return out

    def report(self) -> dict[str, Any]:
        """summary.json's ``restarts`` (how many) and ``restarted`` (which, from where)."""
        return {"restarts": len(self.restarts),
                "restarted": [asdict(r) for r in self.restarts]}
