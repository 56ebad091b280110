"""What a local client can send the control API: none of it stalls the wire, holds the API, or prints a traceback.

``c20sim serve --tcp --control`` as a subprocess, and raw sockets so that
each request is exactly the attack: 256 keep-alive connections held while a
legitimate client asks, connections refused at the cap (a 503 with a
sentence, not a bare reset), a body that never finishes, a client that leaves
mid-body, a stream reader that resets its connection, a non-UTF-8
``Authorization`` header, and ``POST /reset`` of a 3 GiB sparse file, a FIFO
and a link to /dev/zero. Meanwhile a Modbus master polls over RTU over TCP
and every poll must be answered; how fast is measured by
``bench/abuse.py`` (bench/RESULTS.md), not asserted here.
"""

from __future__ import annotations

import base64
import contextlib
import json
import os
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from c20sim.control.httpguard import GRACE, MAX_CONNECTIONS
from c20sim.wire.protocol import ReadRequest, encode
from c20sim.wire.registers import Reg
from tests.conftest import wait_for_ready_file

POLL = encode(ReadRequest(1, Reg.STATUS1, 1))


@dataclass
class Served:
    tcp: int
    control: int
    proc: subprocess.Popen[str]
    token: str | None = None
    err: str = ""

    @property
    def host(self) -> str:
        return f"127.0.0.1:{self.control}"


@pytest.fixture
def served(tmp_path: Path, request: pytest.FixtureRequest) -> Iterator[Served]:
    ready = tmp_path / "ready.json"
    options = getattr(request, "param", ())
    argv = [sys.executable, "-m", "c20sim", "serve", "--tcp", "127.0.0.1:0", "--control", "127.0.0.1:0"]
    argv += ["--ready-file", str(ready), *options]
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        info = wait_for_ready_file(ready, proc)
        server = Served(int(info["tcp"].rsplit(":", 1)[1]), int(info["control"].rsplit(":", 1)[1]), proc)
        server.token = info.get("token")
        yield server
        proc.send_signal(signal.SIGTERM)
        _out, server.err = proc.communicate(timeout=10)
        assert proc.returncode == 0, server.err
        assert "Traceback" not in server.err, server.err
        assert "bug while serving" not in server.err, server.err
        assert "Error handling request" not in server.err, server.err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@dataclass
class Poller:
    """A Modbus master polling 2100H over RTU over TCP in a thread, one request at a time."""

    port: int
    asked: int = 0
    answered: int = 0
    stop: threading.Event = field(default_factory=threading.Event)

    def run(self) -> None:
        with socket.create_connection(("127.0.0.1", self.port), timeout=10) as sock:
            while not self.stop.is_set():
                self.asked += 1
                sock.sendall(POLL)
                reply = b""
                with contextlib.suppress(TimeoutError):
                    while len(reply) < 7:
                        chunk = sock.recv(7 - len(reply))
                        if not chunk:
                            return
                        reply += chunk
                self.answered += reply[:3] == b"\x01\x03\x02"
                time.sleep(0.01)


@contextlib.contextmanager
def polling(served: Served) -> Iterator[Poller]:
    """A poller through the block: every poll it asked must have been answered (10 s each at most)."""
    poller = Poller(served.tcp)
    thread = threading.Thread(target=poller.run, daemon=True)
    thread.start()
    try:
        # the poller under way before the block: a loaded machine started its thread after a short block had ended
        deadline = time.monotonic() + 10
        while poller.asked == 0:
            assert time.monotonic() < deadline, "the poller never asked"
            time.sleep(0.01)
        yield poller
    finally:
        poller.stop.set()
        thread.join(15)
    assert poller.asked > 0 and poller.answered == poller.asked, (poller.answered, poller.asked)


def head_and_body(data: bytes) -> tuple[int, Any]:
    head, _, payload = data.partition(b"\r\n\r\n")
    status = int(head.split(b" ", 2)[1])
    return status, json.loads(payload) if payload else None


def read_response(sock: socket.socket) -> tuple[int, Any]:
    """One response on a keep-alive connection: by its Content-Length."""
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = sock.recv(65536)
        assert chunk, f"closed before a response: {data!r}"
        data += chunk
    head, _, rest = data.partition(b"\r\n\r\n")
    length = next(
        int(line.split(b":", 1)[1]) for line in head.split(b"\r\n") if line.lower().startswith(b"content-length:")
    )
    while len(rest) < length:
        chunk = sock.recv(65536)
        assert chunk
        rest += chunk
    return head_and_body(head + b"\r\n\r\n" + rest[:length])


def read_all(sock: socket.socket) -> bytes:
    data = b""
    while chunk := sock.recv(65536):
        data += chunk
    return data


def request(served: Served, method: str, path: str, body: bytes = b"", *, headers: bytes = b"") -> tuple[int, Any]:
    """One request on a connection of its own (Connection: close)."""
    extra = b"Content-Type: application/json\r\n" if body else b""
    if served.token and b"authorization:" not in headers.lower():
        extra += f"Authorization: Bearer {served.token}\r\n".encode()
    raw = (
        f"{method} {path} HTTP/1.1\r\nHost: {served.host}\r\nContent-Length: {len(body)}\r\nConnection: close\r\n"
    ).encode()
    with socket.create_connection(("127.0.0.1", served.control), timeout=30) as sock:
        sock.sendall(raw + extra + headers + b"\r\n" + body)
        return head_and_body(read_all(sock))


def test_held_keep_alive_connections_leave_room_for_a_legitimate_client(served: Served) -> None:
    """256 clients each ask once and hold their keep-alive connection: before, a legitimate client then had
    0 of 45 requests answered in 45 s. Now each client has a share of the cap, and at the cap the connection
    idle longest is closed for a newcomer; a newcomer that finds none idle gets a 503 that says why."""
    held: list[socket.socket] = []
    statuses: dict[int, int] = {}
    with polling(served):
        try:
            for _ in range(MAX_CONNECTIONS):
                sock = socket.create_connection(("127.0.0.1", served.control), timeout=10)
                held.append(sock)
                sock.sendall(f"GET /time HTTP/1.1\r\nHost: {served.host}\r\n\r\n".encode())
                try:
                    status, answer = read_response(sock)
                except (AssertionError, ConnectionError):
                    status, answer = 0, None  # closed for a newer one
                statuses[status] = statuses.get(status, 0) + 1
                if status == 503:
                    assert "connections open to the control API, its share" in answer["error"], answer
            assert statuses.get(200, 0) >= MAX_CONNECTIONS // 4, statuses
            time.sleep(GRACE + 0.5)  # the held ones are idle now, not being answered
            answers = [request(served, "GET", "/time") for _ in range(45)]
            assert [status for status, _ in answers] == [200] * 45, answers
        finally:
            for sock in held:
                sock.close()


def test_a_refused_client_gets_a_503_that_says_why(served: Served) -> None:
    """Connections opened faster than any can be idle: beyond the client's share they are refused, with a 503
    and a sentence (before: a bare reset); a moment later a legitimate request is answered."""
    held = [socket.create_connection(("127.0.0.1", served.control), timeout=10) for _ in range(MAX_CONNECTIONS + 8)]
    try:
        refused = []
        for sock in held:
            sock.settimeout(0.5)
            with contextlib.suppress(TimeoutError):
                data = sock.recv(65536)
                if data.startswith(b"HTTP/1.1 503"):
                    sock.settimeout(5)
                    refused.append(head_and_body(data + read_all(sock)))
        assert refused, "no connection refused"
        for status, answer in refused:
            assert status == 503
            assert answer["error"].startswith("503 Service Unavailable: this client (127.0.0.1) has "), answer
            assert "connections open to the control API, its share of the " in answer["error"], answer
        time.sleep(GRACE + 0.5)
        with polling(served):
            assert request(served, "GET", "/time")[0] == 200
    finally:
        for sock in held:
            sock.close()


def test_a_body_that_never_finishes_is_answered_408_and_closed(served: Served) -> None:
    """A POST whose body stops half-way: before, it held its connection for more than 50 s; now the body's
    deadline answers 408 and closes it."""
    with polling(served), socket.create_connection(("127.0.0.1", served.control), timeout=60) as sock:
        sock.sendall(
            f"POST /time/advance HTTP/1.1\r\nHost: {served.host}\r\nContent-Type: application/json\r\n"
            'Content-Length: 100\r\n\r\n{"seconds": '.encode()
        )
        status, answer = head_and_body(read_all(sock))
    assert status == 408, answer
    assert answer == {"error": "POST /time/advance: the body did not come within 10 s"}


def test_a_later_requests_headers_have_their_deadline_too(served: Served) -> None:
    """A keep-alive connection asks once, then sends the start of a second request and no more: before, only the
    first request's headers had a deadline and this one held its connection until the idle timeout (30 s);
    now the server closes it at the header deadline (10 s), well within the 20 s this test waits."""
    with polling(served), socket.create_connection(("127.0.0.1", served.control), timeout=10) as sock:
        sock.sendall(f"GET /time HTTP/1.1\r\nHost: {served.host}\r\n\r\n".encode())
        assert read_response(sock)[0] == 200
        sock.sendall(f"GET /time HTTP/1.1\r\nHost: {served.host}\r\nX-Slow: ".encode())
        sock.settimeout(20)
        assert sock.recv(1) == b""


def test_a_client_that_leaves_mid_body_is_no_traceback(served: Served) -> None:
    """Before: the guard's read logged a traceback for each. The fixture checks the server's log."""
    with polling(served):
        for abort in (False, True) * 5:
            sock = socket.create_connection(("127.0.0.1", served.control), timeout=10)
            sock.sendall(
                f"POST /time/advance HTTP/1.1\r\nHost: {served.host}\r\nContent-Type: application/json\r\n"
                'Content-Length: 100\r\n\r\n{"seconds": '.encode()
            )
            time.sleep(0.05)
            if abort:  # a reset, not a close
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            sock.close()
        assert request(served, "GET", "/time")[0] == 200


def websocket(served: Served, rcvbuf: int = 0) -> socket.socket:
    """A raw WebSocket on /stream at 50 Hz, upgraded (``rcvbuf``: its receive buffer, set before connecting)."""
    sock = socket.socket()
    sock.settimeout(10)
    if rcvbuf:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    sock.connect(("127.0.0.1", served.control))
    key = base64.b64encode(os.urandom(16)).decode()
    sock.sendall(
        f"GET /stream?hz=50&frame_hz=100 HTTP/1.1\r\nHost: {served.host}\r\nUpgrade: websocket\r\n"
        f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n".encode()
    )
    data = b""
    while b"\r\n\r\n" not in data:
        data += sock.recv(4096)
    assert data.startswith(b"HTTP/1.1 101"), data
    return sock


#: 32 drives: a telemetry message of about 47 KB, 50 a second, so that an unread stream fills its socket in a
#: second or two and the server's send waits for the reader, as on a slow link.
DRIVES_32 = ("--drives", ",".join(str(a) for a in range(1, 33)))


@pytest.mark.parametrize("served", [DRIVES_32], indirect=True)
def test_a_stream_reader_that_resets_its_connection_is_no_traceback(served: Served) -> None:
    """A reader that stops reading, then resets its connection while the server waits to send: before,
    "bug while serving GET /stream" and a traceback in the server's log (3 of 5 readers held 1.5 s)."""
    with polling(served):
        for _ in range(5):
            sock = websocket(served, rcvbuf=4096)
            time.sleep(3)  # messages pile up unread until the server's send waits
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            sock.close()
        time.sleep(0.5)
        status, answer = request(served, "GET", "/")
        assert status == 200 and answer["stream_readers"] == 0, answer


@pytest.mark.parametrize("served", [("--control-token-file", "token.txt")], indirect=True)
def test_a_non_utf8_authorization_header_is_401(served: Served, tmp_path: Path) -> None:
    """Before: 500 and a traceback (the check encoded the surrogate-escaped header)."""
    assert served.token is not None
    with polling(served):
        for value in (b"Bearer \xff\xfe\xfd", b"\xc3\x28", b"Bearer " + served.token.encode() + b"\xff"):
            status, answer = request(served, "GET", "/time", headers=b"Authorization: " + value + b"\r\n")
            assert status == 401, answer
            assert "a wrong token" in answer["error"] or "no token" in answer["error"], answer
        assert request(served, "GET", "/time")[0] == 200


@pytest.fixture(autouse=True)
def in_tmp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "token.txt").write_text("s3cret-token\n")
    monkeypatch.chdir(tmp_path)


def test_reset_of_a_huge_sparse_file_is_refused_and_the_wire_keeps_answering(served: Served, tmp_path: Path) -> None:
    """Before: a 3 GiB sparse file was read whole on the serving loop (15 s of silence, RSS 3.3 GiB)."""
    sparse = tmp_path / "sparse"
    with open(sparse, "wb") as f:
        f.truncate(3 * 1024**3)
    os.mkfifo(tmp_path / "fifo")
    (tmp_path / "zero").symlink_to("/dev/zero")
    expected = {
        "sparse": "bigger than 256 KiB, too big for a state file; is it the right file?",
        "fifo": "is a FIFO (named pipe), not a regular file; give the state file as a file",
        "zero": "is a character device, not a regular file; give the state file as a file",
    }
    with polling(served):
        for name, reason in expected.items():
            path = str(tmp_path / name)
            status, answer = request(served, "POST", "/reset", json.dumps({"setup": path}).encode())
            assert (status, answer) == (400, {"error": f"setup: {path}: {reason}"})
        assert request(served, "GET", "/time")[0] == 200
