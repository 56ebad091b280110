"""One line, many masters (issue 39): a polite master's reply times beside crowds and scrapers, and the line-timed
pty's back-to-back rate against the real line's.

``c20sim serve`` runs as a child process (the real CLI: bus timing on, as shipped). The polite master is a
blocking Modbus TCP client in this process on 127.0.0.1, reading 2100H every ``--interval`` seconds; each crowd
runs in a process of its own, from 127.0.0.2 (Linux routes all of 127/8 to loopback), so the line tells the two
apart by address as a gateway does, and the crowd's work costs the poller's process nothing:

- ``alone``: nothing else;
- ``1 pipelining client``: four reads in flight at all times;
- ``20 non-readers``: 20 connections that send reads and never read a reply;
- ``500 connections``: 500 connections each keeping four reads in flight (``--max-connections 600``);
- ``4 scrapers``: four threads scraping ``GET /metrics`` back to back, with 247 drives on the bus.

Each figure is the poller's p50 / p99 / max, in milliseconds and in transactions (one read's RS485 time at
19200 8N1 with the profile's 2 ms turnaround: 13.46 ms). Two peers sharing the line in turn give the poller at
worst the other's transaction on the line and then its own: two transactions.

Then the line-timed pty (``serve --pty --line-timing``): a master writes a read, reads the reply's 7 bytes and
writes the next at once, ``--reads`` times; its rate against the real line's for that master (request 8
characters, t3.5, the 2 ms turnaround, the reply's 7 characters: 11.64 ms at 19200).

    .venv/bin/python bench/bench_many_masters.py
"""

from __future__ import annotations

import argparse
import asyncio
import json
import multiprocessing
import os
import select
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
import tty
import urllib.request
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import machine, percentile

from c20sim.wire.protocol import ReadRequest, char_time, encode, silence_times, transaction_time
from c20sim.wire.registers import Reg

BAUD = 19200
TURNAROUND = 0.002
TRANSACTION = transaction_time(8, 7, BAUD, 10, TURNAROUND)
CROWD_HOST = "127.0.0.2"


def start(*args: str) -> tuple[subprocess.Popen[bytes], dict[str, str]]:
    ready = Path(tempfile.mkdtemp(prefix="c20sim-bench-")) / "ready.json"
    command = [sys.executable, "-m", "c20sim", "serve", *args, "--ready-file", str(ready)]
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60.0
    while not ready.exists():
        if proc.poll() is not None or time.monotonic() > deadline:
            raise RuntimeError("c20sim serve did not start")
        time.sleep(0.05)
    time.sleep(0.1)
    return proc, json.loads(ready.read_text())


def mbap_read(transaction: int) -> bytes:
    pdu = struct.pack(">BHH", 3, Reg.STATUS1, 1)
    return struct.pack(">HHHB", transaction & 0xFFFF, 0, len(pdu) + 1, 1) + pdu


def recv_exactly(sock: socket.socket, n: int) -> bytes:
    data = b""
    while len(data) < n:
        chunk = sock.recv(n - len(data))
        if not chunk:
            raise ConnectionError("closed")
        data += chunk
    return data


def poll(port: int, reads: int, interval: float) -> list[float]:
    """The polite master: one read every ``interval``; each read's time to its reply (seconds), sorted."""
    sock = socket.create_connection(("127.0.0.1", port), timeout=30.0)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    times = []
    try:
        for i in range(reads):
            began = time.perf_counter()
            sock.sendall(mbap_read(i))
            header = recv_exactly(sock, 7)
            recv_exactly(sock, struct.unpack_from(">H", header, 4)[0] - 1)
            times.append(time.perf_counter() - began)
            time.sleep(interval)
    finally:
        sock.close()
    return sorted(times)


# --- the crowds, each in a process of its own


async def _pipeliner(port: int) -> None:
    reader, writer = await asyncio.open_connection("127.0.0.1", port, local_addr=(CROWD_HOST, 0))
    transaction = 0
    while True:
        writer.write(b"".join(mbap_read(transaction + k) for k in range(4)))
        transaction += 4
        for _ in range(4):
            header = await reader.readexactly(7)
            await reader.readexactly(struct.unpack_from(">H", header, 4)[0] - 1)


async def _non_reader(port: int) -> None:
    _reader, writer = await asyncio.open_connection("127.0.0.1", port, local_addr=(CROWD_HOST, 0))
    transaction = 0
    while True:
        writer.write(b"".join(mbap_read(transaction + k) for k in range(64)))
        transaction += 64
        try:
            await asyncio.wait_for(writer.drain(), timeout=0.1)
        except TimeoutError:
            await asyncio.sleep(0.5)  # its buffers are full: the server reads no more of it


async def _crowd(kind: str, port: int) -> None:
    if kind == "1 pipelining client":
        tasks = [_pipeliner(port)]
    elif kind == "20 non-readers":
        tasks = [_non_reader(port) for _ in range(20)]
    else:
        tasks = [_pipeliner(port) for _ in range(500)]
    await asyncio.gather(*tasks, return_exceptions=True)


def crowd(kind: str, port: int, scraped: Any = None) -> None:
    if kind == "4 scrapers":
        threads = [threading.Thread(target=scrape, args=(port, scraped), daemon=True) for _ in range(4)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        return
    asyncio.run(_crowd(kind, port))


def scrape(url_port: int, scraped: Any) -> None:
    while True:
        with urllib.request.urlopen(f"http://127.0.0.1:{url_port}/metrics", timeout=30) as response:
            response.read()
        with scraped.get_lock():
            scraped.value += 1


def row(name: str, times: list[float]) -> str:
    p50, p99, top = (percentile(times, 50), percentile(times, 99), times[-1])
    cells = " | ".join(f"{v * 1000:.1f} ms ({v / TRANSACTION:.2f} tx)" for v in (p50, p99, top))
    return f"| {name} | {len(times)} | {cells} |"


def crowds(reads: int, interval: float, scrapers_only: bool = False) -> None:
    print("| beside | reads | p50 | p99 | max |\n|---|---:|---:|---:|---:|")
    if not scrapers_only:
        crowd_rows(reads, interval)
    scraper_rows(reads, interval)


def crowd_rows(reads: int, interval: float) -> None:
    proc, info = start("--modbus-tcp", "127.0.0.1:0", "--max-connections", "600")
    port = int(info["modbus_tcp"].rsplit(":", 1)[1])
    try:
        print(row("nothing (alone)", poll(port, reads, interval)), flush=True)
        for kind in ("1 pipelining client", "20 non-readers", "500 connections"):
            other = multiprocessing.Process(target=crowd, args=(kind, port), daemon=True)
            other.start()
            time.sleep(2.0)  # the crowd connects and fills its queues
            try:
                print(row(kind, poll(port, reads, interval)), flush=True)
            finally:
                other.kill()
                other.join()
            time.sleep(1.0)
    finally:
        proc.kill()
        proc.wait()


def scraper_rows(reads: int, interval: float) -> None:
    drives = ",".join(str(a) for a in range(1, 248))
    proc, info = start("--modbus-tcp", "127.0.0.1:0", "--metrics", "127.0.0.1:0", "--drives", drives)
    port = int(info["modbus_tcp"].rsplit(":", 1)[1])
    metrics_port = int(info["metrics"].split(":")[2].split("/")[0])
    try:
        print(row("nothing, 247 drives", poll(port, reads, interval)), flush=True)
        scraped = multiprocessing.Value("l", 0)
        other = multiprocessing.Process(target=crowd, args=("4 scrapers", metrics_port, scraped), daemon=True)
        other.start()
        time.sleep(2.0)
        try:
            began, before = time.perf_counter(), scraped.value
            times = poll(port, reads, interval)
            rate = (scraped.value - before) / (time.perf_counter() - began)
            print(row(f"4 scrapers back to back ({rate:.0f} answers/s), 247 drives", times), flush=True)
        finally:
            other.kill()
            other.join()
    finally:
        proc.kill()
        proc.wait()


def back_to_back(reads: int) -> None:
    proc, info = start("--pty", "--line-timing")
    fd = os.open(info["pty"], os.O_RDWR | os.O_NOCTTY)
    tty.setraw(fd)
    request = encode(ReadRequest(1, Reg.STATUS1, 1))
    times = []
    try:
        began = time.perf_counter()
        for _ in range(reads):
            sent = time.perf_counter()
            os.write(fd, request)
            got = b""
            while len(got) < 7:
                if not select.select([fd], [], [], 5.0)[0]:
                    raise RuntimeError("no reply in 5 s")
                got += os.read(fd, 7 - len(got))
            times.append(time.perf_counter() - sent)
        elapsed = time.perf_counter() - began
    finally:
        os.close(fd)
        proc.kill()
        proc.wait()
    char = char_time(BAUD, 10)
    line = 8 * char + silence_times(BAUD, 10)[1] + TURNAROUND + 7 * char
    rate, line_rate = reads / elapsed, 1.0 / line
    times.sort()
    print(
        f"line-timed pty, {reads} reads back to back at {BAUD}: {rate:.1f} reads/s; the real line {line_rate:.1f} "
        f"(write to the reply's last byte {line * 1000:.2f} ms); ratio {rate / line_rate:.3f}; "
        f"write to last byte p50 {percentile(times, 50) * 1000:.2f} ms, p99 {percentile(times, 99) * 1000:.2f} ms"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reads", type=int, default=200, help="the polite master's reads per crowd")
    parser.add_argument("--interval", type=float, default=0.05, help="seconds between its reads")
    parser.add_argument("--b2b", type=int, default=500, help="back-to-back reads on the line-timed pty")
    parser.add_argument("--only", choices=["crowds", "scrapers", "pty"], help="one part only")
    args = parser.parse_args()
    print(f"{machine()}; load average {os.getloadavg()[0]:.2f} at start; a transaction {TRANSACTION * 1000:.2f} ms\n")
    if args.only != "pty":
        crowds(args.reads, args.interval, scrapers_only=args.only == "scrapers")
        print()
    if args.only is None or args.only == "pty":
        back_to_back(args.b2b)
    print(f"\nload average {os.getloadavg()[0]:.2f} at the end")


if __name__ == "__main__":
    main()
