"""--address of `qlap experiment --engine ray`: a malformed one is a one-line error with exit
status 2 before Ray sees it, and a cluster that does not answer is a one-line error within
seconds (Ray itself raises a bare ValueError, or retries its GCS for minutes)."""

import re
import socket
import subprocess
import sys
import threading
import time

import pytest

from qlap_runtime.experiments.address import (
    RayUnreachable,
    check_reachable,
    parse_ray_address,
    ray_address,
)
from qlap_runtime.experiments.spec import ExperimentError


def qlap_experiment(*args: str, tmp_path, timeout: float = 30) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "qlap_runtime.cli", "experiment",
                           "core-tasks", "--engine", "ray", "--agents", "1", "--steps",
                           "10000", "--no-live", "--out", str(tmp_path / "out"), *args],
                          capture_output=True, text=True, timeout=timeout)


def closed_port() -> int:
    """A port of 127.0.0.1 that nothing listens on (bound, then released)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize(("text", "expected"), [
    ("127.0.0.1:6379", "127.0.0.1:6379"), ("head-node.example:6379", "head-node.example:6379"),
    (" head:1 ", "head:1"), ("[::1]:6379", "[::1]:6379"), ("ray://head:10001", "ray://head:10001"),
    ("auto", "auto"), ("local", None)])
def test_the_forms_ray_takes_are_accepted(text, expected):
    assert parse_ray_address(text) == expected
    assert ray_address(text) == text.strip()


@pytest.mark.parametrize("text", ["nope", "", ":6379", "head:", "head:0", "head:65536",
                                  "head:-1", "head:+5", "head:abc", "::1:6379", "[nope]:1",
                                  "a b:1", "ray://nope", "ray://auto", "http://head:8265"])
def test_a_malformed_address_is_refused_naming_it(text):
    with pytest.raises(ExperimentError, match=re.escape(repr(text))):
        parse_ray_address(text)


def test_a_malformed_address_is_one_line_with_exit_status_2(tmp_path):
    res = qlap_experiment("--address", "nope", tmp_path=tmp_path)
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr and res.stderr.count("\n") == 1
    assert res.stderr.startswith("qlap experiment: error: argument --address:")
    assert "'nope'" in res.stderr and res.stdout == ""


def test_an_unreachable_cluster_is_one_line_within_seconds(tmp_path):
    address = f"127.0.0.1:{closed_port()}"
    start = time.monotonic()
    res = qlap_experiment("--address", address, tmp_path=tmp_path)
    assert time.monotonic() - start < 20
    assert res.returncode == 1, res.stderr
    assert res.stderr == (f"qlap experiment: cannot reach the Ray cluster at {address} "
                          "(Connection refused; is `ray start --head` running there?)\n")
    assert res.stdout == "" and not (tmp_path / "out").exists()


def _listen(answer: bytes | None):
    """A listener on 127.0.0.1 that accepts, then sends ``answer`` (None: stays silent)."""
    server = socket.create_server(("127.0.0.1", 0))
    conns: list[socket.socket] = []

    def serve() -> None:
        try:
            conn, _ = server.accept()
        except OSError:
            return
        conns.append(conn)
        if answer is not None:
            conn.recv(64)
            conn.sendall(answer)

    threading.Thread(target=serve, daemon=True).start()
    return server, conns


def test_a_port_that_accepts_but_never_answers_is_unreachable_within_the_timeout():
    server, conns = _listen(None)
    address = f"127.0.0.1:{server.getsockname()[1]}"
    try:
        start = time.monotonic()
        with pytest.raises(RayUnreachable, match=f"cluster at {address} .*nothing answered "
                                                 "within 0.5 s") as err:
            check_reachable(address, timeout=0.5)
        assert time.monotonic() - start < 3 and err.value.code == 1
    finally:
        server.close()
        for c in conns:
            c.close()


def test_a_port_that_answers_is_given_to_ray():
    """A gRPC server answers the HTTP/2 preface with its SETTINGS frame."""
    server, conns = _listen(bytes([0, 0, 0, 4, 0, 0, 0, 0, 0]))
    address = f"127.0.0.1:{server.getsockname()[1]}"
    try:
        assert check_reachable(address, timeout=5) == address
    finally:
        server.close()
        for c in conns:
            c.close()


def test_the_ray_backend_checks_the_address_before_ray_starts():
    from qlap_runtime.experiments.engine import RayBackend

    with pytest.raises(ExperimentError, match="'nope'"):
        RayBackend(jobs=1, address="nope")
    pytest.importorskip("ray")
    address = f"127.0.0.1:{closed_port()}"
    with pytest.raises(RayUnreachable, match=f"cannot reach the Ray cluster at {address}"):
        RayBackend(jobs=1, address=address)
    import ray

    assert not ray.is_initialized()
