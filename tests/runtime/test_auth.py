"""Authorisation by default (issue 13, docs/security.md), with real Zenoh sessions on loopback:
an embedded run that listens and the processes placement's router accept only the run's users,
and each user may put only what the run's ACL allows."""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys

import pytest
import trio
import zenoh

from qlap_runtime.bus import keys
from qlap_runtime.bus.auth import CREDENTIALS_FILE, read_credentials
from qlap_runtime.bus.bridge import RejectionCounter, TrioSubscriber
from qlap_runtime.bus.config import client_config
from qlap_runtime.bus.schema import Control, Motor, encode
from qlap_runtime.placements.launcher import free_port, run_embedded_async, run_processes
from qlap_runtime.qlap import Params
from qlap_runtime.runtime.context import RunContext

PARAMS = Params(babble_steps=1000, dbn_period=500, landmark_period=1000)


def refused(config: zenoh.Config) -> bool:
    try:
        zenoh.open(config).close()
    except zenoh.ZError:
        return True
    return False


def start_echo(ep: str, cred) -> subprocess.Popen:
    """``qlap echo --credentials`` (the viewer user) for three sense messages."""
    return subprocess.Popen([sys.executable, "-m", "qlap_runtime.cli", "echo", "--connect", ep,
                             "--credentials", str(cred), "qlap/t-auth/sense", "--count", "3"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_an_embedded_run_that_listens_admits_only_its_users(tmp_path):
    ep = f"tcp/127.0.0.1:{free_port()}"
    ctx = RunContext("t-auth", "core2d", 20_000, 1, PARAMS, out=tmp_path)
    seen: dict[str, object] = {}

    async def outsider(session, ctx):
        cred = tmp_path / CREDENTIALS_FILE
        seen["mode"] = stat.S_IMODE(os.stat(cred).st_mode)
        _, tui_pw, endpoints = read_credentials(cred, "tui")
        _, viewer_pw, _ = read_credentials(cred, "viewer")
        seen["endpoints"] = endpoints
        seen["anonymous refused"] = await trio.to_thread.run_sync(
            refused, client_config([ep]))
        seen["wrong password refused"] = await trio.to_thread.run_sync(
            refused, client_config([ep], user="tui", password="guess"))
        viewer = await trio.to_thread.run_sync(
            zenoh.open, client_config([ep], user="viewer", password=viewer_pw))
        tui = await trio.to_thread.run_sync(
            zenoh.open, client_config([ep], user="tui", password=tui_pw))
        echo = start_echo(ep, cred)
        try:
            counter = RejectionCounter("outsider")
            with TrioSubscriber(viewer, keys.key(ctx.run_id, "sense"), counter=counter) as sub:
                t0 = None
                async for batch in sub:
                    t = batch[-1].msg.step
                    seen["viewer received"] = seen.get("viewer received", 0) + len(batch)
                    if t0 is None:                  # dropped by the ACL: the run goes on
                        t0 = seen["viewer quit at"] = t
                        viewer.put(keys.key(ctx.run_id, "control"),
                                   encode(Control("quit", {})))
                    if t >= t0 + 200 and "tui motor" not in seen:   # dropped by the ACL
                        tui.put(keys.key(ctx.run_id, "motor"),
                                encode(Motor(t + 1, {"u_bogus": 1.0})))
                        seen["tui motor"] = t
                    if t >= t0 + 400 and echo.poll() is not None:   # allowed: ends the run
                        tui.put(keys.key(ctx.run_id, "control"), encode(Control("quit", {})))
                        seen["tui quit at"] = t
                        seen["echo"] = echo.stdout.read().splitlines()
                        return
        finally:
            viewer.close()
            tui.close()
            if echo.poll() is None:
                echo.kill()
            echo.communicate()

    async def main():
        return await run_embedded_async(ctx, listen=(ep,), extra=(outsider,))

    summary = trio.run(main)
    assert seen["mode"] == 0o600
    assert seen["endpoints"] == [ep]
    assert seen["anonymous refused"] and seen["wrong password refused"]
    assert len(seen["echo"]) == 3 and all(" " in line for line in seen["echo"])
    assert seen["viewer received"] >= 400
    world = summary["actors"]["world"]
    assert world["quit_at_step"] >= seen["tui quit at"] >= seen["viewer quit at"] + 400
    assert world["rejected"] == 0                     # the tui's motor never reached the world
    creds = json.loads((tmp_path / CREDENTIALS_FILE).read_text())
    assert set(creds["users"]) == {"tui", "viewer"}   # the actors' passwords are not written


def test_the_processes_router_refuses_strangers(tmp_path):
    ctx = RunContext("t-auth-proc", "core2d", 1500, 1, PARAMS, out=tmp_path)
    checked: dict[str, bool] = {}

    def probe(sup) -> None:
        if checked or sup.board.slot("world").data[0] < 100:
            return
        _, pw, (ep,) = read_credentials(tmp_path / CREDENTIALS_FILE, "viewer")
        checked["anonymous refused"] = refused(client_config([ep]))
        checked["actor name without its password refused"] = refused(
            client_config([ep], user="executor", password=pw))
        checked["viewer admitted"] = not refused(client_config([ep], user="viewer",
                                                               password=pw))

    summary = run_processes(ctx, on_poll=probe)
    assert checked == {"anonymous refused": True,
                       "actor name without its password refused": True,
                       "viewer admitted": True}
    assert summary["steps"] == 1500
    assert (tmp_path / "knowledge.json").exists()


@pytest.mark.parametrize("user", ["tui", "viewer"])
def test_credentials_files_are_read_for_the_right_user(tmp_path, user):
    from qlap_runtime.bus.auth import write_credentials
    from qlap_runtime.bus.config import BusConfigError

    path = write_credentials(tmp_path / "c.json", ["tcp/127.0.0.1:1"],
                             {"tui": "a", "viewer": "b", "world": "secret"})
    assert "secret" not in path.read_text()
    name, pw, eps = read_credentials(path, user)
    assert (name, pw, eps) == (user, {"tui": "a", "viewer": "b"}[user], ["tcp/127.0.0.1:1"])
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(BusConfigError, match="unreadable credentials file"):
        read_credentials(tmp_path / "bad.json", user)
