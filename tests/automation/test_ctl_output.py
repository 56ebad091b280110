"""ctl for scripts: quiet on a closed pipe, exit 1 when the drive refuses, --format text|json, rounded floats."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from c20sim.control.ctl import render, rounded
from c20sim.wire.protocol import ReadRequest, encode
from tests.conftest import wait_for_ready_file


@pytest.fixture
def served(tmp_path: Path) -> Iterator[tuple[dict[str, str], Path]]:
    ready = tmp_path / "ready.json"
    options = ["--clock", "virtual", "--tcp", "127.0.0.1:0", "--control", "127.0.0.1:0", "--ready-file", str(ready)]
    proc = subprocess.Popen(
        [sys.executable, "-m", "c20sim", "serve", *options], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        yield wait_for_ready_file(ready, proc), ready
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=10)


def ctl(ready: Path, *args: str) -> subprocess.CompletedProcess[str]:
    command = [sys.executable, "-m", "c20sim", "ctl", "--ready-file", str(ready), *args]
    return subprocess.run(command, capture_output=True, text=True, timeout=20, check=False)


def test_a_closed_pipe_ends_the_output_without_a_traceback(served: tuple[dict[str, str], Path]) -> None:
    info, ready = served
    host, port = info["tcp"].rsplit(":", 1)
    frame = encode(ReadRequest(1, 0x2100, 1))
    with socket.create_connection((host, int(port)), timeout=5) as sock:
        for _ in range(3):
            sock.sendall(frame)
            got = b""
            while len(got) < 7:
                chunk = sock.recv(64)
                assert chunk, "the server closed the connection"
                got += chunk
    for args in (["frames"], ["frames", "--format", "json"], ["state"]):
        # stdout is a pipe whose reader has gone, as after `| head -1`: the first write fails with EPIPE
        read_end, write_end = os.pipe()
        os.close(read_end)
        command = [sys.executable, "-m", "c20sim", "ctl", "--ready-file", str(ready), *args]
        try:
            proc = subprocess.run(command, stdout=write_end, stderr=subprocess.PIPE, timeout=20, check=False)
        finally:
            os.close(write_end)
        assert (args, proc.returncode, proc.stderr) == (args, 0, b"")
    lines = ctl(ready, "frames").stdout.splitlines()
    assert len(lines) == 6
    assert " rx 01 03 21 00 00 01 8E 36" in lines[0]


def test_a_refused_key_exits_1_with_a_line_saying_so(served: tuple[dict[str, str], Path]) -> None:
    _, ready = served
    result = ctl(ready, "key", "forward")  # the run channel is communication: the panel's forward is refused
    assert result.returncode == 1
    assert result.stdout == "key forward: refused; drive 1: stopped, 0 rpm, bus 48.0 V, no fault\n"
    assert result.stderr == (
        "c20sim: key forward: refused by the drive (stopped, run channel 2 = communication); "
        "the panel's run keys need the keypad channel: ctl run-channel keypad\n"
    )
    result = ctl(ready, "key", "stop", "--format", "json")
    assert (result.returncode, result.stderr) == (0, "")
    assert json.loads(result.stdout)["accepted"] is True


def test_a_refused_reset_exits_1(served: tuple[dict[str, str], Path]) -> None:
    _, ready = served
    assert ctl(ready, "fault", "16", "--persistent").returncode == 0
    result = ctl(ready, "key", "reset")
    assert result.returncode == 1
    assert result.stderr == (
        "c20sim: key reset: refused by the drive: fault 16 was latched to hold until released; release it (ctl clear) "
        "and reset\n"
    )
    result = ctl(ready, "clear", "--no-reset")  # the persistent fault's cause ends; no reset asked
    assert (result.returncode, result.stderr) == (0, "")
    assert ctl(ready, "fault", "16", "--persistent").returncode == 0
    result = ctl(ready, "clear")
    assert (result.returncode, result.stderr) == (0, "")
    said, _, state = result.stdout.partition("; drive 1: ")
    assert (said, state.endswith(", 0 rpm, bus 48.0 V, no fault\n")) == ("clear: reset done", True)


def test_format_text_and_json_with_rounded_floats(served: tuple[dict[str, str], Path]) -> None:
    _, ready = served
    ctl(ready, "advance", "0.123456789")
    result = ctl(ready, "state", "--drive", "1", "--format", "text")
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert "t: 0.123457" in lines
    assert "state: stopped" in lines
    assert "conditions.supply_v: 48.0" in lines
    assert "conditions.hall_fault: -" in lines
    assert "link_faults.offline: no" in lines
    assert "link_faults.active: (none)" in lines
    bus = next(line for line in lines if line.startswith("bus_v: "))
    assert len(bus.split(".")[-1]) <= 3
    as_json = json.loads(ctl(ready, "--format", "json", "--drive", "1", "state").stdout)
    assert as_json["t"] == 0.123457
    assert as_json["bus_v"] == round(as_json["bus_v"], 3)
    result = ctl(ready, "frames", "--format", "json")
    assert json.loads(result.stdout) == {"frames": [], "next": 0, "log_dropped": 0}


def test_rounding_and_text_rendering() -> None:
    assert rounded({"t": 1.23456789, "bus_v": 47.99208130658441, "x": [0.12345, {"model_t": 0.1234567}]}) == {
        "t": 1.234568,
        "bus_v": 47.992,
        "x": [0.123, {"model_t": 0.123457}],
    }
    assert render({"a": {"b": 1.00001, "c": [1, 2]}, "d": [{"e": True}], "f": {}}, "text") == (
        "a.b: 1.0\na.c: 1, 2\nd[0].e: yes\nf: (none)\n"
    )
    assert render({"a": 0.1 + 0.2}, "json") == '{\n  "a": 0.3\n}\n'


def test_an_action_prints_one_line_of_what_it_did_and_json_when_asked(served: tuple[dict[str, str], Path]) -> None:
    """ctl's actions answer in one line of words (what was asked, then what the drive is now); a reading
    prints its JSON answer; --format json prints any answer whole."""
    _, ready = served
    result = ctl(ready, "set", "supply_v=30")
    assert (result.returncode, result.stderr) == (0, "")
    assert result.stdout.startswith("set supply_v=30: drive 1: stopped, 0 rpm, bus ")
    assert result.stdout.endswith(" V, no fault\n") and result.stdout.count("\n") == 1
    result = ctl(ready, "link", "offline=true")
    assert result.stdout == "link offline=true: link faults: offline\n"
    assert ctl(ready, "link", "--clear").stdout == "link --clear: link faults: none\n"
    result = ctl(ready, "fault", "16", "--persistent")
    assert result.stdout.startswith("fault 16 persistent: drive 1: fault, 0 rpm, bus ")
    assert result.stdout.endswith(" V, fault 16 OH2: power module overheat\n")
    as_json = json.loads(ctl(ready, "set", "supply_v=48", "--format", "json").stdout)
    assert (as_json["address"], as_json["conditions"]["supply_v"]) == (1, 48.0)
    assert json.loads(ctl(ready, "causes").stdout)["causes"]["undervoltage"] is False  # a reading: JSON


def test_the_new_users_first_refusals_say_why(served: tuple[dict[str, str], Path]) -> None:
    """What a new user met (a review of the first hour): a reset with no fault is no refusal, a refused run key
    names the channel and how to change it, a locked function code says so, a fault code may be hex."""
    _, ready = served
    result = ctl(ready, "key", "reset")
    assert (result.returncode, result.stderr) == (0, "")
    assert result.stdout.startswith("key reset: no fault to reset; drive 1: stopped, 0 rpm, ")
    result = ctl(ready, "clear")
    assert (result.returncode, result.stderr) == (0, "")
    assert result.stdout.startswith("clear: no fault to reset; drive 1: stopped, ")
    result = ctl(ready, "key", "forward")
    assert (result.returncode, result.stderr) == (
        1,
        "c20sim: key forward: refused by the drive (stopped, run channel 2 = communication); "
        "the panel's run keys need the keypad channel: ctl run-channel keypad\n",
    )
    result = ctl(ready, "write", "2001H", "5000")  # in the register's units, read as exercise reads it
    assert (result.returncode, result.stderr) == (
        2,
        "c20sim: PUT /drives/1/registers/2001H: 400: 2001H communication speed setting: 5000 is outside 0 rpm "
        "to 3000 rpm\n",
    )
    result = ctl(ready, "write", "2001H", "--raw", "5000")  # the raw word goes to the drive, which refuses it
    assert result.stderr.endswith(
        "2001H = 5000 refused: exception 0x03 (illegal data value), as a master would get it: 2001H takes 0-3000\n"
    )
    assert ctl(ready, "fault", "16", "--cause", "overheat").stderr == (
        "c20sim: ctl fault: give a fault code or --cause NAME, not both\n"
    )
    result = ctl(ready, "fault", "0x10")
    assert (result.returncode, result.stderr) == (0, "")
    assert result.stdout.endswith(", fault 16 OH2: power module overheat\n")
    assert ctl(ready, "link", "delay").stderr == "c20sim: 'delay': give KEY=VALUE, such as offline=true\n"
