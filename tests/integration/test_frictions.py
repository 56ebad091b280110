"""The first hour's frictions, each through the path the user took (the command line, the wire), exact outputs.

An RTU master at the Modbus TCP port is told where RTU over TCP is (once: stderr, the frame log, the notices the
dashboard shows), as the opposite mistake is; ``exercise --address 7`` with no drive there blames the address
and the link, not the action; ``serve --clock virtual`` without ``--control`` says that time can never move; a
token file others can read is taken with a warning; ``audit`` refuses a FIFO as ``replay`` and ``decode`` do.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import urllib.request
from pathlib import Path

import pytest
from pymodbus import FramerType
from pymodbus.client import ModbusTcpClient
from pymodbus.exceptions import ModbusException

from c20sim.wire.protocol import WriteSingleRequest, encode
from tests.conftest import wait_for_ready_file
from tests.integration.conftest import c20sim_command, get, stop


def serve(procs: list[subprocess.Popen[str]], ready: Path, *args: str) -> tuple[subprocess.Popen[str], dict[str, str]]:
    proc = subprocess.Popen(
        c20sim_command("serve", *args, "--ready-file", str(ready)),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    procs.append(proc)
    return proc, wait_for_ready_file(ready, proc)


def test_an_rtu_master_at_the_modbus_tcp_port_is_told_where_rtu_over_tcp_is(
    tmp_path: Path, procs: list[subprocess.Popen[str]]
) -> None:
    proc, info = serve(
        procs,
        tmp_path / "ready.json",
        "--tcp",
        "127.0.0.1:0",
        "--modbus-tcp",
        "127.0.0.1:0",
        "--control",
        "127.0.0.1:0",
    )
    host, port = info["modbus_tcp"].rsplit(":", 1)
    for _ in range(3):  # pymodbus speaking RTU framing at the Modbus TCP port: the gateway closes the connection
        master = ModbusTcpClient(host, port=int(port), framer=FramerType.RTU, timeout=1, retries=0)
        assert master.connect()
        try:
            with pytest.raises(ModbusException):
                master.read_holding_registers(0x2100, count=1, device_id=1)
        finally:
            master.close()
    # the RTU port still answers the same master
    rtu_host, rtu_port = info["tcp"].rsplit(":", 1)
    master = ModbusTcpClient(rtu_host, port=int(rtu_port), framer=FramerType.RTU, timeout=2, retries=0)
    assert master.connect()
    try:
        assert master.read_holding_registers(0x2100, count=1, device_id=1).registers == [3]
    finally:
        master.close()
    said = f"Modbus TCP {info['modbus_tcp']}: this looks like Modbus RTU over TCP: use --tcp (RTU over TCP, open on {info['tcp']})"
    assert get(info["control"] + "/telemetry")["notices"] == [said]  # what the dashboard shows, once
    frames = get(info["control"] + "/frames")["frames"]
    assert isinstance(frames, list)
    assert [(f["kind"], f["hex"], f["text"]) for f in frames if f["kind"] == "noise"] == [
        (
            "noise",
            "01 03 21 00 00 01 8E 36",
            "an RTU frame (with its CRC) on the Modbus TCP port: not answered, the connection closed",
        )
    ] * 3
    _, err = stop(proc)
    assert err == f"c20sim: {said}; this port answers Modbus TCP (MBAP) frames only, as a gateway would\n"  # once


def test_an_rtu_master_at_the_modbus_tcp_port_alone_is_told_to_open_rtu_over_tcp(
    tmp_path: Path, procs: list[subprocess.Popen[str]]
) -> None:
    proc, info = serve(procs, tmp_path / "ready.json", "--modbus-tcp", "127.0.0.1:0")
    host, port = info["modbus_tcp"].rsplit(":", 1)
    with socket.create_connection((host, int(port)), timeout=5) as sock:
        sock.sendall(encode(WriteSingleRequest(1, 0x2001, 1500)))  # RTU with its CRC
        assert sock.recv(64) == b""  # closed, no answer
    _, err = stop(proc)
    said = f"Modbus TCP {info['modbus_tcp']}: this looks like Modbus RTU over TCP: use --tcp HOST:PORT (RTU over TCP, not open now)"
    assert err == f"c20sim: {said}; this port answers Modbus TCP (MBAP) frames only, as a gateway would\n"


def test_a_garbled_mbap_header_is_not_taken_for_rtu(tmp_path: Path, procs: list[subprocess.Popen[str]]) -> None:
    proc, info = serve(procs, tmp_path / "ready.json", "--modbus-tcp", "127.0.0.1:0")
    host, port = info["modbus_tcp"].rsplit(":", 1)
    with socket.create_connection((host, int(port)), timeout=5) as sock:
        sock.sendall(bytes.fromhex("00 01 00 07 00 06 01 03 21 00 00 01"))  # protocol id 7: no RTU frame either
        assert sock.recv(64) == b""
    _, err = stop(proc)
    assert err == ""


@pytest.mark.parametrize("scheme", ["tcp", "modbus-tcp"])
def test_exercise_at_an_address_where_no_drive_answers_blames_the_address_and_link(
    tmp_path: Path, procs: list[subprocess.Popen[str]], scheme: str
) -> None:
    _, info = serve(procs, tmp_path / "ready.json", "--tcp", "127.0.0.1:0", "--modbus-tcp", "127.0.0.1:0")
    where = f"{scheme}://{info['tcp' if scheme == 'tcp' else 'modbus_tcp']}"
    for words in (["--address", "7", "read", "speed"], ["read", "speed", "--address", "7"]):
        done = subprocess.run(c20sim_command("exercise", where, *words), capture_output=True, text=True, timeout=60)
        assert (done.returncode, done.stdout, done.stderr) == (
            2,
            "",
            f"c20sim: {where}: no drive answered at address 7 within 0.5 s; check --address (the drive's 2008H, "
            "1 as shipped) and the link (the port)\n",
        )
    done = subprocess.run(
        c20sim_command("exercise", where, "--address", "1", "read", "speed"), capture_output=True, text=True
    )
    assert (done.returncode, done.stdout) == (0, "3006H motor speed: 0 rpm\n")


def test_exercise_on_a_serial_line_with_no_drive_names_the_baud(tmp_path: Path) -> None:
    """A pty nobody answers on: the serial settings are part of what to check."""
    master, slave = os.openpty()
    try:
        path = os.ttyname(slave)
        done = subprocess.run(
            c20sim_command("exercise", path, "--address", "7", "--timeout", "0.2", "read", "speed"),
            capture_output=True,
            text=True,
            timeout=60,
        )
    finally:
        os.close(master)
        os.close(slave)
    assert (done.returncode, done.stdout, done.stderr) == (
        2,
        "",
        f"c20sim: {path}: no drive answered at address 7 within 0.2 s; check --address (the drive's 2008H, 1 as "
        "shipped) and the link (the port, 19200 baud N)\n",
    )


VIRTUAL_WARNING = (
    "c20sim: warning: --clock virtual without --control: nothing can advance the time, so the drives never move "
    "(ramps, trips, timeouts); add --control 127.0.0.1:0 and advance it with ctl advance, or use --clock realtime\n"
)


def test_a_virtual_clock_nothing_can_advance_is_said_in_one_line(
    tmp_path: Path, procs: list[subprocess.Popen[str]]
) -> None:
    proc, _ = serve(procs, tmp_path / "a.json", "--modbus-tcp", "127.0.0.1:0", "--clock", "virtual")
    assert stop(proc)[1] == VIRTUAL_WARNING
    proc, _ = serve(
        procs, tmp_path / "b.json", "--modbus-tcp", "127.0.0.1:0", "--clock", "virtual", "--control", "127.0.0.1:0"
    )
    assert stop(proc)[1] == ""  # ctl advance moves it
    proc, _ = serve(procs, tmp_path / "c.json", "--modbus-tcp", "127.0.0.1:0")
    assert stop(proc)[1] == ""  # real time moves by itself


TOKEN = "a-token-of-my-own-0123456789"


@pytest.mark.parametrize(
    ("mode", "warning"),
    [
        (0o600, ""),
        (0o640, "readable by its group (mode 0640)"),
        (0o644, "readable by its group and every user (mode 0644)"),
        (0o604, "readable by every user (mode 0604)"),
    ],
)
def test_a_token_file_others_can_read_is_taken_with_a_warning(
    tmp_path: Path, procs: list[subprocess.Popen[str]], mode: int, warning: str
) -> None:
    token = tmp_path / "token"
    token.write_text(f"{TOKEN}\n")
    token.chmod(mode)
    proc, info = serve(
        procs,
        tmp_path / "ready.json",
        "--tcp",
        "127.0.0.1:0",
        "--control",
        "127.0.0.1:0",
        "--control-token-file",
        str(token),
    )
    request = urllib.request.Request(info["control"] + "/time", headers={"Authorization": f"Bearer {TOKEN}"})
    with urllib.request.urlopen(request, timeout=10) as response:
        assert response.status == 200  # taken
    _, err = stop(proc)
    expected = f"c20sim: warning: --control-token-file {token}: {warning}; chmod 600 {token}\n" if warning else ""
    assert err == expected


def test_audit_refuses_a_fifo_as_replay_and_decode_do(tmp_path: Path) -> None:
    fifo = tmp_path / "frames.jsonl"
    os.mkfifo(fifo)
    said = {}
    for command in (["audit", str(fifo)], ["replay", str(fifo)], ["decode", "-f", str(fifo)]):
        done = subprocess.run(
            c20sim_command(*command), capture_output=True, text=True, timeout=30
        )  # never waits for a writer
        assert (done.returncode, done.stdout) == (2, ""), command
        said[command[0]] = done.stderr
    assert said["audit"] == (
        f"c20sim: {fifo}: is a FIFO (named pipe), not a regular file; give the frame log or capture as a file; "
        "to read a pipe, give - and pipe it to stdin\n"
    )
    assert (
        said["replay"]
        == said["decode"]
        == (
            f"c20sim: {fifo}: is a FIFO (named pipe), not a regular file; give the capture as a file; "
            "to read a pipe, give - and pipe it to stdin\n"
        )
    )


def test_audit_reads_a_pipe_on_stdin(tmp_path: Path) -> None:
    """What the refusal says to do works: the same log through a pipe to ``-``."""
    line = json.dumps({"t": 0.0, "dir": "rx", "hex": "01 03 21 00 00 01 8E 36"}) + "\n"
    reply = json.dumps({"t": 0.01, "dir": "tx", "hex": "01 03 02 00 03 F8 45"}) + "\n"
    proc = subprocess.Popen(
        c20sim_command("audit", "-"), stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    out, err = proc.communicate(line + reply, timeout=30)
    assert (proc.returncode, out, err) == (
        0,
        "2 frames, 1 requests; line demand peak 0 %, mean 0 % of 19200 8N1; 0 findings\n",
        "",
    )
