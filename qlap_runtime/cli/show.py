"""The ``qlap show`` command: the knowledge of a run or checkpoint directory printed in
the reference's notation, grouped by action (Tables 8.2–8.6)."""

from __future__ import annotations

import argparse
import sys


def cmd_show(args: argparse.Namespace) -> int:
    from ..analysis.runs import AnalysisError, load_knowledge

    try:
        knowledge = load_knowledge(args.path)
    except AnalysisError as exc:
        print(f"qlap show: {exc}", file=sys.stderr)
        return 2
    from ..analysis.show import format_knowledge

    try:
        text = format_knowledge(knowledge, show_all=args.all)
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
        print(f"qlap show: {args.path}: malformed knowledge ({type(exc).__name__}: {exc})",
              file=sys.stderr)
        return 2
    print(text)
    return 0
