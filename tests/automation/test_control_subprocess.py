"""``c20sim serve --clock virtual --control`` as CI in another language uses it: HTTP beside Modbus."""

from __future__ import annotations

import contextlib
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
from pymodbus.exceptions import ModbusIOException

from c20sim.control.ctl import call
from c20sim.wire.errors import C20SimError
from c20sim.wire.protocol import frame_time, transaction_time
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


@contextlib.contextmanager
def master(info: dict[str, str], timeout: float = 2.0) -> Iterator[ModbusTcpClient]:
    """A pymodbus master on the served RTU-over-TCP port, closed on the way out."""
    host, port = info["tcp"].rsplit(":", 1)
    client = ModbusTcpClient(host, port=int(port), framer=FramerType.RTU, timeout=timeout, retries=0)
    assert client.connect()
    try:
        yield client
    finally:
        client.close()


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
    with master(info) as client:
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
    result = ctl(ready, "fault", "16", "--persistent", "--format", "json")
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["fault_name"].startswith("OH2")
    result = ctl(ready, "read", "fault_code")  # one line, the fault by its name
    assert (result.returncode, result.stdout) == (0, "2102H fault code: OH2: power module overheat\n")
    result = ctl(ready, "read", "fault", "--format", "json")
    assert json.loads(result.stdout)["raw"] == 16
    result = ctl(ready, "advance", "1.5", "--format", "json")
    assert json.loads(result.stdout) == {"t": 1.5}
    result = ctl(ready, "set", "hall_fault=stuck9", "--drive", "1")
    assert result.returncode == 2
    assert result.stderr == (
        "c20sim: PUT /drives/1/conditions: 400: hall_fault: expected null or false (none), 'stuck0', 'stuck7' or 'sequence', "
        'got "stuck9"\n'
    )
    result = ctl(ready, "frames", "--last", "0")
    assert (result.returncode, result.stdout) == (2, "")
    assert result.stderr == (
        "c20sim ctl frames: argument --last: 0 must be at least 1 (see: c20sim ctl frames --help)\n"
    )


def test_ctl_fault_by_cause(served: tuple[dict[str, str], Path]) -> None:
    """``ctl fault --cause`` brings the cause about; the drive trips by its own physics, as the bench would."""
    info, ready = served
    with master(info) as client:
        write(client, 0x2001, 1500)
        write(client, 0x2000, 1)
        assert ctl(ready, "advance", "2").returncode == 0
        result = ctl(ready, "fault", "--cause", "undervoltage", "--format", "json")
        assert result.returncode == 0, result.stderr
        assert json.loads(result.stdout)["conditions"]["supply_v"] == 10.0  # half the 20 V trip level
        assert read(client, 0x2102) == 0  # not yet: the bus takes its time to fall
        ctl(ready, "advance", "0.5")
        assert read(client, 0x2102) == 0x0A
        causes = json.loads(ctl(ready, "causes").stdout)["causes"]
        assert (causes["undervoltage"], causes["overheat"]) == (True, False)
        result = ctl(ready, "clear", "--cause", "undervoltage", "--no-reset", "--format", "json")
        assert json.loads(result.stdout)["conditions"]["supply_v"] == 48.0
        ctl(ready, "advance", "1")
        assert json.loads(ctl(ready, "key", "reset", "--format", "json").stdout)["accepted"] is True
        assert read(client, 0x2102) == 0
    result = ctl(ready, "fault", "--cause", "undervoltag")
    assert (result.returncode, result.stdout) == (2, "")
    assert result.stderr.startswith(
        "c20sim: POST /drives/1/fault: 400: unknown cause 'undervoltag'; did you mean 'undervoltage'? (known: "
    )
    result = ctl(ready, "fault")
    assert result.stderr == "c20sim: ctl fault: give a fault code (such as 16) or --cause NAME (such as undervoltage)\n"


def test_counters_count_what_a_master_saw(served: tuple[dict[str, str], Path]) -> None:
    info, ready = served
    with master(info, timeout=0.3) as client:
        for _ in range(3):
            read(client, 0x2100)
        assert client.read_holding_registers(0x0032, count=1, device_id=1).exception_code == 0x02
        assert client.write_register(0x2100, 1, device_id=1).exception_code == 0x07
        assert ctl(ready, "link", "offline=true", "--drive", "1").returncode == 0
        with pytest.raises(ModbusIOException):  # silence: no reply
            client.read_holding_registers(0x2100, count=1, device_id=1)
        ctl(ready, "link", "--clear", "--drive", "1")
        client.send(bytes.fromhex("01 03 21 00 00 01 00 00"))  # a bad CRC: the drive answers 0x06
        assert client.recv(5) == bytes.fromhex("01 83 06 C1 32")
    counters = json.loads(ctl(ready, "counters").stdout)
    demand = counters.pop("line_demand")  # the live audit's: every frame on the line, the bad CRC's too
    assert (demand["transactions"], demand["baud"], demand["format"]) == (7, 19200, "8N1")
    # The line's time of those frames at 19200 8N1 with the 2 ms turnaround: 3 reads, 3 exception replies,
    # the silent read's request alone; the share is against the wall time they were spread over.
    read_time, refused_time = transaction_time(8, 7, 19200, 10, 0.002), transaction_time(8, 5, 19200, 10, 0.002)
    busy = 3 * read_time + 3 * refused_time + frame_time(8, 19200, 10)
    assert counters.pop("line_busy_s") == round(busy, 3)  # ctl prints 3 decimals
    assert 0.0 < counters.pop("line_share") <= 1.0
    assert counters == {
        "requests": 6,
        "replies": 3,
        "exceptions": {"0x02": 1, "0x06": 1, "0x07": 1},
        "crc_errors": 1,
        "length_errors": 0,
        "silences": 1,
        "injected": 1,
    }
    result = ctl(ready, "write", "F00.10", "--raw", "2500")
    assert (result.returncode, result.stdout) == (2, "")
    assert result.stderr == (
        "c20sim: PUT /drives/1/registers/F00.10: 409: F00.10 = 2500 refused: exception 0x04 (operation failed), "
        "as a master would get it: function codes are locked while 200EH = 0 (write 200EH = 1 first)\n"
    )


def test_ctl_against_something_that_is_not_the_api_is_one_line(served: tuple[dict[str, str], Path]) -> None:
    """A wrong --url (a Modbus port, another web server) is one sentence and exit 2, never a traceback."""
    info, _ = served
    modbus = info["tcp"]  # RTU over TCP: it never answers HTTP
    command = [sys.executable, "-m", "c20sim", "ctl", "--url", f"http://{modbus}", "state"]
    result = subprocess.run(command, capture_output=True, text=True, timeout=60, check=False)
    assert (result.returncode, result.stdout) == (2, "")
    assert result.stderr.startswith(f"c20sim: http://{modbus}: not c20sim's control API")
    assert "Traceback" not in result.stderr and len(result.stderr.splitlines()) == 1
    with subprocess.Popen(
        [sys.executable, "-m", "http.server", "0", "--bind", "127.0.0.1"], stdout=subprocess.PIPE, text=True
    ) as web:
        try:
            assert web.stdout is not None
            port = web.stdout.readline().split("port ")[1].split()[0]
            command = [sys.executable, "-m", "c20sim", "ctl", "--url", f"http://127.0.0.1:{port}", "info"]
            result = subprocess.run(command, capture_output=True, text=True, timeout=60, check=False)
        finally:
            web.terminate()
    assert (result.returncode, result.stdout) == (2, "")
    assert result.stderr == (
        f"c20sim: http://127.0.0.1:{port}: not c20sim's control API (its answer to GET / is not JSON); "
        "check --url or --ready-file\n"
    )


def test_ctl_clear_ends_every_cause_then_resets(served: tuple[dict[str, str], Path]) -> None:
    info, ready = served
    with master(info) as client:
        write(client, 0x2001, 1500)
        write(client, 0x2000, 1)
        ctl(ready, "advance", "2")
        ctl(ready, "fault", "--cause", "overheat")
        ctl(ready, "advance", "200")
        assert read(client, 0x2102) == 0x10
        result = ctl(ready, "clear")  # the ambient back, but the module is still hot: refused, and it says why
        assert result.returncode == 1
        assert result.stderr == (
            "c20sim: reset refused by the drive: its cause, overheat, has ended, but the drive has not recovered from "
            "it yet; let time pass (ctl advance 1 on a virtual clock) and reset again (ctl key reset)\n"
        )
        assert json.loads(ctl(ready, "causes").stdout)["causes"]["overheat"] is False
        ctl(ready, "advance", "600")
        assert ctl(ready, "clear").returncode == 0
        assert read(client, 0x2102) == 0


def test_ctl_sends_the_token_of_the_ready_file(tmp_path: Path) -> None:
    ready = tmp_path / "ready.json"
    options = ["--clock", "virtual", "--tcp", "127.0.0.1:0", "--control", "127.0.0.1:0", "--control-token", "s3cret"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "c20sim", "serve", *options, "--ready-file", str(ready)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        url = wait_for_ready_file(ready, proc)["control"]
        assert json.loads(ctl(ready, "time").stdout) == {"t": 0.0, "clock": "virtual"}
        command = [sys.executable, "-m", "c20sim", "ctl", "--url", url, "time"]
        refused = subprocess.run(command, capture_output=True, text=True, timeout=30, check=False)
        assert (refused.returncode, refused.stderr.startswith("c20sim: GET /time: 401: ")) == (2, True)
        with_token = [*command[:-1], "--token", "s3cret", "time"]
        given = subprocess.run(with_token, capture_output=True, text=True, timeout=30, check=False)
        assert (given.returncode, json.loads(given.stdout)) == (0, {"t": 0.0, "clock": "virtual"})
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=10)
