"""The actor runtime: QLAP's agent as independent actors over Zenoh, driven by trio.

``lockstep`` holds the clock's bookkeeping (which knowledge deltas are due at a step),
``snapshot`` the actors' snapshots, ``supervisor`` the supervision of actor processes. The
actors themselves live in the top-level ``actors`` package, above this one; the placements that
start them in :mod:`qlap_runtime.placements`, above that.
"""
