"""IAC panel: a scrolling log of exploration choices and the distribution of IAC weights."""

from __future__ import annotations

from rich.markup import escape
from textual.app import ComposeResult
from textual.containers import Vertical
from textual.widgets import RichLog, Static

from qlap_runtime.bus.schema import IACChoice, Knowledge

from ._format import bar


class IACPanel(Vertical):
    """Each IAC choice (step, action, weight, applicable, babbling) and the current w_a."""

    DEFAULT_CSS = """
    IACPanel { border: round $primary; border-title-color: $accent; }
    IACPanel > RichLog { height: 1fr; }
    IACPanel > #iac-weights { height: auto; max-height: 7; color: $text-muted; }
    """

    def __init__(self, **kw) -> None:
        super().__init__(**kw)
        self.border_title = "IAC choices"
        self.choices = 0
        self.babbles = 0
        self.last: IACChoice | None = None

    def compose(self) -> ComposeResult:
        yield RichLog(max_lines=500, wrap=False, markup=True, id="iac-log")
        yield Static("", id="iac-weights")

    def add(self, choices: list[IACChoice]) -> None:
        log = self.query_one(RichLog)
        for c in choices:
            self.choices += 1
            if c.babbling:
                self.babbles += 1
                log.write(f"[dim]{c.step:>8}  babble        ({c.n_applicable} applicable)[/]")
            else:
                log.write(f"{c.step:>8}  [bold]{escape(c.action)}[/]  p={c.weight:.3f}  "
                          f"of {c.n_applicable}")
            self.last = c
        if choices:
            self.border_title = (f"IAC choices ({self.choices}, "
                                 f"{self.babbles} babbling)")

    def update_knowledge(self, k: Knowledge) -> None:
        """The weight distribution: w_a of every action with a plan, normalised, largest first."""
        ws = sorted(((a.weight, a.label) for a in k.actions if a.weight >= 0), reverse=True)
        total = sum(w for w, _ in ws) or 1.0
        lines = [f"{lbl[:22]:22} {bar(w / total, 16):16} {w / total:.2f}" for w, lbl in ws[:5]]
        if len(ws) > 5:
            lines.append(f"… {len(ws) - 5} more")
        self.query_one("#iac-weights", Static).update(
            "w_a distribution\n" + "\n".join(lines) if lines else "w_a: no action has a plan yet")
