"""``router`` / ``record`` / ``echo`` as subprocesses: they work and exit cleanly on SIGINT."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import zenoh

from qlap_runtime.bus import keys
from qlap_runtime.bus.config import client_config, router_config
from qlap_runtime.bus.recorder import read_mcap
from qlap_runtime.bus.schema import Sense, encode

from .conftest import free_port

CMD = [sys.executable, "-m", "qlap_runtime.bus.cli"]


def _wait_matched(session: zenoh.Session, key: str, timeout: float = 20) -> zenoh.Publisher:
    pub = session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
    deadline = time.monotonic() + timeout
    while not pub.matching_status.matching:
        assert time.monotonic() < deadline, "the subprocess never subscribed"
        time.sleep(0.02)
    return pub


def test_record_and_echo_subprocesses_exit_on_sigint(tmp_path):
    ep = f"tcp/127.0.0.1:{free_port()}"
    out = tmp_path / "cli.mcap"
    with zenoh.open(router_config(ep)), zenoh.open(client_config(ep)) as s:
        rec = subprocess.Popen([*CMD, "record", "--connect", ep, "--out", str(out)],
                               stderr=subprocess.PIPE, text=True)
        ech = subprocess.Popen([*CMD, "echo", "--connect", ep, "qlap/**", "--count", "3"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            key = keys.key("cli", "sense")
            # Both print a line once subscribed; then their subscriptions reach the router.
            assert "recording" in rec.stderr.readline()
            assert "printing" in ech.stderr.readline()
            pub = _wait_matched(s, key)
            time.sleep(0.5)
            for t in range(10):
                pub.put(encode(Sense(t, {"x": 1.0})))
            pub.undeclare()
            echo_out, _ = ech.communicate(timeout=20)
            time.sleep(0.3)
            rec.send_signal(signal.SIGINT)
            _, rec_err = rec.communicate(timeout=10)
        finally:
            for p in (rec, ech):
                if p.poll() is None:
                    p.kill()
                    p.wait()
    assert ech.returncode == 0
    assert echo_out.splitlines()[0] == (f'{key} {{"step":0,"values":{{"x":1.0}},'
                                        '"discontinuity":false,"version":1}')
    assert len(echo_out.splitlines()) == 3
    assert rec.returncode == 0, rec_err
    assert "10 messages" in rec_err
    assert [m.step for _, m, _ in read_mcap(out)] == list(range(10))


def test_router_subprocess_serves_and_exits_on_sigterm():
    ep = f"tcp/127.0.0.1:{free_port()}"
    router = subprocess.Popen([*CMD, "router", "--listen", ep], stderr=subprocess.PIPE,
                              text=True)
    try:
        deadline = time.monotonic() + 20
        while True:
            try:
                with zenoh.open(client_config(ep)) as c:
                    assert c.info.routers_zid()
                break
            except zenoh.ZError:
                assert time.monotonic() < deadline, "router never came up"
                time.sleep(0.1)
        router.send_signal(signal.SIGTERM)
        router.communicate(timeout=10)
    finally:
        if router.poll() is None:
            router.kill()
            router.wait()
    assert router.returncode == 0


def test_bad_endpoint_is_a_clear_error():
    r = subprocess.run([*CMD, "echo", "--connect", "localhost:7447", "qlap/**"],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 2
    assert "connect: 'localhost:7447' is not an endpoint" in r.stderr
