"""Record the telemetry the snapshot test feeds to the UI (``python -m tests.tui.record_fixture``).

core2d, seed 0, the fast parameters of conftest.FAST, 12,000 steps (long enough for several
actions to have the 2θ = 50 calls of eq. 6.1, so the IAC panel shows learning progress): a
knowledge snapshot every 1,000 steps (the counters' and the progress sparklines), then the last 16
IAC choices, the call list, the world and a status with fixed rates and times, so the screen is
the same on every machine. The telemetry is today's (``qlap_runtime.telemetry``): re-record after
changing what it publishes.
"""

from __future__ import annotations

import json
from pathlib import Path

from qlap_runtime import telemetry
from qlap_runtime.bus import keys
from qlap_runtime.bus.schema import encode

FIXTURE = Path(__file__).parent / "fixtures" / "core2d-seed0-12000.jsonl"
RUN = "snap"


def record(path: Path = FIXTURE, steps: int = 12000) -> Path:
    import worlds
    from qlap_runtime.qlap.agent import Agent
    from tests.tui.conftest import FAST

    world = worlds.make("core2d")
    agent = Agent(world.variables, FAST, seed=0)
    obs = world.reset(seed=0)
    lines = []

    def put(topic: str, msg) -> None:
        lines.append(json.dumps({"key": keys.key(RUN, topic), "payload": encode(msg).decode()},
                                ensure_ascii=False))

    for t in range(steps):
        obs = world.step(agent.step(t, obs))
        if (t + 1) % 1000 == 0:
            put("knowledge", telemetry.knowledge_msg(agent))
    for m in telemetry.iac_msgs(agent, -1)[-16:]:
        put("iac", m)
    put("calllist", telemetry.call_list_msg(agent))
    put("world", telemetry.world_msg(agent, world))
    put("status", telemetry.status_msg(agent, steps_per_s=2345.6, paused=True, world="core2d",
                                       wall_s=3.5, message="paused"))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


if __name__ == "__main__":
    print(record())
