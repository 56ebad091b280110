"""The control API refuses what a web page can send, and answers bad input with one line, never a 500.

``c20sim serve --control`` as a subprocess and raw HTTP over a socket, so
that the requests are exactly what a browser (or an attacker) sends: a plain
HTML form's ``text/plain`` and form-encoded bodies, a foreign ``Host`` (DNS
rebinding), a foreign or ``null`` ``Origin``. The drive runs at speed
meanwhile and must keep running, without a fault.
"""

from __future__ import annotations

import json
import resource
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from pymodbus import FramerType
from pymodbus.client import ModbusTcpClient

from c20sim.wire.registers import Reg
from tests.conftest import wait_for_ready_file


@pytest.fixture
def api(tmp_path: Path) -> Iterator[tuple[str, int, subprocess.Popen[str]]]:
    ready = tmp_path / "ready.json"
    command = [sys.executable, "-m", "c20sim", "serve", "--tcp", "127.0.0.1:0", "--control", "127.0.0.1:0"]
    command += ["--clock", "virtual", "--ready-file", str(ready)]
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        info = wait_for_ready_file(ready, proc)
        _host, port = info["control"].removeprefix("http://").rsplit(":", 1)
        yield info["tcp"], int(port), proc
    finally:
        if proc.poll() is None:
            proc.terminate()
        proc.communicate(timeout=10)


def http(port: int, method: str, path: str, headers: dict[str, str], body: bytes = b"") -> tuple[int, Any]:
    """One request, exactly as given (no header added but Content-Length and Connection); status and JSON."""
    lines = [f"{method} {path} HTTP/1.1", *(f"{k}: {v}" for k, v in headers.items())]
    lines += [f"Content-Length: {len(body)}", "Connection: close", "", ""]
    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
        sock.sendall("\r\n".join(lines).encode("latin-1") + body)
        data = b""
        while chunk := sock.recv(65536):
            data += chunk
    head, _, payload = data.partition(b"\r\n\r\n")
    status = int(head.split(b" ", 2)[1])
    return status, json.loads(payload) if payload else None


def drive(port: int) -> dict[str, Any]:
    status, state = http(port, "GET", "/drives/1", {"Host": f"127.0.0.1:{port}"})
    assert status == 200, state
    assert isinstance(state, dict)
    return state


def running_drive(tcp: str, port: int) -> None:
    """Run the drive at 1,500 rpm as its master does: 2001H then 2000H = 1 (forward), over Modbus."""
    master = ModbusTcpClient("127.0.0.1", port=int(tcp.rsplit(":", 1)[1]), framer=FramerType.RTU, timeout=2, retries=0)
    assert master.connect()
    try:
        assert not master.write_register(Reg.SPEED_SETPOINT, 1500, device_id=1).isError()
        assert not master.write_register(Reg.COMMAND, 1, device_id=1).isError()
    finally:
        master.close()
    own = {"Host": f"127.0.0.1:{port}", "Content-Type": "application/json"}
    assert http(port, "POST", "/time/advance", own, b'{"seconds": 3}')[0] == 200
    state = drive(port)
    assert state["state"] == "forward" and state["speed_rpm"] > 1000, state


def test_a_web_page_cannot_trip_or_power_cycle_the_drive(api: tuple[str, int, subprocess.Popen[str]]) -> None:
    tcp, port, _proc = api
    running_drive(tcp, port)
    host = f"127.0.0.1:{port}"
    # A page from file:// (Origin null) posting text/plain, as a form or a no-cors fetch does: no preflight.
    form_text = {"Host": host, "Origin": "null", "Content-Type": "text/plain"}
    status, answer = http(port, "POST", "/drives/1/fault", form_text, b'{"code": 16}')
    assert status == 403, answer
    # The same form without Origin (an older browser): the content type alone refuses it.
    status, answer = http(port, "POST", "/drives/1/fault", {"Host": host, "Content-Type": "text/plain"}, b'{"code":16}')
    assert (status, answer) == (
        415,
        {"error": "POST /drives/1/fault: Content-Type must be application/json, not text/plain"},
    )
    form = {"Host": host, "Content-Type": "application/x-www-form-urlencoded"}
    assert http(port, "POST", "/drives/1/power-cycle", form, b"a=b")[0] == 415
    # A page served from another local port, with a JSON body (script, no-cors): its Origin gives it away.
    other = {"Host": host, "Origin": "http://127.0.0.1:8000", "Content-Type": "application/json"}
    status, answer = http(port, "POST", "/drives/1/fault", other, b'{"code": 16}')
    assert (status, answer) == (
        403,
        {"error": "POST /drives/1/fault: requests from other origins (http://127.0.0.1:8000) are refused"},
    )
    # DNS rebinding: the page's own name in Host, even for a read.
    status, answer = http(port, "GET", "/drives/1", {"Host": f"attacker.example:{port}"})
    assert status == 403 and "attacker.example" in answer["error"], answer
    state = drive(port)
    assert state["state"] == "forward" and state["fault_code"] == 0, state
    # The API's own clients still get through: same origin, loopback names.
    own = {"Host": f"localhost:{port}", "Origin": f"http://localhost:{port}", "Content-Type": "application/json"}
    assert http(port, "GET", "/time", own)[0] == 200


def test_bodies_that_are_not_json_get_400_not_500(api: tuple[str, int, subprocess.Popen[str]]) -> None:
    _host, port, proc = api
    own = {"Host": f"127.0.0.1:{port}", "Content-Type": "application/json"}
    assert http(port, "POST", "/drives/1/fault", own, b"\xff\xfe{") == (
        400,
        {"error": "the body is not JSON: not UTF-8 text (byte 0)"},
    )
    assert http(port, "POST", "/drives/1/fault", own, b"[" * 100_000) == (
        400,
        {"error": "the body is not JSON this API takes: nested deeper than 32 levels"},
    )
    assert http(port, "PUT", "/drives/1/conditions", own, b'{"supply_v": ' + b"[" * 20 + b"]" * 20 + b"}")[0] == 400
    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:  # a 9,000-byte URL
        sock.sendall(b"GET /" + b"a" * 9000 + b" HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        assert sock.recv(100).split(b" ", 2)[1] == b"400"
    assert drive(port)["fault_code"] == 0
    proc.terminate()
    _out, err = proc.communicate(timeout=10)
    assert "Traceback" not in err, err
    assert err.count("malformed HTTP request") == 1, err


def test_a_control_api_beyond_loopback_says_so(tmp_path: Path) -> None:
    ready = tmp_path / "ready.json"
    command = [sys.executable, "-m", "c20sim", "serve", "--tcp", "127.0.0.1:0", "--control", "0.0.0.0:0"]
    proc = subprocess.Popen(
        [*command, "--ready-file", str(ready)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
    )
    try:
        wait_for_ready_file(ready, proc)
    finally:
        proc.terminate()
        _out, err = proc.communicate(timeout=10)
    warnings = [line for line in err.splitlines() if "reachable from other machines" in line]
    assert len(warnings) == 1, err
    assert warnings[0].startswith("c20sim: warning: --control 0.0.0.0:"), warnings


def test_unfinished_http_requests_cannot_use_up_the_wire(tmp_path: Path) -> None:
    """1,100 requests whose headers never end, against a server with 1,024 file descriptors: the API keeps
    to its cap (one client to half of it, the rest answered 503), the wire still takes a new master, and the
    held connections are closed after the header timeout."""
    ready = tmp_path / "ready.json"
    command = [sys.executable, "-m", "c20sim", "serve", "--modbus-tcp", "127.0.0.1:0", "--control", "127.0.0.1:0"]

    def limit_fds() -> None:
        resource.setrlimit(resource.RLIMIT_NOFILE, (1024, resource.getrlimit(resource.RLIMIT_NOFILE)[1]))

    proc = subprocess.Popen(
        [*command, "--ready-file", str(ready)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=limit_fds,
    )
    held: list[socket.socket] = []
    try:
        info = wait_for_ready_file(ready, proc)
        control = int(info["control"].rsplit(":", 1)[1])
        for _ in range(1100):
            sock = socket.create_connection(("127.0.0.1", control), timeout=10)
            sock.sendall(b"GET /drives/1 HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
            held.append(sock)
        # A new Modbus TCP master (a raw socket: this process has more than 1,024 descriptors open, past select()).
        with socket.create_connection(("127.0.0.1", int(info["modbus_tcp"].rsplit(":", 1)[1])), timeout=5) as master:
            master.sendall(bytes.fromhex("0001 0000 0006 01 03 2100 0001"))
            assert master.recv(64) == bytes.fromhex("0001 0000 0005 01 03 02 0003")
        closed = refused = 0
        deadline = time.monotonic() + 30
        for sock in held:  # every one is closed: beyond the client's share at once (with a 503 that says why),
            # or closed for a newer one, or after the header timeout
            sock.settimeout(max(0.1, deadline - time.monotonic()))
            data = b""
            try:
                while chunk := sock.recv(65536):
                    data += chunk
                closed += 1
            except ConnectionResetError:
                closed += 1
            except TimeoutError:
                break
            refused += data.startswith(b"HTTP/1.1 503 Service Unavailable\r\n")
        assert closed == len(held), f"{len(held) - closed} of {len(held)} unfinished requests still held"
        assert refused > 0
    finally:
        for sock in held:
            sock.close()
        proc.terminate()
        _out, err = proc.communicate(timeout=10)
    refusals = [line for line in err.splitlines() if "a connection refused (503)" in line]
    assert refusals, err
    assert refusals[0].startswith(
        "control API: a connection refused (503): this client (127.0.0.1) has 128 connections open to the "
        "control API, its share of the 256 allowed, and none is idle;"
    ), err
    assert "Traceback" not in err, err
