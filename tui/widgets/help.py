"""Help screen: the keys and what the panels show."""

from __future__ import annotations

from typing import ClassVar

from textual.app import ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import VerticalScroll
from textual.screen import ModalScreen
from textual.widgets import Static

HELP = """\
[b]qlap — watch and steer a learning agent[/b]

[b]Keys[/b]
  p        pause / resume the agent
  s        single step (pauses first)
  + / -    faster / slower (free → 1000 → 300 → 100 → 30 → 10 → 3 → 1 steps/s)
  c        save a checkpoint (the agent writes it)
  g        give a goal: pick a variable and a value (or clear the goal)
  o        sort the actions by the next column (or click a column header)
  ↑ ↓      select an action: its plans show in the Plans panel
  ?        this help          q   quit (closes the Zenoh session)

[b]Panels[/b]
  Actions    a(v, q) with a plan or calls: rel(a), plans, calls, IAC weight w_a and
             rel(a) over time; ▶ the action being practised, green = sufficiently reliable
  Plans      the selected action's plans: DBN ⟨{context}: antecedent ⇒ consequent⟩,
             brel (⊥ = undefined), entropy H, extra context C_o, rel(o)
  IAC        each exploration choice (step, action, probability, applicable actions, or
             babbling) and the distribution of w_a
  Call list  from the practised (or goal) action down to the motor command
  Landmarks  learned landmarks per variable, ★ the newest
  Counters   DBNs, plans, landmarks, reliable actions over time
  World      the world drawn from above, raw values and the agent's percept
  Runtime    step, steps/s, clock, placement, actors alive, late/missed ticks, deltas

Press escape or ? to close."""


class HelpScreen(ModalScreen[None]):
    """Keys and panels."""

    SCOPED_CSS = False  # the rules below name the screen itself
    DEFAULT_CSS = """
    HelpScreen { align: center middle; }
    HelpScreen > VerticalScroll { width: 96; height: 80%; border: thick $accent;
                                  background: $surface; padding: 1 2; }
    """
    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("escape", "close", "Close"), Binding("question_mark", "close", "Close"),
        Binding("q", "close", "Close", show=False)]

    def compose(self) -> ComposeResult:
        with VerticalScroll():
            yield Static(HELP)

    def action_close(self) -> None:
        self.dismiss(None)
