"""Plans panel: the plans of the selected action, as in Tables 8.2–8.6."""

from __future__ import annotations

from rich.text import Text
from textual.app import ComposeResult
from textual.containers import Vertical
from textual.widgets import DataTable

from qlap_runtime.bus.schema import ActionInfo

from ._format import num


class PlansPanel(Vertical):
    """Each plan of one action: its DBN in the reference's notation, brel, H, C_o, rel(o)."""

    DEFAULT_CSS = """
    PlansPanel { border: round $primary; border-title-color: $accent; }
    PlansPanel > DataTable { height: 1fr; }
    """

    def __init__(self, **kw) -> None:
        super().__init__(**kw)
        self.border_title = "Plans"
        self.action: ActionInfo | None = None

    def compose(self) -> ComposeResult:
        table: DataTable = DataTable(cursor_type="none", zebra_stripes=True, id="plans-table")
        for key, label in (("dbn", "plan (DBN)"), ("brel", "brel"), ("h", "H"),
                           ("co", "C_o"), ("relo", "rel(o)"), ("calls", "calls"),
                           ("states", "states")):
            table.add_column(label, key=key)
        yield table

    def show(self, action: ActionInfo | None) -> None:
        """Show ``action``'s plans (None: nothing selected)."""
        if action == self.action:
            return
        self.action = action
        table = self.query_one(DataTable)
        table.clear()
        if action is None:
            self.border_title = "Plans (select an action)"
            return
        self.border_title = (f"Plans of {action.label}: rel {action.rel:.2f}, "
                             f"{action.calls} calls")
        for p in action.plans:
            table.add_row(Text(p.label, style="bold" if p.rel_o >= 0.75 else ""), num(p.brel),
                          f"{p.entropy:.2f}", "{" + ", ".join(p.context_o) + "}",
                          f"{p.rel_o:.2f}", str(p.calls), str(p.states), key=str(p.id))
        if not action.plans:
            table.add_row(Text("(no plan: practised through a parent's plan)", style="dim"),
                          "", "", "", "", "", "")

    def plan_labels(self) -> list[str]:
        return [p.label for p in self.action.plans] if self.action else []
