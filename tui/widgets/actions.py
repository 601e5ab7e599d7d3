"""Actions panel: every action a(v, q) with a plan or calls, sortable, the practised one marked."""

from __future__ import annotations

from typing import ClassVar

from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import Vertical
from textual.message import Message
from textual.widgets import DataTable

from qlap_runtime.bus.schema import ActionInfo, Knowledge

from ._format import num, sparkline

COLUMNS = (("action", "action"), ("rel", "rel(a)"), ("plans", "plans"), ("calls", "calls"),
           ("w", "w_a"), ("hist", "rel(a) over time"))
SORTS = ("action", "rel", "plans", "calls", "w")


class ActionsPanel(Vertical):
    """A :class:`DataTable` of actions; the cursor row is the selected action."""

    DEFAULT_CSS = """
    ActionsPanel { border: round $primary; border-title-color: $accent; }
    ActionsPanel > DataTable { height: 1fr; }
    """
    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("o", "cycle_sort", "Sort", show=True)]

    class Selected(Message):
        """The user moved to another action."""

        def __init__(self, label: str) -> None:
            super().__init__()
            self.label = label
            """The action's label, e.g. ``a(ḣ_x, [+])``."""

    def __init__(self, **kw) -> None:
        super().__init__(**kw)
        self.border_title = "Actions"
        self.actions: dict[str, ActionInfo] = {}
        self.practised = ""
        self.sort_by = "rel"
        self.sort_reverse = True
        self._shown: dict[str, dict[str, str]] = {}
        self._order: list[str] = []

    def compose(self) -> ComposeResult:
        table: DataTable = DataTable(cursor_type="row", zebra_stripes=True, id="actions-table")
        for key, label in COLUMNS:
            table.add_column(label, key=key)
        yield table

    @property
    def table(self) -> DataTable:
        return self.query_one(DataTable)

    @property
    def selected(self) -> str:
        t = self.table
        if not t.row_count:
            return ""
        try:
            return str(t.coordinate_to_cell_key(t.cursor_coordinate).row_key.value)
        except Exception:
            return ""

    def _cells(self, a: ActionInfo) -> dict[str, object]:
        mark = a.label == self.practised
        style = "bold reverse" if mark else ("bold green" if a.reliable else "")
        label = Text(("▶ " if mark else "  ") + a.label, style=style)
        return {"action": label, "rel": f"{a.rel:.2f}", "plans": str(len(a.plans)),
                "calls": str(a.calls), "w": num(a.weight, 3),
                "hist": Text(sparkline(a.history, 16), style="cyan")}

    def _sort_value(self, label: str):
        a = self.actions[label]
        return {"action": a.label, "rel": a.rel, "plans": len(a.plans), "calls": a.calls,
                "w": a.weight}[self.sort_by]

    def update_knowledge(self, k: Knowledge) -> None:
        """Show the actions of a snapshot, keeping the selection."""
        self.actions = {a.label: a for a in k.actions}
        self._refresh_rows()

    def set_practised(self, label: str) -> None:
        if label != self.practised:
            old, self.practised = self.practised, label
            for lbl in (old, label):
                if lbl in self.actions:
                    cell = self._cells(self.actions[lbl])["action"]
                    self.table.update_cell(lbl, "action", cell)
                    self._shown.setdefault(lbl, {})["action"] = str(cell)

    def _refresh_rows(self) -> None:
        table = self.table
        selected = self.selected
        existing = {str(k.value) for k in table.rows}
        for gone in existing - set(self.actions):
            table.remove_row(gone)
            self._shown.pop(gone, None)
        for label, a in self.actions.items():
            cells = self._cells(a)
            plain = {c: str(v) for c, v in cells.items()}
            if label in existing:
                old = self._shown.get(label, {})
                for col, value in cells.items():      # only what changed: a cheap refresh
                    if old.get(col) != plain[col]:
                        table.update_cell(label, col, value)
            else:
                table.add_row(*cells.values(), key=label)
            self._shown[label] = plain
        self._sort()
        if selected in self.actions:
            table.move_cursor(row=table.get_row_index(selected), animate=False)
        self.border_title = f"Actions ({len(self.actions)}) sorted by {self.sort_by}"

    def _sort(self) -> None:
        if self.table.row_count:
            keys = sorted(self.actions, key=lambda lbl: (self._sort_value(lbl), lbl),
                          reverse=self.sort_reverse)
            if keys == self._order and self.table.row_count == len(keys):
                return
            self._order = keys
            order = {k: i for i, k in enumerate(keys)}
            self.table.sort("action", key=lambda cell: order.get(cell.plain.strip("▶ "), 0))

    def action_cycle_sort(self) -> None:
        """Sort by the next column (action, rel, plans, calls, w)."""
        i = (SORTS.index(self.sort_by) + 1) % len(SORTS)
        self.sort_by = SORTS[i]
        self.sort_reverse = self.sort_by != "action"
        self._refresh_rows()

    def on_data_table_header_selected(self, event: DataTable.HeaderSelected) -> None:
        key = str(event.column_key.value)
        if key in SORTS:
            self.sort_reverse = not self.sort_reverse if key == self.sort_by else key != "action"
            self.sort_by = key
            self._refresh_rows()

    def on_data_table_row_highlighted(self, event: DataTable.RowHighlighted) -> None:
        event.stop()
        if event.row_key is not None and event.row_key.value is not None:
            self.post_message(self.Selected(str(event.row_key.value)))
