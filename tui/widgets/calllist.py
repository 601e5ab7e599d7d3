"""Call list panel: the chain from the practised action down to the motor command."""

from __future__ import annotations

from rich.markup import escape
from textual.widgets import Static

from qlap_runtime.bus.schema import CallList

from ._format import label, signed


class CallListPanel(Static):
    """The executor's call list, outermost first, each sub-action indented under its parent."""

    DEFAULT_CSS = """
    CallListPanel { border: round $primary; border-title-color: $accent; height: 1fr;
                    padding: 0 1; }
    """

    def __init__(self, **kw) -> None:
        super().__init__("(empty)", **kw)
        self.border_title = "Call list"
        self.actions: tuple[str, ...] = ()
        self.motor: dict[str, float] = {}
        self.goal = ""

    def update_calllist(self, msg: CallList | None = None, motor: dict[str, float] | None = None,
                        goal: str | None = None) -> None:
        if msg is not None:
            self.actions = msg.actions
        if motor is not None:
            self.motor = motor
        if goal is not None:
            self.goal = goal
        lines = [f"[b]goal[/] {escape(self.goal)}"] if self.goal else []
        for depth, a in enumerate(self.actions):
            lines.append(("  " * (depth - 1) + "└ " if depth else "") + escape(a))
        if not self.actions:
            lines.append("[dim](empty: babbling, holding or idle)[/]")
        if self.motor:
            lines.append("[dim]motor: " + "  ".join(
                f"{escape(label(k))}={signed(v)}"
                for k, v in self.motor.items()) + "[/]")
        self.update("\n".join(lines))
