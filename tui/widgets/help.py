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
  p       pause / resume (a finished run stays FINISHED)
  s       one step, pausing first (a finished run takes no more)
  + / -   faster / slower: free → 1000 → 300 → 100 → 30 → 10 → 3 → 1
  c       save a checkpoint: step-N, N the step on the screen
  g       give a goal (a variable and a value) or clear it; pre-filled
          with the action you selected, else the most reliable one
  o       sort the actions by the next column (or click a header)
  ↑ ↓     select an action: the Plans panel shows its plans; the
          cursor stays on the top row until you move it (home: back)
  v, 1–7  compact layout (small terminal): the panel below the actions
  ?       this help        q   quit (closes the Zenoh session)

[b]Panels[/b]
  Actions    a(v, q) with a plan or calls: rel(a), IAC weight w_a,
             calls, plans, rel(a) over the last calls; ▶ the action
             practised, green = sufficiently reliable
  Plans      the selected action's plans: the DBN ⟨{context}:
             antecedent ⇒ consequent⟩, rel(o), brel (⊥: undefined),
             the plan's extra context C_o, entropy H
  IAC        §6.1: the recent choices (step, action, its w_a,
             probability, applicable actions, or babble), the actions
             with the most learning progress rel_new − rel_old (eq. 6.1)
             and Σ progress over time
  Call list  from the practised (or goal) action down to the motor
  Landmarks  learned landmarks per variable, ★ the newest
  Counters   DBNs, plans, landmarks, reliable actions over time
  World      the world from above; each variable's raw value,
             direction of change (↑ · ↓), qualitative value: one step
  Runtime    step, steps/s, clock, placement, actors, ticks, deltas

"step N" counts the steps done: the N of checkpoint step-N and of the
world's t=N.

Press escape or ? to close."""


class HelpScreen(ModalScreen[None]):
    """Keys and panels."""

    SCOPED_CSS = False  # the rules below name the screen itself
    DEFAULT_CSS = """
    HelpScreen { align: center middle; }
    HelpScreen > VerticalScroll { width: 92; max-width: 100%; height: 90%;
                                  border: thick $accent; background: $surface; padding: 1 2; }
    """
    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("escape", "close", "Close"), Binding("question_mark", "close", "Close"),
        Binding("q", "close", "Close", show=False)]

    def compose(self) -> ComposeResult:
        with VerticalScroll():
            yield Static(HELP)

    def action_close(self) -> None:
        self.dismiss(None)
