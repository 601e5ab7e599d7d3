"""The actors of the runtime: each owns its part of the agent and talks only over the bus.

| actor | owns | consumes | publishes |
| --- | --- | --- | --- |
| ``world`` | the physics | ``motor(t)`` | ``sense(t)`` |
| ``perception`` | quantity spaces | ``sense``, deltas | ``qstate(t)`` |
| ``contingency`` | pair and DBN statistics | ``qstate``, deltas | ``delta/dbn`` |
| ``landmarks`` | histories, DBN activations | ``qstate``, deltas | ``delta/landmarks`` |
| ``planner`` | nothing between batches | ``planreq``, deltas | ``delta/plans`` |
| ``executor`` | plans, call list, IAC | ``qstate``, deltas | ``motor(t)``, ``planreq``, display |

Each is a trio coroutine ``run(session, ctx)``; the same code runs in every placement.
"""
