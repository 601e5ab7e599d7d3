"""Clean shutdown: Ctrl-C (SIGINT to the foreground group) or SIGTERM ends a run at once and
leaves no process behind."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest


def children_of(pid: int) -> list[int]:
    out = subprocess.run(["pgrep", "-P", str(pid)], capture_output=True, text=True).stdout
    return [int(x) for x in out.split()]


def running(pid: int) -> bool:
    """The process exists and is not a zombie waiting to be reaped."""
    try:
        with open(f"/proc/{pid}/status") as f:
            state = next(line for line in f if line.startswith("State:"))
    except (FileNotFoundError, StopIteration):
        return False
    return "Z" not in state.split()[1]


def start(placement: str, out) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "qlap_runtime.cli", "run", "--headless", "--quiet",
           "--placement", placement, "--world", "core2d", "--steps", "1000000",
           "--out", str(out)]
    # A runner in the background (CI) may ignore SIGINT, and children inherit that: restore the
    # default so the run sees Ctrl-C as a terminal would deliver it.
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def wait_running(p: subprocess.Popen, placement: str, limit: float = 60) -> list[int]:
    deadline = time.monotonic() + limit
    while time.monotonic() < deadline:
        kids = children_of(p.pid)
        # processes: its two process groups and multiprocessing's resource tracker.
        if placement == "embedded" or len(kids) >= 3:
            time.sleep(3)                                   # well into the run
            return children_of(p.pid)
        time.sleep(0.2)
    raise AssertionError(f"{placement} run did not start its actors")


@pytest.mark.parametrize(("placement", "sig"), [("embedded", signal.SIGINT),
                                                ("processes", signal.SIGINT),
                                                ("processes", signal.SIGTERM)])
def test_a_run_stops_promptly_and_leaves_nothing(placement, sig, tmp_path):
    p = start(placement, tmp_path / "run")
    try:
        kids = wait_running(p, placement)
        t0 = time.monotonic()
        if sig == signal.SIGINT:
            os.killpg(p.pid, sig)                         # what Ctrl-C does
        else:
            p.send_signal(sig)
        p.communicate(timeout=20)
        assert time.monotonic() - t0 < 10
        assert p.returncode in (130, -signal.SIGTERM, 143)
        deadline = time.monotonic() + 5
        while True:
            alive = [k for k in kids if running(k)]
            if not alive or time.monotonic() > deadline:
                break
            time.sleep(0.2)
        assert alive == [], f"left behind: {alive}"
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
        p.communicate()                                 # reap it and close its pipes
