"""Goal dialog: pick a variable and one of its qualitative values, or clear the goal."""

from __future__ import annotations

from typing import ClassVar

from textual.app import ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import Horizontal, Vertical
from textual.screen import ModalScreen
from textual.widgets import Button, Label, Select

from ._format import label

GoalChoice = tuple[str, str] | None
"""(variable, value label) to set a goal, None to clear it; the dialog returns ``False`` when
cancelled."""


class GoalScreen(ModalScreen[GoalChoice | bool]):
    """A modal with two selects; dismisses with (var, value), None (clear) or False (cancel)."""

    SCOPED_CSS = False  # the rules below name the screen itself
    DEFAULT_CSS = """
    GoalScreen { align: center middle; }
    GoalScreen > Vertical { width: 64; max-width: 100%; height: auto; max-height: 100%;
                            border: thick $accent; padding: 1 2; background: $surface; }
    GoalScreen #goal-hint { width: 100%; color: $text-muted; margin-bottom: 1; }
    GoalScreen Select { margin-bottom: 1; }
    GoalScreen Horizontal { height: auto; }
    GoalScreen Button { margin-right: 1; }
    """
    BINDINGS: ClassVar[list[BindingType]] = [Binding("escape", "cancel", "Cancel")]

    def __init__(self, values: dict[str, tuple[str, ...]], suggested: list[tuple[str, str]]
                 | None = None, hint: str = "") -> None:
        super().__init__()
        self.values = values
        self.suggested = suggested or []
        self.hint = hint

    def compose(self) -> ComposeResult:
        first = self.suggested[0] if self.suggested else None
        with Vertical():
            yield Label("Give the agent a goal: a(variable, value)")
            if self.hint:
                yield Label(self.hint, id="goal-hint", markup=False)
            yield Select([(label(v), v) for v in self.values], prompt="variable",
                         id="goal-var", value=first[0] if first else Select.NULL)
            yield Select(self._value_options(first[0] if first else None), prompt="value",
                         id="goal-value", value=first[1] if first else Select.NULL)
            with Horizontal():
                yield Button("Set goal", variant="primary", id="goal-set")
                yield Button("Clear goal", id="goal-clear")
                yield Button("Cancel", id="goal-cancel")

    def _value_options(self, var: str | None) -> list[tuple[str, str]]:
        return [(label(q), q) for q in self.values.get(var or "", ())]

    def on_select_changed(self, event: Select.Changed) -> None:
        if event.select.id == "goal-var":
            values = self.query_one("#goal-value", Select)
            var = event.value if isinstance(event.value, str) else None
            options = self._value_options(var)
            keep = values.value
            values.set_options(options)
            if any(keep == v for _, v in options):
                values.value = keep

    def on_button_pressed(self, event: Button.Pressed) -> None:
        if event.button.id == "goal-set":
            var = self.query_one("#goal-var", Select).value
            value = self.query_one("#goal-value", Select).value
            if isinstance(var, str) and isinstance(value, str):
                self.dismiss((var, value))
            else:
                self.notify("pick a variable and a value", severity="warning")
        elif event.button.id == "goal-clear":
            self.dismiss(None)
        else:
            self.dismiss(False)

    def action_cancel(self) -> None:
        self.dismiss(False)
