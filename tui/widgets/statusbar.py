"""The one-line status bar at the top, and the view tabs of the compact layout."""

from __future__ import annotations

from collections.abc import Sequence

from rich.markup import escape
from textual.widgets import Static

from qlap_runtime.bus.schema import AgentStatus

from ._format import steps_done
from .runtime import state_markup


class StatusBar(Static):
    """QLAP, the run's state, step, rate, mode, goal and the answer to the last command."""

    DEFAULT_CSS = """
    StatusBar { height: 1; background: $panel; padding: 0 1; text-wrap: nowrap;
                text-overflow: ellipsis; }
    """

    def __init__(self, **kw) -> None:
        super().__init__("[b]QLAP[/]  waiting for the agent…", **kw)
        self.run_id = ""

    def show(self, s: AgentStatus | None) -> None:
        if s is None:
            self.update(f"[b]QLAP[/]  run {escape(self.run_id or '?')}  waiting for the agent…")
            return
        parts = [f"[b]QLAP[/] {state_markup(s)}  step [b]{steps_done(s.step)}[/]",
                 f"{s.steps_per_s:,.0f} steps/s", s.mode,
                 f"goal {escape(s.goal)}" if s.goal else "",
                 f"{escape(s.world)} seed {s.seed}", f"{s.wall_s:,.0f} s",
                 f"[i]{escape(s.message)}[/]" if s.message else ""]
        self.update("  ".join(p for p in parts if p))


class ViewTabs(Static):
    """Compact layout: which panel shows below the actions (``v`` or a digit switches; the
    names are clickable)."""

    DEFAULT_CSS = """
    ViewTabs { height: 1; background: $boost; text-wrap: nowrap; text-overflow: ellipsis; }
    """

    def __init__(self, views: Sequence[tuple[str, str]], **kw) -> None:
        super().__init__("", **kw)
        self.views = list(views)
        self.current = self.views[0][0]

    def on_mount(self) -> None:
        self.show(self.current)

    def show(self, current: str) -> None:
        self.current = current
        parts = []
        for i, (key, name) in enumerate(self.views, 1):
            style = "b reverse" if key == current else "dim"
            parts.append(f"[@click=app.view('{key}')][{style}] {i} {name} [/][/]")
        self.update("[b]v[/]iew " + "".join(parts))
