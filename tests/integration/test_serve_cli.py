"""``c20sim serve`` as a user starts it: a subprocess, its ready file, its errors, its signals."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
from pathlib import Path

import pytest
from pymodbus import FramerType
from pymodbus.client import ModbusSerialClient, ModbusTcpClient

from tests.conftest import wait_for_ready_file
from tests.integration.conftest import c20sim_command


def start(procs: list[subprocess.Popen[str]], *args: str) -> subprocess.Popen[str]:
    proc = subprocess.Popen(c20sim_command("serve", *args), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    procs.append(proc)
    return proc


def test_ready_file_link_frame_log_and_sigterm(tmp_path: Path, procs: list[subprocess.Popen[str]]) -> None:
    ready, link, log = tmp_path / "ready.json", tmp_path / "ttyC20", tmp_path / "frames.jsonl"
    proc = start(
        procs,
        "--tcp",
        "127.0.0.1:0",
        "--modbus-tcp",
        "127.0.0.1:0",
        "--link",
        str(link),
        "--drives",
        "1,2",
        "--ready-file",
        str(ready),
        "--log-frames",
        str(log),
    )
    info = wait_for_ready_file(ready, proc)
    assert set(info) == {"tcp", "modbus_tcp", "pty"}
    assert info["pty"] == str(link) and link.is_symlink()
    host, port = info["tcp"].rsplit(":", 1)
    assert host == "127.0.0.1" and int(port) > 0

    client = ModbusTcpClient(host, port=int(port), framer=FramerType.RTU, timeout=2, retries=0)
    assert client.connect()
    assert client.read_holding_registers(0x2103, count=1, device_id=2).registers == [0x20]
    client.close()
    serial = ModbusSerialClient(str(link), timeout=2, retries=0)
    assert serial.connect()
    assert serial.read_holding_registers(0x2101, count=1, device_id=1).registers == [0x41]
    serial.close()

    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    assert out.startswith("c20sim ready: c20-400hr, drives 1,2, realtime clock; pty ")
    assert not link.exists()  # the symlink goes with the server
    lines = [json.loads(line) for line in log.read_text().splitlines()]
    assert [(r["dir"], r["hex"], r["text"]) for r in lines[:2]] == [
        ("rx", "02 03 21 03 00 01 7E 05", "read 2103H (drive ID)"),
        ("tx", "02 03 02 00 20 FD 9C", "2103H = 0020"),
    ]


def test_sigint_stops_cleanly(tmp_path: Path, procs: list[subprocess.Popen[str]]) -> None:
    ready = tmp_path / "ready.json"
    proc = start(procs, "--tcp", "127.0.0.1:0", "--ready-file", str(ready))
    wait_for_ready_file(ready, proc)
    proc.send_signal(signal.SIGINT)
    proc.communicate(timeout=10)
    assert proc.returncode == 0


def run_error(*args: str) -> tuple[int, str]:
    result = subprocess.run(c20sim_command("serve", *args), capture_output=True, text=True, timeout=20, check=False)
    return result.returncode, result.stderr


def test_busy_port_names_it_and_says_what_to_do() -> None:
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        port = holder.getsockname()[1]
        code, err = run_error("--tcp", f"127.0.0.1:{port}")
    assert code == 2
    assert err == (
        f"c20sim: --tcp 127.0.0.1:{port}: the port is in use; "
        "stop the program holding it or choose another port (0 picks a free one)\n"
    )


def test_nothing_is_left_half_started(tmp_path: Path) -> None:
    link = tmp_path / "ttyC20"
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        port = holder.getsockname()[1]
        code, _ = run_error("--link", str(link), "--tcp", f"127.0.0.1:{port}")
    assert code == 2
    assert not link.exists()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--drives", "1,x"], "c20sim: bad drive list '1,x': 'x' is not an address; give addresses such as 1,2,5\n"),
        (["--drives", "1,248"], "c20sim: bad drive list '1,248': address 248 is outside 1-247\n"),
        (
            ["--tcp", "localhost"],
            "c20sim: --tcp 'localhost': give HOST:PORT, such as 127.0.0.1:5020 or [::1]:5020 (port 0 picks a free port)\n",
        ),
        (
            ["--modbus-tcp", "127.0.0.1:http"],
            "c20sim: --modbus-tcp '127.0.0.1:http': the port 'http' is not a number; give HOST:PORT, such as "
            "127.0.0.1:5020 or [::1]:5020 (port 0 picks a free port)\n",
        ),
        (
            ["--serial", "/dev/ttyNOPE0"],
            "c20sim: --serial /dev/ttyNOPE0: no such device; check the adapter is plugged in (ls /dev/ttyUSB* /dev/ttyACM*)\n",
        ),
        (["--profile", "c20-400h", "--tcp", "127.0.0.1:0"], "(did you mean 'c20-400hr'?)\n"),
    ],
)
def test_bad_options_exit_2_with_one_line(args: list[str], message: str) -> None:
    code, err = run_error(*args)
    assert code == 2
    assert err.endswith(message) and err.count("\n") == 1, err


@pytest.mark.parametrize("sig", [signal.SIGHUP, signal.SIGTERM, signal.SIGINT])
def test_each_stop_signal_removes_link_and_ready_file(
    tmp_path: Path, procs: list[subprocess.Popen[str]], sig: signal.Signals
) -> None:
    ready, link = tmp_path / "ready.json", tmp_path / "ttyC20"
    proc = start(procs, "--pty", "--link", str(link), "--ready-file", str(ready))
    wait_for_ready_file(ready, proc)
    assert link.is_symlink()
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=10)
    assert (proc.returncode, err) == (0, "")
    assert not link.is_symlink() and not link.exists()
    assert not ready.exists()


def test_a_held_link_is_refused_naming_its_holder(tmp_path: Path, procs: list[subprocess.Popen[str]]) -> None:
    ready, link = tmp_path / "ready.json", tmp_path / "ttyC20"
    first = start(procs, "--pty", "--link", str(link), "--ready-file", str(ready))
    wait_for_ready_file(ready, first)
    target = link.readlink()
    second = start(procs, "--pty", "--link", str(link))
    _, err = second.communicate(timeout=10)
    assert (second.returncode, err) == (
        2,
        f"c20sim: --link {link} is held by another c20sim (PID {first.pid}); stop it or choose another --link\n",
    )
    assert link.readlink() == target  # the first one's link is left alone
    first.send_signal(signal.SIGTERM)
    assert first.wait(timeout=10) == 0
    third = start(procs, "--pty", "--link", str(link), "--ready-file", str(ready))  # free again once it ended
    wait_for_ready_file(ready, third)
    assert link.readlink() != target or link.exists()
