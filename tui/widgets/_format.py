"""Small text helpers shared by the panels (no widgets here)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from rich.cells import cell_len, set_cell_size

from qlap_runtime.telemetry import pretty

BLOCKS = "▁▂▃▄▅▆▇█"

ARROWS = {"[+]": "↑", "[0]": "·", "[-]": "↓"}
"""A direction of change ḣ as one character (the World panel's derivative column)."""


def sparkline(values: Sequence[float], width: int = 16, lo: float | None = 0.0,
              hi: float | None = 1.0) -> str:
    """The last ``width`` values as block characters (``lo``/``hi`` None: the data's range)."""
    vals = list(values)[-width:] if width > 0 else []
    if not vals:
        return ""
    a = min(vals) if lo is None else lo
    b = max(vals) if hi is None else hi
    span = (b - a) or 1.0
    out = []
    for v in vals:
        i = int((min(max(v, a), b) - a) / span * (len(BLOCKS) - 1) + 0.5)
        out.append(BLOCKS[i])
    return "".join(out)


def bar(fraction: float, width: int = 20) -> str:
    """A horizontal bar of ``fraction`` (0..1) of ``width`` cells, in eighths."""
    fraction = min(max(fraction, 0.0), 1.0)
    eighths = round(fraction * width * 8)
    full, rest = divmod(eighths, 8)
    return "█" * full + ("▏▎▍▌▋▊▉"[rest - 1] if rest else "")


def num(x: float, digits: int = 2) -> str:
    """A number, or ⊥ for the −1 the telemetry uses for undefined."""
    return "⊥" if x < 0 else f"{x:.{digits}f}"


def real(x: float, digits: int = 3) -> str:
    """A raw value with ``digits`` decimals; never ``-0.000`` (a value that rounds to zero is
    written ``0.000``, whatever its sign)."""
    s = f"{x:.{digits}f}"
    return s[1:] if s.startswith("-") and not s.strip("-0.") else s


def signed(x: float, digits: int = 2) -> str:
    """:func:`real` with a ``+`` on positive values (zero has no sign)."""
    s = real(x, digits)
    return s if s.startswith("-") or not s.strip("0.") else "+" + s


def label(text: str) -> str:
    """A variable, value or action label in the reference's notation (``z_F.dot`` → ``ż_F``,
    ``-inf`` → ``−∞``, ``-2.5`` → ``−2.5``, ``-0`` → ``0``), as the telemetry writes the action
    and plan labels."""
    return pretty(text)


def clip(text: str, width: int) -> str:
    """``text`` in at most ``width`` cells, an ellipsis marking a cut. Cells, not characters:
    a label's combining dot (``ż`` as z + U+0307) takes none."""
    if width <= 0:
        return ""
    if cell_len(text) <= width:
        return text
    return set_cell_size(text, max(width - 1, 0)) + "…"


def pad(text: str, width: int) -> str:
    """``text`` clipped to ``width`` cells and padded with spaces to exactly ``width`` (an
    f-string's ``:<width`` counts characters, so a label with a combining dot came out a
    cell short and its row's columns shifted)."""
    text = clip(text, width)
    return text + " " * max(width - cell_len(text), 0)


def steps_done(step: int) -> int:
    """The step count the screen shows: the messages carry the index t of the agent's latest
    step (0-based, −1 before the first), the screen the steps done, t + 1 — the N of a
    ``step-N`` checkpoint and of the world's ``t=N`` line."""
    return max(step + 1, 0)


@dataclass(frozen=True)
class Col:
    """One column a panel's table may show: ``width`` cells of content (the first column is
    the flexible one: ``width`` is its minimum); ``keep`` orders which go first when space
    runs out (lower stays longer; ``keep`` ≤ 1: always shown)."""

    key: str
    header: str
    width: int
    keep: int
    short: str = ""
    """A shorter header for when the column is narrower than ``header``."""

    def title(self, width: int) -> str:
        """The header that fits in ``width`` cells."""
        return self.header if cell_len(self.header) <= width else clip(self.short or self.header,
                                                                   width)


def fit_columns(cols: Sequence[Col], available: int, first: int, pad: int = 2,
                flex: str | None = None, flex_max: int = 0) -> list[tuple[Col, int]]:
    """Which columns fit in ``available`` cells, with their widths.

    The first column should get ``first`` cells (its longest content): the other columns are
    dropped, least kept first, until it does (those with ``keep`` ≤ 1 stay; the first column
    then gets what is left, never below its minimum). ``flex`` (e.g. a sparkline) then takes
    what is left, up to ``flex_max``. Every column costs ``pad`` more cells (the table's
    padding), so nothing is clipped and no header is cut."""
    head, rest = cols[0], list(cols[1:])
    chosen = sorted(rest, key=lambda c: c.keep)
    while chosen and chosen[-1].keep > 1:
        need = first + pad + sum(c.width + pad for c in chosen)
        if need <= available:
            break
        chosen.pop()
    chosen_keys = {c.key for c in chosen}
    others = sum(c.width + pad for c in chosen)
    head_w = max(head.width, min(first, available - others - pad))
    widths = {head.key: head_w}
    spare = available - others - head_w - pad
    for c in chosen:
        widths[c.key] = c.width
        if c.key == flex and spare > 0:
            widths[c.key] = min(c.width + spare, max(flex_max, c.width))
    return [(c, widths[c.key]) for c in cols if c.key == head.key or c.key in chosen_keys]
