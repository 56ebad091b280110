"""Line timing on a pty: reply byte spacing, reply start delay, and the share of good requests answered.

For each baud rate, ``c20sim serve --pty --line-timing --baud B`` runs as a
child process (the real CLI, on the loop it picks). A master opens the pty
raw and sends well-formed, well-spaced requests (a read of 2103H, the next
one t3.5 after the previous reply's last byte, or after a timeout); it stamps
each reply byte with ``time.perf_counter`` as it becomes readable, in a
``select`` loop of its own, at real-time priority where allowed (the master is
the instrument: an ordinary thread's late wake-ups measured as the server's).
It reports:

- per-byte spacing of reply bytes (median, p5, p95), against the ideal of one
  character time (10 bits at 8N1);
- start delay, from the request's write to the reply's first byte, against
  the ideal of t3.5 + the profile's turnaround (the request is written to the
  pty at once, so its last byte "ends" at the write);
- the share of requests answered with the right reply;
- t1.5 judged: the same request written byte by byte at the line's pace (the
  master sleeps between bytes and spins the last 0.15 ms, so that the pty's
  kernel worker can pass each byte on: see docs/line-timing.md) with one
  silence inside it, ``--gap-trials`` times each: 1.28 x t1.5 (1.0 ms at
  19200), which the drive discards, and 0.64 x t1.5, which it answers;
- t3.5 judged the same way: two garbage bytes, a silence, the request, written
  at the line's pace: 0.9 x t3.5 of silence leaves one spoilt frame (no
  reply), 1.1 x t3.5 splits the request off (answered). The tests
  (tests/integration/test_line_timing.py) assert only what load cannot
  break; these fine figures are recorded here.

``--load`` runs every baud again with load on the machine: one CPU burner per
core, and an RTU-over-TCP client polling the same server as fast as it answers
(the soak's kind of traffic, in the server's own event loop).

    .venv/bin/python bench/bench_line_timing.py --requests 2000 --gap-trials 200
    .venv/bin/python bench/bench_line_timing.py --requests 2000 --gap-trials 200 --load
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
import threading
import time
import tty
from dataclasses import dataclass
from pathlib import Path

from c20sim.drive.profile import load_profile
from c20sim.wire.protocol import ReadRequest, ReadResponse, char_time, crc_ok, encode, expected_length, silence_times

BAUDS = (1200, 9600, 19200, 57600)
REQUEST = encode(ReadRequest(1, 0x2103, 1))
REPLY = encode(ReadResponse(1, (0x0020,)))  # 2103H: the drive ID


#: The silences inside a request for the t1.5 trials, in t1.5: over it (discarded), under it (answered).
GAP_OVER = 1.28
GAP_UNDER = 0.64
#: The silences between garbage and a request for the t3.5 trials, in t3.5: under it (joined), over it (split).
SILENCE_JOINED = 0.9
SILENCE_SPLIT = 1.1
GARBAGE = b"\xff\x00"  # FF: a reserved address, so a spoilt frame gets silence
#: The master sleeps until this long before a byte's time and spins the rest (seconds).
SPIN = 0.00015
#: The master's SCHED_FIFO priority where allowed: above the simulator's timing threads (10), so that the
#: instrument is not held up by what it measures.
MASTER_PRIORITY = 20


@dataclass
class Result:
    baud: int
    requests: int
    answered: int
    spacing_ms: list[float]
    start_ms: list[float]
    gap_trials: int = 0
    over_answered: int = 0  #: requests with a silence of GAP_OVER x t1.5 inside that were answered (should be 0)
    under_answered: int = 0  #: the same with GAP_UNDER x t1.5 (should be all)
    joined_answered: int = 0  #: garbage, SILENCE_JOINED x t3.5, a request: answered (should be none)
    split_answered: int = 0  #: the same with SILENCE_SPLIT x t3.5 (should be all)


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, max(0, round(q / 100 * (len(ordered) - 1))))]


def start_server(baud: int, extra: list[str]) -> tuple[subprocess.Popen[bytes], dict[str, object]]:
    ready = Path(tempfile.mkdtemp()) / "ready.json"
    cmd = [sys.executable, "-m", "c20sim", "serve", "--pty", "--line-timing", "--baud", str(baud)]
    cmd.append("--no-bus-timing")  # the --load client polls as fast as the server answers, as before issue 27
    cmd += [*extra, "--ready-file", str(ready)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 20
    while not ready.exists():
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            raise RuntimeError(f"server did not start: {proc.stderr.read().decode() if proc.stderr else ''}")
        time.sleep(0.05)
    return proc, json.loads(ready.read_text())


def receive(fd: int, until: float) -> tuple[bytes, list[float]]:
    """One reply (as far as it came before ``until``), with each byte's arrival on perf_counter."""
    stamps: list[float] = []
    data = b""
    while True:
        left = until - time.perf_counter()
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
    return data, stamps


def drain(fd: int) -> None:
    with contextlib.suppress(BlockingIOError):
        while os.read(fd, 4096):  # nothing stale from a late reply
            pass


def pause(until: float) -> None:
    while time.perf_counter() < until:
        time.sleep(max(0.0, until - time.perf_counter()))


def wait_until(due: float) -> None:
    left = due - time.perf_counter() - SPIN
    if left > 0:
        time.sleep(left)
    while time.perf_counter() < due:
        pass


def send_paced(fd: int, data: bytes, char: float, gap_before: int, gap: float) -> None:
    """``data`` a byte at a time, each when its last bit would arrive on the line, ``gap`` of silence before byte
    ``gap_before``; from when the previous byte really went, so a late master lengthens a gap, never shortens it."""
    t = time.perf_counter()
    for i in range(len(data)):
        if i:
            wait_until(t + char + (gap if i == gap_before else 0.0))
        os.write(fd, data[i : i + 1])
        t = time.perf_counter()


def measure(pty: str, baud: int, requests: int, turnaround: float, gap_trials: int) -> Result:
    char = char_time(baud)
    t15, t35 = silence_times(baud)
    timeout = t35 + turnaround + len(REPLY) * char + 0.2
    fd = os.open(pty, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    tty.setraw(fd)
    result = Result(baud, requests, 0, [], [], gap_trials)
    instrument_priority(True)
    try:
        for _ in range(requests):
            drain(fd)
            sent = time.perf_counter()
            os.write(fd, REQUEST)
            data, stamps = receive(fd, sent + timeout)
            if data == REPLY and crc_ok(data):
                result.answered += 1
                result.start_ms.append((stamps[0] - sent) * 1000)
                result.spacing_ms += [(b - a) * 1000 for a, b in itertools.pairwise(stamps)]
            # The next request after t3.5 of silence from the reply's last byte (or the timeout).
            pause((stamps[-1] if stamps else time.perf_counter()) + t35 * 1.5)
        for _ in range(gap_trials):
            for factor in (GAP_OVER, GAP_UNDER):
                drain(fd)
                send_paced(fd, REQUEST, char, 4, factor * t15)
                data, stamps = receive(fd, time.perf_counter() + timeout)
                if data == REPLY:
                    if factor == GAP_OVER:
                        result.over_answered += 1
                    else:
                        result.under_answered += 1
                pause((stamps[-1] if stamps else time.perf_counter()) + t35 * 1.5)
            for factor in (SILENCE_JOINED, SILENCE_SPLIT):
                drain(fd)
                send_paced(fd, GARBAGE + REQUEST, char, len(GARBAGE), factor * t35)
                data, stamps = receive(fd, time.perf_counter() + timeout)
                if data == REPLY:
                    if factor == SILENCE_JOINED:
                        result.joined_answered += 1
                    else:
                        result.split_answered += 1
                pause((stamps[-1] if stamps else time.perf_counter()) + t35 * 1.5)
    finally:
        instrument_priority(False)  # else the next baud's server and load helpers would inherit it
        os.close(fd)
    return result


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


def run(baud: int, requests: int, load: bool, turnaround: float, gap_trials: int) -> Result:
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
        return measure(str(addresses["pty"]), baud, requests, turnaround, gap_trials)
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
    n = result.gap_trials
    gaps = (
        f"{result.over_answered}/{n} | {result.under_answered}/{n} | {result.joined_answered}/{n} | "
        f"{result.split_answered}/{n} |"
        if n
        else "- | - | - | - |"
    )
    if not result.spacing_ms:
        return (
            f"| {result.baud:>5} | {char:.3f} | - | - | - | - | {ideal_start:.3f} / {earliest:.3f} | - | - | "
            f"{share:.2f} % ({result.answered}/{result.requests}) | {gaps}"
        )
    sp, st = result.spacing_ms, result.start_ms
    within = sum(abs(s - char) <= 0.1 * char for s in sp)
    return (
        f"| {result.baud:>5} | {char:.3f} | {statistics.median(sp):.3f} | {percentile(sp, 5):.3f} | "
        f"{percentile(sp, 95):.3f} | {100.0 * within / len(sp):.1f} % | {ideal_start:.3f} / {earliest:.3f} | "
        f"{statistics.median(st):.3f} | {percentile(st, 5):.3f}-{percentile(st, 95):.3f} | "
        f"{share:.2f} % ({result.answered}/{result.requests}) | {gaps}"
    )


def instrument_priority(on: bool) -> bool:
    """SCHED_FIFO at :data:`MASTER_PRIORITY` for this thread where allowed (``on``), or back to ordinary.

    The master is the instrument.

    An ordinary thread's wake-up for a reply byte is late by up to a few hundred microseconds on this kind of
    machine, which measured as the simulator's spacing (80-89 % of intervals within +-0.1 character at 19200,
    against 95-96 % with a real-time master, the simulator unchanged). The master sleeps between the bytes it
    sends, so the pty's kernel worker still gets its CPU.
    """
    policy, priority = (os.SCHED_FIFO, MASTER_PRIORITY) if on else (os.SCHED_OTHER, 0)
    try:
        os.sched_setscheduler(threading.get_native_id(), policy, os.sched_param(priority))
    except (OSError, AttributeError):
        return False
    return True


def realtime_allowed() -> bool:
    """Whether this process may use SCHED_FIFO, as the server's timing threads ask (tried on a thread of its own)."""
    allowed: list[bool] = []

    def attempt() -> None:
        try:
            os.sched_setscheduler(threading.get_native_id(), os.SCHED_FIFO, os.sched_param(10))
        except (OSError, AttributeError):
            allowed.append(False)
        else:
            allowed.append(True)

    thread = threading.Thread(target=attempt)
    thread.start()
    thread.join()
    return allowed[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--requests", type=int, default=1000, help="requests per baud rate (default 1000)")
    parser.add_argument("--bauds", default=",".join(map(str, BAUDS)), help="comma-separated baud rates")
    parser.add_argument("--load", action="store_true", help="with CPU burners and an RTU-over-TCP poller")
    parser.add_argument(
        "--gap-trials", type=int, default=200, help="t1.5 and t3.5 trials per silence and baud (default 200)"
    )
    args = parser.parse_args()
    turnaround = load_profile().protocol.turnaround_ms / 1000
    print(f"line timing on a pty, {args.requests} requests per baud, {'under load' if args.load else 'idle'}")
    print(
        f"cpus: {os.cpu_count()}, python {sys.version.split()[0]}, turnaround {turnaround * 1000:g} ms (default profile)"
    )
    allowed = "allowed" if realtime_allowed() else "not allowed (the master and the server run at ordinary priority)"
    print(f"real-time scheduling (SCHED_FIFO) for the server's timing threads and the master: {allowed}")
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())} (other work on the machine included)")
    print()
    print(
        "| baud | ideal spacing ms | median | p5 | p95 | within +-0.1 char | ideal start ms (t3.5 + turnaround / "
        "earliest the framing allows) | "
        f"start median | start p5-p95 | answered | {GAP_OVER} x t1.5 gap answered (drive: none) | "
        f"{GAP_UNDER} x t1.5 gap answered (drive: all) | garbage, {SILENCE_JOINED} x t3.5, request: answered "
        f"(drive: none) | garbage, {SILENCE_SPLIT} x t3.5, request: answered (drive: all) |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for baud in (int(b) for b in args.bauds.split(",")):
        result = run(baud, args.requests, args.load, turnaround, args.gap_trials)
        print(report(result, turnaround), flush=True)
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
