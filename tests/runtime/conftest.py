"""Fixtures: real Zenoh sessions (embedded, or a router and clients on loopback), always closed."""

from __future__ import annotations

import socket
from collections.abc import Iterator

import pytest
import zenoh

from qlap_runtime.bus import client_config, embedded_config, router_config


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def run_id() -> str:
    return "test-run"


@pytest.fixture
def embedded() -> Iterator[zenoh.Session]:
    with zenoh.open(embedded_config()) as session:
        yield session


@pytest.fixture
def router_endpoint() -> Iterator[str]:
    """A router on a free loopback port (no auth); yields its endpoint."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with zenoh.open(router_config([endpoint])):
        yield endpoint


@pytest.fixture
def two_clients(router_endpoint: str) -> Iterator[tuple[zenoh.Session, zenoh.Session]]:
    with zenoh.open(client_config(router_endpoint)) as a, \
            zenoh.open(client_config(router_endpoint)) as b:
        yield a, b
