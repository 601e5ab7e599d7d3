"""The copy a periodic checkpoint is written from while the agent goes on (docs/decisions.md
125): it saves exactly what the agent saves, and stays so while the agent learns on."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np

import worlds
from qlap_runtime.agent_run import run_agent
from qlap_runtime.qlap import Params
from qlap_runtime.qlap.checkpoint import save_agent
from qlap_runtime.qlap.checkpoint.files import read_npz


def saved(agent, directory: Path) -> dict[str, object]:
    """Everything a checkpoint of ``agent`` holds: the JSON files' bytes and the arrays (an
    npz's own bytes differ from save to save by its zip entries' times)."""
    save_agent(agent, directory)
    out: dict[str, object] = {}
    for f in sorted(directory.iterdir()):
        if f.suffix == ".npz":
            out.update({f"{f.name}:{k}": (v.dtype.str, v.shape, v.tobytes())
                        for k, v in read_npz(f).items()})
        else:
            out[f.name] = f.read_bytes()
    return out


def test_the_checkpoint_copy_saves_what_the_agent_saves_while_it_goes_on(tmp_path):
    world = worlds.make("core2d")
    try:
        params = Params(babble_steps=1500, dbn_period=500, landmark_period=1000)
        agent, _ = run_agent(world, 4000, 3, params=params)
        assert agent.plans and any(p.sarsa is not None and p.sarsa.e.any()
                                   for p in agent.plans.values())
        live = saved(agent, tmp_path / "live")
        c = agent.checkpoint_copy()
        assert type(c) is type(agent) and c is not agent
        assert saved(c, tmp_path / "copy") == live
        assert saved(copy.deepcopy(agent), tmp_path / "deep") == live
        for pid, plan in agent.plans.items():     # nothing a plan writes in place is shared
            for name in ("q", "call_x", "call_ok", "cpt_s", "cpt_f"):
                assert not np.shares_memory(getattr(plan, name), getattr(c.plans[pid], name))
            if plan.sarsa is not None:
                assert not np.shares_memory(plan.sarsa.e, c.plans[pid].sarsa.e)
        assert c.model_memo is None               # not saved: left out of the copy
        run_agent(world, 1000, 3, params=params, agent=agent, restored=True)
        assert saved(agent, tmp_path / "later") != live         # the agent went on learning
        assert saved(c, tmp_path / "copy-later") == live         # the copy did not move
    finally:
        world.close()
