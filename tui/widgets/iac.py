"""IAC panel (§6.1): the recent exploration choices with their w_a, the actions with the most
learning progress, and the agent's learning progress over time."""

from __future__ import annotations

from collections import deque

from rich.text import Text
from textual import events
from textual.widgets import Static

from qlap_runtime.bus.schema import ActionInfo, IACChoice, Knowledge

from ._format import clip, pad, sparkline

THETA = 25
"""θ of eq. 6.1 (``Params.iac_window``; the snapshot does not carry it): an action's w_a is its
learning progress rel_new − rel_old once it has 2θ calls."""
FLOOR = 0.001
"""The least w_a of eq. 6.1 (``Params.iac_min_weight``): no progress."""


def progress(a: ActionInfo) -> float | None:
    """Learning progress of ``a`` (eq. 6.1 without its floor, 0 at the floor), None while it has
    fewer than 2θ calls or no plan (its w_a is then eq. 6.2's, not progress)."""
    if a.calls < 2 * THETA or a.weight < 0:
        return None
    return a.weight if a.weight > FLOOR else 0.0


class IACPanel(Static):
    """Recent choices (step, action, w_a, probability, applicable), the top actions by learning
    progress with their rel(a), and Σ progress over the knowledge snapshots, fitted to the
    panel's size (newest choices first)."""

    DEFAULT_CSS = """
    IACPanel { border: round $primary; border-title-color: $accent; padding: 0 1;
               text-wrap: nowrap; text-overflow: ellipsis; }
    """

    def __init__(self, points: int = 120, **kw) -> None:
        super().__init__("(no choice yet: the agent babbles first)", **kw)
        self.border_title = "IAC choices"
        self.recent: deque[IACChoice] = deque(maxlen=64)
        self.choices = 0
        self.babbles = 0
        self.knowledge: Knowledge | None = None
        self.weights: dict[str, float] = {}
        self.progress: deque[float] = deque(maxlen=points)
        self._last_step = -1

    @property
    def last(self) -> IACChoice | None:
        return self.recent[-1] if self.recent else None

    def add(self, choices: list[IACChoice]) -> None:
        for c in choices:
            self.choices += 1
            self.babbles += c.babbling
            self.recent.append(c)
        if choices:
            self._show()

    def update_knowledge(self, k: Knowledge) -> None:
        self.knowledge = k
        self.weights = {a.label: a.weight for a in k.actions}
        if k.step != self._last_step:
            self._last_step = k.step
            self.progress.append(sum(p for a in k.actions if (p := progress(a))))
        self._show()

    def on_resize(self, event: events.Resize) -> None:
        self._show()

    def top_progress(self, n: int) -> list[tuple[ActionInfo, float]]:
        """The ``n`` actions with the most learning progress (ties: more calls first)."""
        if self.knowledge is None:
            return []
        ranked = [(a, p) for a in self.knowledge.actions if (p := progress(a)) is not None]
        ranked.sort(key=lambda ap: (-ap[1], -ap[0].calls, ap[0].label))
        return ranked[:n]

    def _show(self) -> None:
        k = self.knowledge
        if k is not None:
            c = k.counters
            self.border_title = (f"IAC §6.1: {c.practice_calls} practised, "
                                 f"{c.babble_commands} babbled")
        width = max(self.content_region.width or self.size.width, 20)
        height = max(self.content_region.height or self.size.height, 6)
        self.update(self.render_text(width, height))

    def render_text(self, width: int, height: int) -> Text:
        """The panel's content in ``width`` × ``height`` cells."""
        lp_all = self.top_progress(10_000)
        n_lp = len(lp_all)
        body = height - 3                          # three headings / summary lines
        n_top = min(n_lp, max(1, body // 3)) if n_lp else 1
        n_recent = max(body - n_top, 1)
        out = Text(no_wrap=True, overflow="ellipsis")

        # 1. Recent choices, newest first, with the action's current w_a.
        lw = max(width - 24, 8)
        out.append(f"{'step':>7} {'choice':<{lw}} {'w_a':>5} {'p':>4} {'of':>3}\n",
                   style="bold dim")
        recent = list(self.recent)[::-1][:n_recent]
        for c in recent:
            if c.babbling:
                out.append(f"{c.step:>7} ", style="dim")
                out.append(clip(f"babble ({c.n_applicable} applicable)", lw) + "\n",
                           style="dim italic")
                continue
            w = self.weights.get(c.action)
            w_s = "—" if w is None or w < 0 else f"{w:.3f}"
            out.append(f"{c.step:>7} ")
            out.append(pad(c.action, lw), style="bold")
            out.append(f" {w_s:>5} {c.weight:>4.2f} {c.n_applicable:>3}\n")
        if not recent:
            out.append("(no choice yet: the agent babbles first)\n", style="dim")
        for _ in range(n_recent - max(len(recent), 1)):
            out.append("\n")

        # 2. The top actions by learning progress (eq. 6.1), with rel(a) over their last calls.
        if n_lp:
            out.append(clip(f"learning progress (eq. 6.1), {n_lp} actions ≥ 2θ calls", width)
                       + "\n", style="bold dim")
            sw = min(10, max(width - 8 - 20, 0))
            aw = width - 8 - sw - (1 if sw else 0)
            for a, p in lp_all[:n_top]:
                style = "bold green" if p > 0 else "dim"
                out.append(pad(a.label, aw), style=style)
                out.append(f" {p:>+6.3f}", style=style)
                if sw:
                    out.append(" " + sparkline(a.history, sw), style="cyan")
                out.append("\n")
        else:
            out.append(clip(f"learning progress: no action has 2θ = {2 * THETA} calls yet",
                            width) + "\n", style="dim")
            out.append(clip("(until then w_a is eq. 6.2: H(rel(a))·rel(o))", width) + "\n",
                       style="dim")

        # 3. Σ progress over the snapshots.
        total = self.progress[-1] if self.progress else 0.0
        label = f"Σ progress {total:.3f} "
        out.append(label, style="bold")
        out.append(sparkline(self.progress, max(width - len(label), 0), lo=0.0, hi=None),
                   style="magenta")
        return out
