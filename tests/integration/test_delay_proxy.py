"""The remote-database benchmark's delaying proxy (bench/delayproxy.py): what goes through it
comes out unchanged, both ways, and each way later by at least the delay; chunks queued behind
one another are not delayed once per chunk before them."""

from __future__ import annotations

import os
import socket
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

BENCH = Path(__file__).resolve().parents[2] / "bench"


@pytest.fixture(scope="module")
def delayproxy() -> Iterator[Any]:
    sys.path.insert(0, str(BENCH))
    try:
        import delayproxy

        yield delayproxy
    finally:
        sys.path.remove(str(BENCH))
        sys.modules.pop("delayproxy", None)


@pytest.fixture
def echo() -> Iterator[tuple[str, int]]:
    """A server on a free port that sends back whatever each connection sends it."""
    server = socket.create_server(("127.0.0.1", 0))

    def serve(conn: socket.socket) -> None:
        with conn:
            while data := conn.recv(65536):
                conn.sendall(data)

    def accept() -> None:
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            threading.Thread(target=serve, args=(conn,), daemon=True).start()

    threading.Thread(target=accept, daemon=True).start()
    try:
        yield server.getsockname()
    finally:
        server.close()


def _exchange(port: int, payload: bytes) -> tuple[bytes, float]:
    """Send ``payload`` through the proxy to the echo server; what came back, and how long."""
    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        began = time.perf_counter()
        sender = threading.Thread(target=sock.sendall, args=(payload,))
        sender.start()
        got = bytearray()
        while len(got) < len(payload):
            chunk = sock.recv(65536)
            assert chunk, "the proxy closed the connection early"
            got += chunk
        took = time.perf_counter() - began
        sender.join()
    return bytes(got), took


@pytest.mark.parametrize("delay_ms", [0.0, 30.0])
def test_bytes_pass_unchanged_both_ways(
    delayproxy: Any, echo: tuple[str, int], delay_ms: float
) -> None:
    payload = os.urandom(300_000)  # many chunks, in both directions
    with delayproxy.DelayProxy(echo, delay_ms) as port:
        got, _ = _exchange(port, payload)
    assert got == payload


def test_each_way_is_delayed(delayproxy: Any, echo: tuple[str, int]) -> None:
    with delayproxy.DelayProxy(echo, 40.0) as port:
        got, took = _exchange(port, b"ping")
    assert got == b"ping"
    assert took >= 0.080  # 40 ms there and 40 ms back, at the least


def test_every_chunk_is_delayed_from_its_arrival(delayproxy: Any, echo: tuple[str, int]) -> None:
    """Each chunk carries the kernel's arrival stamp: the delay is counted from it, not from
    the read (a chunk read late would be delayed by its wait in the socket as well)."""
    proxy = delayproxy.DelayProxy(echo, 5.0)
    with proxy as port:
        got, _ = _exchange(port, os.urandom(200_000))
    assert len(got) == 200_000
    assert proxy.chunks >= 2  # at least one each way
    assert proxy.unstamped == 0


def test_chunks_in_flight_are_delayed_once(delayproxy: Any, echo: tuple[str, int]) -> None:
    """Ten chunks sent back to back arrive about one round trip later, not ten: the delay is
    counted from each chunk's arrival, not after the chunk before it was sent."""
    delay_ms = 100.0
    with (
        delayproxy.DelayProxy(echo, delay_ms) as port,
        socket.create_connection(("127.0.0.1", port), timeout=10) as sock,
    ):
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        began = time.perf_counter()
        for i in range(10):
            sock.sendall(bytes([i]) * 10)
            time.sleep(0.005)
        got = bytearray()
        while len(got) < 100:
            got += sock.recv(1000)
        took = time.perf_counter() - began
    assert bytes(got) == b"".join(bytes([i]) * 10 for i in range(10))
    assert took >= 2 * delay_ms / 1000
    assert took < 10 * delay_ms / 1000  # serial delays would take 2 s: ten times this bound
