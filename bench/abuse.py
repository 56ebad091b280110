"""Abuse: attacks on ``c20sim serve``, bounded in time, while a well-behaved master polls.

``c20sim serve`` runs as a subprocess as a user starts it, on RTU over TCP,
Modbus TCP, a pty and the control API, with ``--log-frames /dev/stdout``
into a pipe nobody reads (the frame log's reader has stopped). A
well-behaved master, in a process of its own, polls 2100H over RTU over TCP
throughout, one request at a time, and records every reply time. The
attacks run one after the other, each for ``--seconds``:

- ``burst``: 5,000 read requests sent in one burst, then the connection
  closed, over and over, over RTU over TCP and Modbus TCP in turn;
- ``pty-burst``: the same through the pty, written by a master that then closes;
- ``never-reads``: 4 clients on each TCP protocol send requests as fast as
  the server takes them and never read a reply;
- ``http``: 1,100 HTTP requests left unfinished (headers never ended), plus
  text/plain and form POSTs that try to trip the drive;
- ``quiet``: no attack, for reference.

Then, the master stopped: 20 times a burst of 5,000 requests and close, and
at once a fresh client's first request, timed.

For each phase: the load held (requests sent by the attackers, connections
held), the server's RSS at its start and peak, and the master's polls asked,
answered, median and worst reply time. Exit 1 if a poll went unanswered.

    .venv/bin/python bench/abuse.py --seconds 10
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from multiprocessing.connection import Connection
from pathlib import Path

from _common import CTX, ROOT, RawRtuClient, ReplyError, machine, percentile, rss_kib

from c20sim.wire.protocol import ReadRequest, encode
from c20sim.wire.registers import Reg

POLL = encode(ReadRequest(1, Reg.STATUS1, 1))
BURST_READ = encode(ReadRequest(1, Reg.SPEED_SETPOINT, 1))
BURST = 5000


def mbap_read(transaction: int) -> bytes:
    pdu = struct.pack(">BHH", 3, Reg.SPEED_SETPOINT, 1)
    return struct.pack(">HHHB", transaction & 0xFFFF, 0, len(pdu) + 1, 1) + pdu


@dataclass
class Phase:
    name: str
    load: str = ""
    attack_requests: int = 0
    rss_start_kib: int = 0
    rss_peak_kib: int = 0
    asked: int = 0
    answered: int = 0
    median_ms: float = 0.0
    p99_ms: float = 0.0
    worst_ms: float = 0.0


# --- the well-behaved master, in a process of its own


def master_main(port: int, conn: Connection) -> None:
    """Poll until told to stop; on each "report" message send (asked, answered, reply times) and start over."""
    client = RawRtuClient("127.0.0.1", port, timeout=2.0)
    asked = answered = 0
    times: list[float] = []
    while True:
        if conn.poll():
            message = conn.recv()
            conn.send((asked, answered, times))
            asked = answered = 0
            times = []
            if message == "stop":
                client.close()
                return
        asked += 1
        start = time.perf_counter()
        try:
            client.transact(POLL)
            times.append(time.perf_counter() - start)
            answered += 1
        except (TimeoutError, ReplyError, OSError):
            with contextlib.suppress(OSError):
                client.reconnect()
        time.sleep(0.01)  # a poll every 10 ms or so, as a SCADA master does


# --- the attacks: each runs until ``stop`` and returns (requests sent, a word on the load)


def burst_close(ports: dict[str, int], stop: threading.Event) -> tuple[int, str]:
    sent = rounds = 0
    payloads = {"tcp": BURST_READ * BURST, "modbus_tcp": b"".join(mbap_read(i) for i in range(BURST))}
    while not stop.is_set():
        for protocol, payload in payloads.items():
            with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", ports[protocol])) as sock:
                sock.sendall(payload)
                sent += BURST
                rounds += 1
        stop.wait(0.2)
    return sent, f"{rounds} bursts of {BURST} requests, each connection closed at once"


def fresh_after_burst(ports: dict[str, int], trials: int = 20) -> tuple[list[float], int]:
    """A burst of 5,000 requests and close, then at once a fresh client: the time to its first answer."""
    times: list[float] = []
    unanswered = 0
    for i in range(trials):
        protocol = "tcp" if i % 2 == 0 else "modbus_tcp"
        payload = BURST_READ * BURST if protocol == "tcp" else b"".join(mbap_read(i) for i in range(BURST))
        with socket.create_connection(("127.0.0.1", ports[protocol])) as sock:
            sock.sendall(payload)
        start = time.perf_counter()
        client = RawRtuClient("127.0.0.1", ports["tcp"], timeout=2.0)
        try:
            client.transact(POLL)
            times.append(time.perf_counter() - start)
        except (TimeoutError, ReplyError, OSError):
            unanswered += 1
        finally:
            client.close()
        time.sleep(0.1)
    return times, unanswered


def pty_burst(pty: str, stop: threading.Event) -> tuple[int, str]:
    sent = rounds = 0
    while not stop.is_set():
        fd = os.open(pty, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            data = BURST_READ * BURST
            while data and not stop.is_set():
                try:
                    written = os.write(fd, data)
                except BlockingIOError:
                    break  # the pty is full: the server reads one request at a time; leave the rest
                sent += written // len(BURST_READ)
                data = data[written:]
        finally:
            os.close(fd)
        rounds += 1
        stop.wait(0.2)
    return sent, f"{rounds} pty masters wrote what the pty took of {BURST} requests and closed"


def never_reads(ports: dict[str, int], stop: threading.Event) -> tuple[int, str]:
    counts = [0] * 8

    def flood(index: int, port: int, payload: bytes) -> None:
        with socket.create_connection(("127.0.0.1", port)) as sock:
            sock.setblocking(False)
            chunk = payload * 512
            while not stop.is_set():
                try:
                    counts[index] += sock.send(chunk) // len(payload)
                except BlockingIOError:
                    stop.wait(0.01)
                except OSError:
                    return

    threads = []
    for i in range(8):
        protocol = "tcp" if i < 4 else "modbus_tcp"
        payload = POLL if protocol == "tcp" else mbap_read(1)
        threads.append(threading.Thread(target=flood, args=(i, ports[protocol], payload), daemon=True))
    for thread in threads:
        thread.start()
    stop.wait()
    for thread in threads:
        thread.join(5)
    return sum(
        counts
    ), "4 RTU-over-TCP and 4 Modbus TCP clients sending without reading (requests: what the kernel took)"


def http_attack(control: int, stop: threading.Event) -> tuple[int, str]:
    held: list[socket.socket] = []
    refused = 0
    for _ in range(1100):
        try:
            sock = socket.create_connection(("127.0.0.1", control), timeout=2)
            sock.sendall(b"GET /drives/1 HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")  # headers never ended
            held.append(sock)
        except OSError:
            refused += 1
    statuses: dict[int, int] = {}
    forms = 0
    while not stop.is_set():
        for content_type in ("text/plain", "application/x-www-form-urlencoded"):
            body = b'{"code": 16}'
            request = (
                f"POST /drives/1/fault HTTP/1.1\r\nHost: 127.0.0.1:{control}\r\nOrigin: null\r\n"
                f"Content-Type: {content_type}\r\nContent-Length: {len(body)}\r\nConnection: close\r\n\r\n"
            ).encode() + body
            try:
                with socket.create_connection(("127.0.0.1", control), timeout=2) as sock:
                    sock.sendall(request)
                    status = int(sock.recv(64).split(b" ", 2)[1])
            except (OSError, IndexError, ValueError):
                status = 0
            statuses[status] = statuses.get(status, 0) + 1
            forms += 1
        stop.wait(0.05)
    still_open = 0
    for sock in held:
        try:
            sock.setblocking(False)
            sock.recv(1)  # b"": closed by the server
        except BlockingIOError:
            still_open += 1  # open, and nothing said: held by the server
        except OSError:
            pass
        sock.close()
    answers = ", ".join(f"{n} x {s or 'no answer'}" for s, n in sorted(statuses.items()))
    load = f"1100 unfinished requests ({refused} refused, {still_open} still open at the end); forms: {answers}"
    return forms, load


def quiet(stop: threading.Event) -> tuple[int, str]:
    stop.wait()
    return 0, "none"


# --- the run


def serve(workdir: Path) -> tuple[subprocess.Popen[bytes], dict[str, str], int]:
    ready = workdir / "ready.json"
    read_end, write_end = os.pipe()  # the frame log's reader: never reads
    command = [sys.executable, "-m", "c20sim", "serve", "--tcp", "127.0.0.1:0", "--modbus-tcp", "127.0.0.1:0"]
    command.append("--no-bus-timing")  # the server's own limits, as recorded before bus timing (issue 27)
    command += ["--pty", "--control", "127.0.0.1:0", "--log-frames", "/dev/stdout", "--ready-file", str(ready)]
    proc = subprocess.Popen(command, stdout=write_end, stderr=subprocess.PIPE, cwd=ROOT)
    os.close(write_end)
    deadline = time.monotonic() + 20
    while not ready.exists():
        if proc.poll() is not None or time.monotonic() > deadline:
            raise SystemExit(f"c20sim serve did not start: {proc.stderr.read().decode() if proc.stderr else ''}")
        time.sleep(0.01)
    return proc, json.loads(ready.read_text()), read_end


def run_phase(
    name: str, attack: Callable[[threading.Event], tuple[int, str]], seconds: float, pid: int, master: Connection
) -> Phase:
    phase = Phase(name, rss_start_kib=rss_kib(pid))
    phase.rss_peak_kib = phase.rss_start_kib
    stop = threading.Event()
    result: list[tuple[int, str]] = []
    thread = threading.Thread(target=lambda: result.append(attack(stop)), daemon=True)
    master.send("report")  # start counting afresh
    master.recv()
    thread.start()
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        phase.rss_peak_kib = max(phase.rss_peak_kib, rss_kib(pid))
        time.sleep(0.1)
    master.send("report")
    asked, answered, times = master.recv()
    stop.set()
    thread.join(30)
    phase.attack_requests, phase.load = result[0] if result else (0, "the attack did not finish")
    phase.asked, phase.answered = asked, answered
    ordered = sorted(times)
    phase.median_ms = round(percentile(ordered, 50) * 1000, 2)
    phase.p99_ms = round(percentile(ordered, 99) * 1000, 2)
    phase.worst_ms = round(ordered[-1] * 1000, 2) if ordered else float("nan")
    return phase


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=10.0, help="length of each phase")
    parser.add_argument("--json", help="also write the results to this file")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        proc, info, log_reader = serve(Path(tmp))
        try:
            ports = {key: int(info[key].rsplit(":", 1)[1]) for key in ("tcp", "modbus_tcp")}
            control = int(info["control"].rsplit(":", 1)[1])
            parent, child = CTX.Pipe()
            master = CTX.Process(target=master_main, args=(ports["tcp"], child))
            master.start()
            phases = [
                run_phase("quiet", quiet, args.seconds, proc.pid, parent),
                run_phase("burst", lambda s: burst_close(ports, s), args.seconds, proc.pid, parent),
                run_phase("pty-burst", lambda s: pty_burst(info["pty"], s), args.seconds, proc.pid, parent),
                run_phase("never-reads", lambda s: never_reads(ports, s), args.seconds, proc.pid, parent),
                run_phase("http", lambda s: http_attack(control, s), args.seconds, proc.pid, parent),
            ]
            parent.send("stop")
            parent.recv()
            fresh, fresh_unanswered = fresh_after_burst(ports)
            master.join(10)
            started = time.monotonic()
            proc.terminate()
            proc.wait(10)
            stop_s = time.monotonic() - started
            err = proc.stderr.read().decode() if proc.stderr else ""
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            os.close(log_reader)
    print(f"abuse: {args.seconds:g} s per phase on {machine()}; frame log to a pipe nobody reads")
    print(
        f"{'phase':<12} {'asked':>6} {'answered':>8} {'median ms':>9} {'p99 ms':>8} {'worst ms':>8} "
        f"{'RSS start':>9} {'RSS peak':>9} {'attack reqs':>11}  load"
    )
    for p in phases:
        print(
            f"{p.name:<12} {p.asked:>6} {p.answered:>8} {p.median_ms:>9.2f} {p.p99_ms:>8.2f} {p.worst_ms:>8.2f} "
            f"{p.rss_start_kib // 1024:>7}Mi {p.rss_peak_kib // 1024:>7}Mi {p.attack_requests:>11}  {p.load}"
        )
    ordered = sorted(fresh)
    print(
        f"fresh client after a {BURST}-request burst and close, {len(fresh) + fresh_unanswered} trials: "
        f"{fresh_unanswered} unanswered, first answer median {percentile(ordered, 50) * 1000:.2f} ms, "
        f"worst {ordered[-1] * 1000 if ordered else float('nan'):.2f} ms"
    )
    tracebacks = err.count("Traceback")
    print(
        f"SIGTERM to exit: {stop_s:.2f} s, exit code {proc.returncode}; server stderr: {len(err.splitlines())} "
        f"lines, {tracebacks} tracebacks"
    )
    if args.json:
        Path(args.json).write_text(json.dumps([asdict(p) for p in phases], indent=1) + "\n")
    ok = all(p.asked == p.answered for p in phases) and tracebacks == 0 and proc.returncode == 0
    ok = ok and fresh_unanswered == 0
    print("PASS" if ok else "FAIL")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
