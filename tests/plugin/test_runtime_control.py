"""Runtime control from a test: pause, resume, speed, reset to a set-up, generators; a real Modbus client."""

from __future__ import annotations

import contextlib
import socket
import struct
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from pymodbus import FramerType
from pymodbus.client import ModbusTcpClient

from c20sim.drive.params import ParameterStore
from c20sim.drive.profile import load_profile
from c20sim.testing import C20Sim
from c20sim.wire.errors import C20SimError
from c20sim.wire.protocol import ReadRequest, ReadResponse, encode


@pytest.fixture
def client(c20sim: C20Sim) -> Iterator[ModbusTcpClient]:
    assert c20sim.host is not None and c20sim.port is not None
    modbus = ModbusTcpClient(c20sim.host, port=c20sim.port, framer=FramerType.RTU, timeout=2, retries=0)
    assert modbus.connect()
    yield modbus
    modbus.close()


def read(client: ModbusTcpClient, register: int) -> int:
    response = client.read_holding_registers(register, count=1, device_id=1)
    assert not response.isError(), response
    return int(response.registers[0])


def wait_until(condition: object, what: str, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():  # type: ignore[operator]
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.005)


@pytest.mark.c20sim(clock="realtime")
def test_pause_stops_model_time_and_the_drive_still_answers(c20sim: C20Sim, client: ModbusTcpClient) -> None:
    client.write_register(0x2001, 1500, device_id=1)
    client.write_register(0x2000, 1, device_id=1)
    c20sim.pause()
    frozen = c20sim.clock()
    assert frozen["paused"] is True and frozen["clock"] == "realtime"
    speed = read(client, 0x3006)  # the drive answers while paused ...
    for _ in range(5):
        assert read(client, 0x3006) == speed  # ... and stands still
    assert c20sim.now() == frozen["t"]
    c20sim.resume()
    wait_until(lambda: c20sim.now() > frozen["t"], "model time to run on after resume")
    assert c20sim.clock()["paused"] is False


@pytest.mark.c20sim(clock="realtime")
def test_speed_factor_is_set_at_runtime(c20sim: C20Sim) -> None:
    c20sim.set_speed(50)
    assert c20sim.clock()["speed"] == 50.0
    with pytest.raises(C20SimError, match=r"^speed: 5000 is outside 0.001-1000$"):
        c20sim.set_speed(5000)


def test_pause_needs_a_realtime_clock(c20sim: C20Sim) -> None:
    with pytest.raises(C20SimError, match="pause: the clock is virtual and moves only when advanced"):
        c20sim.pause()


def test_reset_to_defaults_and_to_a_state_file_without_restarting(
    c20sim: C20Sim, client: ModbusTcpClient, tmp_path: Path
) -> None:
    client.write_register(0x2001, 1500, device_id=1)
    client.write_register(0x2000, 1, device_id=1)
    c20sim.set(supply_v={"sine": 1, "period": 0.5})
    c20sim.link_faults(delay=0.01)
    c20sim.advance(2.0)
    assert read(client, 0x3006) == 1500
    c20sim.reset()
    assert c20sim.drive().generators() == {} and c20sim.link_faults()["active"] == []
    assert (read(client, 0x2100), read(client, 0x3006), read(client, 0x2006)) == (3, 0, 2)  # stopped, F00.01 = 2
    assert c20sim.now() == 2.0  # the clock goes on: a reset is not a restart

    path = tmp_path / "setup.json"
    ParameterStore(load_profile(), path).set(0x0001, 0)  # F00.01 = 0: the keypad runs the drive
    c20sim.reset(path)
    assert read(client, 0x2006) == 0
    refused = client.write_register(0x2000, 1, device_id=1)  # a run command off the comms channel
    assert refused.isError() and refused.exception_code == 0x04


def test_generators_from_the_handle(c20sim: C20Sim, client: ModbusTcpClient) -> None:
    drive = c20sim.drive()
    drive.set(supply_v={"ramp": 30, "over": 5})
    c20sim.advance(2.5)
    assert read(client, 0x3008) == pytest.approx(390, abs=5)  # the bus follows the supply, in 0.1 V
    assert drive.conditions()["supply_v"] == 39.0
    assert list(drive.generators()) == ["supply_v"]
    drive.clear_generators()
    c20sim.advance(1.0)
    assert drive.conditions()["supply_v"] == 39.0
    with pytest.raises(C20SimError, match=r"^ambient_c.sine: 500 is outside 0-200$"):
        drive.set(ambient_c={"sine": 500, "period": 1})


def test_drop_percent_drops_that_share_of_the_replies_on_the_wire(c20sim: C20Sim) -> None:
    """Half the replies dropped at random, counted on a raw RTU-over-TCP socket: 400 requests in one write, served
    one at a time (a dropped reply frees the line for the next at once), 7 bytes a reply that came."""
    assert c20sim.host is not None and c20sim.port is not None
    c20sim.link_faults(drop_percent=50)
    requests = 400
    with socket.create_connection((c20sim.host, c20sim.port), timeout=10) as sock:
        sock.sendall(encode(ReadRequest(1, 0x2100, 1)) * requests)
        wait_until(
            lambda: sum(r.direction == "rx" and r.kind == "request" for r in c20sim.frames()) == requests,
            "every request to be served",
        )
        replies = sum(r.direction == "tx" and r.kind == "reply" for r in c20sim.frames())
        data = b""
        while len(data) < 7 * replies:
            chunk = sock.recv(65536)
            assert chunk, "the server closed the connection"
            data += chunk
        sock.settimeout(0.2)  # every reply the log shows has come; a surplus one would be a dropped reply sent
        with contextlib.suppress(TimeoutError):
            data += sock.recv(65536)
    assert data == encode(ReadResponse(1, (3,))) * replies
    dropped = requests - replies
    # Binomial(400, 0.5): mean 200, sigma 10; 6 sigma either side. Half the rate (25 %, 100) is far outside.
    assert 140 <= dropped <= 260, f"{dropped} of {requests} replies dropped at drop_percent=50"


@pytest.mark.c20sim(transport="modbus-tcp", drives=(1, 2))
def test_the_gateway_answers_0x0b_for_an_absent_unit_and_a_dropped_reply(c20sim: C20Sim) -> None:
    """Modbus TCP through the plugin, on a raw socket: the MBAP answer of a gateway whose drive stays silent is
    exception 0x0B (gateway target device failed to respond), byte for byte, under the request's transaction."""
    assert c20sim.modbus_tcp_port is not None

    def ask(transaction: int, unit: int) -> bytes:
        pdu = struct.pack(">BHH", 3, 0x2103, 1)
        sock.sendall(struct.pack(">HHHB", transaction, 0, len(pdu) + 1, unit) + pdu)
        data = b""
        while len(data) < 6 or len(data) < 6 + struct.unpack(">H", data[4:6])[0]:
            chunk = sock.recv(256)
            assert chunk, "the gateway closed the connection"
            data += chunk
        return data

    with socket.create_connection(("127.0.0.1", c20sim.modbus_tcp_port), timeout=10) as sock:
        assert ask(0x1234, 2).hex(" ") == "12 34 00 00 00 05 02 03 02 00 20"  # drive 2 answers: its ID
        assert ask(0x1235, 9).hex(" ") == "12 35 00 00 00 03 09 83 0b"  # no drive 9 on the line
        c20sim.link_faults(1, drop_next=1)
        assert ask(0x1236, 1).hex(" ") == "12 36 00 00 00 03 01 83 0b"  # drive 1's reply lost on the line
        assert ask(0x1237, 1).hex(" ") == "12 37 00 00 00 05 01 03 02 00 20"


def test_the_ramps_run_at_the_set_rates_seen_over_the_wire(c20sim: C20Sim, client: ModbusTcpClient) -> None:
    """Acceleration and deceleration times of 5.0 s (2003H, 2004H: 0 to 3000 rpm and back), the speed read over
    RTU over TCP in the plugin's virtual time: half way at half the time, up and down."""
    for register, value in ((0x2003, 50), (0x2004, 50), (0x2001, 3000), (0x2000, 1)):
        assert not client.write_register(register, value, device_id=1).isError()
    # Within a model step or two of the ideal (the ramp moves in steps); 10 % fast would be 150 rpm (75 rpm) off.
    c20sim.advance(2.5)
    assert read(client, 0x3006) == pytest.approx(1500, abs=3)
    c20sim.advance(2.5)
    assert read(client, 0x3006) == 3000
    assert not client.write_register(0x2001, 1500, device_id=1).isError()
    c20sim.advance(1.25)  # 1500 rpm down takes 2.5 s at 3000 rpm in 5 s
    assert read(client, 0x3006) == pytest.approx(2250, abs=3)
    c20sim.advance(1.25)
    assert read(client, 0x3006) == 1500
