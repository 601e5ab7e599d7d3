"""Markdown for the generated pages (docs/results.md, the experiment reports): numbers with a
dash for a missing one, mean ± standard error, and tables."""

from __future__ import annotations

import math
from collections.abc import Sequence

__all__ = ["num", "pm", "table"]


def _missing(x: float | None) -> bool:
    return x is None or (isinstance(x, float) and math.isnan(x))


def num(x: float | None, fmt: str = "{:g}") -> str:
    """``x`` formatted, or "—" when it is None or NaN."""
    return "—" if _missing(x) else fmt.format(x)


def pm(mean: float | None, se: float | None, fmt: str = "{:.2f}") -> str:
    """"mean ± se" ("mean" alone without a standard error; "—" without a mean)."""
    if _missing(mean):
        return "—"
    text = fmt.format(mean)
    if not _missing(se):
        text += " ± " + fmt.format(se)
    return text


def table(header: Sequence[str], rows: Sequence[Sequence[object]]) -> str:
    """A Markdown table; a "|" inside a cell is escaped."""
    def line(cells: Sequence[object]) -> str:
        return "| " + " | ".join(str(c).replace("|", "\\|") for c in cells) + " |"

    return "\n".join([line(header), line(["---"] * len(header)), *map(line, rows)])
