#!/usr/bin/env python
"""Bus benchmark: round-trip latency (median, p99) and burst throughput.

    .venv/bin/python scripts/bench_bus.py [--n 5000] [--burst 50000]

1. same session (embedded config): a trio task puts a ``Sense`` on ``ping``; a second trio task
   receives it through a :class:`TrioSubscriber` and puts it back on ``pong``; round trip
   measured in the first task (the full trio bridge, encode and decode included);
2. two processes over loopback TCP: an echo process (started with ``spawn``) connected to a
   router that this process runs in-process;
3. burst: N messages with BLOCK from a thread, received whole and in order by a trio task in
   another session over loopback, in messages per second.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import trio
import zenoh

from qlap_runtime.bus.bridge import Publisher, TrioSubscriber
from qlap_runtime.bus.config import client_config, embedded_config, router_config
from qlap_runtime.bus.schema import Motor, Sense, encode
from qlap_runtime.placements.launcher import free_port

RUN = "bench"
VALUES = {f"v{i:02d}": 0.123456 * i for i in range(8)}  # ~200-byte payloads


async def _echo_loop(session: zenoh.Session, stop_after: int) -> None:
    """Answer every ``sense`` with a ``motor`` of the same step."""
    with TrioSubscriber(session, f"qlap/{RUN}/sense") as sub, \
            Publisher(session, RUN, "motor") as pub:
        n = 0
        async for batch in sub:
            for r in batch:
                pub.put(Motor(r.msg.step, {"u": 1.0}))
                n += 1
            if n >= stop_after:
                return


async def _ping(session: zenoh.Session, n: int, warmup: int) -> list[float]:
    rtts = []
    with TrioSubscriber(session, f"qlap/{RUN}/motor") as sub, \
            Publisher(session, RUN, "sense") as pub:
        with trio.fail_after(30):
            await pub.wait_matched()
        for i in range(n + warmup):
            t0 = time.perf_counter()
            pub.put(Sense(i, VALUES))
            while True:
                batch = await sub.receive_batch()
                if any(r.msg.step == i for r in batch):
                    break
            if i >= warmup:
                rtts.append(time.perf_counter() - t0)
    return rtts


def _stats(name: str, rtts: list[float]) -> None:
    rtts = sorted(rtts)
    p50 = statistics.median(rtts) * 1e6
    p99 = rtts[int(0.99 * (len(rtts) - 1))] * 1e6
    print(f"{name:<38} median {p50:7.1f} µs   p99 {p99:7.1f} µs   (n={len(rtts)})")


async def same_session(n: int) -> None:
    with zenoh.open(embedded_config()) as s:
        async with trio.open_nursery() as nursery:
            nursery.start_soon(_echo_loop, s, n + 100)
            await trio.sleep(0.05)
            rtts = await _ping(s, n, 100)
    _stats("round trip, same session (embedded)", rtts)


def _echo_process(endpoint: str, n: int) -> None:
    with zenoh.open(client_config(endpoint)) as s:
        trio.run(_echo_loop, s, n)


async def two_processes(n: int) -> None:
    ep = f"tcp/127.0.0.1:{free_port()}"
    with zenoh.open(router_config(ep)), zenoh.open(client_config(ep)) as s:
        proc = mp.get_context("spawn").Process(target=_echo_process, args=(ep, n + 100))
        proc.start()
        try:
            rtts = await _ping(s, n, 100)
        finally:
            proc.join(30)
            if proc.is_alive():
                proc.kill()
    _stats("round trip, two processes (loopback)", rtts)


async def burst(n: int) -> None:
    ep = f"tcp/127.0.0.1:{free_port()}"
    with zenoh.open(router_config(ep)), zenoh.open(client_config(ep)) as a, \
            zenoh.open(client_config(ep)) as b, \
            TrioSubscriber(a, f"qlap/{RUN}/sense") as sub, Publisher(b, RUN, "sense") as pub:
        with trio.fail_after(30):
            await pub.wait_matched()
        msgs = [Sense(i, VALUES) for i in range(n)]

        def flood() -> None:
            for m in msgs:
                pub.put(m)

        got = 0
        last = -1
        t0 = time.perf_counter()
        async with trio.open_nursery() as nursery:
            nursery.start_soon(trio.to_thread.run_sync, flood)
            while got < n:
                for r in await sub.receive_batch():
                    assert r.msg.step == last + 1, "lost or reordered"
                    last = r.msg.step
                    got += 1
        dt = time.perf_counter() - t0
    print(f"{'burst, BLOCK, two sessions (loopback)':<38} {n / dt:9.0f} msg/s "
          f"({n} messages, none lost, in order; decode included)")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, default=5000, help="round trips per measurement")
    p.add_argument("--burst", type=int, default=50_000, help="messages in the burst")
    a = p.parse_args()
    print(f"payload: {len(encode(Sense(0, VALUES)))} bytes of JSON per sense message")
    trio.run(same_session, a.n)
    trio.run(two_processes, a.n)
    trio.run(burst, a.burst)


if __name__ == "__main__":
    main()
