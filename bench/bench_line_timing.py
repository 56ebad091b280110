"""Line timing on a pty: reply byte spacing, reply start delay, and the share of good requests answered.

For each baud rate, ``c20sim serve --pty --line-timing --baud B`` runs as a
child process (the real CLI, on the loop it picks). A master opens the pty
raw and sends well-formed, well-spaced requests (a read of 2103H, the next
one t3.5 after the previous reply's last byte, or after a timeout); it stamps
each reply byte with ``time.perf_counter`` as it becomes readable, in a tight
``select`` loop of its own. It reports:

- per-byte spacing of reply bytes (median, p5, p95), against the ideal of one
  character time (10 bits at 8N1);
- start delay, from the request's write to the reply's first byte, against
  the ideal of t3.5 + the profile's turnaround (the request is written to the
  pty at once, so its last byte "ends" at the write);
- the share of requests answered with the right reply.

``--load`` runs every baud again with load on the machine: one CPU burner per
core, and an RTU-over-TCP client polling the same server as fast as it answers
(the soak's kind of traffic, in the server's own event loop).

    .venv/bin/python bench/bench_line_timing.py --requests 2000
    .venv/bin/python bench/bench_line_timing.py --requests 2000 --load
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import multiprocessing
import os
import select
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import tty
from dataclasses import dataclass
from pathlib import Path

from c20sim.profile import load_profile
from c20sim.protocol import ReadRequest, ReadResponse, char_time, crc_ok, encode, expected_length, silence_times

BAUDS = (1200, 9600, 19200, 57600)
REQUEST = encode(ReadRequest(1, 0x2103, 1))
REPLY = encode(ReadResponse(1, (0x0020,)))  # 2103H: the drive ID


@dataclass
class Result:
    baud: int
    requests: int
    answered: int
    spacing_ms: list[float]
    start_ms: list[float]


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, max(0, round(q / 100 * (len(ordered) - 1))))]


def start_server(baud: int, extra: list[str]) -> tuple[subprocess.Popen[bytes], dict[str, object]]:
    ready = Path(tempfile.mkdtemp()) / "ready.json"
    cmd = [sys.executable, "-m", "c20sim", "serve", "--pty", "--line-timing", "--baud", str(baud)]
    cmd += [*extra, "--ready-file", str(ready)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 20
    while not ready.exists():
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            raise RuntimeError(f"server did not start: {proc.stderr.read().decode() if proc.stderr else ''}")
        time.sleep(0.05)
    return proc, json.loads(ready.read_text())


def measure(pty: str, baud: int, requests: int, turnaround: float) -> Result:
    char = char_time(baud)
    _, t35 = silence_times(baud)
    timeout = t35 + turnaround + len(REPLY) * char + 0.2
    fd = os.open(pty, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    tty.setraw(fd)
    spacing: list[float] = []
    starts: list[float] = []
    answered = 0
    try:
        for _ in range(requests):
            with contextlib.suppress(BlockingIOError):
                while os.read(fd, 4096):  # nothing stale from a late reply
                    pass
            sent = time.perf_counter()
            os.write(fd, REQUEST)
            stamps: list[float] = []
            data = b""
            end = sent + timeout
            while True:
                left = end - time.perf_counter()
                if left <= 0:
                    break
                ready, _, _ = select.select([fd], [], [], left)
                now = time.perf_counter()
                if not ready:
                    break
                chunk = os.read(fd, 1)
                if not chunk:
                    break
                stamps.append(now)
                data += chunk
                want = expected_length(data, "response") if len(data) >= 3 else None
                if want is not None and len(data) >= want:
                    break
            if data == REPLY and crc_ok(data):
                answered += 1
                starts.append((stamps[0] - sent) * 1000)
                spacing += [(b - a) * 1000 for a, b in itertools.pairwise(stamps)]
            # The next request after t3.5 of silence from the reply's last byte (or the timeout).
            pause_until = (stamps[-1] if stamps else time.perf_counter()) + t35 * 1.5
            while time.perf_counter() < pause_until:
                time.sleep(max(0.0, pause_until - time.perf_counter()))
    finally:
        os.close(fd)
    return Result(baud, requests, answered, spacing, starts)


def burn(stop_at: float) -> None:
    while time.monotonic() < stop_at:
        pass


def tcp_poller(port: int, stop_at: float) -> None:
    with socket.create_connection(("127.0.0.1", port)) as sock:
        sock.settimeout(2.0)
        request = encode(ReadRequest(1, 0x2100, 1))
        while time.monotonic() < stop_at:
            sock.sendall(request)
            got = b""
            while len(got) < 7:
                chunk = sock.recv(64)
                if not chunk:
                    return
                got += chunk


def run(baud: int, requests: int, load: bool, turnaround: float) -> Result:
    extra = ["--tcp", "127.0.0.1:0"] if load else []
    proc, addresses = start_server(baud, extra)
    helpers: list[multiprocessing.Process] = []
    try:
        if load:
            stop_at = time.monotonic() + 3600
            tcp = addresses["tcp"]
            port = int(str(tcp).rsplit(":", 1)[1]) if not isinstance(tcp, dict) else int(tcp["port"])
            helpers = [
                multiprocessing.Process(target=burn, args=(stop_at,), daemon=True) for _ in range(os.cpu_count() or 1)
            ]
            helpers.append(multiprocessing.Process(target=tcp_poller, args=(port, stop_at), daemon=True))
            for helper in helpers:
                helper.start()
            time.sleep(0.5)
        return measure(str(addresses["pty"]), baud, requests, turnaround)
    finally:
        for helper in helpers:
            helper.kill()
        proc.terminate()
        proc.wait(10)


def report(result: Result, turnaround: float) -> str:
    char = char_time(result.baud) * 1000
    _, t35 = silence_times(result.baud)
    ideal_start = (t35 + turnaround) * 1000
    # The silence that ends a frame is known one character after t3.5: with a turnaround shorter than a
    # character (1200 baud), the earliest start is t3.5 + one character.
    earliest = (t35 + max(turnaround, char_time(result.baud))) * 1000
    share = 100.0 * result.answered / result.requests
    if not result.spacing_ms:
        return (
            f"| {result.baud:>5} | {char:.3f} | - | - | - | - | {ideal_start:.3f} / {earliest:.3f} | - | - | "
            f"{share:.2f} % ({result.answered}/{result.requests}) |"
        )
    sp, st = result.spacing_ms, result.start_ms
    within = sum(abs(s - char) <= 0.1 * char for s in sp)
    return (
        f"| {result.baud:>5} | {char:.3f} | {statistics.median(sp):.3f} | {percentile(sp, 5):.3f} | "
        f"{percentile(sp, 95):.3f} | {100.0 * within / len(sp):.1f} % | {ideal_start:.3f} / {earliest:.3f} | "
        f"{statistics.median(st):.3f} | {percentile(st, 5):.3f}-{percentile(st, 95):.3f} | "
        f"{share:.2f} % ({result.answered}/{result.requests}) |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--requests", type=int, default=1000, help="requests per baud rate (default 1000)")
    parser.add_argument("--bauds", default=",".join(map(str, BAUDS)), help="comma-separated baud rates")
    parser.add_argument("--load", action="store_true", help="with CPU burners and an RTU-over-TCP poller")
    args = parser.parse_args()
    turnaround = load_profile().protocol.turnaround_ms / 1000
    print(f"line timing on a pty, {args.requests} requests per baud, {'under load' if args.load else 'idle'}")
    print(
        f"cpus: {os.cpu_count()}, python {sys.version.split()[0]}, turnaround {turnaround * 1000:g} ms (default profile)"
    )
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())} (other work on the machine included)")
    print()
    print(
        "| baud | ideal spacing ms | median | p5 | p95 | within +-0.1 char | ideal start ms (t3.5 + turnaround / "
        "earliest the framing allows) | "
        "start median | start p5-p95 | answered |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for baud in (int(b) for b in args.bauds.split(",")):
        result = run(baud, args.requests, args.load, turnaround)
        print(report(result, turnaround), flush=True)
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
