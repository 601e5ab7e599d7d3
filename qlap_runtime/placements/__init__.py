"""Placements: where the actors run (docs/architecture.md §2, Layers).

``launcher`` starts the actors of one run — embedded (every actor in one process on a
socket-less session) or processes (one process per actor around an in-process router) — and
supervises them (:mod:`qlap_runtime.runtime.supervisor`). The synchronous loop, the other
placement, is :mod:`qlap_runtime.agent_run`. This layer sits above ``actors`` and below the
terminal UI and the command line.
"""
