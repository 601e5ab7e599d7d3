"""Runtime panel: step, steps/s, clock, placement, actors alive, ticks, pending deltas."""

from __future__ import annotations

from rich.markup import escape
from textual.widgets import Static

from qlap_runtime.bus.schema import AgentStatus, Stats

from ._format import steps_done


class RuntimePanel(Static):
    """The running agent's status and the actors alive (liveliness tokens)."""

    DEFAULT_CSS = """
    RuntimePanel { border: round $primary; border-title-color: $accent; padding: 0 1; }
    """

    def __init__(self, **kw) -> None:
        super().__init__("(waiting for the agent)", **kw)
        self.border_title = "Runtime"
        self.status: AgentStatus | None = None
        self.alive: set[str] = set()
        self.stats: dict[str, Stats] = {}
        self.run_id = ""
        self.connection = ""

    def show(self, status: AgentStatus | None = None, alive: set[str] | None = None,
             stats: dict[str, Stats] | None = None) -> None:
        if status is not None:
            self.status = status
        if alive is not None:
            self.alive = set(alive)
        if stats is not None:
            self.stats = stats
        s = self.status
        if s is None:
            self.update(f"run {self.run_id or '?'} via {self.connection}\n(waiting for the agent)")
            return
        speed = f"{s.speed:g}/s" if s.speed > 0 else "free"
        late = sum(x.late_ticks for x in self.stats.values()) or s.late_ticks
        missed = sum(x.missed_ticks for x in self.stats.values()) or s.missed_ticks
        rejected = sum(x.rejected.total for x in self.stats.values())
        lines = [
            f"{state_markup(s)}  step [b]{steps_done(s.step)}[/]  {s.steps_per_s:,.0f} steps/s",
            f"mode {s.mode}  goal {escape(s.goal) if s.goal else '—'}"
            f"{'' if s.learning else '  (learning off)'}",
            f"clock {s.clock} ({speed})  placement {s.placement}",
            f"world {s.world}  seed {s.seed}  run {self.run_id}",
            f"actors alive: {', '.join(sorted(self.alive)) or '—'}",
            f"late ticks {late}  missed {missed}  pending deltas {s.pending_deltas}"
            f"{f'  rejected {rejected}' if rejected else ''}",
            f"wall {s.wall_s:,.0f} s  via {self.connection}",
        ]
        if s.message:
            lines.append(f"[i]{escape(s.message)}[/]")
        self.update("\n".join(lines))


def state_word(s: AgentStatus) -> str:
    """FINISHED (the last step is done; nothing pauses or steps it), PAUSED or RUNNING."""
    return "FINISHED" if s.finished else "PAUSED" if s.paused else "RUNNING"


def state_markup(s: AgentStatus) -> str:
    word = state_word(s)
    colour = {"FINISHED": "yellow", "PAUSED": "red", "RUNNING": "green"}[word]
    return f"[b {colour}]{word}[/]"
