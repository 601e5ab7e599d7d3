"""Key-expression scheme and Zenoh configs."""

from __future__ import annotations

import json
import os
import time

import pytest
import zenoh

from qlap_runtime.bus import keys
from qlap_runtime.bus.config import (
    BusConfigError,
    TlsFiles,
    acl_own_keys,
    client_config,
    embedded_config,
    router_config,
)

from .conftest import free_port


def test_keys():
    assert keys.key("r1", "delta/dbn") == "qlap/r1/delta/dbn"
    assert keys.alive_key("r1", "world") == "qlap/r1/alive/world"
    assert keys.run_pattern("r1") == "qlap/r1/**"
    assert keys.run_pattern(None) == "qlap/**"
    assert keys.parse("qlap/r1/alive/world") == ("r1", "alive/world")
    assert keys.parse("qlap/r1/delta/plans") == ("r1", "delta/plans")
    keys.validate_run_id(keys.new_run_id())
    with pytest.raises(keys.BusKeyError, match="unknown topic"):
        keys.key("r1", "senses")


@pytest.mark.parametrize("bad", ["", "a*b", "a$b", "a/b", "a#b", "a?b", "a b", "**"])
def test_run_id_validator(bad):
    with pytest.raises(keys.BusKeyError):
        keys.validate_run_id(bad)


def _get(cfg: zenoh.Config, option: str):
    return json.loads(cfg.get_json(option))


def test_every_config_disables_scouting():
    for cfg in (embedded_config(), router_config("tcp/127.0.0.1:7447"),
                client_config(["tcp/127.0.0.1:7447"], user="u", password="p")):
        assert _get(cfg, "scouting/multicast/enabled") is False
        assert _get(cfg, "scouting/gossip/enabled") is False
    assert _get(router_config("tcp/127.0.0.1:7447"), "mode") == "router"
    c = client_config("tcp/127.0.0.1:7447", user="u", password="p")
    assert _get(c, "mode") == "client"
    assert _get(c, "transport/auth/usrpwd/user") == "u"


def _sockets() -> set[str]:
    out = set()
    for fd in os.listdir("/proc/self/fd"):
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if target.startswith("socket:"):
            out.add(target)
    return out


@pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="needs Linux /proc")
def test_embedded_session_opens_no_sockets():
    cfg = embedded_config()
    assert _get(cfg, "listen/endpoints") == []
    assert _get(cfg, "connect/endpoints") == []
    assert _get(cfg, "mode") == "peer"
    before = _sockets()
    with zenoh.open(cfg) as s:
        got = []
        sub = s.declare_subscriber("qlap/x/sense", lambda sample: got.append(1))
        s.put("qlap/x/sense", b"{}")
        deadline = time.monotonic() + 5
        while not got and time.monotonic() < deadline:
            time.sleep(0.001)
        assert got == [1]  # it works as a bus...
        assert _sockets() - before == set()  # ...without a single socket
        sub.undeclare()


def test_config_errors_name_the_option(tmp_path):
    with pytest.raises(BusConfigError, match="listen: 'localhost:7447' is not an endpoint"):
        router_config(["localhost:7447"])
    with pytest.raises(BusConfigError, match="connect: at least one endpoint"):
        client_config([])
    with pytest.raises(BusConfigError, match="port 0-65535"):
        client_config("tcp/127.0.0.1:99999")
    with pytest.raises(BusConfigError, match="tls/ or quic/ endpoint needs tls"):
        client_config("tls/127.0.0.1:7447")
    with pytest.raises(BusConfigError, match="user and password go together"):
        client_config("tcp/127.0.0.1:7447", user="world")
    with pytest.raises(BusConfigError, match="listen_certificate.*no such file"):
        router_config("tls/127.0.0.1:7447", tls=TlsFiles(certificate=tmp_path / "nope.pem"))
    with pytest.raises(BusConfigError, match="users: user name 'a:b'"):
        router_config("tcp/127.0.0.1:7447", users={"a:b": "x"})
    acl = acl_own_keys({"world": ["qlap/*/sense"]})
    acl["rules"][0]["messages"] = ["puts"]
    with pytest.raises(BusConfigError, match=r"access_control.rules\[0\].messages: unknown"):
        router_config("tcp/127.0.0.1:7447", acl=acl)
    with pytest.raises(BusConfigError, match="policies.*no subject 'ghost'"):
        router_config("tcp/127.0.0.1:7447", acl={"rules": [], "subjects": [],
                                                 "policies": [{"subjects": ["ghost"]}]})


def test_nobody_can_connect_to_an_embedded_session():
    port = free_port()
    with zenoh.open(embedded_config()), pytest.raises(zenoh.ZError):
        zenoh.open(client_config(f"tcp/127.0.0.1:{port}"))


def test_embedded_with_listen_accepts_a_client():
    ep = f"tcp/127.0.0.1:{free_port()}"
    with zenoh.open(embedded_config([ep])) as host, zenoh.open(client_config(ep)) as c:
        assert host.info.zid() != c.info.zid()
        assert c.info.peers_zid() or c.info.routers_zid()
