"""The executor's state a batch reads (§6.2.1), carried to the batch actors by ``batchctx``.

Algorithm 2's batches consult the agent: no DBN is added for, and DBNs are deleted whose
consequent is a sufficiently reliable action; DBNs that are plans are never deleted as old.
The batch actors keep no actions or plans, so without the executor's context their batches
would differ from the synchronous loop's once an action becomes reliable (practice).
"""

from __future__ import annotations

import worlds
from actors.convert import apply_batch_context, batch_context
from qlap_runtime.agent_run import params_for_world, run_agent
from qlap_runtime.bus.schema import BatchContext, decode, encode
from qlap_runtime.qlap import Params
from qlap_runtime.qlap.checkpoint import load_learner, save_learner
from qlap_runtime.qlap.delta import DeleteDBN


def ops(learner, step: int) -> list:
    parts = learner.batch_copy().compute_parts(step, ("dbn", "landmarks"))
    return [op for kind in ("dbn", "landmarks") for op in parts[kind].ops]


def test_a_replica_with_the_executors_context_computes_the_synchronous_batch(tmp_path):
    world = worlds.make("core2d")
    # A short run that makes plans: batches every 500 steps, k fixed (Appendix C needs more
    # data than 4,000 steps give) and 15 data points instead of 30 (App. B.2).
    params = params_for_world(world, Params(babble_steps=1500, dbn_period=500,
                                            landmark_period=1000, k_fixed=5,
                                            min_data_points=15))
    agent, _ = run_agent(world, 4000, 7, params=params)
    world.close()
    learner = agent.learner
    plans = sorted(i for i, d in learner.dbns.items() if d.is_plan)
    assert plans, "the run made no plan: nothing to carry"
    # A sufficiently reliable action: the consequent of a DBN that is not a plan.
    other = next(d for i, d in sorted(learner.dbns.items()) if not d.is_plan)
    learner.reliable_actions = {(other.consequent.var, other.consequent.value)}

    # A batch actor's replica: the same statistics, none of the agent's state.
    save_learner(learner, tmp_path)
    replica = load_learner(tmp_path)
    replica.reliable_actions = set()
    for d in replica.dbns.values():
        d.is_plan = False
    expected = ops(learner, 4000)
    assert ops(replica, 4000) != expected          # without the context: another batch

    msg = decode("qlap/r/batchctx", encode(batch_context(agent, 3999)))
    assert msg == BatchContext(3999, ((other.consequent.var, other.consequent.value),),
                               tuple(plans))
    apply_batch_context(replica, msg)
    assert ops(replica, 4000) == expected
    assert DeleteDBN(other.id) in expected    # §6.2.1 item 4: its DBNs go
