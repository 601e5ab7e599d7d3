"""Running a sweep: agents × conditions in parallel, resumably, with one progress display.

Two backends share one scheduler (:func:`run_sweep`): a local pool of spawned worker processes
(``--engine local``, the default, ``--jobs`` of them, default every core) and Ray
(``--engine ray``: ``ray.init(num_cpus=jobs)`` on this machine, or ``--address HOST:PORT`` to
join a running cluster, whose nodes need this package installed and ``--out`` on storage they
share, since workers write the run directories). The scheduler keeps at most as many jobs in
flight as there are worker slots, evaluations of finished runs first, and writes every result
the moment it arrives: a finished run is its directory (``summary.json``), a finished
evaluation a row of curve.csv (:mod:`.sweep`). A killed sweep therefore continues where it
stopped: finished runs and evaluations are reused, an interrupted run starts again from step 0
(the runs are deterministic: the same seed gives the same agent).

Jobs are the JSON-in, JSON-out functions of :mod:`.jobs`.
"""

from __future__ import annotations

import importlib.util
import json
import math
import multiprocessing
import os
import time
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor
from concurrent.futures import wait as wait_futures
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from ..analysis.curve import RANDOM_RUN, CurveRow, read_rows, write_rows
from ..errors import one_line
from . import jobs
from .address import RayUnreachable, check_reachable, parse_ray_address
from .jobs import file_lock
from .spec import ExperimentError
from .sweep import EvalSpec, Sweep, run_done

__all__ = ["Backend", "LocalBackend", "RayBackend", "SweepResult", "make_backend", "run_sweep"]

Echo = Callable[[str], None]
Done = list[tuple[Any, str | BaseException]]

JOB_FUNCTIONS: dict[str, Callable[[str], str]] = {"run": jobs.run_job, "eval": jobs.eval_job}


class Backend(Protocol):
    """Where jobs run."""

    name: str
    slots: int
    """Jobs that can run at once."""

    def submit(self, kind: str, payload: str) -> Any: ...
    def wait(self, handles: list[Any], timeout: float) -> Done: ...
    def close(self, cancel: bool = False) -> None: ...


def _watch_parent(parent: int) -> None:
    """In a pool worker: exit when the sweep that started it is gone (killed), so that no
    orphan goes on writing a run directory that the next sweep is about to redo."""
    import threading

    def watch() -> None:
        while True:
            time.sleep(1.0)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watch, name="watch-parent", daemon=True).start()


class LocalBackend:
    """A pool of ``jobs`` spawned worker processes on this machine."""

    name = "local"

    def __init__(self, jobs: int | None = None) -> None:
        self.slots = max(1, jobs or os.cpu_count() or 1)
        self.pool = ProcessPoolExecutor(max_workers=self.slots,
                                        mp_context=multiprocessing.get_context("spawn"),
                                        initializer=_watch_parent, initargs=(os.getpid(),))

    def submit(self, kind: str, payload: str) -> Future[str]:
        return self.pool.submit(JOB_FUNCTIONS[kind], payload)

    def wait(self, handles: list[Any], timeout: float) -> Done:
        done, _ = wait_futures(handles, timeout=timeout, return_when=FIRST_COMPLETED)
        out: Done = []
        for fut in done:
            exc = fut.exception()
            out.append((fut, exc if exc is not None else fut.result()))
        return out

    def close(self, cancel: bool = False) -> None:
        self.pool.shutdown(wait=not cancel, cancel_futures=cancel)


class RayBackend:
    """Ray tasks: a local Ray with ``jobs`` CPUs, or the cluster at ``address``."""

    name = "ray"

    def __init__(self, jobs: int | None = None, address: str | None = None) -> None:
        """``address`` is checked first (:mod:`.address`): a malformed one raises
        :class:`ExperimentError`, a cluster whose port does not answer within a few seconds
        :class:`RayUnreachable` — instead of Ray's ``ValueError`` or its endless retries."""
        if address is not None:
            address = parse_ray_address(address)
        try:
            import ray
        except ImportError:
            raise ExperimentError("--engine ray needs Ray: pip install -e .[experiments]"
                                  ) from None
        self.ray = ray
        self.owned = not ray.is_initialized()
        if self.owned:
            if address and address.startswith("ray://") and \
                    importlib.util.find_spec("grpc") is None:
                raise ExperimentError(f"--address {address}: the Ray Client needs "
                                      "pip install 'ray[client]'")
            if address:
                address = check_reachable(address)
            kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                                      "configure_logging": False}
            try:
                if address:
                    ray.init(address=address, **kwargs)
                else:
                    ray.init(num_cpus=max(1, jobs or os.cpu_count() or 1), **kwargs)
            except (ConnectionError, ValueError, RuntimeError) as exc:
                if ray.is_initialized():
                    ray.shutdown()
                where = f"join the Ray cluster at {address}" if address else "start Ray"
                env = "" if address else os.environ.get("RAY_ADDRESS", "")
                hint = (f" (RAY_ADDRESS={env} is set: unset it, or give it as --address)"
                        if env else "")
                raise RayUnreachable(f"cannot {where}: {one_line(exc)}{hint}") from None
        cpus = int(ray.cluster_resources().get("CPU", 1))
        self.slots = max(1, min(jobs, cpus) if jobs and address else cpus)
        self.remote = {k: ray.remote(num_cpus=1, max_retries=0)(f)
                       for k, f in JOB_FUNCTIONS.items()}
        self.pending: set[Any] = set()
        """The submitted tasks not yet returned (cancelled by :meth:`close` on an interrupt)."""

    def submit(self, kind: str, payload: str) -> Any:
        ref = self.remote[kind].remote(payload)
        self.pending.add(ref)
        return ref

    def wait(self, handles: list[Any], timeout: float) -> Done:
        ready, _ = self.ray.wait(handles, num_returns=1, timeout=timeout)
        out: Done = []
        for ref in ready:
            self.pending.discard(ref)
            try:
                out.append((ref, self.ray.get(ref)))
            except Exception as exc:  # a job's error, raised by Ray on get
                out.append((ref, exc))
        return out

    def close(self, cancel: bool = False) -> None:
        """``cancel`` (an interrupted sweep): the tasks still running are cancelled — on a
        cluster they would go on writing run directories, as a local pool's would not."""
        if cancel:
            for ref in self.pending:
                self.ray.cancel(ref, force=True)
            self.pending.clear()
        if self.owned:
            self.ray.shutdown()


def make_backend(engine: str, jobs: int | None, address: str | None) -> Backend:
    """The backend of ``--engine``, ``--jobs`` and ``--address``."""
    if engine == "local":
        if address:
            raise ExperimentError("--address goes with --engine ray")
        return LocalBackend(jobs)
    if engine == "ray":
        return RayBackend(jobs, address)
    raise ExperimentError(f"unknown engine {engine!r}; engines: local, ray")


# ---------------------------------------------------------------------------------------------
# The progress display
# ---------------------------------------------------------------------------------------------
class _Display:
    """One rich display for the sweep: agents done with their steps/s and ETA, evaluations
    done with theirs; without a terminal, one line per finished job."""

    def __init__(self, total_steps: int, agents: int, evals: int, echo: Echo | None,
                 live: bool) -> None:
        from rich.console import Console
        from rich.progress import BarColumn, Progress, TextColumn

        self.console = Console(stderr=True)
        self.live = live and self.console.is_terminal
        self.echo = echo
        self.progress = Progress(TextColumn("{task.description:<12}"), BarColumn(),
                                 TextColumn("{task.fields[info]}"), console=self.console,
                                 disable=not self.live, transient=False)
        self.runs = self.progress.add_task("agent runs", total=max(1, total_steps), info="")
        self.evals = self.progress.add_task("evaluations", total=max(1, evals), info="")
        self.total_steps, self.agents, self.n_evals = total_steps, agents, evals
        self.t0 = time.perf_counter()
        self.steps_at_start: int | None = None
        self.evals_at_start: int | None = None

    def __enter__(self) -> _Display:
        self.progress.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.progress.stop()

    def line(self, text: str) -> None:
        if self.live:
            self.progress.console.print(text, highlight=False)
        elif self.echo is not None:
            self.echo(text)

    def update(self, steps: int, agents_done: int, evals_done: int) -> None:
        if self.steps_at_start is None:
            self.steps_at_start, self.evals_at_start = steps, evals_done
        el = max(1e-9, time.perf_counter() - self.t0)
        rate = (steps - self.steps_at_start) / el
        left = self.total_steps - steps
        eta = _duration(left / rate) if rate > 0 and left > 0 else ("done" if left <= 0 else "—")
        self.progress.update(self.runs, completed=steps,
                             info=f"{agents_done}/{self.agents} agents  {rate:,.0f} steps/s  "
                                  f"ETA {eta}")
        erate = (evals_done - (self.evals_at_start or 0)) / el
        eleft = self.n_evals - evals_done
        eeta = (_duration(eleft / erate) if erate > 0 and eleft > 0
                else ("done" if eleft <= 0 else "—"))
        self.progress.update(self.evals, completed=evals_done,
                             info=f"{evals_done}/{self.n_evals}  {erate * 60:,.1f}/min  "
                                  f"ETA {eeta}")


def _duration(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "—"
    s = int(seconds)
    return f"{s // 3600}h{s % 3600 // 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"


# ---------------------------------------------------------------------------------------------
# The scheduler
# ---------------------------------------------------------------------------------------------
@dataclass
class SweepResult:
    """What a sweep did."""

    runs_done: int = 0
    runs_reused: int = 0
    evals_done: int = 0
    evals_reused: int = 0
    failures: list[str] = field(default_factory=list)
    wall_s: float = 0.0
    steps_run: int = 0
    """Agent steps computed by this invocation (reused runs excluded)."""
    agent_seconds: float = 0.0
    """Sum of the runs' own wall times (their steps/s per core is steps_run / this)."""


def _read_progress(run_dir: Path) -> int:
    try:
        return int(json.loads((run_dir / "progress.json").read_text())["step"])
    except (OSError, ValueError, KeyError, TypeError):
        return 0


def run_sweep(sweep: Sweep, backend: Backend, echo: Echo | None = print,
              live: bool = True, poll: float = 0.5) -> SweepResult:
    """Run every run and evaluation of ``sweep`` that is not done yet, on ``backend``."""
    res = SweepResult()
    t0 = time.perf_counter()
    specs = sweep.runs
    done_runs = {k for k, s in specs.items() if run_done(sweep.run_dir(k), s)}
    res.runs_reused = len(done_runs)
    # Evaluations of a run that is not finished are not results: the run starts again.
    rows = {key: r for key, r in sweep.rows().items()
            if r.run == RANDOM_RUN or r.run in done_runs}
    by_file: dict[str, dict[tuple[Any, ...], CurveRow]] = {}
    for r in rows.values():
        by_file.setdefault(r.run, {})[r.key] = r
    pending_evals = [e for e in sweep.evals if e.key not in rows]
    res.evals_reused = len(sweep.evals) - len(pending_evals)
    pending_runs = [k for k in specs if k not in done_runs]
    failed_runs: set[str] = set()
    inflight: dict[Any, tuple[str, Any]] = {}
    running: set[str] = set()
    total_steps = sum(s.steps for s in specs.values())
    done_steps = sum(specs[k].steps for k in done_runs)

    def ready_run(k: str) -> bool:
        dep = specs[k].landmark_run
        return dep is None or dep in done_runs

    def submit_more() -> None:
        while len(inflight) < backend.slots:
            e = next((e for e in pending_evals
                      if e.run == RANDOM_RUN or e.run in done_runs), None)
            if e is not None:
                pending_evals.remove(e)
                ckpt = None if e.run == RANDOM_RUN else \
                    str(sweep.run_dir(e.run) / "checkpoints" / e.checkpoint)
                payload = json.dumps({"eval": e.to_json(), "checkpoint": ckpt})
                inflight[backend.submit("eval", payload)] = ("eval", e)
                continue
            k = next((k for k in pending_runs if ready_run(k)), None)
            if k is None:
                return
            pending_runs.remove(k)
            running.add(k)
            payload = jobs.run_payload(specs[k], sweep.run_dir(k), sweep.root)
            inflight[backend.submit("run", payload)] = ("run", k)

    def drop_failed() -> None:
        """Evaluations and dependants of failed runs can never run."""
        for e in [e for e in pending_evals if e.run in failed_runs]:
            pending_evals.remove(e)
        for k in [k for k in pending_runs if specs[k].landmark_run in failed_runs]:
            pending_runs.remove(k)
            failed_runs.add(k)
            res.failures.append(f"run {k}: its landmark run failed")

    display = _Display(total_steps, len(specs), len(sweep.evals), echo, live)
    last_poll = 0.0
    try:
        with display:
            while True:
                drop_failed()
                submit_more()
                if not inflight:
                    break
                for handle, out in backend.wait(list(inflight), timeout=poll):
                    kind, what = inflight.pop(handle)
                    if kind == "run":
                        running.discard(what)
                        _run_finished(what, out, sweep, res, done_runs, failed_runs,
                                      display)
                        if what in done_runs:
                            done_steps += specs[what].steps
                    else:
                        _eval_finished(what, out, sweep, res, by_file, display)
                now = time.perf_counter()
                if now - last_poll >= 1.0:
                    last_poll = now
                    live_steps = sum(min(_read_progress(sweep.run_dir(k)), specs[k].steps)
                                     for k in running)
                    display.update(done_steps + live_steps, len(done_runs),
                                   len(sweep.evals) - len(pending_evals) - sum(
                                       1 for v in inflight.values() if v[0] == "eval"))
            display.update(done_steps, len(done_runs), len(sweep.evals) - len(pending_evals))
    except BaseException:
        backend.close(cancel=True)
        raise
    res.wall_s = time.perf_counter() - t0
    return res


def _run_finished(key: str, out: str | BaseException, sweep: Sweep, res: SweepResult,
                  done_runs: set[str], failed_runs: set[str], display: _Display) -> None:
    spec = sweep.runs[key]
    if isinstance(out, BaseException):
        failed_runs.add(key)
        msg = f"run {key}: {type(out).__name__}: {str(out).splitlines()[0] if str(out) else ''}"
        res.failures.append(msg)
        display.line(f"FAILED {msg}")
        return
    data = json.loads(out)
    done_runs.add(key)
    res.runs_done += 1
    summary = data.get("summary") or {}
    if not data.get("reused"):
        res.steps_run += spec.steps
        res.agent_seconds += float(data.get("seconds") or 0.0)
    rate = summary.get("steps_per_s")
    display.line(f"agent {key}: {spec.steps:,} steps in {data.get('seconds', 0):.0f} s"
                 + (f" ({rate} steps/s)" if rate else ""))


def _eval_finished(e: EvalSpec, out: str | BaseException, sweep: Sweep, res: SweepResult,
                   by_file: dict[str, dict[tuple[Any, ...], CurveRow]],
                   display: _Display) -> None:
    what = "random policy" if e.run == RANDOM_RUN else f"{e.run} {e.checkpoint}"
    if isinstance(out, BaseException):
        msg = f"evaluation {what} {e.task}: {type(out).__name__}: {out}"
        res.failures.append(msg.splitlines()[0])
        display.line(f"FAILED {msg.splitlines()[0]}")
        return
    d = json.loads(out)
    row = CurveRow(run=e.run, step=e.step, task=e.task, mean_reward=float(d["mean_reward"]),
                   stderr=float(d["stderr"]), success_rate=float(d["success_rate"]),
                   trials=int(d["trials"]), seed=e.seed, world=e.world, policy=e.policy,
                   checkpoint=e.checkpoint)
    path = sweep.curve_path(e.run)
    with file_lock(path.with_name(path.name + ".lock")):    # another sweep may share the run
        rows = by_file.setdefault(e.run, {})
        for r in read_rows(path):
            rows.setdefault(r.key, r)
        rows[row.key] = row
        write_rows(path, list(rows.values()))
    res.evals_done += 1
    display.line(f"eval {what} {e.task}: {row.mean_reward:.3f} ± {row.stderr:.3f} "
                 f"({float(d.get('seconds', 0)):.1f} s)")
