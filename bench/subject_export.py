"""Benchmark of a person's export: time, size and the server's peak memory, by history length.

    .venv/bin/python bench/subject_export.py                          # 1,000 and 10,000 episodes
    .venv/bin/python bench/subject_export.py --episodes 2000,20000 --engine postgresql

For each length, one process builds a fresh database with one person of that many episodes
(through the services, as bench/console.py does), then ``attune serve`` (one worker, 127.0.0.1
only) starts on it, a staff key reads the person's profile once (warm-up), and the export
``GET /v1/users/big/export`` is read as a stream. It prints the time to the first byte and to
the last, the document's size, and the server's resident memory before the export and its peak
(Linux's VmHWM) after: an export streamed a page at a time keeps the peak about flat as the
history grows, where one built whole would grow with it. Every loop is bounded by the arguments.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import httpx
from console import USER, build  # bench/console.py, beside this file
from rich.console import Console
from rich.table import Table

from tests.support.live import LiveService, fresh_database

out = Console()


def _memory_kib(pid: int) -> dict[str, int]:
    """VmRSS and VmHWM of ``pid`` (Linux), in KiB."""
    found: dict[str, int] = {}
    with open(f"/proc/{pid}/status", encoding="ascii") as status:
        for line in status:
            name, _, value = line.partition(":")
            if name in ("VmRSS", "VmHWM"):
                found[name] = int(value.split()[0])
    return found


def measure(engine: str, episodes: int) -> dict[str, float]:
    with tempfile.TemporaryDirectory() as tmp, fresh_database(engine, Path(tmp)) as url:
        build(url, episodes, 0)
        with LiveService(url, log_path=Path(tmp) / "serve.log") as service:
            assert service.process is not None
            key = service.create_key("staff", name="bench")
            headers = {"Authorization": f"Bearer {key}"}
            with httpx.Client(base_url=service.url, timeout=600, headers=headers) as client:
                assert client.get(f"/v1/users/{USER}/profile").status_code == 200
                before = _memory_kib(service.process.pid)
                began = time.perf_counter()
                first = None
                size = 0
                body = bytearray()
                with client.stream("GET", f"/v1/users/{USER}/export") as r:
                    r.raise_for_status()
                    for chunk in r.iter_bytes():
                        if first is None:
                            first = time.perf_counter() - began
                        size += len(chunk)
                        body += chunk
                took = time.perf_counter() - began
                after = _memory_kib(service.process.pid)
            doc = json.loads(body)
            assert len(doc["episodes"]) == episodes, len(doc["episodes"])
    return {
        "episodes": episodes,
        "first_byte_s": first or 0.0,
        "total_s": took,
        "mb": size / 1e6,
        "rss_before_mib": before["VmRSS"] / 1024,
        "peak_before_mib": before["VmHWM"] / 1024,
        "peak_after_mib": after["VmHWM"] / 1024,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--engine", choices=("sqlite", "postgresql"), default="sqlite")
    parser.add_argument("--episodes", default="1000,10000", help="history lengths, comma-separated")
    parser.add_argument("--json", type=Path, help="also write the figures here")
    args = parser.parse_args()
    lengths = [int(n) for n in args.episodes.split(",")]
    rows = []
    for n in lengths:
        out.log(f"{args.engine}: a person with {n:,} episodes")
        rows.append(measure(args.engine, n))
        r = rows[-1]
        out.log(
            f"  {r['total_s']:.2f} s ({r['first_byte_s']:.3f} s to the first byte), "
            f"{r['mb']:.1f} MB, memory {r['rss_before_mib']:.0f} MiB before (peak so far "
            f"{r['peak_before_mib']:.0f} MiB), peak {r['peak_after_mib']:.0f} MiB"
        )
    table = Table(title=f"A person's export, {args.engine}, 1 worker")
    names = ("episodes", "time s", "first byte s", "MB", "RSS before MiB", "peak before MiB")
    for name in (*names, "peak after MiB"):
        table.add_column(name, justify="right")
    for r in rows:
        table.add_row(
            f"{r['episodes']:,}",
            f"{r['total_s']:.2f}",
            f"{r['first_byte_s']:.3f}",
            f"{r['mb']:.1f}",
            f"{r['rss_before_mib']:.0f}",
            f"{r['peak_before_mib']:.0f}",
            f"{r['peak_after_mib']:.0f}",
        )
    out.print(table)
    for r in rows:
        out.print(
            f"{r['episodes']:,} episodes: the export raised the peak by "
            f"{r['peak_after_mib'] - r['peak_before_mib']:.0f} MiB over what the profile's read "
            f"had reached ({r['mb']:.0f} MB sent)."
        )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2), encoding="utf-8")


if __name__ == "__main__":
    main()
