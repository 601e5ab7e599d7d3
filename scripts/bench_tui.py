#!/usr/bin/env python3
"""Steps/s of the local driver with and without the UI attached (docs/tui.md).

    .venv/bin/python scripts/bench_tui.py [--steps 8000] [--world core2d]

Each mode runs a fresh agent (seed 0, short babbling: conftest.FAST) for the same steps:

- ``bare``        the agent loop alone (no bus, no telemetry)
- ``driver``      the local driver publishing telemetry, nobody watching
- ``ui-thread``   the driver plus the Textual UI in the same process (headless, 160x50)
- ``ui-process``  the driver listening on loopback, the UI in another process (spawn)
"""

from __future__ import annotations

import argparse
import asyncio
import multiprocessing as mp
import socket
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from qlap_runtime.qlap import Params

FAST = Params(babble_steps=2000, dbn_period=500, landmark_period=1000)


def world(name: str):
    import worlds

    return worlds.make(name)


def bare(name: str, steps: int) -> float:
    from qlap_runtime.qlap.agent import Agent

    w = world(name)
    agent = Agent(w.variables, FAST, seed=0)
    obs = w.reset(seed=0)
    t0 = time.perf_counter()
    for t in range(steps):
        obs = w.step(agent.step(t, obs))
    return steps / (time.perf_counter() - t0)


def _driver(name: str, steps: int, **kw):
    from tui import LocalDriver

    return LocalDriver(world(name), params=FAST, seed=0, steps=steps, run_id="bench", **kw)


def _timed(d) -> float:
    t0 = time.perf_counter()
    d.start()
    while not d.finished:
        time.sleep(0.01)
    return d.steps / (time.perf_counter() - t0)


def driver_only(name: str, steps: int) -> float:
    d = _driver(name, steps)
    try:
        return _timed(d)
    finally:
        d.stop()


def ui_thread(name: str, steps: int) -> float:
    from tui import QlapApp

    d = _driver(name, steps)
    d.open()

    async def main() -> float:
        app = QlapApp(d.session, run_id=d.run_id)
        async with app.run_test(size=(160, 50)) as pilot:
            t0 = time.perf_counter()
            d.start()
            while not d.finished:
                await pilot.pause(0.05)
            rate = steps / (time.perf_counter() - t0)
            print(f"    (UI refreshes: {app.refreshes}, IAC lines {app.iac_seen})")
            return rate

    try:
        return asyncio.run(main())
    finally:
        d.stop()


def _viewer(endpoint: str, ready, done) -> None:
    from tui import QlapApp

    async def main() -> None:
        app = QlapApp(connect=endpoint, run_id="bench")
        async with app.run_test(size=(160, 50)) as pilot:
            ready.set()
            while not done.is_set():
                await pilot.pause(0.05)
            print(f"    (viewer refreshes: {app.refreshes}, status seen: "
                  f"{app.status.step if app.status else None})", flush=True)

    asyncio.run(main())


def ui_process(name: str, steps: int) -> float:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    endpoint = f"tcp/127.0.0.1:{port}"
    d = _driver(name, steps, listen=[endpoint])
    d.open()
    ctx = mp.get_context("spawn")
    ready, done = ctx.Event(), ctx.Event()
    p = ctx.Process(target=_viewer, args=(endpoint, ready, done))
    p.start()
    try:
        ready.wait(60)
        time.sleep(1.0)
        return _timed(d)
    finally:
        done.set()
        p.join(30)
        d.stop()


MODES = {"bare": bare, "driver": driver_only, "ui-thread": ui_thread, "ui-process": ui_process}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=8000)
    ap.add_argument("--world", default="core2d")
    ap.add_argument("--modes", default=",".join(MODES))
    args = ap.parse_args()
    for mode in args.modes.split(","):
        rate = MODES[mode](args.world, args.steps)
        print(f"{mode:11} {rate:8.0f} steps/s  ({args.steps} steps, {args.world})", flush=True)


if __name__ == "__main__":
    main()
