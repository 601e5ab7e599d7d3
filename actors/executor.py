"""The executor actor: plans, the call list, IAC and babbling (ch. 5–6) -> ``motor(t)``.

It holds the :class:`~qlap_runtime.qlap.agent.Agent` whose learner is a follower: it keeps the
DBN statistics that rel(r, s) needs from the ``qstate`` stream and applies the batch actors'
deltas at step boundaries, but never learns DBNs or landmarks itself. Plan conversion (Algorithm
2 line 15) runs here, right after the deltas are applied, because it reads the executor's own
action and plan statistics (a departure from a separate planner actor, see docs/runtime.md).
Writes checkpoints (with the retention ``ctx.extra["keep_checkpoints"]``), the metrics log,
``knowledge.json`` and ``summary.json`` like the synchronous loop.

It obeys the UI's agent commands on ``control`` — ``goal`` and ``save`` — at a step boundary
(between ``motor(t)`` and ``qstate(t + 1)``), and applies the clock commands the world obeys to
its own :class:`~.common.RunControl`, so that its ``status`` reports pause and speed (docs/
runtime.md, Controls). While no step flows (paused), a side task applies the commands and
publishes the status.
"""

from __future__ import annotations

import logging
import tempfile
import time
from pathlib import Path
from typing import Any

import trio

from qlap_runtime import telemetry
from qlap_runtime.bus import keys
from qlap_runtime.bus.bridge import Publisher, RejectionCounter, TrioSubscriber, declare_alive
from qlap_runtime.bus.replay import ReplayLog
from qlap_runtime.bus.schema import Control, Motor, decode, encode
from qlap_runtime.metrics import METRICS_EVERY, METRICS_FILE, MetricsLog
from qlap_runtime.qlap.agent import Agent
from qlap_runtime.qlap.checkpoint import (
    atomic_write_json,
    load_agent,
    save_agent,
    save_final_checkpoint,
    save_step_checkpoint,
)
from qlap_runtime.runtime.lockstep import batch_kinds
from qlap_runtime.runtime.watchdog import slot_of

from .checkpoint_parts import keep_on_stall
from .common import (
    ControlError,
    Controls,
    DeltaInbox,
    Resume,
    RunContext,
    RunControl,
    RunEnded,
    StepInbox,
    batch_context,
    percept_from_qstate,
    resume_inputs,
    snapshot_due,
    snapshot_stats,
    world_variables,
    write_snapshot,
)
from .rules import qstate_rule

NAME = "executor"
STATUS_EVERY_S = 0.1
"""While no step flows (paused, or waiting), the status goes out this often (the display
cadence's own rate, so that the step in flight when a pause arrived shows at once)."""

log = logging.getLogger("qlap.actors.executor")


async def run(session, ctx: RunContext) -> dict:
    specs, _ = world_variables(ctx.world)
    resume = Resume.of(ctx, NAME)
    agent = load_agent(resume.path) if resume.path is not None \
        else Agent(specs, ctx.params, seed=ctx.seed)
    agent.learner.auto_batches = False
    agent.learner.follower = True
    counter = RejectionCounter(NAME)
    rejected: list[str] = list(resume.state.get("rejected", []))
    snapshot_s: list[float] = []
    t_start = time.perf_counter()
    steps_done = 0
    keep = ctx.extra.get("keep_checkpoints")
    keep = None if keep is None else int(keep)
    metrics = MetricsLog(Path(ctx.out) / METRICS_FILE, agent, start=resume.step + 1,
                         every=int(ctx.extra.get("metrics_every", METRICS_EVERY))) \
        if ctx.out is not None else None
    # The last periodic checkpoint: (agent step, agent commands applied by then, its path).
    last_saved: tuple[int, int, Path | None] = (-1, -1, None)
    with declare_alive(session, ctx.run_id, NAME), \
            TrioSubscriber(session, keys.key(ctx.run_id, "qstate"), counter=counter) as sub, \
            Publisher(session, ctx.run_id, "motor") as pub, \
            ReplayLog(session, ctx.run_id, "motor", ctx.replay_keep) as replay, \
            Publisher(session, ctx.run_id, "batchctx") as ctx_pub, \
            ReplayLog(session, ctx.run_id, "batchctx", ctx.replay_keep) as ctx_replay, \
            Controls(session, ctx, counter) as controls, \
            Display(session, ctx) as display:
        slot = slot_of(ctx, NAME)
        deltas = DeltaInbox(session, ctx, counter, slot, n_vars=len(agent.table))
        commands = Commands(agent, ctx, controls, counter, display, deltas)
        # batchctx(s) of a batch at s + 1 went out before the snapshot at s, so a restarted
        # executor never publishes it again: its snapshot carries the logged ones, served
        # again to a batch actor restarted later from an older snapshot (docs/runtime.md).
        ctx_key = keys.key(ctx.run_id, "batchctx")
        for step, payload in resume.state.get("batchctx", []):
            ctx_replay.append(int(step), decode(ctx_key, payload))
        try:
            inbox = StepInbox(sub, first=resume.step + 1, end=controls, slot=slot,
                              topic="qstate", counter=counter,
                              key=keys.key(ctx.run_id, "qstate"),
                              window=None if ctx.realtime else 1,
                              rule=qstate_rule([v.name for v in agent.table]))
            await resume_inputs(session, ctx, resume, inbox, "qstate", deltas, counter)
            async with trio.open_nursery() as nursery:
                nursery.start_soon(commands.between_steps)
                for t in range(resume.step + 1, ctx.start + ctx.steps):
                    if controls.pending:
                        commands.apply()
                    commands.at_boundary = True
                    try:
                        msg = await inbox.get(t)
                    except RunEnded:
                        break
                    finally:
                        commands.at_boundary = False
                    if msg.rejected:
                        deltas.book.skipped.add(t)
                        rejected.append(f"step {t}: {msg.rejected}")
                        motor = Motor(t, dict(agent.motor))
                    else:
                        # The learner's percept (not the message's): a landmark applied at
                        # this step renumbers its q in place, as in the synchronous loop, so
                        # the decision reads the current values with the new landmarks.
                        # Waited for before observing: a cancel (a stall) leaves the agent at
                        # a step boundary, which keep_on_stall saves.
                        due = await deltas.due_now(t, ctx.realtime)
                        p = agent.learner.observe_percept(percept_from_qstate(msg, agent.table))
                        for d in due:
                            agent.learner.apply_delta(d)
                        motor = Motor(t, dict(agent.decide(p)))
                    if batch_kinds(ctx.params, t + 1) and t + 1 < ctx.start + ctx.steps:
                        # Before motor(t): the batch at t + 1 reads this state (§6.2.1).
                        bc = batch_context(agent, t)
                        ctx_pub.put(bc)
                        ctx_replay.append(t, bc)
                    pub.put(motor)
                    replay.append(t, motor)
                    slot.done(t)
                    steps_done += 1
                    if metrics is not None:
                        metrics.after_step(t + 1, agent)
                    if not msg.rejected:
                        display.publish(agent, deltas, commands.rc)
                        if ctx.out is not None and (t + 1) % ctx.checkpoint_every == 0:
                            last_saved = (agent.step_count, commands.agent_changes,
                                          save_step_checkpoint(agent, Path(ctx.out) /
                                                               "checkpoints", t + 1,
                                                               ctx.world, keep))
                    if snapshot_due(ctx, t):
                        snapshot_s.append(write_snapshot(ctx, NAME, t, deltas,
                                                         lambda d: save_agent(agent, d),
                                                         rejected=rejected,
                                                         batchctx=[
                                                             [s, encode(m).decode()] for s, m
                                                             in ctx_replay.entries()]))
                nursery.cancel_scope.cancel()
            slot.finished()
            commands.apply()
            display.finished = True
            if not commands.rc.message.startswith("run ended"):
                commands.rc.message = f"finished {steps_done} steps"
            display.publish(agent, deltas, commands.rc, force=True)
        except BaseException:                   # cancelled (maybe in a group) by a stall
            keep_on_stall(ctx, agent)           # a stalled run keeps what was learned
            raise
        finally:
            deltas.close()
            if metrics is not None:
                metrics.finish(resume.step + 1 + steps_done, agent)
    wall = time.perf_counter() - t_start
    result = {"rejected": counter.snapshot().total, "waits": deltas.book.waits,
              "wait_s": round(deltas.wait_s, 3), "rejected_observations": len(rejected),
              "rejected_examples": rejected[:20], "wall_s": wall, "steps_done": steps_done,
              **snapshot_stats(snapshot_s, resume)}
    if controls.last_step is not None:
        result["quit_at_step"] = controls.last_step
    if ctx.out is not None:
        out = Path(ctx.out)
        atomic_write_json(out / "knowledge.json", agent.knowledge())
        # final links to the last step-N when nothing changed the agent since (no step, no
        # goal command): the same state, not a copy.
        same = last_saved[2] if last_saved[:2] == (agent.step_count,
                                                   commands.agent_changes) else None
        save_final_checkpoint(agent, out / "checkpoints", ctx.world, same_as=same)
        from qlap_runtime.metrics import summary_of

        summary = summary_of(agent, type("W", (), {"name": ctx.world})(), ctx.seed,
                             steps_done if controls.last_step is not None else ctx.steps,
                             wall, rejected)
        atomic_write_json(out / "actors" / f"{NAME}.json", summary)
    return result


class Commands:
    """The UI's commands as the executor obeys them (the semantics of ``tui/driver.py``).

    ``goal`` and ``save`` change or read the agent, so they are applied only at a step
    boundary: by the step loop before it waits for the next ``qstate``, or by
    :meth:`between_steps` while the loop is parked in that wait (``at_boundary``), which is
    what a paused run needs. A status goes out at once after a command.
    """

    def __init__(self, agent: Agent, ctx: RunContext, controls: Controls,
                 counter: RejectionCounter, display: Display, deltas: DeltaInbox) -> None:
        self.agent, self.ctx, self.controls, self.counter = agent, ctx, controls, counter
        self.display, self.deltas = display, deltas
        hz = float(ctx.extra.get("hz", 100.0)) if ctx.realtime else 0.0
        self.rc = RunControl(speed=hz, default_speed=hz)
        self.at_boundary = False
        self.agent_changes = 0
        """Commands applied that change the agent (goal): a checkpoint taken before one is no
        longer the agent's state."""
        self._tmp_checkpoints: Path | None = None

    def apply(self) -> bool:
        """Apply every pending command; publish a status if there was one."""
        pending = self.controls.take()
        for c in pending:
            try:
                if not self.rc.apply(c):
                    self._agent_command(c)
            except ControlError as e:
                self.counter.reject(self.controls.key, f"{c.command}: {e}")
                self.rc.message = f"{c.command} refused: {e}"
        if pending:
            self.display.publish(self.agent, self.deltas, self.rc, force=True)
        return bool(pending)

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
                self.display.publish(self.agent, self.deltas, self.rc)

    def _agent_command(self, c: Control) -> None:
        a = c.args
        if c.command == "goal":
            self.agent_changes += 1
            self.rc.message = self._goal(a)
        elif c.command == "save":
            path = a.get("path")
            if path is not None and (type(path) is not str or not path):
                raise ControlError(f"path must be a non-empty string, got {path!r}")
            target = self._confined(path) if path else \
                self._checkpoints() / f"step-{max(self.agent.step_count + 1, 0):07d}"
            try:
                save_agent(self.agent, target, self.ctx.world)
                self.rc.message = f"saved {target}"
            except Exception as e:                  # a bad path must not stop the run
                log.warning("save to %s failed: %s", target, e)
                self.rc.message = f"save failed: {type(e).__name__}: {e}"

    def _confined(self, path: str) -> Path:
        """``save``'s path inside the run directory (a relative path is taken from there):
        whoever may put on ``control`` must not write anywhere else (issue 13)."""
        root = (Path(self.ctx.out) if self.ctx.out is not None
                else self._checkpoints()).resolve()
        target = (root / path).resolve()
        if target == root or not target.is_relative_to(root):
            raise ControlError(f"path {path!r} is outside the run directory {root}")
        return target

    def _checkpoints(self) -> Path:
        """``<out>/checkpoints``, or a temporary directory when the run writes no outputs."""
        if self.ctx.out is not None:
            return Path(self.ctx.out) / "checkpoints"
        if self._tmp_checkpoints is None:
            self._tmp_checkpoints = Path(tempfile.mkdtemp(prefix=f"qlap-{self.ctx.run_id}-"))
        return self._tmp_checkpoints

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
    """The display topics the terminal UI reads (docs/tui.md), published with DROP at a bounded
    rate: they only read the agent, so they never change what it does."""

    def __init__(self, session, ctx: RunContext) -> None:
        self.telemetry = telemetry
        self.ctx = ctx
        self.cadence = telemetry.Cadence()
        self.t0 = time.perf_counter()
        self.finished = False
        self.pubs = {topic: Publisher(session, ctx.run_id, topic)
                     for topic in ("iac", "calllist", "status", "stats", "knowledge")}

    def publish(self, agent: Agent, deltas: DeltaInbox, rc: RunControl | None = None,
                force: bool = False) -> None:
        """Publish what is due (everything but the unchanged knowledge with ``force``, e.g.
        after a command); ``rc`` gives the status its pause, speed and last answer."""
        tm, cad, now = self.telemetry, self.cadence, time.perf_counter()
        rc = rc or RunControl()
        if cad.display_due(now) or force:
            for msg in tm.iac_msgs(agent, cad.last_iac_step):
                self.pubs["iac"].put(msg)
                cad.last_iac_step = msg.step
            self.pubs["calllist"].put(tm.call_list_msg(agent))
            status = tm.status_msg(
                agent, steps_per_s=cad.steps_per_s(now, agent.step_count),
                paused=rc.paused and not self.finished, finished=self.finished,
                speed=rc.speed, clock="realtime" if self.ctx.realtime else "lockstep",
                placement=self.ctx.extra.get("placement", "embedded"), world=self.ctx.world,
                seed=self.ctx.seed, wall_s=now - self.t0, message=rc.message)
            self.pubs["status"].put(status)
            if cad.stats_due(now):
                self.pubs["stats"].put(tm.stats_msg(status, actor=NAME))
        sig = tm.knowledge_signature(agent)
        if (cad.knowledge_due(now, agent.step_count, sig)
                or (force and sig != cad.last_signature)) and self.pubs["knowledge"].matched:
            # Built only for someone (a UI, a recorder, the progress bar): ~35 ms when grown.
            cad.last_signature = sig
            self.pubs["knowledge"].put(tm.knowledge_msg(agent))

    def __enter__(self) -> Display:
        return self

    def __exit__(self, *exc: object) -> None:
        for pub in self.pubs.values():
            pub.close()
