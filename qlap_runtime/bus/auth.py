"""Authorisation by default for every endpoint a run opens (docs/security.md).

A run that listens — the embedded placement's ``--listen``, the terminal UI driver's
``--listen``, the processes placement's router — generates a password per user for this run
(``secrets.token_urlsafe``), turns on Zenoh's user/password authentication
(``transport/auth/usrpwd``) and an ACL like ``examples/router.json5``: every authenticated user
may subscribe and query under ``qlap/**``; each actor may put only on its own topics
(``keys.WRITERS``), the UI's user ``tui`` on ``control``, and the read-only user ``viewer`` on
nothing but its liveliness token. Only ``tui`` and ``viewer`` are written to the run's
credentials file (``<out>/bus-credentials.json``, mode 0600); the actors' passwords never leave
the launcher (they reach the spawned actor processes through their start-up pipe).

``qlap tui --connect`` / ``qlap echo`` / ``qlap record`` take ``--credentials FILE`` (or
``$QLAP_CREDENTIALS``): the file's ``tui`` user for the UI, its ``viewer`` user for the
read-only commands.
"""

from __future__ import annotations

import json
import os
import secrets
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from . import keys
from .config import BusConfigError, acl_own_keys

CREDENTIALS_FILE = "bus-credentials.json"
UI_USER = "tui"
VIEWER = "viewer"
ENV = "QLAP_CREDENTIALS"


def generate(users: Iterable[str]) -> dict[str, str]:
    """A fresh random password (144 bits) for each user."""
    return {u: secrets.token_urlsafe(18) for u in users}


def run_users(actors: Iterable[str] = ()) -> dict[str, str]:
    """Passwords for the run's ``actors`` (those that connect as clients), the UI and the
    viewer."""
    return generate([*actors, UI_USER, VIEWER])


def run_acl(users: Iterable[str]) -> dict[str, Any]:
    """The ACL of a run (``access_control``): each of ``users`` may put only on its own keys
    (``keys.actor_put_keys``; a process group's user, its actors joined by ``+``, on those of
    each of its actors); ``viewer`` only on its liveliness token; everyone authenticated may
    subscribe, query and receive under ``qlap/**``; everything else is denied."""
    puts: dict[str, list[str]] = {}
    for user in users:
        if user == VIEWER:
            puts[user] = [f"{keys.ROOT}/*/{keys.ALIVE}/{VIEWER}"]
        else:
            puts[user] = [k for actor in user.split("+") for k in keys.actor_put_keys(actor)]
    return acl_own_keys(puts)


def write_credentials(path: Path, endpoints: Iterable[str], users: Mapping[str, str]) -> Path:
    """The credentials a UI or viewer needs (``tui`` and ``viewer`` only), mode 0600, written
    atomically; returns the path."""
    data = {"endpoints": list(endpoints),
            "users": {u: users[u] for u in (UI_USER, VIEWER) if u in users}}
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(data, f, indent=1)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if tmp.exists():
            tmp.unlink()
        raise
    return path


def read_credentials(path: Path | str, user: str) -> tuple[str, str, list[str]]:
    """(user, password, endpoints) from a credentials file: ``user`` if present, else the
    other one of ``tui``/``viewer``; :class:`BusConfigError` in one line otherwise."""
    p = Path(path)
    try:
        data = json.loads(p.read_text())
        users = data["users"]
        endpoints = [str(e) for e in data.get("endpoints", [])]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise BusConfigError(f"--credentials {p}: unreadable credentials file "
                             f"({type(exc).__name__}: {exc})") from None
    if not isinstance(users, dict):
        raise BusConfigError(f"--credentials {p}: 'users' must be an object")
    for name in (user, UI_USER, VIEWER):
        if isinstance(users.get(name), str) and users[name]:
            return name, users[name], endpoints
    raise BusConfigError(f"--credentials {p}: no {user!r} user in it")


def credentials_from_env(explicit: Path | str | None) -> Path | None:
    """``--credentials`` if given, else ``$QLAP_CREDENTIALS`` if set."""
    if explicit is not None:
        return Path(explicit)
    env = os.environ.get(ENV)
    return Path(env) if env else None
