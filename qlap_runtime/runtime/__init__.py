"""The actor runtime: QLAP's agent as independent actors over Zenoh, driven by trio.

``lockstep`` holds the clock's bookkeeping (which knowledge deltas are due at a step),
``launcher`` the placements (embedded: every actor in one process on a socket-less session;
processes: one process per actor around an in-process router). The actors themselves live in the
top-level ``actors`` package.
"""
