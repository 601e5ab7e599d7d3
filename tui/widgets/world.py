"""World panel: a top-down text drawing and the variables, raw and qualitative, of one step."""

from __future__ import annotations

from rich.text import Text
from textual import events
from textual.app import ComposeResult
from textual.containers import VerticalScroll
from textual.geometry import Size
from textual.widget import Widget
from textual.widgets import Static

from qlap_runtime.bus.schema import WorldView

from ._format import ARROWS, clip, label, real, steps_done

SIDE_BY_SIDE = 44 + 2 + 28
"""Content width from which the values go beside the drawing instead of below it."""


class WorldValues(Widget):
    """The variables' rows, cut (never wrapped) to the widget's width."""

    DEFAULT_CSS = """
    WorldValues { width: 1fr; height: auto; }
    """

    def __init__(self, panel: WorldPanel, **kw) -> None:
        super().__init__(**kw)
        self.panel = panel

    def render(self) -> Text:
        rows = self.panel.rows(self.content_region.width or 40)
        return Text("\n", no_wrap=True, overflow="ellipsis").join(rows)

    def get_content_height(self, container: Size, viewport: Size, width: int) -> int:
        return len(self.panel.rows(width))


class WorldPanel(VerticalScroll):
    """The world's ``render_text`` drawing, then each variable: raw value, direction of change
    and qualitative value, all of the same step (motor rows: the command that led to it)."""

    DEFAULT_CSS = """
    WorldPanel { border: round $primary; border-title-color: $accent; padding: 0 1;
                 scrollbar-size-vertical: 1; }
    WorldPanel.-side { layout: horizontal; }
    WorldPanel > #world-drawing { width: auto; height: auto; color: $success; margin-right: 2;
                                  text-wrap: nowrap; text-overflow: clip; }
    """

    def __init__(self, **kw) -> None:
        super().__init__(**kw)
        self.border_title = "World"
        self.view: WorldView | None = None

    def compose(self) -> ComposeResult:
        yield Static("(waiting for the world)", id="world-drawing")
        yield WorldValues(self, id="world-values")

    def on_resize(self, event: events.Resize) -> None:
        side = self.content_region.width >= SIDE_BY_SIDE
        if side != self.has_class("-side"):
            self.set_class(side, "-side")

    def rows(self, width: int = 60) -> list[Text]:
        """One line per motor and magnitude (or nominal) variable: name, raw value, ↑/·/↓ of
        its direction of change, qualitative value."""
        w = self.view
        if w is None:
            return []
        names = [*w.motor, *(n for n in w.values if n not in w.motor)]
        nw = max((len(label(n)) for n in names), default=3)
        out = []
        for name in names:
            v = w.motor[name] if name in w.motor else w.values[name]
            q = label(w.qualitative.get(name, ""))
            arrow = ARROWS.get(w.qualitative.get(f"{name}.dot", ""), " ")
            row = Text(no_wrap=True, overflow="ellipsis")
            row.append(f"{label(name):>{nw}} ", style="bold yellow" if name in w.motor else "")
            row.append(f"{real(v):>9} ")
            row.append(arrow, style="cyan")
            row.append(" " + clip(q, max(width - nw - 13, 4)), style="dim")
            out.append(row)
        return out

    def update_world(self, w: WorldView) -> None:
        self.view = w
        self.border_title = f"World {w.world} · step {steps_done(w.step)}"
        self.query_one("#world-drawing", Static).update(Text(w.text, no_wrap=True,
                                                             overflow="crop"))
        self.query_one(WorldValues).refresh(layout=True)
