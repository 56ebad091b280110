"""record between a real master (pymodbus) and c20sim on a pty, then replay the log across two profiles.

The drive is ``c20sim serve`` with one profile, on a pty (a serial device to
the sniffer); the master is pymodbus over raw RTU on TCP, or on the
sniffer's own pty. The log replayed against the same profile matches; against
the other it differs exactly where the profiles do: the DC bus voltage
(3008H), supply_v x 10 in each.
"""

from __future__ import annotations

import contextlib
import json
import os
import select
import signal
import socket
import subprocess
import sys
import time
import tty
from collections.abc import Iterator
from pathlib import Path

import pytest
from pymodbus import FramerType
from pymodbus.client import ModbusSerialClient, ModbusTcpClient

from c20sim.drive.profile import load_profile
from tests.conftest import wait_for_ready_file

#: What the master asks, and what c20-400hr answers (at standstill, so no answer depends on timing).
SESSION = [
    ("rx", "01 03 21 00 00 01 8E 36", "request", "read 2100H (status word 1)"),
    ("tx", "01 03 02 00 03 F8 45", "reply", "2100H = 0003: stopped"),
    ("rx", "01 03 30 08 00 01 0A C8", "request", "read 3008H (DC bus voltage)"),
    ("tx", "01 03 02 01 E0 B8 5C", "reply", "3008H = 01E0: 48.0 V"),
    ("rx", "01 06 20 01 03 E8 D3 74", "request", "write 2001H = 03E8: 1000 rpm"),
    ("tx", "01 06 20 01 03 E8 D3 74", "reply", "write 2001H = 03E8: 1000 rpm"),
    ("rx", "01 06 00 0A 09 C4 AE 0B", "request", "write F00.10 = 09C4: 25.00 Hz"),
    ("tx", "01 86 04 43 A3", "exception", "exception 0x04 to write: operation failed"),
    ("rx", "01 03 25 00 00 01 8F 06", "request", "read 2500H"),
    ("tx", "01 83 02 C0 F1", "exception", "exception 0x02 to read: illegal data address"),
    ("rx", "01 03 30 08 00 01 0A C8", "request", "read 3008H (DC bus voltage)"),
    ("tx", "01 03 02 01 E0 B8 5C", "reply", "3008H = 01E0: 48.0 V"),
]


def master_session(client: ModbusTcpClient | ModbusSerialClient) -> None:
    assert client.connect()
    try:
        assert client.read_holding_registers(0x2100, count=1, device_id=1).registers == [3]
        assert client.read_holding_registers(0x3008, count=1, device_id=1).registers == [480]
        assert client.write_register(0x2001, 1000, device_id=1).registers == [1000]
        assert client.write_register(0x000A, 2500, device_id=1).exception_code == 4
        assert client.read_holding_registers(0x2500, count=1, device_id=1).exception_code == 2
        assert client.read_holding_registers(0x3008, count=1, device_id=1).registers == [480]
    finally:
        client.close()


def start(args: list[str], ready: Path) -> tuple[subprocess.Popen[str], dict[str, str]]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "c20sim", *args, "--ready-file", str(ready)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    return proc, wait_for_ready_file(ready, proc)


def stop(proc: subprocess.Popen[str]) -> tuple[str, str]:
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    return out, err


@pytest.fixture
def drive(tmp_path: Path) -> Iterator[str]:
    """c20sim serve with c20-400hr on a pty: the 'real drive' of the recording."""
    proc, ready = start(["serve", "--pty", "--profile", "c20-400hr"], tmp_path / "serve.json")
    try:
        yield ready["pty"]
    finally:
        if proc.poll() is None:
            stop(proc)


def replay(log: Path, profile: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "c20sim", "replay", str(log), "--profile", profile],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )


def check_log(log: Path) -> list[dict[str, object]]:
    records = [json.loads(line) for line in log.read_text().splitlines()]
    assert [(r["dir"], r["hex"], r["kind"], r["text"]) for r in records] == SESSION
    times = [float(r["t"]) for r in records]  # type: ignore[arg-type]
    assert times == sorted(times) and times[0] >= 0
    assert {r["slave"] for r in records} == {1}
    return records


@pytest.mark.parametrize("master", ["tcp", "pty"])
def test_record_then_replay_across_profiles(drive: str, tmp_path: Path, master: str) -> None:
    log = tmp_path / "session.jsonl"
    side = ["--master-tcp", "127.0.0.1:0"] if master == "tcp" else ["--master-pty"]
    recorder, ready = start(["record", "--drive-serial", drive, *side, "--out", str(log)], tmp_path / "rec.json")
    try:
        if master == "tcp":
            host, port = ready["master"].rsplit(":", 1)
            client: ModbusTcpClient | ModbusSerialClient = ModbusTcpClient(
                host, port=int(port), framer=FramerType.RTU, timeout=10, retries=0
            )
        else:
            client = ModbusSerialClient(ready["master"], framer=FramerType.RTU, baudrate=19200, timeout=10, retries=0)
        master_session(client)
    finally:
        out, err = stop(recorder)
    assert err == ""
    assert out.splitlines()[-1] == f"c20sim record: 12 frame(s) written to {log}"
    check_log(log)

    same = replay(log, "c20-400hr")
    assert (same.returncode, same.stderr) == (0, ""), same.stdout
    assert same.stdout == (
        f"replay {log} against c20-400hr, drives 1: 6 frame(s) from the master\n6 replayed: every reply matches\n"
    )

    other = replay(log, "c20-2200hv")
    assert (other.returncode, other.stderr) == (1, ""), other.stdout
    # the profiles differ in the supply: 3008H reads supply_v x 10 at standstill, 48 V against 310 V
    recorded = round(load_profile("c20-400hr").supply.voltage_v * 10)
    simulated = round(load_profile("c20-2200hv").supply.voltage_v * 10)
    assert (recorded, simulated) == (480, 3100)
    records = json.loads("[" + ",".join(log.read_text().splitlines()) + "]")
    lines = [3, 11]  # the two reads of 3008H, by their line in the log
    assert other.stdout.splitlines() == [
        f"replay {log} against c20-2200hv, drives 1: 6 frame(s) from the master",
        *(
            f"  DIFF line {n} (t {records[n - 1]['t']:.6f} s): read 3008H (DC bus voltage): "
            f"recorded 3008H = {recorded:04X}: 48.0 V [01 03 02 01 E0 B8 5C]; "
            f"simulated 3008H = {simulated:04X}: 310.0 V [01 03 02 0C 1C BC 8D]"
            for n in lines
        ),
        "6 replayed: 2 replies differ",
    ]


def test_record_refuses_a_bad_command_line(tmp_path: Path) -> None:
    def record(*args: str) -> subprocess.CompletedProcess[str]:
        command = [sys.executable, "-m", "c20sim", "record", "--out", str(tmp_path / "x.jsonl"), *args]
        return subprocess.run(command, capture_output=True, text=True, timeout=30, check=False)

    result = record("--drive-serial", "/dev/null")
    assert (result.returncode, result.stdout) == (2, "")
    assert result.stderr == (
        "c20sim: give the master's side once: --master-pty, --master-serial DEVICE or --master-tcp HOST:PORT\n"
    )
    result = record("--drive-serial", str(tmp_path / "nosuch"), "--master-pty")
    assert result.returncode == 2
    assert result.stderr.startswith(f"c20sim: {tmp_path / 'nosuch'}: cannot open the serial port: ")
    assert "Traceback" not in result.stderr
    result = record("--drive-serial", "/dev/null", "--master-tcp", "127.0.0.1:0", "--baud", "1234")
    assert (
        result.stderr == "c20sim: --baud 1234: not one the C20 supports: 1200, 2400, 4800, 9600, 19200, 38400, 57600\n"
    )


def test_record_between_two_serial_ports(drive: str, tmp_path: Path) -> None:
    """The master's cable on one serial port (here a pty whose other end the test holds), the drive on another."""
    cable, device = os.openpty()
    tty.setraw(device)
    tty.setraw(cable)
    log = tmp_path / "serial.jsonl"
    try:
        recorder, ready = start(
            ["record", "--master-serial", os.ttyname(device), "--drive-serial", drive, "--out", str(log)],
            tmp_path / "rec.json",
        )
        try:
            assert ready["master"] == os.ttyname(device)
            os.write(cable, bytes.fromhex("01 03 30 08 00 01 0A C8"))
            reply = b""
            deadline = time.monotonic() + 5
            while len(reply) < 7:
                left = deadline - time.monotonic()
                assert left > 0, f"no reply through the sniffer in time: {reply.hex(' ')}"
                if select.select([cable], [], [], left)[0]:
                    reply += os.read(cable, 64)
        finally:
            stop(recorder)
    finally:
        os.close(cable)
        os.close(device)
    assert reply == bytes.fromhex("01 03 02 01 E0 B8 5C")
    records = [json.loads(line) for line in log.read_text().splitlines()]
    assert [(r["dir"], r["kind"], r["text"]) for r in records] == [
        ("rx", "request", "read 3008H (DC bus voltage)"),
        ("tx", "reply", "3008H = 01E0: 48.0 V"),
    ]


def test_record_stops_when_the_drive_port_is_lost(tmp_path: Path) -> None:
    serve, ready = start(["serve", "--pty"], tmp_path / "serve.json")
    log = tmp_path / "lost.jsonl"
    try:
        recorder, _ = start(
            ["record", "--drive-serial", ready["pty"], "--master-tcp", "127.0.0.1:0", "--out", str(log)],
            tmp_path / "rec.json",
        )
    finally:
        stop(serve)  # the pty goes with the server: the sniffer's drive port hangs up
    try:
        out, err = recorder.communicate(timeout=10)
    finally:
        if recorder.poll() is None:
            recorder.kill()
            recorder.wait()
    assert recorder.returncode == 1
    assert out.splitlines()[-1] == f"c20sim record: 0 frame(s) written to {log}"
    assert err == f"c20sim record: stopped: the port was lost ({ready['pty']}: hung up)\n"
    assert log.read_text() == ""


def logged_noise(log: Path) -> int:
    """Bytes of noise in the log so far (its last line may be half-written)."""
    total = 0
    for line in log.read_text().splitlines():
        with contextlib.suppress(json.JSONDecodeError):
            total += len(bytes.fromhex(json.loads(line)["hex"]))
    return total


def noise_through_the_sniffer(drive: str, tmp_path: Path, size: int, until: int, *options: str) -> tuple[Path, str]:
    """``size`` bytes of line noise from a master on RTU over TCP through ``record``, until ``until`` bytes of
    it are in the log; the log and record's stderr."""
    log = tmp_path / "noise.jsonl"
    recorder, ready = start(
        ["record", "--drive-serial", drive, "--master-tcp", "127.0.0.1:0", "--out", str(log), *options],
        tmp_path / "rec.json",
    )
    try:
        host, port = ready["master"].rsplit(":", 1)
        noise = bytes((i * 7919 + 13) % 251 for i in range(size))  # no valid frame in it, CRC or length
        with socket.create_connection((host, int(port)), timeout=10) as master:
            for start_at in range(0, size, 1024):
                master.sendall(noise[start_at : start_at + 1024])
            deadline = time.monotonic() + 20
            while logged_noise(log) < until:
                assert time.monotonic() < deadline, f"{logged_noise(log)} of {until} bytes logged"
                time.sleep(0.05)
    finally:
        _out, err = stop(recorder)
    return log, err


def test_noise_is_logged_compactly(drive: str, tmp_path: Path) -> None:
    """Before: 3.4 bytes of log a byte of noise (a record a broken piece, its bytes spaced and described)."""
    log, err = noise_through_the_sniffer(drive, tmp_path, 40_000, 40_000)
    lines = log.read_text().splitlines()
    noise = [line for line in lines if json.loads(line)["dir"] == "rx"]  # the drive may answer a piece of it
    assert sum(len(bytes.fromhex(json.loads(line)["hex"])) for line in noise) == 40_000, err
    assert {json.loads(line)["kind"] for line in noise} == {"noise"}
    assert sum(len(line) + 1 for line in noise) < 2.2 * 40_000


def test_the_log_is_bounded_in_bytes(drive: str, tmp_path: Path) -> None:
    """Before: --max-records bounded records only, whatever their size."""
    log, err = noise_through_the_sniffer(drive, tmp_path, 200_000, 20_000, "--max-mb", "0.05")
    assert 0.04 * 1024 * 1024 < log.stat().st_size <= 0.05 * 1024 * 1024
    assert err == "c20sim record: 0.05 MiB written (the log's bound); the rest is passed on, not logged\n"
