"""A TCP proxy that delays every chunk by a fixed time each way: a database one network hop away.

    python bench/delayproxy.py --listen 127.0.0.1:6543 --to 127.0.0.1:5432 --delay-ms 1

Loopback only. Each accepted connection gets a connection of its own to ``--to``; each direction
of it has one thread, which reads each chunk with the kernel's stamp of when it arrived
(``SO_TIMESTAMPNS``), sleeps until that time plus the delay, and sends it on. Chunks that arrive
while the thread sleeps wait in the socket with their own stamps, so each is delayed by the
delay from its own arrival, not by the delay times their number, and no connection or
direction waits for another. A thread per direction that wakes once per chunk, and no thread
that wakes another: the proxy shares the machine with what it measures (the benchmark prints
its CPU). With ``--delay-ms 0`` each chunk is sent on as it is read. The proxy stops by itself
after ``--max-seconds`` (default one hour), or on SIGTERM or SIGINT.

:class:`DelayProxy` is the same proxy for a Python program: ``with DelayProxy(target, 1.0) as
port:`` serves on a free port of 127.0.0.1 in threads of the caller's process.
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import socket
import struct
import sys
import threading
import time
from types import TracebackType

__all__ = ["DelayProxy", "parse_address"]

CHUNK = 65536


def parse_address(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit():
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {text!r}")
    return host, int(port)


# Linux's SO_TIMESTAMPNS (the cmsg type of its stamps is the same number); Python names neither.
_SO_TIMESTAMPNS = 35
_STAMP = struct.Struct("@qq")  # struct timespec: seconds, nanoseconds (CLOCK_REALTIME)
_ANCILLARY = socket.CMSG_SPACE(_STAMP.size)


class _Direction:
    """One direction of a proxied connection: chunks read from ``source``, sent to ``sink``
    ``delay_s`` after they arrived."""

    def __init__(self, source: socket.socket, sink: socket.socket, delay_s: float) -> None:
        self.source, self.sink, self.delay_s = source, sink, delay_s
        self.chunks = 0  # chunks delayed
        self.unstamped = 0  # of them, read without the kernel's stamp: delayed from the read

    def run(self) -> None:
        try:
            if self.delay_s <= 0:
                while data := self.source.recv(CHUNK):
                    self.sink.sendall(data)
                return
            while True:
                data, ancillary, _, _ = self.source.recvmsg(CHUNK, _ANCILLARY)
                if not data:
                    break
                arrived = None
                for level, kind, raw in ancillary:
                    if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS:
                        seconds, nanoseconds = _STAMP.unpack(raw[: _STAMP.size])
                        arrived = seconds + nanoseconds * 1e-9
                self.chunks += 1
                if arrived is None:
                    self.unstamped += 1
                    arrived = time.time()
                wait = arrived + self.delay_s - time.time()
                if wait > 0:
                    time.sleep(wait)  # Linux oversleeps by about 0.05 ms (its timer slack)
                self.sink.sendall(data)
        except OSError:
            pass
        finally:
            _shut(self.sink)


def _shut(sock: socket.socket) -> None:
    with contextlib.suppress(OSError):
        sock.shutdown(socket.SHUT_WR)


class DelayProxy:
    """The proxy on a free port of 127.0.0.1 (or ``listen``), in daemon threads of this process;
    ``with DelayProxy(target, delay_ms) as port:``."""

    def __init__(
        self, target: tuple[str, int], delay_ms: float, listen: tuple[str, int] | None = None
    ) -> None:
        self.target, self.delay_s = target, max(0.0, delay_ms) / 1000.0
        self.server = socket.create_server(listen or ("127.0.0.1", 0))
        if self.delay_s > 0:  # stamps from the first byte on: accepted sockets inherit it
            self.server.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
        self.port: int = self.server.getsockname()[1]
        self.connections = 0
        self._directions: list[_Direction] = []
        self._sockets: list[socket.socket] = []
        self._stopped = threading.Event()

    def serve_forever(self) -> None:
        self.server.settimeout(0.2)
        while not self._stopped.is_set():
            try:
                client, _ = self.server.accept()
            except TimeoutError:
                continue
            except OSError:
                break
            client.settimeout(None)
            try:
                upstream = self._connect()
            except OSError:
                client.close()
                continue
            upstream.settimeout(None)
            for sock in (client, upstream):
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self._sockets.append(sock)
            self.connections += 1
            for direction in (
                _Direction(client, upstream, self.delay_s),
                _Direction(upstream, client, self.delay_s),
            ):
                self._directions.append(direction)
                threading.Thread(target=direction.run, daemon=True).start()

    def _connect(self) -> socket.socket:
        """A connection to the target, stamping what arrives on it from the first byte on."""
        host, port = self.target
        family, kind, proto, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
        sock = socket.socket(family, kind, proto)
        try:
            if self.delay_s > 0:
                sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
            sock.settimeout(10)
            sock.connect(address)
        except OSError:
            sock.close()
            raise
        return sock

    @property
    def chunks(self) -> int:
        """Chunks delayed so far (none with ``delay_ms`` 0)."""
        return sum(d.chunks for d in self._directions)

    @property
    def unstamped(self) -> int:
        """Of them, those the kernel gave no arrival stamp: delayed from when they were read,
        later than the delay by however long they waited in the socket."""
        return sum(d.unstamped for d in self._directions)

    def stop(self) -> None:
        self._stopped.set()
        self.server.close()
        for sock in self._sockets:
            with contextlib.suppress(OSError):
                sock.close()

    def __enter__(self) -> int:
        threading.Thread(target=self.serve_forever, daemon=True).start()
        return self.port

    def __exit__(
        self,
        kind: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description="A TCP proxy that delays every chunk by --delay-ms each way (loopback only)."
    )
    parser.add_argument("--listen", type=parse_address, default=("127.0.0.1", 0))
    parser.add_argument("--to", type=parse_address, required=True, help="HOST:PORT to forward to")
    parser.add_argument("--delay-ms", type=float, default=1.0, help="delay each way (default 1)")
    parser.add_argument(
        "--max-seconds", type=float, default=3600.0, help="stop after this long (default 3600)"
    )
    args = parser.parse_args(argv)
    proxy = DelayProxy(args.to, args.delay_ms, args.listen)
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    threading.Thread(target=proxy.serve_forever, daemon=True).start()
    print(f"listening on 127.0.0.1:{proxy.port}", flush=True)
    stop.wait(args.max_seconds)
    proxy.stop()
    if proxy.delay_s > 0:
        print(
            f"{proxy.chunks} chunks delayed, {proxy.unstamped} of them without the kernel's "
            "arrival stamp (delayed from when they were read)",
            file=sys.stderr,
            flush=True,
        )
    sys.exit(0)


if __name__ == "__main__":
    main()
