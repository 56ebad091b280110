"""The API's one HTTP client (:class:`c20sim.control.client.ControlClient`) under ``c20sim ctl``: what it says of a
peer that is not the API, each way it fails, and one kept-alive connection for an action's calls.

The peers here are small servers on port 0, each failing one way; the API itself is covered by the route tests.
"""

from __future__ import annotations

import json
import socket
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import ClassVar

import pytest

from c20sim.cli import main
from c20sim.control.client import ControlClient, Refused, Unreachable
from c20sim.control.ctl import call
from c20sim.wire.errors import C20SimError


@contextmanager
def raw_peer(answer: Callable[[socket.socket], None]) -> Iterator[str]:
    """A TCP listener on port 0 that hands each connection to ``answer``; its URL."""
    listener = socket.create_server(("127.0.0.1", 0))
    listener.settimeout(0.05)  # the loop looks at ``stop`` between connections
    stop = threading.Event()

    def serve() -> None:
        while not stop.is_set():
            try:
                conn, _ = listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            with conn:
                answer(conn)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{listener.getsockname()[1]}"
    finally:
        stop.set()
        listener.close()
        thread.join(5)


class Fake(BaseHTTPRequestHandler):
    """An HTTP/1.1 peer with kept-alive connections: ``GET /`` is an index of drive 1, ``/text`` is not JSON,
    ``/gone`` a 404 in text, ``/bug`` a 500 with no body; anything else echoes the request as JSON."""

    protocol_version = "HTTP/1.1"
    connections = 0
    requests: ClassVar[list[tuple[str, str, str | None, str]]] = []

    def setup(self) -> None:
        type(self).connections += 1
        super().setup()

    def _send(self, status: int, body: bytes, media: str = "application/json") -> None:
        self.send_response(status)
        self.send_header("Content-Type", media)
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def _answer(self) -> None:
        length = int(self.headers.get("Content-Length") or 0)
        sent = self.rfile.read(length).decode() if length else ""
        type(self).requests.append((self.command, self.path, self.headers.get("Content-Type"), sent))
        if self.path == "/":
            self._send(200, json.dumps({"drives": [1], "profile": "x", "clock": "virtual"}).encode())
        elif self.path == "/text":
            self._send(200, b"<html>hello</html>", "text/html")
        elif self.path == "/gone":
            self._send(404, b"nothing here\n", "text/plain")
        elif self.path == "/bug":
            self._send(500, b"")
        else:
            self._send(200, json.dumps({"method": self.command, "path": self.path, "body": sent}).encode())

    do_GET = do_POST = do_DELETE = do_PUT = do_PATCH = _answer

    def log_message(self, format: str, *args: object) -> None:
        pass


@pytest.fixture
def fake() -> Iterator[str]:
    Fake.connections = 0
    Fake.requests = []
    server = ThreadingHTTPServer(("127.0.0.1", 0), Fake)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()
        thread.join(5)


def test_nothing_listening_is_cannot_reach() -> None:
    with socket.create_server(("127.0.0.1", 0)) as probe:
        url = f"http://127.0.0.1:{probe.getsockname()[1]}"
    with pytest.raises(Unreachable) as caught:
        ControlClient(url).call("GET", "/")
    assert (caught.value.stage, caught.value.status, type(caught.value.cause)) == (
        "connect",
        503,
        ConnectionRefusedError,
    )
    assert str(caught.value) == f"the control API at {url} does not answer: {caught.value.cause}"
    with pytest.raises(C20SimError) as said:
        call(url, "GET", "/")
    assert str(said.value) == (
        f"{url}: cannot reach the control API ([Errno 111] Connection refused); is c20sim serve --control running?"
    )


def test_a_peer_that_answers_not_in_http_is_not_the_api() -> None:
    def garbage(conn: socket.socket) -> None:
        conn.recv(4096)
        conn.sendall(b"MODBUS\r\n\r\n")

    with raw_peer(garbage) as url:
        with pytest.raises(Unreachable) as caught:
            ControlClient(url).call("GET", "/")
        assert caught.value.stage == "reply"
        with pytest.raises(C20SimError) as said:
            call(url, "GET", "/")
    assert str(said.value) == (
        f"{url}: not c20sim's control API (BadStatusLine: MODBUS\r\n); check --url or --ready-file"
    )


def test_a_peer_that_never_answers_is_stuck() -> None:
    answered = threading.Event()

    def silent(conn: socket.socket) -> None:
        answered.wait(5)  # holds the connection open, unanswered, until the test has its errors

    with raw_peer(silent) as url:
        try:
            with pytest.raises(Unreachable) as caught:
                ControlClient(url, timeout=0.3).call("GET", "/drives")
            assert (caught.value.stage, type(caught.value.cause)) == ("timeout", TimeoutError)
            answered.set()
            answered.clear()
            with pytest.raises(C20SimError) as said:
                call(url, "GET", "/drives", timeout=0.3)
        finally:
            answered.set()
    assert str(said.value) == (
        f"{url}: not c20sim's control API, or it is stuck: no answer to GET /drives within 0.3 s; "
        "check --url or --ready-file"
    )


def test_answers_that_are_not_the_apis(fake: str) -> None:
    client = ControlClient(fake)
    assert client.call("GET", "/text") is None  # the dashboard's reading: nothing
    assert client.answer("GET", "/text") == "<html>hello</html>"  # mcp's: the text
    with pytest.raises(Unreachable) as caught:
        client.call("GET", "/text", strict=True)
    assert (caught.value.stage, str(caught.value)) == ("not json", f"{fake}: its answer to GET /text is not JSON")
    with pytest.raises(Refused) as refused:
        client.call("GET", "/gone")
    assert (refused.value.status, refused.value.said, str(refused.value)) == (
        404,
        "nothing here",
        "GET /gone: HTTP 404",
    )
    with pytest.raises(Refused) as bug:
        client.call("POST", "/bug", {})
    assert (bug.value.status, bug.value.said) == (500, "Internal Server Error")
    client.close()
    with pytest.raises(C20SimError) as said:
        call(fake, "GET", "/gone")
    assert str(said.value) == "GET /gone: 404: nothing here"
    with pytest.raises(C20SimError) as said:
        call(fake, "GET", "/text")
    assert str(said.value) == (
        f"{fake}: not c20sim's control API (its answer to GET /text is not JSON); check --url or --ready-file"
    )


def test_ctl_makes_an_actions_calls_on_one_connection(fake: str, capsys: pytest.CaptureFixture[str]) -> None:
    """``ctl clear``: every cause of the first drive (the index names it) ended, then reset: four calls, one
    connection; a state change without a body still goes as JSON."""
    assert main(["ctl", "--url", fake, "--format", "json", "clear"]) == 0
    assert Fake.connections == 1
    assert Fake.requests == [
        ("GET", "/", None, ""),
        ("DELETE", "/drives/1/causes", "application/json", ""),
        ("GET", "/", None, ""),
        ("DELETE", "/drives/1/fault", "application/json", '{"reset": true}'),
    ]
    assert json.loads(capsys.readouterr().out) == {
        "method": "DELETE",
        "path": "/drives/1/fault",
        "body": '{"reset": true}',
    }


def test_ctl_refuses_an_https_url(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["ctl", "--url", "https://127.0.0.1:8020", "info"]) == 2
    assert capsys.readouterr().err == (
        "c20sim: --url 'https://127.0.0.1:8020': give the API's address as http://HOST:PORT, such as "
        "http://127.0.0.1:8020\n"
    )
