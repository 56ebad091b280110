"""ctl and the API's answers as a new user found them: a written value means what a read's ``value`` means (in the
register's units or by name, as exercise takes it; the raw word by ``raw``), checked over the wire by pymodbus."""

from __future__ import annotations

import json
import re
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.automation.test_control_subprocess import master, read
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


def put(info: dict[str, str], path: str, body: str) -> tuple[int, Any]:
    """One PUT with urllib (not c20sim's client), its status and JSON answer."""
    request = urllib.request.Request(
        info["control"] + path, data=body.encode(), method="PUT", headers={"Content-Type": "application/json"}
    )
    try:
        with urllib.request.urlopen(request, timeout=10) as answer:
            return answer.status, json.loads(answer.read())
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read())


def test_ctl_write_takes_what_exercise_takes(served: tuple[dict[str, str], Path]) -> None:
    info, ready = served
    with master(info) as client:
        result = ctl(ready, "write", "accel", "2.5")
        assert (result.returncode, result.stdout, result.stderr) == (0, "write accel 2.5: 2003H = 2.5 s\n", "")
        assert read(client, 0x2003) == 25  # 0.1 s a count, read over the wire
        result = ctl(ready, "write", "accel", "--raw", "7")
        assert (result.returncode, result.stdout, result.stderr) == (0, "write accel --raw 7: 2003H = 0.7 s\n", "")
        assert read(client, 0x2003) == 7
        result = ctl(ready, "write", "accel", "0x10", "--format", "json")  # not a hex register: 0x10 is no amount
        assert (result.returncode, result.stdout) == (2, "")
        assert (
            result.stderr
            == "c20sim: PUT /drives/1/registers/accel: 400: 2003H acceleration time: '0x10' is not a number\n"
        )
        result = ctl(ready, "write", "command", "forward")
        assert (result.returncode, result.stdout, result.stderr) == (
            0,
            "write command forward: 2000H = forward run\n",
            "",
        )
        assert read(client, 0x2000) == 1
        refused = {
            "2.55": "2.55 is not a whole number of its steps of 0.1 s; the nearest is 2.5 s",
            "nan": "nan is not a finite number; give one from 0.1 s to 600.0 s",
            "inf": "inf is not a finite number; give one from 0.1 s to 600.0 s",
            "6553.6": "6553.6 is outside 0.1 s to 600.0 s",  # raw 65536: never wrapped to 0
            "-1": "-1 is outside 0.1 s to 600.0 s",
        }
        for typed, said in refused.items():
            result = (
                ctl(ready, "write", "accel", "--", typed)
                if typed.startswith("-")
                else ctl(ready, "write", "accel", typed)
            )
            assert (typed, result.returncode, result.stdout, result.stderr) == (
                typed,
                2,
                "",
                f"c20sim: PUT /drives/1/registers/accel: 400: 2003H acceleration time: {said}\n",
            )
        assert read(client, 0x2003) == 7  # none of them reached the drive
        result = ctl(ready, "write", "accel")
        assert (result.returncode, result.stderr) == (
            2,
            "c20sim: PUT /drives/1/registers/accel: 400: give the value in the register's units or by name, such as "
            '{"value": 2.5} or {"value": "forward"}, or the raw word, such as {"raw": 1500}; not both\n',
        )
        result = ctl(ready, "panel", "decel", "1.5")
        assert (result.returncode, result.stdout, result.stderr) == (0, "panel decel 1.5: 2004H = 1.5 s\n", "")
        assert read(client, 0x2004) == 15


def test_the_api_takes_a_value_as_a_read_gives_it_and_the_raw_word_as_raw(
    served: tuple[dict[str, str], Path],
) -> None:
    info, _ = served
    path = "/drives/1/registers/accel"
    shown = {"register": "2003H", "address": 0x2003, "name": "acceleration time", "unit": "s"}
    with master(info) as client:
        assert put(info, path, '{"value": 0.5}') == (200, {**shown, "raw": 5, "value": 0.5, "text": "0.5 s"})
        assert read(client, 0x2003) == 5
        assert put(info, path, '{"value": "2.5"}') == (200, {**shown, "raw": 25, "value": 2.5, "text": "2.5 s"})
        assert put(info, path, '{"raw": 15}') == (200, {**shown, "raw": 15, "value": 1.5, "text": "1.5 s"})
        assert read(client, 0x2003) == 15
        status, was = put(info, path, '{"raw": 7}')
        assert (status, was["value"]) == (200, 0.7000000000000001)  # 7 x 0.1 s, as a float carries it
        assert put(info, path, json.dumps({"value": was["value"]}))[1]["raw"] == 7  # what a read gives, written back
        # the old form, kept: a JSON integer value is the raw word (the dashboard and the browser page send it)
        assert put(info, path, '{"value": 30}') == (200, {**shown, "raw": 30, "value": 3.0, "text": "3.0 s"})
        status, said = put(info, "/drives/1/registers/command", '{"value": "forward"}')
        assert (status, said["raw"], said["text"]) == (200, 1, "forward run")
        assert read(client, 0x2000) == 1
        assert put(info, path, '{"value": 0.5, "raw": 5}')[0] == 400
        assert put(info, path, '{"value": 1e400}') == (
            400,
            {"error": "2003H acceleration time: inf is not a finite number; give one from 0.1 s to 600.0 s"},
        )
        assert put(info, path, '{"value": true}') == (
            400,
            {"error": "value: expected a number or a value's name, got true"},
        )
        assert put(info, path, '{"raw": 65536}') == (400, {"error": "raw: 65536 is outside 0-65535"})
        assert put(info, path, json.dumps({"value": "9" * 5000})) == (
            400,
            {"error": "value: a text of 5000 characters; an amount or a name is 256 at most"},
        )
        assert read(client, 0x2003) == 30


def test_a_refused_reset_says_why_as_the_drive_decides(served: tuple[dict[str, str], Path]) -> None:
    """The cause still there, the cause ended but the bus not yet recovered, a fault latched to hold: three reasons,
    each from the drive's own reset guard, in ctl's line and in the API's answer (``refused``)."""
    _, ready = served
    for args in (("run-channel", "keypad"), ("write", "setpoint", "1000"), ("key", "forward"), ("advance", "2")):
        assert ctl(ready, *args).returncode == 0, args  # running: a stopped drive loses its power, it does not trip
    assert ctl(ready, "fault", "--cause", "undervoltage").returncode == 0
    assert ctl(ready, "advance", "1").returncode == 0  # the bus falls below the trip level: UV
    result = ctl(ready, "key", "reset")
    assert (result.returncode, result.stderr) == (
        1,
        "c20sim: key reset: refused by the drive: its cause, undervoltage, is still present; end it "
        "(ctl clear --cause undervoltage)\n",
    )
    result = ctl(ready, "clear", "--no-reset")
    assert (result.returncode, result.stderr) == (0, "")
    result = ctl(ready, "key", "reset", "--format", "json")
    answer = json.loads(result.stdout)
    assert (result.returncode, answer["accepted"], answer["fault_code"], answer["refused"]) == (
        1,
        False,
        10,
        "its cause, undervoltage, has ended, but the drive has not recovered from it yet; let time pass "
        "(ctl advance 1 on a virtual clock) and reset again (ctl key reset)",
    )
    result = ctl(ready, "clear")  # the bus is still low: the same reason
    assert (result.returncode, result.stderr) == (
        1,
        "c20sim: reset refused by the drive: its cause, undervoltage, has ended, but the drive has not recovered "
        "from it yet; let time pass (ctl advance 1 on a virtual clock) and reset again (ctl key reset)\n",
    )
    assert ctl(ready, "advance", "1").returncode == 0  # the bus charges back above its recover level
    result = ctl(ready, "key", "reset")
    assert (result.returncode, result.stdout, result.stderr) == (
        0,
        "key reset: accepted; drive 1: coasting, 0 rpm, bus 48.0 V, no fault\n",
        "",
    )
    assert ctl(ready, "fault", "16", "--persistent").returncode == 0
    result = ctl(ready, "key", "reset")
    assert (result.returncode, result.stderr) == (
        1,
        "c20sim: key reset: refused by the drive: fault 16 was latched to hold until released; release it "
        "(ctl clear) and reset\n",
    )
    result = ctl(ready, "clear")
    assert (result.returncode, result.stdout, result.stderr) == (
        0,
        "clear: reset done; drive 1: coasting, 0 rpm, bus 48.0 V, no fault\n",
        "",
    )


def test_the_nits_a_new_user_met(served: tuple[dict[str, str], Path]) -> None:
    _, ready = served
    result = ctl(ready, "generators")
    assert (result.returncode, result.stdout) == (0, "generators: none running\n")
    assert ctl(ready, "set", 'supply_v={"ramp": 30, "over": 5}').returncode == 0
    assert ctl(ready, "generators").stdout == "generators: supply_v\n"
    assert ctl(ready, "generators", "--clear", "supply_v").stdout == "generators --clear supply_v: none running\n"
    assert ctl(ready, "set", "hall_fault=stuck0").returncode == 0
    assert (
        json.loads(ctl(ready, "state", "--drive", "1", "--format", "json").stdout)["conditions"]["hall_fault"]
        == "stuck0"
    )
    result = ctl(ready, "set", "hall_fault=false")  # false is "no fault", as null is
    assert (result.returncode, result.stderr) == (0, "")
    assert (
        json.loads(ctl(ready, "state", "--drive", "1", "--format", "json").stdout)["conditions"]["hall_fault"] is None
    )
    result = ctl(ready, "set", "hall_fault=none")
    assert (result.returncode, result.stderr) == (
        2,
        "c20sim: PUT /drives/1/conditions: 400: hall_fault: expected null or false (none), 'stuck0', 'stuck7' or "
        "'sequence', got \"none\"\n",
    )


def test_a_busy_control_port_is_worded_as_the_other_busy_ports() -> None:
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        port = holder.getsockname()[1]
        options = ["--clock", "virtual", "--tcp", "127.0.0.1:0", "--control", f"127.0.0.1:{port}"]
        result = subprocess.run(
            [sys.executable, "-m", "c20sim", "serve", *options], capture_output=True, text=True, timeout=30, check=False
        )
    assert (result.returncode, result.stderr) == (
        2,
        f"c20sim: --control 127.0.0.1:{port}: the port is in use; stop the program holding it or choose another "
        "port (0 picks a free one)\n",
    )


@pytest.fixture
def realtime(tmp_path: Path) -> Iterator[Path]:
    ready = tmp_path / "ready.json"
    options = ["--tcp", "127.0.0.1:0", "--control", "127.0.0.1:0", "--ready-file", str(ready)]
    proc = subprocess.Popen(
        [sys.executable, "-m", "c20sim", "serve", *options], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        wait_for_ready_file(ready, proc)
        yield ready
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=10)


def test_a_change_on_a_realtime_clock_is_described_after_it_has_acted(realtime: Path) -> None:
    """What the one-line answer says is the drive once the change has acted: a step past a new supply (the bus
    already falling), the trip a fault's cause brings about; not the drive as it was a microsecond after."""
    ready = realtime
    for args in (("run-channel", "keypad"), ("write", "setpoint", "1000"), ("key", "forward")):
        assert ctl(ready, *args).returncode == 0, args
    deadline = time.monotonic() + 20
    while json.loads(ctl(ready, "state", "--drive", "1", "--format", "json").stdout)["speed_rpm"] < 990:
        assert time.monotonic() < deadline, "the drive never reached 1000 rpm"
    result = ctl(ready, "set", "supply_v=30")
    line = re.fullmatch(r"set supply_v=30: drive 1: forward, (\d+) rpm, bus (\d+\.\d) V, no fault\n", result.stdout)
    assert line is not None, result.stdout
    assert 30.0 <= float(line.group(2)) < 48.0  # the bus has begun to fall to the new supply
    assert ctl(ready, "set", "supply_v=48").returncode == 0
    result = ctl(ready, "fault", "--cause", "undervoltage")
    assert (result.returncode, result.stderr) == (0, "")
    assert re.fullmatch(
        r"fault undervoltage: drive 1: undervoltage: supply_v 10; drive 1: fault, \d+ rpm, bus \d+\.\d V, "
        r"fault 10 UV: bus undervoltage\n",
        result.stdout,
    ), result.stdout
    assert ctl(ready, "read", "fault").stdout == "2102H fault code: UV: bus undervoltage\n"


def test_a_fault_cause_on_a_virtual_clock_says_it_has_not_tripped_yet(served: tuple[dict[str, str], Path]) -> None:
    _, ready = served
    for args in (("run-channel", "keypad"), ("write", "setpoint", "1000"), ("key", "forward"), ("advance", "2")):
        assert ctl(ready, *args).returncode == 0, args
    result = ctl(ready, "fault", "--cause", "undervoltage")
    assert (result.returncode, result.stdout, result.stderr) == (
        0,
        "fault undervoltage: drive 1: undervoltage: supply_v 10; drive 1: forward, 1000 rpm, bus 48.0 V, no fault; "
        "not tripped yet: the drive trips when its physics says (ctl advance 1 moves a virtual clock)\n",
        "",
    )
    assert ctl(ready, "advance", "1").returncode == 0
    assert ctl(ready, "read", "fault").stdout == "2102H fault code: UV: bus undervoltage\n"
