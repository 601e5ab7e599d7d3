"""Counters panel: DBNs, plans, landmarks and sufficiently reliable actions over time."""

from __future__ import annotations

from collections import deque

from textual.app import ComposeResult
from textual.containers import Horizontal, Vertical
from textual.widgets import Label, Sparkline

from qlap_runtime.bus.schema import Knowledge

SERIES = (("dbns", "DBNs"), ("plans", "plans"), ("landmarks", "landmarks"),
          ("reliable_actions", "reliable a"))


class CountersPanel(Vertical):
    """One sparkline per counter, one point per knowledge snapshot (at most ``points``)."""

    DEFAULT_CSS = """
    CountersPanel { border: round $primary; border-title-color: $accent; padding: 0 1; }
    CountersPanel Horizontal { height: 1; }
    CountersPanel Horizontal > Label { width: 18; }
    CountersPanel Sparkline { width: 1fr; }
    CountersPanel #counters-practice { height: 1; color: $text-muted; }
    """

    def __init__(self, points: int = 120, **kw) -> None:
        super().__init__(**kw)
        self.border_title = "Counters"
        self.history: dict[str, deque[float]] = {k: deque(maxlen=points) for k, _ in SERIES}
        self.last_step = -1

    def compose(self) -> ComposeResult:
        for key, _ in SERIES:
            with Horizontal():
                yield Label("", id=f"counter-{key}")
                yield Sparkline([0.0], id=f"spark-{key}")
        yield Label("", id="counters-practice")

    def update_knowledge(self, k: Knowledge) -> None:
        c = k.counters
        if k.step != self.last_step:
            self.last_step = k.step
            for key, _ in SERIES:
                self.history[key].append(float(getattr(c, key)))
        for key, name in SERIES:
            self.query_one(f"#counter-{key}", Label).update(f"{name:11}{getattr(c, key):>6}")
            self.query_one(f"#spark-{key}", Sparkline).data = list(self.history[key]) or [0.0]
        self.query_one("#counters-practice", Label).update(
            f"practice {c.practice_calls}  ✓{c.successes} ✗{c.failures}  "
            f"babble {c.babble_commands}  k={k.k}")
