"""The run context: what every actor of a run knows about it, typed and immutable.

One :class:`RunContext` is built by the command line (or a test) and handed to every actor; the
processes placement sends it to each actor process as JSON (:meth:`RunContext.to_json`). It is
frozen: a placement that adds something (its name, a snapshot directory, the progress board)
makes a new one with :meth:`RunContext.with_`, so no actor sees another's edits.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..metrics import METRICS_EVERY
from ..qlap.params import Params
from .snapshot import DEFAULT_EVERY

CLOCKS = ("lockstep", "realtime")


@dataclass(frozen=True)
class RunContext:
    """What an actor needs to know about the run (the same in every process)."""

    run_id: str
    world: str
    steps: int
    seed: int
    params: Params
    out: Path | None = None
    checkpoint_every: int = 10_000
    clock: str = "lockstep"
    """``lockstep`` (the world waits for every motor) or ``realtime`` (it ticks at ``hz``)."""
    hz: float = 100.0
    """The realtime clock's tick rate."""
    start_step: int = 0
    """The first step of the run."""
    placement: str = ""
    """``embedded``, ``processes``, ``distributed`` (set by the placement)."""
    groups: tuple[tuple[str, ...], ...] = ()
    """The actors that share a process (set by the placement: embedded, one group of all;
    processes, its layout); an actor in no group is alone. What is hosted, shared or handed
    over in memory follows from it (:meth:`together`), not from the placement's name."""
    keep_checkpoints: int | None = None
    """Periodic checkpoints kept (the newest N; None: all)."""
    metrics_every: int = METRICS_EVERY
    snapshot_dir: Path | None = None
    """Where actors write their snapshots (set by the processes launcher); None: none."""
    snapshot_every: int = DEFAULT_EVERY
    replay_keep_steps: int | None = None
    """Overrides :attr:`replay_keep` (tests)."""
    stall_s: float = 0.0
    """Seconds without progress before the watchdog stops the run (0: its default)."""
    credentials: Path | None = None
    """Where the credentials of a listening run were written."""
    restarted: bool = False
    """This actor was restarted by the supervisor (from :attr:`resume_from`, or the start)."""
    resume_from: Path | None = None
    resumes: dict[str, str] | None = None
    """A restarted process group's snapshots, actor -> snapshot directory (an actor absent:
    from the start); each actor of the group reads its own (:meth:`for_actor`)."""
    resume_checkpoint: Path | None = None
    """The checkpoint a resumed run starts from (``qlap run --resume``; its step is
    :attr:`start_step`): every actor without a snapshot of its own loads it
    (:mod:`actors.resume`)."""
    faults: dict[str, Any] | None = None
    """Messages to drop or delay (tests and the chaos harness only; the JSON form of
    :class:`~qlap_runtime.bus.faults.Faults`); None: none."""
    board: Any = field(default=None, repr=False, compare=False)
    """The run's progress board (:mod:`~qlap_runtime.runtime.watchdog`), set by the launcher
    in each process; not part of the JSON form."""

    def __post_init__(self) -> None:
        if self.clock not in CLOCKS:
            raise ValueError(f"clock must be one of {CLOCKS}, got {self.clock!r}")

    def with_(self, **changes: Any) -> RunContext:
        """A copy with ``changes`` (a placement adding what it knows)."""
        return dataclasses.replace(self, **changes)

    def for_actor(self, name: str) -> RunContext:
        """The context of actor ``name`` of a (restarted) process group: ``resume_from`` its
        own snapshot of :attr:`resumes`; the context itself when there are none."""
        if self.resumes is None:
            return self
        path = self.resumes.get(name)
        return self.with_(resume_from=None if path is None else Path(path))

    def together(self, *names: str) -> bool:
        """True when the actors ``names`` run in one process (one group), so that they may
        share a task, a learner or objects in memory."""
        return any(set(names) <= set(group) for group in self.groups)

    @property
    def realtime(self) -> bool:
        return self.clock == "realtime"

    @property
    def start(self) -> int:
        return self.start_step

    @property
    def snapshots(self) -> Path | None:
        """Where this actor writes snapshots; None under the realtime clock, whose state is
        not a function of the input stream."""
        return None if self.realtime else self.snapshot_dir

    @property
    def replay_keep(self) -> int:
        """Steps a writer keeps in its replay logs: enough for a consumer whose snapshot is up
        to two periods old and that died just before a landmark batch was due."""
        if self.replay_keep_steps is not None:
            return self.replay_keep_steps
        p = self.params
        return 2 * max(1, self.snapshot_every) + max(p.landmark_period, p.dbn_period) \
            + 2 * p.batch_lag + 100

    @property
    def end(self) -> int:
        """The step after the run's last one."""
        return self.start_step + self.steps

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            if f.name == "board":
                continue
            v = getattr(self, f.name)
            out[f.name] = v.to_dict() if isinstance(v, Params) else \
                str(v) if isinstance(v, Path) else v
        return out

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> RunContext:
        names = {f.name for f in dataclasses.fields(cls)} - {"board"}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"unknown run context fields: {sorted(unknown)}")
        kw: dict[str, Any] = dict(d)
        kw["params"] = Params.from_dict(d["params"])
        kw["groups"] = tuple(tuple(str(a) for a in g) for g in d.get("groups", ()))
        for name in ("out", "snapshot_dir", "credentials", "resume_from",
                     "resume_checkpoint"):
            if kw.get(name) is not None:
                kw[name] = Path(kw[name])
        return cls(**kw)


def world_variables(spec: str) -> tuple[Any, dict[str, Any]]:
    """The variable table and agent options of a world (the world is built and closed)."""
    import worlds

    w = worlds.make(spec)
    try:
        return w.variables, dict(getattr(w, "agent_options", {}) or {})
    finally:
        w.close()
