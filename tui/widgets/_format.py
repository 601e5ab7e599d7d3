"""Small text helpers shared by the panels (no widgets here)."""

from __future__ import annotations

from collections.abc import Sequence

BLOCKS = "▁▂▃▄▅▆▇█"


def sparkline(values: Sequence[float], width: int = 16, lo: float | None = 0.0,
              hi: float | None = 1.0) -> str:
    """The last ``width`` values as block characters (``lo``/``hi`` None: the data's range)."""
    vals = list(values)[-width:]
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
