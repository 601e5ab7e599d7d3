"""Zenoh session configurations for the three placements (docs/architecture.md §2–3; docs/bus.md).

Every config built here has multicast scouting and gossip switched off and explicit endpoints:

- :func:`embedded_config` — a peer with no listen and no connect endpoints: one in-process
  session with no sockets (the ``embedded`` placement). ``listen=[...]`` lets outside
  subscribers attach (``qlap run --listen``).
- :func:`router_config` — ``mode: router`` listening on the given endpoints, with optional TLS,
  user/password authentication (``transport/auth/usrpwd``) and an ACL (``access_control``).
- :func:`client_config` — ``mode: client`` connecting to a router, with optional TLS and
  credentials.
- :func:`config_from_file` — a JSON5 router/client config file (``qlap router --config``), with
  scouting forced off.

Invalid arguments raise :class:`BusConfigError` naming the offending option. Key names were
checked against eclipse-zenoh 1.10 (``zenoh.Config().get_json(...)``).
"""

from __future__ import annotations

import atexit
import json
import os
import re
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh

PROTOCOLS = ("tcp", "tls", "udp", "quic", "ws", "unixsock-stream")
"""Endpoint protocols accepted in ``listen`` / ``connect`` lists."""

ACL_MESSAGES = ("put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
                "liveliness_token", "declare_liveliness_subscriber", "liveliness_query")
"""Message types an ``access_control`` rule may name (zenoh 1.x)."""

_ENDPOINT = re.compile(r"^(?P<proto>[a-z-]+)/(?P<addr>[^#?]+)(?P<rest>[#?].*)?$")


class BusConfigError(ValueError):
    """A bus configuration that cannot work; the message names the offending option."""


@dataclass(frozen=True)
class TlsFiles:
    """PEM files for TLS endpoints (``transport/link/tls``); ``scripts/make_test_certs.sh``
    writes a matching set."""

    ca: Path | None = None
    """The CA certificate that signed the other side's certificate (``root_ca_certificate``).
    Required on clients; on a router only with ``mtls``."""
    certificate: Path | None = None
    """This side's certificate: required on a router (``listen_certificate``), and on a
    client with ``mtls`` (``connect_certificate``)."""
    private_key: Path | None = None
    """The key of ``certificate`` (``listen_private_key`` / ``connect_private_key``)."""
    mtls: bool = False
    """Mutual TLS: the router also checks the client's certificate (``enable_mtls``)."""
    verify_name: bool = True
    """Check that the router's certificate names the host connected to
    (``verify_name_on_connect``)."""


def _set(cfg: zenoh.Config, option: str, value: Any) -> None:
    try:
        cfg.insert_json5(option, json.dumps(value))
    except zenoh.ZError as e:
        raise BusConfigError(f"zenoh rejected option {option!r} = {value!r}: {e}") from None


def _base(mode: str) -> zenoh.Config:
    cfg = zenoh.Config()
    _set(cfg, "mode", mode)
    # docs/architecture.md §3: the default config joins multicast scouting and listens everywhere.
    _set(cfg, "scouting/multicast/enabled", False)
    _set(cfg, "scouting/gossip/enabled", False)
    _set(cfg, "listen/endpoints", [])
    _set(cfg, "connect/endpoints", [])
    return cfg


def validate_endpoint(endpoint: str, option: str) -> str:
    """Check one ``proto/address`` endpoint (e.g. ``tcp/127.0.0.1:7447``); return it."""
    if not isinstance(endpoint, str):
        raise BusConfigError(f"{option}: endpoint must be a string, got {endpoint!r}")
    m = _ENDPOINT.match(endpoint)
    if m is None or m["proto"] not in PROTOCOLS:
        raise BusConfigError(
            f"{option}: {endpoint!r} is not an endpoint of the form PROTOCOL/HOST:PORT with "
            f"PROTOCOL one of {', '.join(PROTOCOLS)} (e.g. tcp/127.0.0.1:7447)")
    if m["proto"] != "unixsock-stream":
        host, sep, port = m["addr"].rpartition(":")
        if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
            raise BusConfigError(f"{option}: {endpoint!r} needs HOST:PORT with a port 0-65535")
    return endpoint


def _endpoints(endpoints: Sequence[str] | str, option: str, *, allow_empty: bool) -> list[str]:
    if isinstance(endpoints, str):
        endpoints = [endpoints]
    eps = [validate_endpoint(e, option) for e in endpoints]
    if not eps and not allow_empty:
        raise BusConfigError(f"{option}: at least one endpoint is needed")
    return eps


def _file(path: Path | str | None, option: str) -> str:
    if path is None:
        raise BusConfigError(f"{option}: a file is required")
    p = Path(path)
    if not p.is_file():
        raise BusConfigError(f"{option}: no such file {str(p)!r}")
    return str(p.resolve())


def _needs_tls(eps: list[str], tls: TlsFiles | None, option: str) -> None:
    if tls is None and any(e.startswith(("tls/", "quic/")) for e in eps):
        raise BusConfigError(f"{option}: a tls/ or quic/ endpoint needs tls=TlsFiles(...)")


def embedded_config(listen: Sequence[str] = (), *,
                    users: Mapping[str, str] | Path | str | None = None,
                    acl: Mapping[str, Any] | None = None) -> zenoh.Config:
    """A peer session with no sockets: no listen or connect endpoints, no scouting.

    With ``listen`` (e.g. ``["tcp/127.0.0.1:7447"]``) the session also accepts outside
    subscribers (a TUI, a recorder) while staying a single in-process session for the actors.
    ``users`` and ``acl`` as for :func:`router_config`: outside sessions must authenticate and
    may put only what the ACL allows (the in-process actors are not subject to it);
    ``qlap_runtime.bus.auth`` builds both for a run.
    """
    cfg = _base("peer")
    _set(cfg, "listen/endpoints", _endpoints(listen, "listen", allow_empty=True))
    if users is not None:
        _set(cfg, "transport/auth/usrpwd/dictionary_file", _dictionary_file(users))
    if acl is not None:
        _set(cfg, "access_control", _validate_acl(acl))
    return cfg


def router_config(listen: Sequence[str] | str, *, tls: TlsFiles | None = None,
                  users: Mapping[str, str] | Path | str | None = None,
                  acl: Mapping[str, Any] | None = None) -> zenoh.Config:
    """A router listening on ``listen``.

    ``users`` is a ``{user: password}`` mapping or the path of a zenoh dictionary file (one
    ``user:password`` a line); with it, clients must authenticate (``transport/auth/usrpwd``).
    A mapping is written to a private temporary file removed when the interpreter exits.
    ``acl`` is an ``access_control`` object (see :func:`acl_own_keys`); ``enabled`` defaults to
    true.
    """
    eps = _endpoints(listen, "listen", allow_empty=False)
    _needs_tls(eps, tls, "listen")
    cfg = _base("router")
    _set(cfg, "listen/endpoints", eps)
    if tls is not None:
        tls_opts: dict[str, Any] = {
            "listen_certificate": _file(tls.certificate, "tls.certificate (listen_certificate)"),
            "listen_private_key": _file(tls.private_key, "tls.private_key (listen_private_key)"),
            "enable_mtls": tls.mtls}
        if tls.mtls or tls.ca is not None:
            tls_opts["root_ca_certificate"] = _file(tls.ca, "tls.ca (root_ca_certificate)")
        for k, v in tls_opts.items():
            _set(cfg, f"transport/link/tls/{k}", v)
    if users is not None:
        _set(cfg, "transport/auth/usrpwd/dictionary_file", _dictionary_file(users))
    if acl is not None:
        _set(cfg, "access_control", _validate_acl(acl))
    return cfg


def client_config(connect: Sequence[str] | str, *, tls: TlsFiles | None = None,
                  user: str | None = None, password: str | None = None) -> zenoh.Config:
    """A client connecting to a router at ``connect`` (fails fast if none answers)."""
    eps = _endpoints(connect, "connect", allow_empty=False)
    _needs_tls(eps, tls, "connect")
    cfg = _base("client")
    _set(cfg, "connect/endpoints", eps)
    if tls is not None:
        _set(cfg, "transport/link/tls/root_ca_certificate",
             _file(tls.ca, "tls.ca (root_ca_certificate)"))
        _set(cfg, "transport/link/tls/verify_name_on_connect", tls.verify_name)
        if tls.mtls:  # the client only presents its certificate with enable_mtls set
            _set(cfg, "transport/link/tls/enable_mtls", True)
            _set(cfg, "transport/link/tls/connect_certificate",
                 _file(tls.certificate, "tls.certificate (connect_certificate)"))
            _set(cfg, "transport/link/tls/connect_private_key",
                 _file(tls.private_key, "tls.private_key (connect_private_key)"))
    if (user is None) != (password is None):
        raise BusConfigError("transport/auth/usrpwd: user and password go together")
    if user is not None:
        _check_user(user, "user")
        _set(cfg, "transport/auth/usrpwd/user", user)
        _set(cfg, "transport/auth/usrpwd/password", password)
    return cfg


def config_from_file(path: Path | str) -> zenoh.Config:
    """Load a JSON5 zenoh config file (e.g. ``examples/router.json5``).

    Relative file paths inside it are resolved by zenoh from the working directory. Scouting is
    forced off whatever the file says.
    """
    p = Path(path)
    if not p.is_file():
        raise BusConfigError(f"--config: no such file {str(p)!r}")
    try:
        cfg = zenoh.Config.from_file(str(p))
    except zenoh.ZError as e:
        raise BusConfigError(f"--config {str(p)!r}: {_parse_reason(e)}") from None
    _set(cfg, "scouting/multicast/enabled", False)
    _set(cfg, "scouting/gossip/enabled", False)
    return cfg


def _parse_reason(exc: BaseException) -> str:
    """Zenoh's error for a config file as one line: a JSON5 syntax error's drawing ("--> 1:1",
    the line, a caret, "= expected …") becomes "line 1, column 1: expected …"; the Rust
    source location is dropped."""
    from ..errors import one_line

    text = str(exc)
    where = re.search(r"-->\s*(\d+):(\d+)", text)
    what = re.search(r"^\s*=\s*(.+?)(?:\s+at \S+\.rs:\d+\.?)?\s*$", text, re.M)
    if where and what:
        return f"line {where[1]}, column {where[2]}: {what[1]}"
    msg = re.search(r'msg:\s*"((?:[^"\\]|\\.)*)"', text)
    loc = re.search(r"line:\s*(\d+),\s*column:\s*(\d+)", text)
    if msg and loc:                                 # a value of the wrong type
        return f"line {loc[1]}, column {loc[2]}: {msg[1]}"
    return one_line(exc)


def acl_own_keys(puts: Mapping[str, Sequence[str]], *,
                 readers: Sequence[str] | None = None) -> dict[str, Any]:
    """An ACL where each user may put (and reply, and declare liveliness tokens) only on its
    own key expressions, and every authenticated client may subscribe, query and receive.

    ``puts`` maps a user name to the key expressions it may write, e.g.
    ``{"world": ["qlap/*/sense", "qlap/*/alive/world"]}``. ``readers`` restricts who may
    subscribe (default: everyone). Everything else is denied (``default_permission: deny``).
    """
    read = ["declare_subscriber", "query", "declare_queryable", "declare_liveliness_subscriber",
            "liveliness_query"]
    rules: list[dict[str, Any]] = [
        {"id": "read", "permission": "allow", "flows": ["ingress", "egress"], "messages": read,
         "key_exprs": ["qlap/**"]},
        {"id": "deliver", "permission": "allow", "flows": ["egress"],
         "messages": ["put", "delete", "reply", "liveliness_token"], "key_exprs": ["qlap/**"]}]
    subjects: list[dict[str, Any]] = [{"id": "readers"} if readers is None else
                                      {"id": "readers", "usernames": list(readers)}]
    policies: list[dict[str, Any]] = [{"rules": ["read", "deliver"], "subjects": ["readers"]}]
    for user, keys in puts.items():
        _check_user(user, f"puts[{user!r}]")
        if not keys:
            continue
        rules.append({"id": f"put-{user}", "permission": "allow", "flows": ["ingress"],
                      "messages": ["put", "delete", "reply", "liveliness_token"],
                      "key_exprs": list(keys)})
        subjects.append({"id": f"user-{user}", "usernames": [user]})
        policies.append({"rules": [f"put-{user}"], "subjects": [f"user-{user}"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules,
            "subjects": subjects, "policies": policies}


def _check_user(user: str, option: str) -> None:
    if not isinstance(user, str) or not user or ":" in user or any(c.isspace() for c in user):
        raise BusConfigError(f"{option}: user name {user!r} must be non-empty, without ':' "
                             "or spaces")


def _dictionary_file(users: Mapping[str, str] | Path | str) -> str:
    if isinstance(users, (str, os.PathLike)):
        return _file(users, "users (transport/auth/usrpwd/dictionary_file)")
    if not users:
        raise BusConfigError("users: at least one user is needed")
    lines = []
    for user, password in users.items():
        _check_user(user, "users")
        if not isinstance(password, str) or not password or "\n" in password:
            raise BusConfigError(f"users[{user!r}]: the password must be a non-empty line")
        lines.append(f"{user}:{password}\n")
    fd, path = tempfile.mkstemp(prefix="qlap-users-", suffix=".txt")  # mode 0600
    with os.fdopen(fd, "w") as f:
        f.writelines(lines)
    atexit.register(_unlink, path)
    return path


def _unlink(path: str) -> None:
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass


def _validate_acl(acl: Mapping[str, Any]) -> dict[str, Any]:
    acl = dict(acl)
    acl.setdefault("enabled", True)
    if acl.get("default_permission", "deny") not in ("allow", "deny"):
        raise BusConfigError("access_control.default_permission must be 'allow' or 'deny'")
    rule_ids = set()
    for i, rule in enumerate(acl.get("rules", [])):
        where = f"access_control.rules[{i}]"
        if "id" not in rule:
            raise BusConfigError(f"{where}: needs an 'id'")
        rule_ids.add(rule["id"])
        if rule.get("permission") not in ("allow", "deny"):
            raise BusConfigError(f"{where}.permission must be 'allow' or 'deny'")
        bad = [m for m in rule.get("messages", []) if m not in ACL_MESSAGES]
        if bad:
            raise BusConfigError(f"{where}.messages: unknown {bad}; known: {list(ACL_MESSAGES)}")
        bad = [f for f in rule.get("flows", []) if f not in ("ingress", "egress")]
        if bad:
            raise BusConfigError(f"{where}.flows: unknown {bad}; known: ingress, egress")
        if not rule.get("key_exprs"):
            raise BusConfigError(f"{where}.key_exprs: at least one key expression is needed")
    subject_ids = {s.get("id") for s in acl.get("subjects", [])}
    for i, pol in enumerate(acl.get("policies", [])):
        for r in pol.get("rules", []):
            if r not in rule_ids:
                raise BusConfigError(f"access_control.policies[{i}].rules: no rule {r!r}")
        for s in pol.get("subjects", []):
            if s not in subject_ids:
                raise BusConfigError(f"access_control.policies[{i}].subjects: no subject {s!r}")
    return acl
