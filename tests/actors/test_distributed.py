"""The distributed pieces from the command line: a router and one `qlap actor` per actor."""

from __future__ import annotations

import json
import subprocess
import sys

import worlds
from qlap_runtime.agent_run import knowledge_json, params_for_world, run_agent
from qlap_runtime.placements.launcher import free_port
from qlap_runtime.qlap import Params

STEPS, SEED, LAG, BABBLE = 2600, 4, 300, 2000


def wait_listening(port: int, limit_s: float = 30.0) -> None:
    """Wait until the router accepts TCP connections (it starts in another process)."""
    import socket
    import time

    deadline = time.monotonic() + limit_s
    while True:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        assert time.monotonic() < deadline, f"router not listening on {port}"
        time.sleep(0.1)


def qlap(*args: str) -> list[str]:
    return [sys.executable, "-m", "qlap_runtime.cli", *args]


def test_router_and_six_actor_processes_learn_what_the_synchronous_loop_learns(tmp_path):
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    router = subprocess.Popen(qlap("router", "--listen", endpoint),
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    procs = []
    try:
        wait_listening(port)
        common = ["--connect", endpoint, "--run", "dist-test", "--world", "core2d", "--steps",
                  str(STEPS), "--seed", str(SEED), "--lag", str(LAG), "--babble-steps",
                  str(BABBLE)]
        for name in ("perception", "contingency", "landmarks", "planner", "executor", "world"):
            # The world and contingency actors write their parts of the final checkpoint
            # into the same --out (one machine here; a shared directory across machines).
            extra = ["--out", str(tmp_path)] if name in ("executor", "world",
                                                         "contingency") else []
            procs.append(subprocess.Popen(qlap("actor", name, *common, *extra),
                                          stdout=subprocess.PIPE, stderr=subprocess.PIPE))
        for p in procs:
            out, err = p.communicate(timeout=240)
            assert p.returncode == 0, err.decode()[-2000:]
        world_result = json.loads(out)
        assert world_result["steps"] == STEPS
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
        router.terminate()
        router.wait(10)
    world = worlds.make("core2d")
    agent, _ = run_agent(world, STEPS, SEED,
                         params=params_for_world(world, Params(batch_lag=LAG,
                                                               babble_steps=BABBLE)))
    world.close()
    expected = knowledge_json(agent)
    assert (tmp_path / "knowledge.json").read_text() == expected
    final = tmp_path / "checkpoints" / "final"
    assert {"agent.json", "world.json", "stats.json", "stats.npz"} <= \
        {p.name for p in final.iterdir()}
    assert not (tmp_path / "checkpoints" / ".final-parts").exists()


def test_actor_rejects_bad_arguments():
    r = subprocess.run(qlap("actor", "world", "--connect", "tcp/127.0.0.1:1", "--run", "a/b"),
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert "run id" in r.stderr
    r = subprocess.run(qlap("actor", "nobody", "--connect", "tcp/127.0.0.1:1", "--run", "a"),
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
