"""World panel: a top-down text drawing and the raw values of the variables."""

from __future__ import annotations

from rich.markup import escape
from textual.app import ComposeResult
from textual.containers import VerticalScroll
from textual.widgets import Static

from qlap_runtime.bus.schema import WorldView


class WorldPanel(VerticalScroll):
    """The world's ``render_text`` drawing, then each variable: raw value and percept."""

    DEFAULT_CSS = """
    WorldPanel { border: round $primary; border-title-color: $accent; padding: 0 1; }
    WorldPanel > #world-drawing { color: $success; }
    """

    def __init__(self, **kw) -> None:
        super().__init__(**kw)
        self.border_title = "World"
        self.view: WorldView | None = None

    def compose(self) -> ComposeResult:
        yield Static("(waiting for the world)", id="world-drawing")
        yield Static("", id="world-values")

    def update_world(self, w: WorldView) -> None:
        self.view = w
        self.border_title = f"World {w.world} (step {w.step})"
        self.query_one("#world-drawing", Static).update(escape(w.text))
        lines = []
        for name, v in {**w.motor, **w.values}.items():
            q = w.qualitative.get(name, "")
            lines.append(f"{name:>7} {v:>9.3f}  [dim]{escape(q)}[/]")
        self.query_one("#world-values", Static).update("\n".join(lines))
