"""One register vocabulary for every tool: names, short names, addresses and Fgg.nn, with a did-you-mean.

Through each tool's own path: ctl and exercise as a user types them, the control API on its port, a scenario
file, the pytest handle; and the fault code's name wherever a value is said (ctl, the frame log, exercise).
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest
from pymodbus.client import ModbusTcpClient

from c20sim.drive.profile import load_profile
from c20sim.testing import C20Sim
from c20sim.wire.errors import C20SimError
from c20sim.wire.registers import FIXED_REGISTERS, Reg
from c20sim.wire.vocabulary import SHORT_NAMES, UnknownRegister, register_names, resolve_register
from tests.conftest import wait_for_ready_file

HELP = (
    "give a name such as speed or status, an address such as 3006H, 0x3006 or 12294, or a function code such as F00.10"
)


def test_every_spelling_of_a_register_is_one_address() -> None:
    registers = load_profile().registers
    for spelling in ("speed", "motor_speed", "MOTOR_SPEED", "motor speed", "Motor-Speed", "3006H", "3006h", "0x3006"):
        assert resolve_register(spelling, registers) == 0x3006, spelling
    assert resolve_register("12294", registers) == 0x3006  # a whole number is decimal, as Modbus tools count
    assert resolve_register(0x3006, registers) == 0x3006
    assert resolve_register("F00.10", registers) == 0x000A
    assert resolve_register("setpoint") == resolve_register("speed setpoint") == 0x2001
    assert resolve_register("communication speed setting") == 0x2001  # the sheet's name
    assert resolve_register("status") == resolve_register("status word 1") == resolve_register("status1") == 0x2100


def test_every_name_is_one_register_and_every_fixed_register_has_its_names() -> None:
    names = register_names()
    every = [*SHORT_NAMES.items(), *((r.name.lower(), int(r)) for r in Reg)]
    every += [(spec.name, spec.address) for spec in FIXED_REGISTERS.values()]
    meant: dict[str, set[int]] = {}
    for name, address in every:  # case, spaces, - and _ do not count
        meant.setdefault("_".join(name.lower().replace("-", " ").replace("_", " ").split()), set()).add(address)
    assert {key: found for key, found in meant.items() if len(found) > 1} == {}  # no spelling names two registers
    assert len(names) == len(meant)
    for name, address in names.items():
        assert resolve_register(name) == address
    for spec in FIXED_REGISTERS.values():
        assert resolve_register(spec.name) == spec.address  # the sheet's name of every fixed register
        assert resolve_register(Reg(spec.address).name.lower()) == spec.address
    for short, address in SHORT_NAMES.items():
        assert names[short] == address


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("sped", f"unknown register 'sped'; did you mean 'speed'? ({HELP})"),
        ("motor_sped", f"unknown register 'motor_sped'; did you mean 'motor_speed'? ({HELP})"),
        ("torque", f"unknown register 'torque' ({HELP})"),
        ("", f"register '': empty; {HELP}"),
        ("70000", "register '70000': an address is 0000H-FFFFH (0-65535)"),
        (
            "2100",
            "register '2100': the profile c20-400hr has no register 2100 (F08.52); did you mean 2100H? "
            "(a whole number is decimal)",
        ),
        ("2010H", "register '2010H': the profile c20-400hr has no register 2010H"),
        ("F40.01", "register 'F40.01': 'F40.01': group must be 00-31 and number 00-255"),
    ],
)
def test_a_misspelt_register_is_one_line_with_a_did_you_mean(text: str, message: str) -> None:
    with pytest.raises(UnknownRegister) as caught:
        resolve_register(text, load_profile().registers, "the profile c20-400hr")
    assert str(caught.value) == message


@pytest.fixture
def served(tmp_path: Path) -> Iterator[tuple[dict[str, str], Path]]:
    ready = tmp_path / "ready.json"
    options = ["--clock", "virtual", "--tcp", "127.0.0.1:0", "--modbus-tcp", "127.0.0.1:0"]
    options += ["--control", "127.0.0.1:0", "--ready-file", str(ready)]
    proc = subprocess.Popen(
        [sys.executable, "-m", "c20sim", "serve", *options], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        yield wait_for_ready_file(ready, proc), ready
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=10)


def c20sim(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "c20sim", *args], capture_output=True, text=True, timeout=30, check=False
    )


def test_ctl_and_exercise_take_the_same_names_and_say_a_fault_by_its_name(
    served: tuple[dict[str, str], Path],
) -> None:
    info, ready = served
    for name in ("speed", "motor_speed", "motor speed", "3006H", "0x3006", "12294"):
        result = c20sim("ctl", "--ready-file", str(ready), "read", name)
        assert (result.returncode, result.stdout, result.stderr) == (0, "3006H motor speed: 0 rpm\n", "")
        result = c20sim("exercise", f"tcp://{info['tcp']}", "read", name)
        assert (result.returncode, result.stdout, result.stderr) == (0, "3006H motor speed: 0 rpm\n", "")
    result = c20sim("ctl", "--ready-file", str(ready), "read", "sped")
    assert result.returncode == 2
    assert result.stderr == (
        f"c20sim: GET /drives/1/registers/sped: 400: unknown register 'sped'; did you mean 'speed'? ({HELP})\n"
    )
    assert c20sim("ctl", "--ready-file", str(ready), "fault", "10").returncode == 0  # UV latched
    result = c20sim("ctl", "--ready-file", str(ready), "read", "fault")
    assert result.stdout == "2102H fault code: UV: bus undervoltage\n"
    result = c20sim("ctl", "--ready-file", str(ready), "read", "fault", "--format", "json")
    assert json.loads(result.stdout) == {
        "register": "2102H",
        "address": 0x2102,
        "name": "fault code",
        "raw": 10,
        "value": 10.0,
        "unit": "",
        "text": "UV: bus undervoltage",
    }
    result = c20sim("exercise", f"modbus-tcp://{info['modbus_tcp']}", "read", "fault", "current_fault")
    assert result.stdout == "2102H fault code: UV: bus undervoltage\n300BH current fault type: UV: bus undervoltage\n"
    # an independent master's read, in the frame log's words
    client = ModbusTcpClient("127.0.0.1", port=int(info["modbus_tcp"].rsplit(":", 1)[1]), timeout=2, retries=0)
    assert client.connect()
    try:
        assert client.read_holding_registers(0x2102, count=1, device_id=1).registers == [10]
    finally:
        client.close()
    result = c20sim("ctl", "--ready-file", str(ready), "frames", "--last", "2")
    assert result.stdout.splitlines()[-1].endswith(
        " tx 00 01 00 00 00 05 01 03 02 00 0A 2102H = 000A: UV: bus undervoltage"
    )


def test_the_api_takes_every_spelling_and_refuses_a_misspelt_one_with_400(
    served: tuple[dict[str, str], Path],
) -> None:
    info, _ = served
    base = info["control"]
    for name in ("speed", "motor%20speed", "MOTOR_SPEED", "3006H", "0x3006", "12294"):
        with urllib.request.urlopen(f"{base}/drives/1/registers/{name}", timeout=10) as response:
            assert json.loads(response.read())["register"] == "3006H"
    with pytest.raises(urllib.error.HTTPError) as caught:
        urllib.request.urlopen(f"{base}/drives/1/registers/setpiont", timeout=10)
    assert caught.value.code == 400
    assert json.loads(caught.value.read())["error"] == (
        f"unknown register 'setpiont'; did you mean 'setpoint'? ({HELP})"
    )


def test_a_scenario_names_registers_in_the_same_words(tmp_path: Path) -> None:
    path = tmp_path / "s.toml"
    path.write_text('[[step]]\nat = 0\nwrite = { setpoint = 1200, "speed source" = 3 }\nexpect = { status = 3 }\n')
    result = c20sim("run-scenario", str(path))
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines()[1:] == [
        "  ok   step 1 (at 0 s): write setpoint = 1200: taken",
        "  ok   step 1 (at 0 s): write speed source = 3: taken",
        "  ok   step 1 (at 0 s): 2100H (status word 1) = 3 (stopped), expected 3",
        "passed: 3 check(s)",
    ]
    path.write_text("[[step]]\nat = 0\nexpect = { statu = 3 }\n")
    result = c20sim("run-scenario", str(path))
    assert result.returncode == 2
    assert result.stderr == (
        f"c20sim: {path}: step 1 (at 0 s), key 'expect': unknown register 'statu'; did you mean 'status'? ({HELP})\n"
    )
    path.write_text("[[step]]\nat = 0\nexpect = { 2100 = 3 }\n")
    result = c20sim("run-scenario", str(path))
    assert result.stderr == (
        f"c20sim: {path}: step 1 (at 0 s), key 'expect': register '2100': the profile c20-400hr has no register "
        "2100 (F08.52); did you mean 2100H? (a whole number is decimal)\n"
    )


def test_the_pytest_handle_takes_the_same_names() -> None:
    with C20Sim.start() as sim:
        assert sim.read("speed setpoint") == sim.read("2001H") == sim.read(0x2001) == sim.read("8193") == 0
        sim.inject_fault(10)
        assert sim.read("fault") == 10
        with pytest.raises(C20SimError) as caught:
            sim.read("speeed")
        assert str(caught.value) == f"unknown register 'speeed'; did you mean 'speed'? ({HELP})"


def test_the_readmes_example_prints_what_it_shows(served: tuple[dict[str, str], Path]) -> None:
    """README, "One name for each register": its two commands, run against a drive at 1500 rpm, then faulted."""
    import re

    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    block = re.search(r"^```\n(\$ c20sim ctl --ready-file ready\.json read speed\n.*?)^```", readme, re.M | re.S)
    assert block is not None
    lines = block.group(1).splitlines()
    assert len(lines) == 4
    info, ready = served
    tcp = f"tcp://{info['tcp']}"
    assert c20sim("exercise", tcp, "write", "setpoint", "1500").returncode == 0
    assert c20sim("exercise", tcp, "write", "command", "forward").returncode == 0
    assert c20sim("ctl", "--ready-file", str(ready), "advance", "5").returncode == 0
    command = lines[0].removeprefix("$ c20sim ").replace("ready.json", str(ready)).split()
    assert c20sim(*command).stdout == lines[1] + "\n"
    assert c20sim("ctl", "--ready-file", str(ready), "fault", "--cause", "undervoltage").returncode == 0
    assert c20sim("ctl", "--ready-file", str(ready), "advance", "1").returncode == 0
    command = lines[2].removeprefix("$ c20sim ").replace("tcp://127.0.0.1:5020", tcp).split()
    assert c20sim(*command).stdout == lines[3] + "\n"
