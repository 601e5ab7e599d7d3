"""The metrics log of a run (``RUN_DIR/metrics.jsonl``) and the plain progress lines.

Every placement writes the same log as the agent learns: the synchronous loop
(:func:`~qlap_runtime.agent_run.run_agent`), the executor actor (embedded and processes) and
the terminal UI's local driver. Each builds its lines with :func:`metrics_line` through a
:class:`MetricsLog`, one JSON object per line every 1,000 steps (schema: docs/outputs.md).

A line is appended with one ``write`` of the whole line to a file opened with ``O_APPEND``; a
crash can still leave a torn last line, which :func:`read_metrics` skips and which the next
writer of the same log cuts off before appending. A writer that starts from a step s (a resumed
run, an executor restarted from a snapshot) first drops the lines after s: the log always
describes one history of the agent.

:class:`PlainProgress` prints a progress line every 10 % or 30 s when stdout is not a terminal
(fed with metrics lines: same counts as the log and the summary), and a final line built from
the summary, so that the two agree.
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from .qlap.checkpoint import atomic_write_bytes

if TYPE_CHECKING:
    from .qlap.agent import Agent

METRICS_FILE = "metrics.jsonl"
METRICS_EVERY = 1000
"""Steps between two lines of the metrics log."""
IAC_TOP = 5
"""Actions listed in a line's ``iac_top`` (the most chosen since the previous line)."""

LineFn = Callable[[dict[str, Any]], None]


def knowledge_counts(agent: Any) -> dict[str, int]:
    """What the agent knows, counted as summary.json counts it (docs/outputs.md): DBNs by kind,
    plans, landmarks of the motor and magnitude variables (the initial ones included),
    sufficiently reliable actions on non-motor variables, and the window k."""
    learner = agent.learner
    change = sum(1 for d in learner.dbns.values() if d.kind == "change")
    spaces = learner.perception.spaces
    landmarks = sum(len(spaces[v.index].landmarks) for v in agent.table
                    if v.kind.value in ("motor", "magnitude"))
    reliable = sum(1 for key, st in agent.actions.items()
                   if st.reliable and agent.table[key[0]].kind.value != "motor")
    return {"k": int(learner.k), "dbns": len(learner.dbns), "change_dbns": change,
            "magnitude_dbns": len(learner.dbns) - change,
            "reliable_dbns": sum(1 for d in learner.dbns.values() if d.ever_reliable),
            "plans": len(agent.plans), "landmarks": landmarks, "reliable_actions": reliable}


def metrics_line(agent: Any, step: int, *, wall_s: float, steps_per_s: float | None,
                 since_step: int, since_counters: tuple[int, int]) -> dict[str, Any]:
    """One line of the metrics log: the agent after it has observed ``step`` steps.

    ``since_step`` (steps observed at the previous line) and ``since_counters`` (practice
    calls and babble commands then) delimit the IAC choices reported: ``iac_choices``
    (actions chosen to practise), ``iac_babbles`` (babbling commands chosen instead) and
    ``iac_top``: the most chosen actions ``[label, times, mean w_a]`` among the choices the
    agent's log still holds (its last 200).
    """
    c = agent.counters
    line: dict[str, Any] = {"step": int(step), "wall_s": round(wall_s, 3),
                            "steps_per_s": None if steps_per_s is None
                            else round(steps_per_s, 1)}
    line.update(knowledge_counts(agent))
    times: Counter = Counter()
    weights: dict[Any, float] = {}
    for ch in agent.iac_log:
        # an IACChoice's step is the agent step t; ``step`` counts steps observed (t + 1)
        if since_step <= ch.step < step and ch.action is not None:
            times[ch.action] += 1
            weights[ch.action] = weights.get(ch.action, 0.0) + ch.weight
    line.update({
        "practice_calls": c.practice_calls, "practice_successes": c.successes,
        "practice_failures": c.failures, "babble_commands": c.babble_commands,
        "iac_choices": c.practice_calls - since_counters[0],
        "iac_babbles": c.babble_commands - since_counters[1],
        "iac_top": [[agent.action_label(key), n, round(weights[key] / n, 4)]
                    for key, n in sorted(times.items(), key=lambda kv: (-kv[1], kv[0]))
                    [:IAC_TOP]],
    })
    return line


def read_metrics(path: str | Path) -> list[dict[str, Any]]:
    """The lines of a metrics log (none if it does not exist); a torn or unreadable line (a
    crash while appending) is skipped."""
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        return []
    out = []
    for raw in data.split(b"\n"):
        if not raw.strip():
            continue
        try:
            line = json.loads(raw)
        except ValueError:
            continue
        if isinstance(line, dict) and isinstance(line.get("step"), int):
            out.append(line)
    return out


class MetricsLog:
    """Writes a run's metrics log: :meth:`after_step` every step, a line every ``every``.

    Args:
        path: the log (``RUN_DIR/metrics.jsonl``); None builds the lines (for ``on_line``)
            without writing them.
        agent: the agent, as it is when the run starts.
        start: steps the agent has observed when the run starts (0 for a fresh agent);
            lines after it already in the log are dropped (a resumed or restarted run
            writes them again).
        every: steps between two lines.
        on_line: called with every line written (e.g. :class:`PlainProgress`).
    """

    def __init__(self, path: str | Path | None, agent: Any, start: int = 0,
                 every: int = METRICS_EVERY, on_line: LineFn | None = None) -> None:
        self.path = None if path is None else Path(path)
        self.every = max(1, int(every))
        self.on_line = on_line
        self.last_step = int(start)
        self._t0 = time.perf_counter()
        self._wall0 = 0.0
        self._last_t = self._t0
        self._since = (agent.counters.practice_calls, agent.counters.babble_commands)
        self._fd: int | None = None
        if self.path is not None:
            kept = [line for line in read_metrics(self.path) if line["step"] <= start]
            if kept:
                self._wall0 = float(kept[-1].get("wall_s") or 0.0)
            atomic_write_bytes(self.path, b"".join(_encode(line) for line in kept))
            self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND)

    def after_step(self, step: int, agent: Any) -> dict[str, Any] | None:
        """Call after each step with the steps observed (t + 1); writes a line when due."""
        if step % self.every == 0 and step > self.last_step:
            return self.write(step, agent)
        return None

    def finish(self, step: int, agent: Any) -> dict[str, Any] | None:
        """At the end of the run: a last line unless one was written at ``step``."""
        line = self.write(step, agent) if step > self.last_step else None
        self.close()
        return line

    def write(self, step: int, agent: Any) -> dict[str, Any]:
        now = time.perf_counter()
        span = now - self._last_t
        line = metrics_line(agent, step, wall_s=self._wall0 + now - self._t0,
                            steps_per_s=(step - self.last_step) / span if span > 0 else None,
                            since_step=self.last_step, since_counters=self._since)
        if self._fd is not None:
            os.write(self._fd, _encode(line))   # one write of the whole line (O_APPEND)
        self.last_step, self._last_t = step, now
        self._since = (agent.counters.practice_calls, agent.counters.babble_commands)
        if self.on_line is not None:
            self.on_line(line)
        return line

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def __del__(self) -> None:  # pragma: no cover - closed explicitly
        self.close()


def _encode(line: dict[str, Any]) -> bytes:
    return (json.dumps(line, separators=(",", ":"), ensure_ascii=False) + "\n").encode()


# ---------------------------------------------------------------------------------------------
# Plain progress lines (stdout not a terminal)
# ---------------------------------------------------------------------------------------------
def _duration(seconds: float) -> str:
    seconds = max(0, round(seconds))
    h, rest = divmod(seconds, 3600)
    m, s = divmod(rest, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


class PlainProgress:
    """Progress as plain lines (for logs and pipes): one every ``fraction`` of the run or
    ``seconds``, whichever comes first, fed with metrics lines; :meth:`final` prints the last
    one from the run's summary."""

    def __init__(self, total: int, start: int = 0, stream: TextIO | None = None,
                 fraction: float = 0.1, seconds: float = 30.0) -> None:
        self.total, self.start = int(total), int(start)
        self.stream = stream
        self.fraction, self.seconds = fraction, seconds
        self._t0 = time.perf_counter()
        self._last_t = self._t0
        self._last_done = 0
        self._lock = threading.Lock()
        self.closed = False
        """The reader of the stream left (a closed pipe): nothing more is printed."""

    def _print(self, text: str) -> None:
        """Print a line; a reader that left (``qlap run … | head``) ends the printing, not
        the run: the rest of the progress goes to /dev/null."""
        if self.closed:
            return
        self.closed = not print_to(self.stream if self.stream is not None else sys.stdout, text)

    def __call__(self, line: dict[str, Any]) -> None:
        with self._lock:
            done = int(line["step"]) - self.start
            now = time.perf_counter()
            step_due = done >= self._last_done + self.fraction * self.total
            if done >= self.total or not (step_due or now - self._last_t >= self.seconds):
                return                       # the last line comes from the summary
            self._last_done, self._last_t = done, now
            rate = done / (now - self._t0) if now > self._t0 else 0.0
            eta = (self.total - done) / rate if rate > 0 else float("nan")
            self._print(self.format(done, rate, line, f"ETA {_duration(eta)}"
                                    if eta == eta else ""))

    def format(self, done: int, rate: float, counts: dict[str, Any], tail: str) -> str:
        pct = 100.0 * done / self.total if self.total else 100.0
        return (f"step {done:,}/{self.total:,} ({pct:.0f}%)  {rate:,.1f} steps/s  "
                f"DBNs {counts.get('dbns')}  plans {counts.get('plans')}  "
                f"landmarks {counts.get('landmarks')}  {tail}").rstrip()

    def final(self, summary: dict[str, Any]) -> None:
        """The last line, from the summary's own figures (they agree by construction)."""
        with self._lock:
            rate = float(summary.get("steps_per_s") or 0.0)
            wall = float(summary.get("wall_time_s") or 0.0)
            self._print(self.format(int(summary.get("steps", self.total)), rate, summary,
                                    f"done in {_duration(wall)}"))


def print_to(stream: TextIO, *values: object) -> bool:
    """``print`` flushed to ``stream``; False when its reader has left (``qlap run … | head``):
    the stream is silenced, so that what follows goes on without it."""
    try:
        print(*values, file=stream, flush=True)
        return True
    except BrokenPipeError:
        silence_stream(stream)
        return False


def silence_stream(stream: TextIO) -> None:
    """Point a closed pipe's file descriptor at /dev/null, so that later writes and the
    interpreter's flush at exit do not fail on it again (the Python docs' "Note on SIGPIPE")."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, stream.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):   # no file descriptor (a captured stream)
        pass


def follow_metrics(path: str | Path, on_line: LineFn, stop: threading.Event,
                   poll_s: float = 0.5) -> threading.Thread:
    """A daemon thread that reads the lines appended to a metrics log (written by another
    task or process, e.g. the executor actor) and hands each new one to ``on_line`` until
    ``stop`` is set. A log rewritten shorter (an executor restarted from a snapshot) is read
    again; lines at or before the last step handed on are not repeated."""
    path = Path(path)

    def run() -> None:
        pos, last, buf = 0, -1, b""
        while True:
            ending = stop.is_set()
            try:
                size = path.stat().st_size
                if size < pos:
                    pos, buf = 0, b""
                if size > pos:
                    with open(path, "rb") as f:
                        f.seek(pos)
                        chunk = f.read(size - pos)
                    pos += len(chunk)
                    buf += chunk
                    *complete, buf = buf.split(b"\n")
                    for raw in complete:
                        try:
                            line = json.loads(raw)
                        except ValueError:
                            continue
                        if isinstance(line, dict) and int(line.get("step", -1)) > last:
                            last = int(line["step"])
                            on_line(line)
            except (OSError, ValueError, TypeError):
                pass
            if ending:
                return
            stop.wait(poll_s)

    thread = threading.Thread(target=run, name="qlap-metrics-follow", daemon=True)
    thread.start()
    return thread


@dataclass
class Rejections:
    """The observations a run rejected (a NaN, an unknown variable): how many, and the first
    :attr:`KEEP` of them as ``step t: why`` — bounded, however many steps are rejected."""

    KEEP = 20
    count: int = 0
    examples: list[str] = field(default_factory=list)

    def add(self, what: str) -> None:
        self.count += 1
        if len(self.examples) < self.KEEP:
            self.examples.append(what)

    def to_state(self) -> dict[str, Any]:
        return {"count": self.count, "examples": list(self.examples)}

    @classmethod
    def from_state(cls, state: Any) -> Rejections:
        """From :meth:`to_state` (or a list of examples, as snapshots held them before)."""
        if isinstance(state, list):
            return cls(len(state), [str(e) for e in state[:cls.KEEP]])
        if not state:
            return cls()
        return cls(int(state["count"]), [str(e) for e in state["examples"][:cls.KEEP]])


def summary_of(agent: Agent, world: Any, seed: int, steps: int, wall: float,
               rejected: Rejections, placement: str = "sync") -> dict[str, Any]:
    """summary.json's figures of a run (docs/outputs.md); the counts are those of the metrics
    log (:func:`~qlap_runtime.metrics.knowledge_counts`), so the two agree. ``placement``:
    ``sync`` (the synchronous loop) or ``local`` (the terminal UI's agent thread)."""
    n = knowledge_counts(agent)
    c = agent.counters
    return {
        "placement": placement,
        "world": getattr(world, "name", type(world).__name__), "seed": seed, "steps": steps,
        "wall_time_s": round(wall, 3), "steps_per_s": round(steps / wall, 1) if wall else None,
        "k": n["k"], "dbns": n["dbns"], "change_dbns": n["change_dbns"],
        "magnitude_dbns": n["magnitude_dbns"], "reliable_dbns": n["reliable_dbns"],
        "plans": n["plans"], "landmarks": n["landmarks"],
        "reliable_actions": n["reliable_actions"],
        "practice_calls": c.practice_calls, "babble_commands": c.babble_commands,
        "practice_successes": c.successes, "practice_failures": c.failures,
        "plans_created": c.plans_created, "plans_removed": c.plans_removed,
        "rejected_observations": rejected.count, "rejected_examples": list(rejected.examples),
    }
