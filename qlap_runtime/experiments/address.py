"""``--address`` of ``qlap experiment --engine ray``: checked before Ray sees it.

Ray's ``ray.init(address=...)`` takes ``HOST:PORT`` (a cluster's GCS, ``ray start --head``'s
port, 6379 by default), ``ray://HOST:PORT`` (the Ray Client server of a cluster, 10001 by
default; needs ``ray[client]``), ``auto`` (the cluster last started on this machine with
``ray start``, or ``RAY_ADDRESS``) and ``local`` (a new Ray on this machine). Ray raises a bare
``ValueError`` for a malformed address and, for a cluster that does not answer, retries its GCS
for minutes with a warning every few seconds. So :func:`ray_address` checks the form (an
argparse type: a one-line error naming the value, exit status 2) and :func:`check_reachable`
opens a TCP connection to the cluster's port with a short timeout before ``ray.init`` is
called, and waits as briefly for an answer to gRPC's opening bytes (a one-line
:class:`RayUnreachable`, exit status 1).

Kept free of heavy imports: the ``qlap`` parser uses :func:`ray_address`.
"""

from __future__ import annotations

import argparse
import ipaddress
import os
import re
import socket
from pathlib import Path

from ..errors import CliError
from .spec import ExperimentError

__all__ = ["CONNECT_TIMEOUT_S", "RayUnreachable", "check_reachable", "host_port",
           "parse_ray_address", "ray_address"]

CONNECT_TIMEOUT_S = 5.0
"""How long :func:`check_reachable` waits for the cluster's port to accept a connection."""

FORMS = "HOST:PORT, ray://HOST:PORT, auto or local"
_LABEL = r"[A-Za-z0-9_](?:[A-Za-z0-9_-]*[A-Za-z0-9_])?"
_HOSTNAME = re.compile(rf"{_LABEL}(?:\.{_LABEL})*\.?")
_CLIENT = "ray://"
_H2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])
"""HTTP/2's client connection preface and an empty SETTINGS frame (RFC 9113 §3.4): what a
gRPC client sends first, and what a gRPC server (Ray's GCS, its Ray Client server) answers."""


class RayUnreachable(CliError):
    """The Ray cluster of ``--address`` cannot be reached (or found): one line, exit 1."""

    def __init__(self, message: str) -> None:
        super().__init__(message, code=1)


def host_port(address: str) -> tuple[str, int] | None:
    """``HOST:PORT`` (``ray://`` removed) as (host, port), ``[v6]:PORT`` unbracketed; None for
    ``auto``/``local``. Raises ValueError (saying what is wrong) for anything else."""
    rest = address.removeprefix(_CLIENT)
    if address in ("auto", "local"):
        return None
    host, sep, port = rest.rpartition(":")
    if not sep or not host:
        raise ValueError("no HOST:PORT")
    if not re.fullmatch(r"[0-9]{1,5}", port) or not 1 <= int(port) <= 65535:
        raise ValueError(f"port {port!r} is not an integer 1-65535")
    if host.startswith("[") and host.endswith("]"):
        try:
            ipaddress.IPv6Address(host[1:-1])
        except ValueError:
            raise ValueError(f"host {host!r} is not an IPv6 address") from None
        return host[1:-1], int(port)
    if not _HOSTNAME.fullmatch(host):
        raise ValueError(f"host {host!r} is not a host name or IP address"
                         + (" (an IPv6 address goes in brackets: [::1]:6379)"
                            if ":" in host else ""))
    return host, int(port)


def parse_ray_address(text: str) -> str | None:
    """The address to give ``ray.init`` for ``--address TEXT``: None for ``local`` (start a
    Ray on this machine, as without ``--address``), else TEXT stripped. Raises
    :class:`ExperimentError` naming TEXT when it is none of the forms Ray takes."""
    address = text.strip()
    try:
        host_port(address)
    except ValueError as exc:
        raise ExperimentError(f"--address: expected {FORMS}, got {text!r} ({exc})") from None
    return None if address == "local" else address


def ray_address(text: str) -> str:
    """argparse type of ``--address``: TEXT stripped, or a one-line error naming it."""
    try:
        parse_ray_address(text)
    except ExperimentError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("--address: ")) from None
    return text.strip()


CURRENT_CLUSTER = Path("/tmp/ray/ray_current_cluster")
"""Where ``ray start --head`` writes the address of the cluster it started (Ray's default
temporary directory), which ``auto`` reads as Ray does."""


def _resolve_auto() -> str:
    """``auto`` as Ray resolves it: ``RAY_ADDRESS``, else the cluster last started on this
    machine with ``ray start`` (:data:`CURRENT_CLUSTER`)."""
    env = os.environ.get("RAY_ADDRESS", "").strip()
    if env and env != "auto":
        return env
    try:
        found = CURRENT_CLUSTER.read_text().strip()
    except OSError:
        found = ""
    if not found:
        raise RayUnreachable("--address auto: no running Ray cluster found (RAY_ADDRESS is "
                             f"not set and {CURRENT_CLUSTER} names none)")
    return found


def check_reachable(address: str, timeout: float = CONNECT_TIMEOUT_S) -> str:
    """Check that the cluster at ``address`` (a :func:`parse_ray_address` result, not None)
    accepts a TCP connection within ``timeout`` seconds, and return the address to give
    ``ray.init`` (``auto`` resolved to the cluster's HOST:PORT). Raises
    :class:`RayUnreachable` (one line, naming the address) when it does not."""
    shown = address
    if address == "auto":
        address = _resolve_auto()
        if address == "auto":
            return address
        shown = f"{address} (--address auto)"
    try:
        hp = host_port(address)
    except ValueError as exc:
        raise ExperimentError(f"--address: expected {FORMS}, got {address!r} ({exc})"
                              ) from None
    if hp is None:
        return address
    try:
        conn = socket.create_connection(hp, timeout=timeout)
    except TimeoutError:
        raise RayUnreachable(f"cannot reach the Ray cluster at {shown} (no answer within "
                             f"{timeout:g} s)") from None
    except socket.gaierror as exc:
        raise RayUnreachable(f"cannot reach the Ray cluster at {shown} (unknown host "
                             f"{hp[0]!r}: {exc.strerror or exc})") from None
    except OSError as exc:
        reason = exc.strerror or " ".join(str(exc).split()) or type(exc).__name__
        raise RayUnreachable(f"cannot reach the Ray cluster at {shown} ({reason}; is "
                             f"`ray start --head` running there?)") from None
    with conn:
        try:                # a GCS (gRPC) answers a client's HTTP/2 preface at once; a port
            conn.sendall(_H2_PREFACE)   # that accepts and stays silent would keep ray.init
            conn.recv(1)                # retrying for minutes. Any answer, or a close, will do
        except TimeoutError:            # (a TLS server's alert, say): ray.init then decides.
            raise RayUnreachable(f"cannot reach the Ray cluster at {shown} (the port accepts "
                                 f"connections but nothing answered within {timeout:g} s; "
                                 "is it a Ray head's GCS port?)") from None
        except OSError:
            pass
    return address
