"""Plans panel: the plans of the selected action, as in Tables 8.2–8.6."""

from __future__ import annotations

from rich.text import Text
from textual import events
from textual.app import ComposeResult
from textual.containers import Vertical
from textual.widgets import DataTable

from qlap_runtime.bus.schema import ActionInfo

from ._format import Col, fit_columns, num

COLUMNS = (Col("dbn", "plan (DBN)", 20, 0), Col("relo", "rel(o)", 6, 1),
           Col("brel", "brel", 4, 2), Col("co", "C_o", 3, 3), Col("h", "H", 4, 4),
           Col("calls", "calls", 5, 5), Col("states", "states", 6, 6))


class PlansPanel(Vertical):
    """Each plan of one action: its DBN in the reference's notation, brel, H, C_o, rel(o)."""

    DEFAULT_CSS = """
    PlansPanel { border: round $primary; border-title-color: $accent; }
    PlansPanel > DataTable { height: 1fr; scrollbar-size-vertical: 1; }
    """

    def __init__(self, **kw) -> None:
        super().__init__(**kw)
        self.border_title = "Plans (select an action)"
        self.action: ActionInfo | None = None
        self._layout: tuple[tuple[str, int], ...] = ()

    def compose(self) -> ComposeResult:
        yield DataTable(cursor_type="none", zebra_stripes=True, id="plans-table")

    def on_resize(self, event: events.Resize) -> None:
        self._render_action(force=False)

    def show(self, action: ActionInfo | None) -> None:
        """Show ``action``'s plans (None: nothing selected)."""
        if action == self.action and self._layout:
            return
        self.action = action
        self._render_action(force=True)

    def _columns(self) -> list[tuple[Col, int]]:
        plans = self.action.plans if self.action else ()
        width = self.content_region.width or self.size.width or 80
        co = max((len(self._co(p.context_o)) for p in plans), default=3)
        cols = tuple(Col(c.key, c.header, max(c.width, co), c.keep) if c.key == "co" else c
                     for c in COLUMNS)
        longest = max((len(p.label) for p in plans), default=40)
        return fit_columns(cols, width - 1, first=longest)

    @staticmethod
    def _co(context: tuple[str, ...]) -> str:
        return "{" + ", ".join(context) + "}"

    def _render_action(self, force: bool) -> None:
        fitted = self._columns()
        layout = tuple((c.key, w) for c, w in fitted)
        if layout == self._layout and not force:
            return
        table = self.query_one(DataTable)
        if layout != self._layout:
            table.clear(columns=True)
            for c, w in fitted:
                table.add_column(c.title(w), key=c.key, width=w)
            self._layout = layout
        else:
            table.clear()
        action = self.action
        if action is None:
            self.border_title = "Plans (select an action)"
            return
        self.border_title = (f"Plans of {action.label}: rel {action.rel:.2f}, "
                             f"{action.calls} calls")
        keys = [k for k, _ in layout]
        for p in action.plans:
            cells = {"dbn": Text(p.label, style="bold" if p.rel_o >= 0.75 else ""),
                     "brel": num(p.brel), "h": f"{p.entropy:.2f}", "co": self._co(p.context_o),
                     "relo": f"{p.rel_o:.2f}", "calls": str(p.calls), "states": str(p.states)}
            table.add_row(*(cells[k] for k in keys), key=str(p.id))
        if not action.plans:
            table.add_row(Text("(no plan: practised through a parent's plan)", style="dim"),
                          *([""] * (len(keys) - 1)))

    def plan_labels(self) -> list[str]:
        return [p.label for p in self.action.plans] if self.action else []
