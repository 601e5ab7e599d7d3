"""Learned knowledge as text, in the reference's notation (``qlap show``; Tables 8.1–8.6)."""

from __future__ import annotations

from ..telemetry import pretty

__all__ = ["format_knowledge"]


def format_knowledge(k: dict, show_all: bool = False, limit: int | None = None) -> str:
    """Knowledge grouped by action (Tables 8.2–8.6), landmarks first."""
    lines = [f"after {k['step'] + 1:,} steps (t = {k['step']}), window k = {k['k']}", "",
             "landmarks learned (beside the initial ones of Table 3.1):"]
    n_lines = len(lines)
    for name, lms in k["landmarks"].items():
        learned = [m["label"] for m in lms if m["source"] != "initial"]
        if learned:
            lines.append(f"  {pretty(name):10s} {', '.join(pretty(lm) for lm in learned)}")
    if len(lines) == n_lines:
        lines.append("  none yet")
    dbns = {d["id"]: d for d in k["dbns"]}
    actions = sorted(k.get("actions", []), key=lambda a: (-a["reliability"], a["label"]))
    lines += ["", f"actions with plans ({sum(1 for a in actions if a['plans'])}):"]
    shown = 0
    for a in actions:
        if not a["plans"]:
            continue
        if limit is not None and shown >= limit:
            lines.append("  …")
            break
        shown += 1
        flag = "  (sufficiently reliable)" if a["sufficiently_reliable"] else ""
        lines.append(f"  {pretty(a['label'])}  rel {a['reliability']:.2f}  "
                     f"calls {a['calls']}{flag}")
        for p in a["plans"]:
            d = dbns.get(p["dbn"], {})
            brel = "⊥" if d.get("brel") is None else f"{d['brel']:.2f}"
            co = "{" + ", ".join(pretty(v) for v in p["context_o"]) + "}"
            lines.append(f"      {pretty(p['dbn_label'])}  brel {brel}  "
                         f"H {d.get('entropy', float('nan')):.2f}  C_o {co}  "
                         f"rel(o) {p['rel_o']:.2f}")
    if show_all:
        lines += ["", "DBNs that are not plans:"]
        for d in k["dbns"]:
            if not d["plan"]:
                brel = "⊥" if d["brel"] is None else f"{d['brel']:.2f}"
                lines.append(f"  {pretty(d['label'])}  brel {brel}  H {d['entropy']:.2f}")
    return "\n".join(lines)
