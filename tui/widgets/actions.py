"""Actions panel: every action a(v, q) with a plan or calls, sortable, the practised one marked."""

from __future__ import annotations

from typing import ClassVar

from rich.text import Text
from textual import events
from textual.app import ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import Vertical
from textual.message import Message
from textual.widgets import DataTable
from textual.widgets.data_table import CellDoesNotExist

from qlap_runtime.bus.schema import ActionInfo, Knowledge

from ._format import Col, fit_columns, num, sparkline

COLUMNS = (Col("action", "action", 16, 0), Col("rel", "rel(a)", 6, 1),
           Col("w", "w_a", 5, 2), Col("calls", "calls", 5, 3),
           Col("plans", "plans", 5, 5), Col("hist", "rel(a) history", 8, 4, short="history"))
"""The columns, first to go last: plans, then the sparkline, calls, w_a."""
SORTS = ("action", "rel", "plans", "calls", "w")
HISTORY = 32
"""The longest sparkline (the telemetry carries the last 32 values of rel(a))."""


class ActionsTable(DataTable):
    """The actions' table: it tells its panel when the *user* moves the cursor (keys, clicks),
    as opposed to the panel re-sorting the rows."""

    def _moved(self) -> None:
        panel = self.parent
        if isinstance(panel, ActionsPanel):
            panel.user_moved(self.cursor_row)

    def action_cursor_up(self) -> None:
        super().action_cursor_up()
        self._moved()

    def action_cursor_down(self) -> None:
        super().action_cursor_down()
        self._moved()

    def action_page_up(self) -> None:
        super().action_page_up()
        self._moved()

    def action_page_down(self) -> None:
        super().action_page_down()
        self._moved()

    def action_scroll_top(self) -> None:
        super().action_scroll_top()
        self._moved()

    def action_scroll_bottom(self) -> None:
        super().action_scroll_bottom()
        self._moved()

    def action_scroll_home(self) -> None:
        """``home``: the top row (the table has no columns to scroll to)."""
        self.action_scroll_top()

    def action_scroll_end(self) -> None:
        """``end``: the last row."""
        self.action_scroll_bottom()

    async def _on_click(self, event: events.Click) -> None:
        await super()._on_click(event)
        if event.style and event.style.meta.get("row", -1) >= 0:
            self._moved()


class ActionsPanel(Vertical):
    """A :class:`DataTable` of actions; the cursor row is the selected action.

    Until the user moves the cursor it stays on the top row (the most reliable action when
    sorted by rel(a)), whatever the re-sorting does; once moved it follows its action, until
    the user brings it back to the top row (``home``)."""

    DEFAULT_CSS = """
    ActionsPanel { border: round $primary; border-title-color: $accent; }
    ActionsPanel > DataTable { height: 1fr; scrollbar-size-vertical: 1; }
    """
    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("o", "cycle_sort", "Sort", show=True)]

    class Selected(Message):
        """The selected action changed (the user moved, or another action came on top)."""

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
        self.follow_top = True
        """The cursor stays on the top row (the user has not moved it, or moved it back)."""
        self._shown: dict[str, dict[str, str]] = {}
        self._order: list[str] = []
        self._layout: tuple[tuple[str, int], ...] = ()
        self._restore = ""

    def compose(self) -> ComposeResult:
        yield ActionsTable(cursor_type="row", zebra_stripes=True, id="actions-table")

    def on_mount(self) -> None:
        self._fit()

    def on_resize(self, event: events.Resize) -> None:
        if self._fit():
            self._refresh_rows()

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
        except CellDoesNotExist:
            return ""

    # ----------------------------------------------------------------------------- columns
    def _fit(self) -> bool:
        """Choose the columns that fit the panel's width (no header cut, nothing hidden
        behind a horizontal scroll); rebuild the table when they change. True if rebuilt."""
        width = self.content_region.width or self.size.width
        if width <= 0:
            width = 80
        longest = max((len(lbl) for lbl in self.actions), default=24) + 2
        fitted = fit_columns(COLUMNS, width - 1, first=longest, flex="hist",
                             flex_max=HISTORY)
        layout = tuple((c.key, w) for c, w in fitted)
        if layout == self._layout:
            return False
        self._layout = layout
        table = self.table
        selected = self.selected
        table.clear(columns=True)
        self._shown.clear()
        self._order = []
        for c, w in fitted:
            table.add_column(c.title(w), key=c.key, width=w)
        if selected and not self.follow_top:
            self._restore = selected
        return True

    @property
    def columns(self) -> tuple[str, ...]:
        """The keys of the columns shown (they depend on the width)."""
        return tuple(k for k, _ in self._layout)

    def _width(self, key: str) -> int:
        return dict(self._layout).get(key, 0)

    def _cells(self, a: ActionInfo) -> dict[str, object]:
        mark = a.label == self.practised
        style = "bold reverse" if mark else ("bold green" if a.reliable else "")
        label = Text(("▶ " if mark else "  ") + a.label, style=style)
        cells: dict[str, object] = {
            "action": label, "rel": f"{a.rel:.2f}", "w": num(a.weight, 3),
            "calls": str(a.calls), "plans": str(len(a.plans)),
            "hist": Text(sparkline(a.history, self._width("hist")), style="cyan")}
        return {k: cells[k] for k in self.columns}

    def _sort_value(self, label: str):
        a = self.actions[label]
        return {"action": a.label, "rel": a.rel, "plans": len(a.plans), "calls": a.calls,
                "w": a.weight}[self.sort_by]

    # ----------------------------------------------------------------------------- updates
    def update_knowledge(self, k: Knowledge) -> None:
        """Show the actions of a snapshot, keeping the selection."""
        self.actions = {a.label: a for a in k.actions}
        self._fit()
        self._refresh_rows()

    def set_practised(self, label: str) -> None:
        if label != self.practised:
            old, self.practised = self.practised, label
            for lbl in (old, label):
                if lbl in self.actions and lbl in self._shown:
                    cell = self._cells(self.actions[lbl])["action"]
                    self.table.update_cell(lbl, "action", cell)
                    self._shown[lbl]["action"] = str(cell)

    def user_moved(self, row: int) -> None:
        """The user put the cursor on ``row``: follow that action, or the top row again."""
        self.follow_top = row <= 0

    def _refresh_rows(self) -> None:
        table = self.table
        selected = getattr(self, "_restore", "") or self.selected
        self._restore = ""
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
        if table.row_count:
            row = 0 if self.follow_top or selected not in self.actions \
                else table.get_row_index(selected)
            if row != table.cursor_row:
                table.move_cursor(row=row, animate=False)
        self.border_title = f"Actions ({len(self.actions)}) by {self.sort_by}"

    def _sort(self) -> None:
        if self.table.row_count:
            keys = sorted(self.actions, key=lambda lbl: (self._sort_value(lbl), lbl),
                          reverse=self.sort_reverse)
            if keys == self._order and self.table.row_count == len(keys):
                return
            self._order = keys
            order = {k: i for i, k in enumerate(keys)}
            self.table.sort("action", key=lambda cell: order.get(cell.plain[2:], 0))

    def top(self) -> str:
        """The label on the top row ('' when empty)."""
        return self._order[0] if self._order else ""

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
        # The event names the row highlighted when it was posted; a re-sort may since have
        # put another action under the cursor: report what is selected now.
        event.stop()
        if self.selected:
            self.post_message(self.Selected(self.selected))
