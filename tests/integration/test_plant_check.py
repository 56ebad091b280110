"""``c20sim plant-check`` and its probe, against served drives on real TCP ports and against bad peers."""

from __future__ import annotations

import asyncio
import json
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from c20sim.drive.profile import load_profile
from c20sim.plant import check_bus
from c20sim.transport.probe import NoAnswer, Prober
from c20sim.wire.protocol import ExceptionResponse

from .conftest import ServeFactory

PROFILE = load_profile()


def plant_check(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "c20sim", "plant-check", *args],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, **(env or {})},
        check=False,
    )


async def test_a_table_of_every_drive_on_every_bus(serve: ServeFactory) -> None:
    bus_a = await serve((1, 2))
    bus_b = await serve((7,))
    bus_b.sim.drives[7].force_fault(0x0A)  # UV, bus undervoltage
    a, b = f"127.0.0.1:{bus_a.tcp_port}", f"127.0.0.1:{bus_b.tcp_port}"
    result = await asyncio.to_thread(plant_check, "--drives", "1,2,7", "--timeout", "0.3", a, b)
    width = len(a)
    assert result.stdout.splitlines() == [
        f"{'bus':<{width}}  drive  speed  status",
        f"{a}      1      0  stopped",
        f"{a}      2      0  stopped",
        f"{a}      7      -  no answer: timed out after 0.3 s",
        f"{b}      1      -  no answer: timed out after 0.3 s",
        f"{b}      2      -  no answer: timed out after 0.3 s",
        f"{b}      7      0  fault 0x0A UV",
        "3 of 6 drives on 2 bus(es) answered",
    ]
    assert result.returncode == 1
    assert result.stderr == ""


async def test_quiet_probe_and_the_drives_from_the_environment(serve: ServeFactory) -> None:
    bus = await serve((3, 4))
    rtu, mbap = f"127.0.0.1:{bus.tcp_port}", f"127.0.0.1:{bus.modbus_tcp_port}"
    ok = await asyncio.to_thread(plant_check, "--quiet", rtu, env={"C20SIM_DRIVES": "3-4"})
    assert (ok.returncode, ok.stdout, ok.stderr) == (0, "", "")
    ok = await asyncio.to_thread(plant_check, "--quiet", "--modbus-tcp", mbap, env={"C20SIM_DRIVES": "3,4"})
    assert (ok.returncode, ok.stdout, ok.stderr) == (0, "", "")
    # without the variable, drive 1: absent here, so the probe fails
    missing = await asyncio.to_thread(plant_check, "--quiet", "--timeout", "0.2", rtu, env={"C20SIM_DRIVES": ""})
    assert (missing.returncode, missing.stdout) == (1, "")


async def test_check_bus_reads_a_running_drive_over_modbus_tcp(serve: ServeFactory) -> None:
    bus = await serve((1,))
    drive = bus.sim.drives[1]
    drive.write(0x2001, 1500)  # speed reference, rpm
    drive.write(0x2000, 1)  # forward run
    bus.sim.advance(5.0)
    rows = await asyncio.to_thread(check_bus, "127.0.0.1", bus.modbus_tcp_port, [1], PROFILE, modbus_tcp=True)
    assert [(r.drive, r.ok, r.status, r.speed) for r in rows] == [(1, True, "forward running", 1500)]


@pytest.mark.parametrize(
    "args",
    [
        ["127.0.0.1"],
        ["127.0.0.1:99999"],
        ["--drives", "0-3", "127.0.0.1:502"],
        ["--timeout", "0", "127.0.0.1:502"],
    ],
)
def test_bad_arguments_are_one_line_and_exit_2(args: list[str]) -> None:
    result = plant_check(*args)
    assert (result.returncode, result.stdout) == (2, "")
    assert result.stderr.startswith("c20sim: ") and result.stderr.count("\n") == 1, result.stderr


# Bad peers: a TCP server that answers each request with what the test gives it.


@pytest.fixture
def peer() -> Iterator[tuple[int, list[bytes]]]:
    """A one-connection-at-a-time TCP peer; each request gets the next reply from the list (none: silence)."""
    replies: list[bytes] = []
    listener = socket.create_server(("127.0.0.1", 0))
    listener.settimeout(5)
    stop = threading.Event()

    def serve() -> None:
        while not stop.is_set():
            try:
                conn, _ = listener.accept()
            except OSError:
                return
            with conn:
                conn.settimeout(5)
                while not stop.is_set():
                    try:
                        if not conn.recv(256):
                            break
                    except OSError:
                        break
                    if replies:
                        conn.sendall(replies.pop(0))

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    yield listener.getsockname()[1], replies
    stop.set()
    listener.shutdown(socket.SHUT_RDWR)  # wakes the accept() in the thread
    listener.close()
    thread.join(timeout=10)
    assert not thread.is_alive()


@pytest.mark.parametrize(
    ("reply", "message"),
    [
        (bytes.fromhex("01 03 02 00 20 B9 9C"), None),  # a good reply: 0x0020
        (bytes.fromhex("01 03 02 00 20 00 00"), "a malformed reply (bad CRC): 01 03 02 00 20 00 00"),
        (bytes.fromhex("02 03 02 00 20 FD 9C"), None),  # wrong address: checked below
        (bytes.fromhex("01 05 00 00"), "a reply that is not a C20 read reply: 01 05 00"),
        (b"", "timed out after 0.2 s"),
    ],
)
def test_probe_takes_only_a_right_reply(peer: tuple[int, list[bytes]], reply: bytes, message: str | None) -> None:
    port, replies = peer
    if reply:
        replies.append(reply)
    with Prober("127.0.0.1", port, timeout=0.2) as prober:
        if message is None and reply[0] == 1:
            assert prober.read(1, 0x2103) == 0x20
            return
        expected = message or "a reply from address 2, not 1"
        with pytest.raises(NoAnswer) as excinfo:
            prober.read(1, 0x2103)
        assert str(excinfo.value) == expected


def test_unreachable_and_unnamable_hosts_are_rows_not_tracebacks() -> None:
    result = plant_check("--timeout", "0.2", "a" * 70 + ":502", "[::1]:1")
    assert result.returncode == 1, result.stderr
    rows = result.stdout.splitlines()[1:]
    assert [row.split(None, 3)[0] for row in rows[:-1]] == ["a" * 70 + ":502", "[::1]:1"]
    assert rows[0].endswith(f"no answer: not a host name: '{'a' * 70}'")
    # refused where the machine has IPv6 loopback, some other reason where not: a row either way
    assert rows[1].split(None, 3)[1:3] == ["1", "-"] and rows[1].split(None, 3)[3].startswith("no answer: ")
    assert rows[-1] == "0 of 2 drives on 2 bus(es) answered"


def test_probe_passes_on_an_exception_reply(peer: tuple[int, list[bytes]]) -> None:
    port, replies = peer
    replies.append(bytes.fromhex("01 83 02 C0 F1"))  # the sheet's 'read F00.50 (absent)' answer
    with Prober("127.0.0.1", port, timeout=1) as prober:
        reply = prober.read(1, 0x0032)
    assert isinstance(reply, ExceptionResponse) and reply.code == 0x02


def test_probe_reconnects_after_a_timeout(peer: tuple[int, list[bytes]]) -> None:
    port, replies = peer
    with Prober("127.0.0.1", port, timeout=0.2) as prober:
        with pytest.raises(NoAnswer, match="timed out"):
            prober.read(1, 0x2103)  # silence
        replies.append(bytes.fromhex("01 03 02 00 20 B9 9C"))
        # the silent connection was closed; a new one carries the next request
        assert prober.read(1, 0x2103) == 0x20


def test_serve_and_the_probe_take_the_drives_from_the_environment(tmp_path: Path) -> None:
    """As in a plant's pod: C20SIM_DRIVES (from the ConfigMap) sets both what is served and what is probed."""
    ready = tmp_path / "ready.json"
    env = {**os.environ, "C20SIM_DRIVES": "5-6"}
    server = subprocess.Popen(
        [sys.executable, "-m", "c20sim", "serve", "--tcp", "127.0.0.1:0", "--ready-file", str(ready)],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 30
        while not ready.exists():
            assert server.poll() is None, server.communicate()
            assert time.monotonic() < deadline, "no ready file within 30 s"
            time.sleep(0.02)
        tcp = json.loads(ready.read_text())["tcp"]
        result = plant_check(tcp, env={"C20SIM_DRIVES": "5-6"})
        assert result.returncode == 0, result.stdout + result.stderr
        assert result.stdout.splitlines()[-1] == "2 of 2 drives on 1 bus(es) answered"
    finally:
        server.terminate()
        out, _ = server.communicate(timeout=30)
    assert "drives 5,6" in out


@pytest.mark.parametrize("command", [["serve", "--tcp", "127.0.0.1:0"], ["plant-check", "127.0.0.1:502"]])
def test_a_bad_drives_variable_is_named_in_one_line(command: list[str]) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "c20sim", *command],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "C20SIM_DRIVES": "1-300"},
        check=False,
    )
    assert (result.returncode, result.stdout) == (2, "")
    assert result.stderr.startswith("c20sim: $C20SIM_DRIVES: bad drive list '1-300': "), result.stderr
    assert result.stderr.count("\n") == 1


def test_a_peer_that_trickles_its_reply_cannot_hold_the_probe_past_its_timeout() -> None:
    listener = socket.create_server(("127.0.0.1", 0))
    reply = bytes.fromhex("01 03 02 00 20 B9 9C")
    done = threading.Event()

    def trickle() -> None:
        conn, _ = listener.accept()
        with conn:
            conn.recv(256)
            for byte in reply:  # a right reply, one byte every 0.1 s: 0.7 s in all
                if done.wait(0.1):
                    return
                conn.sendall(bytes([byte]))

    thread = threading.Thread(target=trickle, daemon=True)
    thread.start()
    try:
        prober = Prober("127.0.0.1", listener.getsockname()[1], timeout=0.3)
        with prober, pytest.raises(NoAnswer, match=r"^timed out after 0\.3 s$"):
            prober.read(1, 0x2103)
    finally:
        done.set()
        thread.join(timeout=10)
        listener.close()
