"""Landmarks panel: the landmarks of each variable, the newest marked."""

from __future__ import annotations

from rich.markup import escape
from textual.widgets import Static

from qlap_runtime.bus.schema import Knowledge

from ._format import label


class LandmarksPanel(Static):
    """Learned landmarks per magnitude/motor variable; ★ marks the most recently adopted."""

    DEFAULT_CSS = """
    LandmarksPanel { border: round $primary; border-title-color: $accent; height: 1fr;
                     padding: 0 1; overflow-y: auto; }
    """

    def __init__(self, **kw) -> None:
        super().__init__("(none yet)", **kw)
        self.border_title = "Landmarks"
        self.newest: tuple[str, str] | None = None

    def update_knowledge(self, k: Knowledge) -> None:
        newest, newest_step = None, 0
        for var, lms in k.landmarks.items():
            for lm in lms:
                if lm.source != "initial" and lm.step >= newest_step:
                    newest, newest_step = (var, lm.label), lm.step
        self.newest = newest
        lines = []
        for var, lms in k.landmarks.items():
            learned = [lm for lm in lms if lm.source != "initial"]
            if not learned:
                continue
            parts = [(f"[b yellow]★{escape(label(lm.label))}[/]" if (var, lm.label) == newest
                      else escape(label(lm.label)))
                     for lm in learned]
            lines.append(f"[b]{escape(label(var)):>5}[/] " + ", ".join(parts))
        if newest:
            lines.append(f"[dim]★ newest: {escape(label(newest[0]))} "
                         f"{escape(label(newest[1]))} at step {newest_step}[/]")
        self.update("\n".join(lines) if lines else "(no landmark learned yet)")
        self.border_title = f"Landmarks ({k.counters.landmarks} learned)"
