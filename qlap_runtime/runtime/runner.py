"""One runner contract: how whatever runs an agent obeys the UI's controls and feeds its display.

The executor actor and the terminal UI's local runner (``tui/driver.py``) both hold an agent;
both obey ``control`` with the same semantics (docs/runtime.md, Controls) and publish the same
display topics (docs/tui.md), through the two classes here:

- :class:`Runner` applies a control stream: the clock commands (``pause``, ``resume``,
  ``step``, ``speed``, ``quit``) to a :class:`~.controls.RunControl`, the agent commands
  (``goal``, ``save``) to the agent; a command with malformed arguments is refused, counted and
  answered, never a crash. Its :attr:`Runner.message` is the status's answer.
- :class:`Display` publishes ``iac``, ``calllist``, ``status``, ``stats`` and ``knowledge``
  with DROP at a bounded rate (:class:`~qlap_runtime.telemetry.Cadence`): it only reads the
  agent, so it never changes what the agent does.

Where the commands come from differs (a trio task in the actors, a thread in the local runner);
what they do does not.
"""

from __future__ import annotations

import logging
import tempfile
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import trio

from .. import telemetry
from ..bus.bridge import Publisher, RejectionCounter
from ..bus.schema import Control
from ..qlap.checkpoint import save_agent_checkpoint
from .controls import ControlError, RunControl

log = logging.getLogger("qlap.runner")

DISPLAY_TOPICS = ("iac", "calllist", "status", "stats", "knowledge")
CLOCK_COMMANDS = ("pause", "resume", "step")


class Runner:
    """Applies controls to a run's clock state and its agent (see the module docstring).

    ``out`` is the run directory: ``save`` without a path writes
    ``<checkpoints>/step-NNNNNNN`` (``checkpoints``: default ``<out>/checkpoints``, a temporary
    directory when the run has neither), and a ``save`` path is taken relative to the run
    directory and refused if it resolves outside it: whoever may put on ``control`` must not
    write anywhere else.
    """

    def __init__(self, agent: Any, world_spec: str | None, *,
                 clock: RunControl | None = None,
                 out: Path | None = None, checkpoints: Path | None = None,
                 counter: RejectionCounter | None = None, key: str = "control",
                 run_id: str = "run", world_state: Callable[[], Any] | None = None) -> None:
        self.agent = agent
        self.world_state = world_state
        """The world's state now (``World.get_state``), for ``save`` — a runner that steps the
        world itself gives it, so that its saves resume exactly as the periodic checkpoints
        do (``world.json``); None: a save holds the agent alone."""
        self.world_spec = world_spec
        self.clock = clock if clock is not None else RunControl()
        self.out = None if out is None else Path(out)
        self._checkpoints = Path(checkpoints) if checkpoints is not None else (
            self.out / "checkpoints" if self.out is not None else None)
        self.counter = counter if counter is not None else RejectionCounter("runner")
        self.key = key
        self.run_id = run_id
        self.agent_changes = 0
        """Commands applied that change the agent (goal): a checkpoint taken before one is no
        longer the agent's state."""
        self.finished = False
        """The last step is done: the clock commands are answered and ignored."""

    @property
    def message(self) -> str:
        """The answer to the last command (``AgentStatus.message``)."""
        return self.clock.message

    @message.setter
    def message(self, text: str) -> None:
        self.clock.message = text

    def apply(self, commands: Iterable[Control]) -> bool:
        """Apply ``commands`` in order; True if there was any."""
        any_ = False
        for c in commands:
            any_ = True
            try:
                if self.finished and c.command in CLOCK_COMMANDS:
                    self.message = (f"finished at step {self.agent.step_count + 1}: "
                                    f"{c.command} ignored")
                elif not self.clock.apply(c):
                    self._agent_command(c)
            except ControlError as e:
                self.counter.reject(self.key, f"{c.command}: {e}")
                self.message = f"{c.command} refused: {e}"
        return any_

    @property
    def checkpoints(self) -> Path:
        """Where ``save`` writes by default (a temporary directory when the run has none)."""
        if self._checkpoints is None:
            self._checkpoints = Path(tempfile.mkdtemp(prefix=f"qlap-{self.run_id}-"))
        return self._checkpoints

    def _agent_command(self, c: Control) -> None:
        a = c.args
        if c.command == "goal":
            self.agent_changes += 1
            self.message = self._goal(a)
        elif c.command == "save":
            path = a.get("path")
            if path is not None and (type(path) is not str or not path):
                raise ControlError(f"path must be a non-empty string, got {path!r}")
            target = self._confined(path) if path else \
                self.checkpoints / f"step-{max(self.agent.step_count + 1, 0):07d}"
            try:
                save_agent_checkpoint(self.agent, target, self.world_spec,
                                None if self.world_state is None else self.world_state())
                self.message = f"saved {target}"
            except Exception as e:                  # a bad path must not stop the run
                log.warning("save to %s failed: %s", target, e)
                self.message = f"save failed: {type(e).__name__}: {e}"

    def _confined(self, path: str) -> Path:
        root = (self.out if self.out is not None else self.checkpoints).resolve()
        try:
            target = (root / path).resolve()
        except (OSError, ValueError) as e:              # e.g. an embedded NUL byte
            raise ControlError(f"path {path!r}: {e}") from None
        if target == root or not target.is_relative_to(root):
            raise ControlError(f"path {path!r} is outside the run directory {root}")
        return target

    def _goal(self, a: dict[str, Any]) -> str:
        agent = self.agent
        var = a.get("var")
        if a.get("clear") or var in (None, ""):
            agent.clear_goal()
            return "goal cleared"
        if type(var) is not str:
            raise ControlError(f"var must be a variable name, got {var!r}")
        try:
            key = telemetry.goal_key(agent, var, a.get("value"))
            agent.set_goal(*key)
        except (ValueError, KeyError, TypeError, IndexError) as e:
            return f"goal refused: {e}"
        return f"goal {telemetry.pretty(agent.action_label(key))}"


class Display:
    """The display topics of one agent (see the module docstring).

    ``world_view`` (the local runner, which owns the world) adds the ``world`` topic; in the
    actor placements the world actor publishes it. ``only_for_subscribers``: the knowledge
    snapshot (~35 ms when grown) is built only when someone listens.
    """

    def __init__(self, session: Any, run_id: str, *, placement: str, world: str, seed: int,
                 actor: str = "agent", world_view: Callable[[], Any] | None = None,
                 cadence: telemetry.Cadence | None = None) -> None:
        self.placement, self.world, self.seed, self.actor = placement, world, seed, actor
        self.world_view = world_view
        self.cadence = cadence or telemetry.Cadence()
        self.t0 = time.perf_counter()
        self.finished_at: float | None = None
        self.first: tuple[float, int] | None = None
        """(time, agent step) of the first status: a finished run's rate is its mean since."""
        self.dropped_seen: tuple[int, str] | None = None
        """The agent's last dropped goal already told (its status message says it once)."""
        topics = DISPLAY_TOPICS + (("world",) if world_view is not None else ())
        self.pubs = {topic: Publisher(session, run_id, topic) for topic in topics}

    def finish(self) -> None:
        """The last step is done: the status says so and its wall clock stops."""
        if self.finished_at is None:
            self.finished_at = time.perf_counter()

    def status(self, agent: Any, clock: RunControl, *, clock_name: str, now: float,
               late_ticks: int = 0, missed_ticks: int = 0) -> Any:
        finished = self.finished_at is not None
        dropped = agent.goal_dropped
        if dropped is not None and dropped != self.dropped_seen:
            self.dropped_seen = dropped         # a landmark split the goal's value
            clock.message = dropped[1]
        if self.first is None:
            self.first = (now, agent.step_count)
        rate = self.cadence.steps_per_s(now, agent.step_count)
        if finished:                            # no steps in the last second: say the mean
            t, step = self.first
            rate = (agent.step_count - step) / (self.finished_at - t) \
                if self.finished_at > t else 0.0
        return telemetry.status_msg(
            agent, steps_per_s=rate,
            paused=clock.paused and not finished, finished=finished, speed=clock.speed,
            clock=clock_name, placement=self.placement, world=self.world, seed=self.seed,
            late_ticks=late_ticks, missed_ticks=missed_ticks,
            wall_s=(self.finished_at if finished else now) - self.t0, message=clock.message)

    def publish(self, agent: Any, clock: RunControl, *, clock_name: str, force: bool = False,
                **ticks: int) -> None:
        """Publish what is due (everything but the unchanged knowledge with ``force``, e.g.
        after a command); ``clock`` gives the status its pause, speed and last answer."""
        cad, now, pubs = self.cadence, time.perf_counter(), self.pubs
        if cad.display_due(now) or force:
            for msg in telemetry.iac_msgs(agent, cad.last_iac_step):
                pubs["iac"].put(msg)
                cad.last_iac_step = msg.step
            pubs["calllist"].put(telemetry.call_list_msg(agent))
            if self.world_view is not None:
                pubs["world"].put(self.world_view())
            status = self.status(agent, clock, clock_name=clock_name, now=now, **ticks)
            pubs["status"].put(status)
            if cad.stats_due(now):
                pubs["stats"].put(telemetry.stats_msg(status, actor=self.actor))
        if not force and now - cad.last_knowledge < cad.knowledge_min_s:
            return                  # most steps: no knowledge snapshot is due, skip its signature
        sig = telemetry.knowledge_signature(agent)
        if (cad.knowledge_due(now, agent.step_count, sig)
                or (force and sig != cad.last_signature)) and pubs["knowledge"].matched:
            cad.last_signature = sig
            pubs["knowledge"].put(telemetry.knowledge_msg(agent))

    def close(self) -> None:
        for pub in self.pubs.values():
            pub.close()
        self.pubs = {}

    def __enter__(self) -> Display:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


STATUS_EVERY_S = 0.1
"""While no step flows (paused, or waiting), the status goes out this often (the display
cadence's own rate, so that the step in flight when a pause arrived shows at once)."""


class BoundaryCommands:
    """The runner contract on an actor's trio loop: the commands of ``controls`` applied by
    ``runner`` only at a step boundary — by the step loop (:meth:`apply`) before it waits for
    its next input, or by :meth:`between_steps` while the loop is parked in that wait
    (:meth:`waiting`), which is what a paused run needs. ``publish(force)`` sends the status:
    at once after a command, and every ``STATUS_EVERY_S`` while no step flows."""

    def __init__(self, controls: Any, runner: Runner,
                 publish: Callable[[bool], None]) -> None:
        self.controls, self.runner, self.publish = controls, runner, publish
        self.at_boundary = False

    def apply(self) -> bool:
        """Apply every pending command; publish a status if there was one."""
        if self.runner.apply(self.controls.take()):
            self.publish(True)
            return True
        return False

    @contextmanager
    def waiting(self) -> Iterator[None]:
        """The step loop waits for its next input: commands may be applied meanwhile."""
        self.at_boundary = True
        try:
            yield
        finally:
            self.at_boundary = False

    async def between_steps(self) -> None:
        """While the step loop waits: apply commands as they come, and keep the status (and
        the knowledge snapshot, for late viewers) going out when no step flows."""
        while True:
            with trio.move_on_after(STATUS_EVERY_S):
                await self.controls.wait()
            if not self.at_boundary:
                await trio.sleep(0.05)      # mid-step: the loop applies them at its boundary
                continue
            if not self.apply():
                self.publish(False)
