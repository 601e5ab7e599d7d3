"""A router in-process with user/password authentication and an ACL (and TLS), on loopback."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest
import trio
import zenoh

from qlap_runtime.bus import keys
from qlap_runtime.bus.bridge import Publisher, TrioSubscriber
from qlap_runtime.bus.config import (
    TlsFiles,
    acl_own_keys,
    client_config,
    config_from_file,
    router_config,
)
from qlap_runtime.bus.schema import Motor, QState, Sense

from .conftest import free_port

ROOT = Path(__file__).resolve().parents[2]
USERS = {"world": "w-secret", "perception": "p-secret", "reader": "r-secret"}


async def _allowed_arrives_denied_dropped(world: zenoh.Session, perception: zenoh.Session,
                                          reader: zenoh.Session, run_id: str) -> None:
    """(a) world's sense arrives; (b) world's put on motor and perception's put on sense (keys
    the ACL does not give them) are dropped by the router. The reader is a third session: a
    session's own subscribers see its puts locally, before any router."""
    with TrioSubscriber(reader, keys.run_pattern(run_id)) as sub, \
            Publisher(world, run_id, "sense") as sense, \
            Publisher(world, run_id, "motor") as forged_motor, \
            Publisher(perception, run_id, "sense") as forged_sense, \
            Publisher(perception, run_id, "qstate") as qstate:
        with trio.fail_after(10):
            await sense.wait_matched()
            await qstate.wait_matched()
        forged_motor.put(Motor(0, {"u": 1e6}))
        forged_sense.put(Sense(666, {"x": 0.0}))
        sense.put(Sense(1, {"x": 1.0}))
        got = []
        with trio.fail_after(10):
            while not any(r.msg == Sense(1, {"x": 1.0}) for r in got):
                got.extend(await sub.receive_batch())
        qstate.put(QState(1, {"x": 0}))  # perception's own key: allowed
        with trio.fail_after(10):
            while not any(isinstance(r.msg, QState) for r in got):
                got.extend(await sub.receive_batch())
        await trio.sleep(0.2)
        got.extend(sub.receive_nowait())
    assert [r.key for r in got] == [keys.key(run_id, "sense"), keys.key(run_id, "qstate")]


def _acl() -> dict:
    return acl_own_keys({a: keys.actor_put_keys(a) for a in ("world", "perception")})


async def test_acl_drops_forged_puts_and_wrong_password_cannot_connect(run_id):
    ep = f"tcp/127.0.0.1:{free_port()}"
    with zenoh.open(router_config([ep], users=USERS, acl=_acl())):
        with zenoh.open(client_config(ep, user="world", password="w-secret")) as world, \
                zenoh.open(client_config(ep, user="perception", password="p-secret")) as per, \
                zenoh.open(client_config(ep, user="reader", password="r-secret")) as reader:
            await _allowed_arrives_denied_dropped(world, per, reader, run_id)
        with pytest.raises(zenoh.ZError):  # (c)
            zenoh.open(client_config(ep, user="world", password="wrong"))
        with pytest.raises(zenoh.ZError):
            zenoh.open(client_config(ep, user="nobody", password="w-secret"))


@pytest.fixture(scope="module")
def certs(tmp_path_factory) -> Path:
    assert shutil.which("openssl"), "openssl is needed to make the test CA (Debian: openssl)"
    out = tmp_path_factory.mktemp("certs")
    subprocess.run(["bash", str(ROOT / "scripts/make_test_certs.sh"), str(out)], check=True,
                   capture_output=True, timeout=60)
    return out


def _example_router(certs: Path, tmp_path: Path, port: int) -> zenoh.Config:
    """examples/router.json5 as shipped, with the port, certificate and user file moved."""
    users = tmp_path / "users.txt"
    users.write_text("".join(f"{u}:{p}\n" for u, p in USERS.items()))
    cfg = config_from_file(ROOT / "examples/router.json5")
    for option, value in {
            "listen/endpoints": [f"tls/127.0.0.1:{port}"],
            "transport/link/tls/listen_certificate": str(certs / "router.pem"),
            "transport/link/tls/listen_private_key": str(certs / "router.key"),
            "transport/link/tls/root_ca_certificate": str(certs / "ca.pem"),
            "transport/auth/usrpwd/dictionary_file": str(users)}.items():
        cfg.insert_json5(option, json.dumps(value))
    return cfg


@pytest.fixture
def other_ca(tmp_path) -> Path:
    out = tmp_path / "other"
    subprocess.run(["bash", str(ROOT / "scripts/make_test_certs.sh"), str(out)], check=True,
                   capture_output=True, timeout=60)
    return out / "ca.pem"


async def test_example_router_config_with_tls(certs, other_ca, tmp_path, run_id):
    port = free_port()
    tls = TlsFiles(ca=certs / "ca.pem")
    with zenoh.open(_example_router(certs, tmp_path, port)):
        for host in ("127.0.0.1", "localhost"):
            ep = f"tls/{host}:{port}"
            with zenoh.open(client_config(ep, tls=tls, user="world", password="w-secret")) as w, \
                    zenoh.open(client_config(ep, tls=tls, user="perception",
                                             password="p-secret")) as p, \
                    zenoh.open(client_config(ep, tls=tls, user="reader",
                                             password="r-secret")) as r:
                await _allowed_arrives_denied_dropped(w, p, r, f"{run_id}-{host}")
        ep = f"tls/127.0.0.1:{port}"
        with pytest.raises(zenoh.ZError):  # wrong password over TLS
            zenoh.open(client_config(ep, tls=tls, user="world", password="nope"))
        with pytest.raises(zenoh.ZError):  # TLS with a CA that did not sign the router
            zenoh.open(client_config(ep, tls=TlsFiles(ca=other_ca), user="world",
                                     password="w-secret"))
        with pytest.raises(zenoh.ZError):  # plain TCP to a TLS port
            zenoh.open(client_config(f"tcp/127.0.0.1:{port}", user="world", password="w-secret"))


async def test_mutual_tls(certs, run_id):
    port = free_port()
    ep = f"tls/127.0.0.1:{port}"
    server = TlsFiles(ca=certs / "ca.pem", certificate=certs / "router.pem",
                      private_key=certs / "router.key", mtls=True)
    client = TlsFiles(ca=certs / "ca.pem", certificate=certs / "client.pem",
                      private_key=certs / "client.key", mtls=True)
    with zenoh.open(router_config(ep, tls=server)):
        with zenoh.open(client_config(ep, tls=client)) as c:
            assert c.info.routers_zid()
        with pytest.raises(zenoh.ZError):  # no client certificate
            zenoh.open(client_config(ep, tls=TlsFiles(ca=certs / "ca.pem")))
