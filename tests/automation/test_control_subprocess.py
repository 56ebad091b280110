"""``c20sim serve --clock virtual --control`` as CI in another language uses it: HTTP beside Modbus."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from pymodbus import FramerType
from pymodbus.client import ModbusTcpClient

from c20sim.control import call
from c20sim.errors import C20SimError
from tests.conftest import wait_for_ready_file


@pytest.fixture
def served(tmp_path: Path) -> Iterator[tuple[dict[str, str], Path]]:
    ready = tmp_path / "ready.json"
    options = ["--clock", "virtual", "--tcp", "127.0.0.1:0", "--control", "127.0.0.1:0", "--ready-file", str(ready)]
    proc = subprocess.Popen(
        [sys.executable, "-m", "c20sim", "serve", *options],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        yield wait_for_ready_file(ready, proc), ready
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=10)
        assert proc.returncode == 0, err
        assert "virtual clock; tcp 127.0.0.1:" in out and "; control http://127.0.0.1:" in out
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def read(client: ModbusTcpClient, register: int) -> int:
    response = client.read_holding_registers(register, count=1, device_id=1)
    assert not response.isError(), response
    return int(response.registers[0])


def write(client: ModbusTcpClient, register: int, value: int) -> None:
    response = client.write_register(register, value, device_id=1)
    assert not response.isError(), response


def test_undervoltage_trip_over_http_and_modbus(served: tuple[dict[str, str], Path]) -> None:
    info, _ = served
    url = info["control"]
    assert url.startswith("http://127.0.0.1:")
    host, port = info["tcp"].rsplit(":", 1)
    client = ModbusTcpClient(host, port=int(port), framer=FramerType.RTU, timeout=2, retries=0)
    assert client.connect()
    try:
        write(client, 0x2001, 1500)
        write(client, 0x2000, 1)  # forward run
        assert call(url, "POST", "/time/advance", {"seconds": 2.0}) == {"t": 2.0}
        assert read(client, 0x2100) == 1  # forward running
        assert read(client, 0x3006) == 1500  # at speed after the 0.5 s ramp

        state: dict[str, Any] = call(url, "PUT", "/drives/1/conditions", {"supply_v": 15})
        assert (state["supply_v"], state["state"]) == (15.0, "forward")
        call(url, "POST", "/time/advance", {"seconds": 0.1})
        assert read(client, 0x2100) == 4  # fault
        assert read(client, 0x2102) == 0x0A  # undervoltage, as the sheet's example
        state = call(url, "GET", "/drives/1")
        assert (state["state"], state["fault_code"], state["t"]) == ("fault", 0x0A, 2.1)

        # the cause persists: a reset is refused; with the supply back it is taken
        assert call(url, "POST", "/drives/1/keypad", {"key": "reset"})["accepted"] is False
        call(url, "PUT", "/drives/1/conditions", {"supply_v": 48})
        call(url, "POST", "/time/advance", {"seconds": 0.5})
        write(client, 0x2000, 7)  # fault reset over Modbus
        assert read(client, 0x2102) == 0
        assert read(client, 0x2100) == 3  # stopped

        log = call(url, "GET", "/frames?slave=1")["frames"]
        requests = [(r["hex"], r["text"]) for r in log if r["dir"] == "rx"]
        assert requests[:2] == [
            ("01 06 20 01 05 DC D1 03", "write 2001H = 05DC: 1500 rpm"),
            ("01 06 20 00 00 01 43 CA", "write 2000H = 0001: forward run"),
        ]
        assert [r["seq"] for r in log] == list(range(len(log)))
    finally:
        client.close()


def test_bad_requests_say_what_is_wrong(served: tuple[dict[str, str], Path]) -> None:
    url = served[0]["control"]
    with pytest.raises(C20SimError, match=r"^GET /drives/9: 404: no drive at address 9; drives: 1$"):
        call(url, "GET", "/drives/9")
    with pytest.raises(
        C20SimError, match=r"^PUT /drives/1/conditions: 400: unknown condition 'supply'; did you mean 'supply_v'\?"
    ):
        call(url, "PUT", "/drives/1/conditions", {"supply": 30})
    with pytest.raises(C20SimError, match=r"^POST /time/advance: 400: seconds: expected a number, got \"1\"$"):
        call(url, "POST", "/time/advance", {"seconds": "1"})


def ctl(ready: Path, *args: str) -> subprocess.CompletedProcess[str]:
    command = [sys.executable, "-m", "c20sim", "ctl", "--ready-file", str(ready), *args]
    return subprocess.run(command, capture_output=True, text=True, timeout=20, check=False)


def test_ctl_from_a_shell(served: tuple[dict[str, str], Path]) -> None:
    _, ready = served
    result = ctl(ready, "fault", "16", "--persistent")
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["fault_name"].startswith("OH2")
    result = ctl(ready, "read", "fault_code")
    assert json.loads(result.stdout)["raw"] == 16
    result = ctl(ready, "advance", "1.5")
    assert json.loads(result.stdout) == {"t": 1.5}
    result = ctl(ready, "set", "hall_fault=stuck9", "--drive", "1")
    assert result.returncode == 2
    assert result.stderr == (
        "c20sim: PUT /drives/1/conditions: 400: hall_fault: expected null, 'stuck0', 'stuck7' or 'sequence', "
        'got "stuck9"\n'
    )
    result = ctl(ready, "frames", "--last", "0")
    assert (result.returncode, result.stdout) == (2, "")
    assert result.stderr.endswith("error: argument --last: 0 must be at least 1\n")
