"""The local driver: the synchronous agent in a worker thread, publishing telemetry on Zenoh.

``qlap run`` in a terminal uses it (no placement given): the agent steps in its own
thread (never waiting for a viewer), publishes the display topics of
:mod:`qlap_runtime.telemetry` with ``CongestionControl.DROP`` on an embedded session (no
sockets; ``listen=[...]`` lets outside viewers attach, ``qlap tui --connect``), and obeys
:class:`~qlap_runtime.bus.schema.Control` messages on ``qlap/<run>/control`` through the
runner contract the executor actor uses too (:mod:`qlap_runtime.runtime.runner`):

=========  =========================================================================
pause      stop stepping (publishes a status at once)
resume     go on
step       ``{"n": 1}``: advance n steps while paused
speed      ``{"steps_per_s": x}``: pace the run at x steps/s (realtime clock); 0 = free
save       ``{"path": dir}`` (optional, inside the run directory): checkpoint via
           ``save_agent`` (default: the run's ``checkpoints/step-NNNNNNN``)
goal       ``{"var": name, "value": label or index}`` → ``agent.set_goal``; ``{"clear": true}``
quit       stop the run (the thread ends; the driver's owner closes the session)
=========  =========================================================================

The viewer sees only bus messages: the actor runtime's executor publishes the same telemetry,
and the actors obey the same controls (docs/runtime.md, Controls), so the same UI attaches to
either.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import threading
import time
from collections import deque
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import zenoh

from qlap_runtime import telemetry
from qlap_runtime.bus import keys
from qlap_runtime.bus.bridge import RejectionCounter, declare_alive
from qlap_runtime.bus.config import embedded_config
from qlap_runtime.bus.schema import Control
from qlap_runtime.errors import WorldFailed
from qlap_runtime.metrics import Rejections
from qlap_runtime.runtime.background import CheckpointWriter
from qlap_runtime.runtime.controls import RunControl
from qlap_runtime.runtime.runner import Display, Runner

PLACEMENT = "local"
"""What the Runtime panel and summary.json call this runner: the synchronous agent (Algorithm
2) stepping in a thread of the UI's process, not an actor placement."""

log = logging.getLogger("qlap.tui.driver")


class LocalDriver:
    """Runs ``agent`` in ``world`` in a thread and publishes its telemetry.

    Args:
        world: a world (``worlds.make(...)``); reset with ``seed`` unless ``reset=False``.
        agent: the agent (built from the world with ``params`` when None).
        steps: stop after this many steps (None: until quit); the driver then reports
            ``finished`` and waits for ``quit``.
        session: a Zenoh session to publish on; when None the driver opens an embedded one
            (``listen`` endpoints, if any) and closes it in :meth:`stop`.
        run_id: the run's id (a fresh one by default).
        speed: steps/s limit (0 = as fast as possible); paused: start paused.
        checkpoint_dir: where ``save`` writes (``<dir>/step-NNNNNNN``); default
            ``<out>/checkpoints`` (``qlap-checkpoints`` without ``out``).
        out: the run directory (docs/outputs.md): ``checkpoints/step-NNNNNNN`` every
            ``checkpoint_every`` steps (the newest ``keep_checkpoints`` kept, None: all),
            ``metrics.jsonl`` every 1,000 steps, and, when the last step is done or the run
            is quit, ``knowledge.json``, ``summary.json`` and ``checkpoints/final``.
        world_spec: the world's spec, recorded in the checkpoints (default: its name).
        on_finish: called in the worker thread with the driver when the last step is done,
            or when the run is quit before that (after the outputs are written).
    """

    def __init__(self, world: Any, agent: Any = None, *, seed: int = 0,
                 params: Any = None, steps: int | None = None,
                 session: zenoh.Session | None = None, listen: Sequence[str] = (),
                 run_id: str | None = None, speed: float = 0.0, paused: bool = False,
                 checkpoint_dir: Path | str | None = None, reset: bool = True,
                 cadence: telemetry.Cadence | None = None, on_finish: Any = None,
                 out: Path | str | None = None, checkpoint_every: int = 10_000,
                 keep_checkpoints: int | None = None, world_spec: str | None = None,
                 users: Mapping[str, str] | None = None) -> None:
        from qlap_runtime.agent_run import params_for_world
        from qlap_runtime.qlap.agent import Agent

        self.world = world
        self.seed = seed
        if agent is None:
            agent = Agent(world.variables, params_for_world(world, params), seed=seed)
        self.agent = agent
        self.steps = steps
        self.run_id = keys.validate_run_id(run_id) if run_id else keys.new_run_id()
        self.out = None if out is None else Path(out)
        self.checkpoint_dir = Path(checkpoint_dir) if checkpoint_dir is not None else (
            self.out / "checkpoints" if self.out is not None else Path("qlap-checkpoints"))
        self.checkpoint_every = int(checkpoint_every)
        self.keep_checkpoints = keep_checkpoints
        self.world_spec = world_spec or getattr(world, "spec", None) \
            or getattr(world, "name", None)
        self._metrics: Any = None
        self.counter = RejectionCounter("agent")
        self.runner = Runner(agent, self.world_spec,
                             clock=RunControl(paused=paused, speed=max(0.0, float(speed))),
                             out=self.out, checkpoints=self.checkpoint_dir,
                             counter=self.counter, key=keys.key(self.run_id, "control"),
                             run_id=self.run_id, world_state=self._world_state)
        """Applies the controls (the contract the executor actor shares)."""
        self.display: Display | None = None
        self._last_saved: tuple[int, int, Path | None] = (-1, -1, None)
        self._writer = CheckpointWriter()
        """Writes the periodic checkpoints off this loop (docs/decisions.md 107)."""
        self._rejected = Rejections()
        self._outputs_written = False
        self.cadence = cadence or telemetry.Cadence()
        self.on_finish = on_finish
        self._listen = list(listen)
        self._users = dict(users) if users else None
        """With ``listen``: the users that may connect (usrpwd) under the run's ACL
        (``qlap_runtime.bus.auth``: ``tui`` may put on ``control``, ``viewer`` nothing)."""
        self._own_session = session is None
        self._session = session
        self._reset = reset
        self._controls: deque[Control] = deque()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._started = 0.0
        self._late = 0
        self._missed = 0
        self._obs: Mapping[str, float] = {}
        self._motor: dict[str, float] = {}
        self.finished = False
        self.error: BaseException | None = None
        self.steps_done = 0
        """Steps run by this driver (read from other threads for tests and benches)."""

    @property
    def paused(self) -> bool:
        return self.runner.clock.paused

    @property
    def speed(self) -> float:
        return self.runner.clock.speed

    # ----------------------------------------------------------------------------- lifecycle
    @property
    def session(self) -> zenoh.Session:
        assert self._session is not None, "start() the driver first"
        return self._session

    def open(self) -> zenoh.Session:
        """Open the embedded session (if none was given) without starting the agent."""
        if self._session is None:
            auth: dict[str, Any] = {}
            if self._users and self._listen:
                from qlap_runtime.bus.auth import run_acl

                auth = {"users": self._users, "acl": run_acl(self._users)}
            self._session = zenoh.open(embedded_config(self._listen, **auth))
        return self._session

    def start(self) -> LocalDriver:
        """Open the session if needed, subscribe to control and start the worker thread."""
        session = self.open()
        self.display = Display(session, self.run_id, placement=PLACEMENT,
                               world=str(getattr(self.world, "name", "")), seed=self.seed,
                               world_view=lambda: telemetry.world_msg(self.agent, self.world),
                               cadence=self.cadence)
        self._control_sub = session.declare_subscriber(keys.key(self.run_id, "control"),
                                                       self._on_control)
        self._token = declare_alive(session, self.run_id, "agent")
        if self._reset:
            self._obs = self.world.reset(seed=self.seed)
        else:
            self._obs = dict(self.world.observation)
        self._motor = dict(self.agent.motor)
        if self.out is not None:
            from qlap_runtime.metrics import METRICS_FILE, MetricsLog

            self._metrics = MetricsLog(self.out / METRICS_FILE, self.agent,
                                       start=self.agent.step_count + 1)
        self._thread = threading.Thread(target=self._main, name=f"qlap-agent-{self.run_id}",
                                        daemon=True)
        self._started = time.perf_counter()
        self._thread.start()
        return self

    def stop(self, timeout: float = 10.0) -> None:
        """Stop the worker thread, undeclare everything, close the session if the driver
        opened it. Idempotent."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout)
            if self._thread.is_alive():  # pragma: no cover - a step never takes that long
                log.error("agent thread did not stop within %.1f s", timeout)
        for obj in [getattr(self, "_control_sub", None), getattr(self, "_token", None)]:
            if obj is None:
                continue
            try:
                obj.undeclare()
            except zenoh.ZError:  # pragma: no cover - already gone
                pass
        if self.display is not None:
            self.display.close()
            self.display = None
        self._control_sub = self._token = None
        if self._own_session and self._session is not None:
            self._session.close()
            self._session = None

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def wait(self, timeout: float | None = None) -> bool:
        """Wait until the worker thread ends (quit or stop); True if it did."""
        if self._thread is None:
            return True
        self._thread.join(timeout)
        return not self._thread.is_alive()

    def __enter__(self) -> LocalDriver:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ----------------------------------------------------------------------------- control
    def _on_control(self, sample: zenoh.Sample) -> None:
        # Zenoh's thread (or the publisher's, same session): only queue and wake.
        msg = self.counter.decode(str(sample.key_expr), sample.payload.to_bytes())
        if isinstance(msg, Control):
            self._controls.append(msg)
            self._wake.set()

    def command(self, command: str, **args: Any) -> None:
        """Queue a control command directly (same effect as one arriving on the bus)."""
        self._controls.append(Control(command, args))  # type: ignore[arg-type]
        self._wake.set()

    def _apply_pending(self) -> bool:
        """Apply the queued commands (the runner contract); True if there were any."""
        pending = []
        while self._controls:
            pending.append(self._controls.popleft())
        if not self.runner.apply(pending):
            return False
        if any(c.command in ("speed", "resume", "step") for c in pending):
            self._tick0 = None              # the pace restarts from now: no catching up
        if self.runner.clock.quit:
            self._stop.set()
        return True

    # ----------------------------------------------------------------------------- the loop
    def _main(self) -> None:
        try:
            self._loop()
        except BaseException as e:  # report, never hang the UI
            self.error = e
            self.runner.message = f"agent stopped: {type(e).__name__}: {e}"
            log.exception("agent thread failed")
            try:
                self._publish(time.perf_counter(), force=True)
            except Exception:  # pragma: no cover
                pass

    def _loop(self) -> None:
        from qlap_runtime.qlap.perception import InvalidObservation

        agent, world = self.agent, self.world
        self._tick0: tuple[float, int] | None = None
        self._publish(time.perf_counter(), force=True)
        clock = self.runner.clock
        while not self._stop.is_set():
            if self._apply_pending():
                self._publish(time.perf_counter(), force=True)
                if self._stop.is_set():
                    break
            if self.finished or not clock.may_step:
                self._wake.wait(0.25)
                self._wake.clear()
                self._publish(time.perf_counter())
                continue
            t = agent.step_count + 1
            try:
                self._motor = agent.step(t, self._obs,
                                         discontinuity=bool(getattr(world, "discontinuity", False)))
            except InvalidObservation as e:
                log.warning("step %d: %s", t, e)
                self._rejected.add(f"step {t}: {e}")
            try:
                self._obs = world.step(self._motor)
            except Exception as exc:
                self._world_failed(t, exc)
                continue
            self.steps_done += 1
            self._record(t)
            if clock.budget > 0:
                clock.stepped()
                if clock.budget == 0:
                    self._publish(time.perf_counter(), force=True)
            if self.steps is not None and self.steps_done >= self.steps:
                self.finished = self.runner.finished = True
                if self.display is not None:
                    self.display.finish()                   # the wall clock stops here
                self.runner.message = f"finished {self.steps_done} steps"
                self.write_outputs()
                if self.on_finish is not None:
                    self.on_finish(self)
                self._publish(time.perf_counter(), force=True)
                continue
            now = time.perf_counter()
            self._publish(now)
            if self.speed > 0 and not self.paused:
                self._pace(now)
        if not self.finished and self.steps_done:
            self.write_outputs()           # quit early: the outputs still describe the run
            if self.on_finish is not None:
                self.on_finish(self)
        if self._metrics is not None:
            self._metrics.close()

    def _world_failed(self, t: int, exc: Exception) -> None:
        """The world's step after agent step ``t`` raised: the run ends there as the
        synchronous loop's does — the outputs of what was learned up to t are written (no
        world state in the final checkpoint) — and the UI shows why until it is quit."""
        self.steps_done += 1
        self.error = WorldFailed(str(self.world_spec or type(self.world).__name__), t, exc)
        log.error("%s", self.error)
        self.runner.message = str(self.error)
        if self.display is not None:
            self.display.finish()
        self.write_outputs()
        if self.on_finish is not None:
            self.on_finish(self)
        self.finished = self.runner.finished = True         # last: the outputs are there
        self._publish(time.perf_counter(), force=True)

    # ----------------------------------------------------------------------------- outputs
    def _world_state(self) -> Any:
        """The world's state between two steps, as a periodic checkpoint saves it."""
        from qlap_runtime.qlap.checkpoint import world_state_of

        return world_state_of(self.world)

    def _record(self, t: int) -> None:
        """After agent step ``t``: the metrics line and the periodic checkpoint when due."""
        if self._metrics is not None:
            self._metrics.after_step(t + 1, self.agent)
        if self.out is not None and (t + 1) % self.checkpoint_every == 0:
            from qlap_runtime.qlap.checkpoint import world_state_of

            last = self.steps is not None and self.steps_done >= self.steps
            self._last_saved = (self.agent.step_count, self.runner.agent_changes,
                                self._writer.save(self.agent, self.out / "checkpoints", t + 1,
                                                  self.world_spec, self.keep_checkpoints,
                                                  world_state_of(self.world),
                                                  copy_agent=not last))

    def write_outputs(self) -> None:
        """``knowledge.json``, ``summary.json``, the metrics log's last line and
        ``checkpoints/final`` (a link to the last periodic checkpoint when it holds this very
        state) into ``out``; once."""
        if self.out is None or self._outputs_written:
            return
        from qlap_runtime.metrics import summary_of
        from qlap_runtime.qlap.checkpoint import (
            atomic_write_json,
            save_final_checkpoint,
            world_state_of,
        )

        self._outputs_written = True
        agent = self.agent
        self._writer.wait()                              # the periodic checkpoint in flight
        wall = time.perf_counter() - self._started
        if self._metrics is not None:
            self._metrics.finish(agent.step_count + 1, agent)
        atomic_write_json(self.out / "knowledge.json", agent.knowledge())
        summary = summary_of(agent, self.world, self.seed, self.steps_done, wall,
                             self._rejected, placement=PLACEMENT)
        failed = isinstance(self.error, WorldFailed)
        if failed:
            summary["world_error"] = str(self.error)
        atomic_write_json(self.out / "summary.json", summary)
        step, changes, path = self._last_saved
        same = path if (step, changes) == (agent.step_count, self.runner.agent_changes) \
            else None
        save_final_checkpoint(agent, self.out / "checkpoints", self.world_spec, same_as=same,
                              world_state=None if failed else world_state_of(self.world))
        from qlap_runtime.analysis.plot import plot_run_if_possible

        plot_run_if_possible(self.out)                   # metrics.png beside the metrics log

    def _pace(self, now: float) -> None:
        """Realtime clock: tick n starts at t0 + n / speed; count late and missed ticks."""
        if self._tick0 is None:
            self._tick0 = (now, self.steps_done)
            return
        t0, n0 = self._tick0
        deadline = t0 + (self.steps_done - n0) / self.speed
        delay = deadline - now
        if delay > 0:
            self._wake.wait(delay)
            self._wake.clear()
        elif -delay > 1.0 / self.speed:
            self._late += 1
            if -delay > 1.0:                  # more than a second behind: skip ahead
                self._missed += int(-delay * self.speed)
                self._tick0 = (now, self.steps_done)

    # ----------------------------------------------------------------------------- publish
    def _publish(self, now: float, force: bool = False) -> None:
        if self.display is not None:
            self.display.publish(self.agent, self.runner.clock,
                                 clock_name="realtime" if self.speed > 0 else "free",
                                 force=force, late_ticks=self._late, missed_ticks=self._missed)


# --------------------------------------------------------------------------------- process
def _free_loopback_endpoint() -> str:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def _child_main(spec_json: str, ready: Any = None) -> None:
    """Entry point of the agent process (spawn): a LocalDriver listening on loopback, from
    :class:`DriverProcess`'s spec as JSON text (no pickled object crosses)."""
    import worlds
    from qlap_runtime.qlap import Params

    spec = json.loads(spec_json)
    # Take every key that is not a LocalDriver argument out of the spec unconditionally:
    # popping only when truthy left ``params={}`` (the default of ``qlap run``) in the spec,
    # so it reached LocalDriver twice (issue 12).
    overrides = spec.pop("params", None) or {}
    world_spec = spec.pop("world")
    world = worlds.make(world_spec)
    params = Params().replace(**overrides) if overrides else None
    spec.setdefault("world_spec", world_spec)

    # The terminal's signals are the UI's: Ctrl-C and the terminal closing (SIGHUP, sent to the
    # whole foreground group) reach this process too, and the UI tells it to quit. A SIGTERM
    # meant for it alone stops it as `q` does: the outputs are written.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    d = LocalDriver(world, params=params, **spec)
    signal.signal(signal.SIGTERM, lambda *_: d.stop())
    d.start()
    if ready is not None:
        ready.set()                      # listening: viewers may connect
    parent = os.getppid()

    def orphaned() -> None:              # the UI's process died (SIGKILL): quit as `q` would
        while d.alive:
            time.sleep(1.0)
            if os.getppid() != parent:
                log.warning("the UI's process is gone: the agent stops and writes its outputs")
                d.stop()
                return

    threading.Thread(target=orphaned, name="qlap-watch-ui", daemon=True).start()
    try:
        d.wait()
    finally:
        d.stop()


class DriverProcess:
    """A :class:`LocalDriver` in its own process (spawn), listening on a loopback endpoint, so
    that the UI (another process's GIL) never slows the agent. Viewers connect to
    :attr:`endpoint` (``client_config(endpoint)``); ``quit`` on the control topic, or
    :meth:`stop`, ends it.

    ``params`` is a dict of :class:`~qlap_runtime.qlap.Params` overrides (JSON values); the other
    keyword arguments go to :class:`LocalDriver` (``seed``, ``steps``, ``speed``, ``paused``,
    ``checkpoint_dir``, ``keep_checkpoints``); ``out`` is the run directory: checkpoints, the
    metrics log, and knowledge.json, summary.json and a final checkpoint when the last step is
    done (or the run is quit).
    """

    def __init__(self, world: str, *, run_id: str | None = None,
                 listen: Sequence[str] = (), params: dict[str, Any] | None = None,
                 out: Path | str | None = None, **driver: Any) -> None:
        import multiprocessing as mp

        from qlap_runtime.bus.auth import CREDENTIALS_FILE, UI_USER, run_users, write_credentials

        self.run_id = keys.validate_run_id(run_id) if run_id else keys.new_run_id()
        self.endpoint = _free_loopback_endpoint()
        # Authorisation by default (docs/security.md): fresh credentials for this run; the UI
        # connects as `tui`; <out>/bus-credentials.json lets other viewers attach.
        self.users = run_users()
        self.client = {"user": UI_USER, "password": self.users[UI_USER]}
        """``client_config`` options of the UI's session (``QlapApp(**client)``)."""
        self.credentials = write_credentials(Path(out) / CREDENTIALS_FILE,
                                             [self.endpoint, *listen], self.users) \
            if out else None
        spec = dict(driver, world=world, run_id=self.run_id,
                    listen=[self.endpoint, *listen], params=params or {},
                    out=str(out) if out else None, users=self.users)
        if "checkpoint_dir" in spec:
            spec["checkpoint_dir"] = str(spec["checkpoint_dir"])
        ctx = mp.get_context("spawn")
        self._ready = ctx.Event()
        self._process = ctx.Process(target=_child_main, args=(json.dumps(spec), self._ready),
                                    name=f"qlap-agent-{self.run_id}", daemon=True)

    def start(self, timeout: float = 60.0) -> DriverProcess:
        """Start the process and wait until it listens (RuntimeError if it dies first)."""
        self._process.start()
        deadline = time.monotonic() + timeout
        while not self._ready.wait(0.1):
            if not self._process.is_alive() or time.monotonic() > deadline:
                self.stop()
                raise RuntimeError(f"the agent process did not start (exit code "
                                   f"{self._process.exitcode})")
        return self

    @property
    def alive(self) -> bool:
        return self._process.is_alive()

    @property
    def exitcode(self) -> int | None:
        return self._process.exitcode

    def stop(self, timeout: float = 10.0) -> None:
        """Ask the agent to quit over the bus, then wait; terminate it if it does not end."""
        if self._process.pid is None:
            return
        if self._process.is_alive():
            try:
                with zenoh.open(_client(self.endpoint, **self.client)) as s:
                    s.put(keys.key(self.run_id, "control"),
                          b'{"command":"quit","args":{},"version":1}')
            except zenoh.ZError:
                pass
            self._process.join(timeout)
        if self._process.is_alive():  # pragma: no cover - a stuck agent
            self._process.terminate()
            self._process.join(5)


def _client(endpoint: str, **auth: Any) -> zenoh.Config:
    from qlap_runtime.bus.config import client_config

    return client_config([endpoint], **auth)
