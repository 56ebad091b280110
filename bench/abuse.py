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
- ``reset-files``: ``POST /reset`` of a 3 GiB sparse file, a FIFO and a link
  to /dev/zero, over and over;
- ``held``: 256 keep-alive connections that asked once and hold on, renewed
  as the server closes them, while a legitimate HTTP client asks ``GET /time``
  every 50 ms on a connection of its own each time (its answers and worst
  time are in the load column);
- ``slow-body``: 64 POSTs whose bodies stop half-way, renewed as they are
  answered 408;
- ``stream-reset``: stream readers that stop reading and reset their
  connection while the server waits to send, one after the other;
- ``bad-auth``: requests with a non-UTF-8 ``Authorization`` header (the
  server has a token, from ``--control-token-file``);
- ``quiet``: no attack, for reference.

Then, the master stopped: 20 times a burst of 5,000 requests and close, and
at once a fresh client's first request, timed.

For each phase: the load held (requests sent by the attackers, connections
held), the server's RSS at its start and peak, and the master's polls asked,
answered, median and worst reply time (the worst is the figure each attack is
judged by: how long the wire went unanswered). Exit 1 if a poll went
unanswered, or the server's log has a traceback.

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


TOKEN = "abuse-bench-token"


def http_request(control: int, method: str, path: str, body: bytes = b"", headers: bytes = b"") -> tuple[int, bytes]:
    """One request with the token on a connection of its own; (status, body), (0, b"") if none came."""
    auth = b"" if b"Authorization" in headers else f"Authorization: Bearer {TOKEN}\r\n".encode()
    kind = b"Content-Type: application/json\r\n" if body else b""
    head = f"{method} {path} HTTP/1.1\r\nHost: 127.0.0.1:{control}\r\nContent-Length: {len(body)}\r\n"
    try:
        with socket.create_connection(("127.0.0.1", control), timeout=30) as sock:
            sock.sendall(head.encode() + auth + kind + headers + b"Connection: close\r\n\r\n" + body)
            data = b""
            while chunk := sock.recv(65536):
                data += chunk
        return int(data.split(b" ", 2)[1]), data.partition(b"\r\n\r\n")[2]
    except (OSError, IndexError, ValueError):
        return 0, b""


def reset_files(control: int, workdir: Path, stop: threading.Event) -> tuple[int, str]:
    sparse, fifo, zero = workdir / "sparse", workdir / "fifo", workdir / "zero"
    with open(sparse, "wb") as f:
        f.truncate(3 * 1024**3)
    if not fifo.exists():
        os.mkfifo(fifo)
    if not zero.exists():
        zero.symlink_to("/dev/zero")
    statuses: dict[int, int] = {}
    sent = 0
    while not stop.is_set():
        for path in (sparse, fifo, zero):
            status, _ = http_request(control, "POST", "/reset", json.dumps({"setup": str(path)}).encode())
            statuses[status] = statuses.get(status, 0) + 1
            sent += 1
        stop.wait(0.02)
    answers = ", ".join(f"{n} x {s or 'no answer'}" for s, n in sorted(statuses.items()))
    return sent, f"POST /reset of a 3 GiB sparse file, a FIFO, a link to /dev/zero: {answers}"


def held(control: int, stop: threading.Event) -> tuple[int, str]:
    holders: list[socket.socket] = []
    opened = 0
    request = f"GET /time HTTP/1.1\r\nHost: 127.0.0.1:{control}\r\nAuthorization: Bearer {TOKEN}\r\n\r\n"
    legit: list[float] = []
    legit_status: dict[int, int] = {}

    def legitimate() -> None:
        while not stop.is_set():
            start = time.perf_counter()
            status, _ = http_request(control, "GET", "/time")
            legit.append(time.perf_counter() - start)
            legit_status[status] = legit_status.get(status, 0) + 1
            stop.wait(0.05)

    client = threading.Thread(target=legitimate, daemon=True)
    client.start()
    while not stop.is_set():
        alive = []
        for sock in holders:  # those the server closed are opened again
            try:
                sock.setblocking(False)
                gone = sock.recv(65536) == b""
            except BlockingIOError:
                gone = False
            except OSError:
                gone = True
            if gone:
                sock.close()
            else:
                alive.append(sock)
        holders = alive
        while len(holders) < 256 and not stop.is_set():
            try:
                sock = socket.create_connection(("127.0.0.1", control), timeout=2)
                sock.sendall(request.encode())
                holders.append(sock)
                opened += 1
            except OSError:
                break
        stop.wait(0.2)
    client.join(30)
    for sock in holders:
        sock.close()
    ordered = sorted(legit)
    answers = ", ".join(f"{n} x {s or 'no answer'}" for s, n in sorted(legit_status.items()))
    worst = ordered[-1] * 1000 if ordered else float("nan")
    return opened, (
        f"256 keep-alive holders ({opened} opened in all); a legitimate client: {answers}, "
        f"median {percentile(ordered, 50) * 1000:.1f} ms, worst {worst:.1f} ms"
    )


def slow_body(control: int, stop: threading.Event) -> tuple[int, str]:
    held_now: list[socket.socket] = []
    sent = 0
    answered: dict[bytes, int] = {}
    head = (
        f"POST /time/advance HTTP/1.1\r\nHost: 127.0.0.1:{control}\r\nAuthorization: Bearer {TOKEN}\r\n"
        'Content-Type: application/json\r\nContent-Length: 100\r\n\r\n{"seconds": '
    ).encode()
    while not stop.is_set():
        alive = []
        for sock in held_now:
            try:
                sock.setblocking(False)
                data = sock.recv(65536)
                status = data[9:12] if data else b"closed"
                answered[status] = answered.get(status, 0) + 1
                sock.close()
            except BlockingIOError:
                alive.append(sock)
            except OSError:
                sock.close()
        held_now = alive
        while len(held_now) < 64:
            try:
                sock = socket.create_connection(("127.0.0.1", control), timeout=2)
                sock.sendall(head)
                held_now.append(sock)
                sent += 1
            except OSError:
                break
        stop.wait(0.2)
    for sock in held_now:
        sock.close()
    answers = ", ".join(f"{n} x {s.decode()}" for s, n in sorted(answered.items()))
    return sent, f"64 bodies that stop half-way held at a time ({sent} in all); answered: {answers or 'none yet'}"


def stream_reset(control: int, stop: threading.Event) -> tuple[int, str]:
    readers = 0
    while not stop.is_set():
        sock = socket.socket()
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        try:
            sock.settimeout(5)
            sock.connect(("127.0.0.1", control))
            key = "dGhlIHNhbXBsZSBub25jZQ=="
            sock.sendall(
                f"GET /stream?hz=50&token={TOKEN} HTTP/1.1\r\nHost: 127.0.0.1:{control}\r\n"
                "Upgrade: websocket\r\nConnection: Upgrade\r\n"
                f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n".encode()
            )
            stop.wait(1.5)  # unread: the server's sends pile up until it waits
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            readers += 1
        except OSError:
            pass
        finally:
            sock.close()
    return readers, f"{readers} stream readers that stopped reading, then reset their connection"


def bad_auth(control: int, stop: threading.Event) -> tuple[int, str]:
    statuses: dict[int, int] = {}
    sent = 0
    while not stop.is_set():
        status, _ = http_request(control, "GET", "/time", headers=b"Authorization: Bearer \xff\xfe\r\n")
        statuses[status] = statuses.get(status, 0) + 1
        sent += 1
        stop.wait(0.01)
    answers = ", ".join(f"{n} x {s or 'no answer'}" for s, n in sorted(statuses.items()))
    return sent, f"non-UTF-8 Authorization headers: {answers}"


def quiet(stop: threading.Event) -> tuple[int, str]:
    stop.wait()
    return 0, "none"


# --- the run


def serve(workdir: Path) -> tuple[subprocess.Popen[bytes], dict[str, str], int]:
    ready = workdir / "ready.json"
    read_end, write_end = os.pipe()  # the frame log's reader: never reads
    command = [sys.executable, "-m", "c20sim", "serve", "--tcp", "127.0.0.1:0", "--modbus-tcp", "127.0.0.1:0"]
    (workdir / "token").write_text(TOKEN + "\n")
    command.append("--no-bus-timing")  # the server's own limits, as recorded before bus timing (issue 27)
    command += ["--pty", "--control", "127.0.0.1:0", "--log-frames", "/dev/stdout", "--ready-file", str(ready)]
    command += ["--control-token-file", str(workdir / "token"), "--drives", ",".join(map(str, range(1, 33)))]
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
                run_phase("reset-files", lambda s: reset_files(control, Path(tmp), s), args.seconds, proc.pid, parent),
                run_phase("held", lambda s: held(control, s), args.seconds, proc.pid, parent),
                run_phase("slow-body", lambda s: slow_body(control, s), args.seconds, proc.pid, parent),
                run_phase("stream-reset", lambda s: stream_reset(control, s), args.seconds, proc.pid, parent),
                run_phase("bad-auth", lambda s: bad_auth(control, s), args.seconds, proc.pid, parent),
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
