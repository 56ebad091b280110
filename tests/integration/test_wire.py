"""c20sim on real ports, checked by independent masters: pymodbus's clients and Debian's mbpoll."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import os
import tempfile
import tty
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from pymodbus.client import AsyncModbusSerialClient, AsyncModbusTcpClient
from pymodbus.exceptions import ModbusIOException

from c20sim.drive.profile import load_profile
from c20sim.wire.protocol import ExceptionCode, ReadRequest, ReadResponse, WriteSingleRequest, encode
from tests.integration.conftest import Served, ServeFactory, need

X = ExceptionCode


async def read(client: AsyncModbusSerialClient | AsyncModbusTcpClient, address: int, device: int = 1) -> int:
    response = await client.read_holding_registers(address, count=1, device_id=device)
    assert not response.isError(), response
    return int(response.registers[0])


async def exception_of_write(
    client: AsyncModbusSerialClient | AsyncModbusTcpClient, address: int, value: int, device: int = 1
) -> int:
    response = await client.write_register(address, value, device_id=device)
    assert response.isError(), response
    return int(response.exception_code)


@pytest.fixture(params=["pty", "rtu-over-tcp"])
async def client_and_served(
    request: pytest.FixtureRequest, serve: ServeFactory
) -> tuple[AsyncModbusSerialClient | AsyncModbusTcpClient, Served]:
    served = await serve()
    client = await (served.serial_client() if request.param == "pty" else served.rtu_tcp_client())
    request.addfinalizer(client.close)
    return client, served


async def test_every_register_class(
    client_and_served: tuple[AsyncModbusSerialClient | AsyncModbusTcpClient, Served],
) -> None:
    client, _ = client_and_served
    # R
    assert await read(client, 0x2103) == 0x0020
    assert await read(client, 0x2100) == 3
    assert await read(client, 0x2101) == 0x0041
    assert await read(client, 0x300A) == 100
    # W/R
    assert not (await client.write_register(0x2001, 1500, device_id=1)).isError()
    assert await read(client, 0x2001) == 1500
    # W/R* while stopped, and its mirror F02.00
    assert not (await client.write_register(0x2002, 2, device_id=1)).isError()
    assert await read(client, 0x0200) == 2
    # Function code, after write enable; 0x10 across two registers
    assert not (await client.write_register(0x200E, 1, device_id=1)).isError()
    assert not (await client.write_register(0x000A, 2500, device_id=1)).isError()
    assert await read(client, 0x000A) == 2500
    assert not (await client.write_registers(0x2003, [20, 30], device_id=1)).isError()
    assert (await read(client, 0x2003), await read(client, 0x2004)) == (20, 30)


async def test_every_exception_code(
    client_and_served: tuple[AsyncModbusSerialClient | AsyncModbusTcpClient, Served],
) -> None:
    client, _ = client_and_served
    response = await client.read_input_registers(0x3000, count=1, device_id=1)
    assert (response.function_code, response.exception_code) == (0x84, X.ILLEGAL_FUNCTION)
    response = await client.read_holding_registers(0x0032, count=1, device_id=1)
    assert (response.function_code, response.exception_code) == (0x83, X.ILLEGAL_ADDRESS)
    response = await client.read_holding_registers(0x2100, count=2, device_id=1)
    assert response.exception_code == X.ILLEGAL_VALUE
    assert await exception_of_write(client, 0x0000, 5) == X.ILLEGAL_VALUE
    assert await exception_of_write(client, 0x000A, 2500) == X.OPERATION_FAILED
    assert await exception_of_write(client, 0x2100, 1) == X.READ_ONLY
    # 0x08: W/R* while running
    assert not (await client.write_register(0x2001, 1000, device_id=1)).isError()
    assert not (await client.write_register(0x2000, 1, device_id=1)).isError()
    assert await read(client, 0x2100) == 1
    assert await exception_of_write(client, 0x2002, 2) == X.NOT_WHILE_RUNNING


async def test_password_error_on_the_wire(serve: ServeFactory) -> None:
    base = load_profile()
    locked = dataclasses.replace(base, protocol=dataclasses.replace(base.protocol, password=4321))
    served = await serve(profile=locked)
    client = await served.rtu_tcp_client()
    try:
        assert not (await client.write_register(0x200E, 1, device_id=1)).isError()
        assert await exception_of_write(client, 0x000A, 2500) == X.PASSWORD_ERROR
        assert await exception_of_write(client, 0x0700, 1) == X.PASSWORD_ERROR
        assert not (await client.write_register(0x0700, 4321, device_id=1)).isError()
        assert not (await client.write_register(0x000A, 2500, device_id=1)).isError()
    finally:
        client.close()


async def test_a_wrong_password_locks_again_on_the_pty(serve: ServeFactory) -> None:
    """Unlocked by the right password, a wrong one (written to F07.00) is refused with 0x05 and locks the function
    codes again until the right one comes: through the pty, by pymodbus's serial master."""
    base = load_profile()
    locked = dataclasses.replace(base, protocol=dataclasses.replace(base.protocol, password=4321))
    served = await serve(profile=locked)
    client = await served.serial_client(timeout=2.0)
    try:
        assert not (await client.write_register(0x200E, 1, device_id=1)).isError()
        assert not (await client.write_register(0x0700, 4321, device_id=1)).isError()
        assert not (await client.write_register(0x000A, 2500, device_id=1)).isError()  # unlocked
        assert await exception_of_write(client, 0x0700, 1234) == X.PASSWORD_ERROR  # a wrong password ...
        assert await exception_of_write(client, 0x000A, 2600) == X.PASSWORD_ERROR  # ... locks again
        assert await read(client, 0x000A) == 2500
        assert not (await client.write_register(0x0700, 4321, device_id=1)).isError()
        assert not (await client.write_register(0x000A, 2600, device_id=1)).isError()
    finally:
        client.close()


async def test_bad_crc_gets_exception_06(serve: ServeFactory) -> None:
    corrupt = {"on": False}

    def trace(sending: bool, data: bytes) -> bytes:
        if sending and corrupt["on"]:
            return data[:-1] + bytes((data[-1] ^ 0x55,))
        return data

    served = await serve()
    client = await served.rtu_tcp_client(trace_packet=trace)
    try:
        corrupt["on"] = True
        response = await client.read_holding_registers(0x2100, count=1, device_id=1)
        assert (response.function_code, response.exception_code) == (0x83, X.FRAME_ERROR)
        corrupt["on"] = False
        assert await read(client, 0x2100) == 3
    finally:
        client.close()


async def test_modbus_tcp_gateway(serve: ServeFactory) -> None:
    served = await serve(addresses=(1, 2))
    client = AsyncModbusTcpClient("127.0.0.1", port=served.modbus_tcp_port, timeout=2, retries=0)
    assert await client.connect()
    try:
        assert await read(client, 0x2103, device=2) == 0x20
        assert not (await client.write_register(0x2001, 777, device_id=2)).isError()
        assert await read(client, 0x2001, device=2) == 777
        response = await client.read_holding_registers(0x0032, count=1, device_id=1)
        assert response.exception_code == X.ILLEGAL_ADDRESS
        response = await client.read_holding_registers(0x2103, count=1, device_id=9)
        assert response.exception_code == 0x0B  # gateway: target device failed to respond
    finally:
        client.close()


async def test_three_drives_on_one_pty_and_a_broadcast(serve: ServeFactory) -> None:
    served = await serve(addresses=(1, 2, 5))
    client = await served.serial_client(timeout=0.3)
    try:
        for address in (1, 2, 5):
            assert not (await client.write_register(0x2001, 100 * address, device_id=address)).isError()
        assert [await read(client, 0x2001, device=a) for a in (1, 2, 5)] == [100, 200, 500]
        with pytest.raises(ModbusIOException):
            await client.read_holding_registers(0x2001, count=1, device_id=3)
        # A broadcast write acts on all three and is not answered.
        await client.write_register(0x2001, 2400, device_id=0, no_response_expected=True)
        await wait_for(lambda: all(d.read(0x2001) == 2400 for d in served.sim.drives.values()))
        records = [r for r in served.sim.bus.records if r.slave == 0]
        assert [(r.direction, r.note) for r in records] == [("rx", "broadcast: no reply")]
        assert [await read(client, 0x2001, device=a) for a in (1, 2, 5)] == [2400, 2400, 2400]
    finally:
        client.close()


async def test_a_broadcast_is_never_answered_on_rtu_over_tcp(serve: ServeFactory) -> None:
    """A raw socket sends a broadcast write and a read of drive 2 in one go: the first bytes back are the read's
    reply, and nothing else follows (an answered broadcast would come first). No waiting for silence: the line
    serves the two in order."""
    served = await serve(addresses=(1, 2))
    reader, writer = await asyncio.open_connection("127.0.0.1", served.tcp_port)
    try:
        writer.write(encode(WriteSingleRequest(0, 0x2001, 2400)) + encode(ReadRequest(2, 0x2001, 1)))
        await writer.drain()
        first = await asyncio.wait_for(reader.readexactly(7), timeout=10)
        assert first == encode(ReadResponse(2, (2400,))), first.hex(" ")
        writer.write(encode(ReadRequest(1, 0x2001, 1)))  # and the next bytes are the next read's, not a late echo
        await writer.drain()
        second = await asyncio.wait_for(reader.readexactly(7), timeout=10)
        assert second == encode(ReadResponse(1, (2400,))), second.hex(" ")
    finally:
        writer.close()


async def wait_for(condition: object, timeout: float = 5.0) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while not condition():  # type: ignore[operator]
        assert loop.time() < deadline, "condition not met in time"
        await asyncio.sleep(0.005)


# --- link faults, as the client sees them


async def test_dropped_reply_is_a_timeout_and_the_drive_still_acted(serve: ServeFactory) -> None:
    served = await serve()
    client = await served.rtu_tcp_client(timeout=0.3)
    try:
        served.sim.link_faults(1).drop_next = 1
        with pytest.raises(ModbusIOException):
            await client.write_register(0x2001, 1234, device_id=1)
        assert await read(client, 0x2001) == 1234
    finally:
        client.close()


async def test_offline_drive_is_silent_until_cleared(serve: ServeFactory) -> None:
    served = await serve()
    client = await served.serial_client(timeout=0.3)
    try:
        served.sim.link_faults(1).offline = True
        with pytest.raises(ModbusIOException):
            await client.write_register(0x2001, 99, device_id=1)
        served.sim.link_faults(1).clear()
        assert await read(client, 0x2001) == 0  # offline: it never saw the write
    finally:
        client.close()


async def test_forced_exception_reaches_the_client(serve: ServeFactory) -> None:
    served = await serve()
    client = await served.rtu_tcp_client()
    try:
        served.sim.link_faults().forced_exception = X.OPERATION_FAILED
        response = await client.read_holding_registers(0x2103, count=1, device_id=1)
        assert (response.function_code, response.exception_code) == (0x83, X.OPERATION_FAILED)
    finally:
        client.close()


@pytest.mark.parametrize("fault", ["corrupt_crc", "truncate", "wrong_address"])
async def test_broken_replies_are_not_taken_as_answers(serve: ServeFactory, fault: str) -> None:
    served = await serve()
    client = await served.serial_client(timeout=0.3)
    try:
        link = served.sim.link_faults(1)
        if fault == "wrong_address":
            link.wrong_address = 7
        else:
            setattr(link, fault, True)
        with pytest.raises(ModbusIOException):
            await client.read_holding_registers(0x2103, count=1, device_id=1)
        tx = [r for r in served.sim.bus.records if r.direction == "tx"][-1]
        assert "(injected)" in tx.note
        link.clear()
        assert await read(client, 0x2103) == 0x20
    finally:
        client.close()


async def test_delay_beyond_the_client_timeout_is_a_timeout(serve: ServeFactory) -> None:
    served = await serve()
    client = await served.rtu_tcp_client(timeout=0.2)
    try:
        served.sim.link_faults(1).delay = 0.6
        with pytest.raises(ModbusIOException):
            await client.read_holding_registers(0x2103, count=1, device_id=1)
        tx = [r for r in served.sim.bus.records if r.direction == "tx"][-1]
        assert tx.note == "delayed 600 ms (injected)"
    finally:
        client.close()


async def test_garbage_before_a_reply_breaks_it_and_garbage_after_does_not(serve: ServeFactory) -> None:
    served = await serve()
    client = await served.rtu_tcp_client(timeout=0.3)
    try:
        link = served.sim.link_faults(1)
        link.garbage_before = b"\xff\x00"
        with pytest.raises(ModbusIOException):  # pymodbus does not resynchronise on the frame behind it
            await client.read_holding_registers(0x2103, count=1, device_id=1)
        link.clear()
        link.garbage_after = b"\x13"
        assert await read(client, 0x2103) == 0x20
        tx = [r for r in served.sim.bus.records if r.direction == "tx"][-1]
        assert tx.data == bytes.fromhex("01 03 02 00 20 B9 9C 13")
        assert tx.note == "garbage added (injected)"
    finally:
        client.close()


async def test_two_tcp_clients_never_receive_each_others_replies(serve: ServeFactory) -> None:
    served = await serve(addresses=(1, 2))
    a = await served.rtu_tcp_client()
    b = await served.rtu_tcp_client()
    try:
        assert not (await a.write_register(0x2001, 1111, device_id=1)).isError()
        assert not (await b.write_register(0x2001, 2222, device_id=2)).isError()

        async def hammer(client: AsyncModbusTcpClient, device: int, expected: int) -> int:
            for _ in range(200):
                assert await read(client, 0x2001, device=device) == expected
            return 200

        assert await asyncio.gather(hammer(a, 1, 1111), hammer(b, 2, 2222)) == [200, 200]
    finally:
        a.close()
        b.close()


async def test_a_client_leaving_mid_frame_costs_the_others_nothing(serve: ServeFactory) -> None:
    served = await serve()
    assert served.server.endpoints.tcp is not None
    connections = served.server.endpoints.tcp.connections
    client = await served.rtu_tcp_client()
    try:
        _reader, writer = await asyncio.open_connection("127.0.0.1", served.tcp_port)
        await wait_for(lambda: len(connections) == 2)
        writer.write(bytes.fromhex("01 03 21"))  # half a request
        await writer.drain()
        writer.close()
        await wait_for(lambda: len(connections) == 1)
        # Had the half frame stayed in a shared buffer, this request would be garbled behind it.
        assert await read(client, 0x2103) == 0x20
        kinds = [r.kind for r in served.sim.bus.records if r.direction == "rx"]
        assert kinds == ["request"]
    finally:
        client.close()


# --- real serial port (socat pty pair) and Debian's mbpoll


@dataclass
class SerialPair:
    """Two linked ptys made by socat: the drive's end and the master's, like an RS485 adapter pair."""

    drive: Path
    master: Path
    proc: asyncio.subprocess.Process


@contextlib.asynccontextmanager
async def socat_pair() -> AsyncIterator[SerialPair]:
    socat = need("socat")
    with tempfile.TemporaryDirectory() as tmp:
        a, b = Path(tmp) / "drive", Path(tmp) / "master"
        proc = await asyncio.create_subprocess_exec(
            socat,
            f"pty,raw,echo=0,link={a}",
            f"pty,raw,echo=0,link={b}",
            stdout=asyncio.subprocess.DEVNULL,
            stderr=asyncio.subprocess.DEVNULL,
        )
        try:
            await wait_for(lambda: a.exists() and b.exists())
            yield SerialPair(a, b, proc)
        finally:
            if proc.returncode is None:
                proc.terminate()
                await proc.wait()


async def test_serial_port_through_a_socat_pair(serve: ServeFactory) -> None:
    async with socat_pair() as pair:
        served = await serve(serial=str(pair.drive), pty=False)
        client = AsyncModbusSerialClient(str(pair.master), timeout=1, retries=0)
        assert await client.connect()
        try:
            assert await read(client, 0x2103) == 0x20
            assert not (await client.write_register(0x2001, 321, device_id=1)).isError()
            assert served.sim.drive(1).read(0x2001) == 321
        finally:
            client.close()


async def test_a_lost_serial_port_is_closed_and_the_rest_keeps_serving(serve: ServeFactory) -> None:
    async with socat_pair() as pair:
        served = await serve(serial=str(pair.drive), pty=False)
        port = served.server.endpoints.serial
        assert port is not None and port.is_open
        pair.proc.kill()  # the adapter is unplugged: its device hangs up
        await pair.proc.wait()
        await wait_for(lambda: not port.is_open)
        client = await served.rtu_tcp_client()
        try:
            assert await read(client, 0x2103) == 0x20
        finally:
            client.close()


async def test_mbpoll_reads_the_drive_id_through_the_pty(serve: ServeFactory) -> None:
    mbpoll = need("mbpoll")
    served = await serve()
    proc = await asyncio.create_subprocess_exec(
        mbpoll,
        "-m",
        "rtu",
        "-b",
        "19200",
        "-P",
        "none",
        "-a",
        "1",
        "-t",
        "4:hex",
        "-0",
        "-r",
        str(0x2103),
        "-c",
        "1",
        "-1",
        "-o",
        "2",
        served.pty,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.STDOUT,
    )
    out, _ = await proc.communicate()
    text = out.decode()
    assert proc.returncode == 0, text
    assert f"[{0x2103}]: \t0x0020" in text, text


async def test_line_timing_pty_serves_a_master(serve: ServeFactory) -> None:
    # Replies paced at 19200 baud, frames held to t1.5/t3.5: an ordinary master still works.
    served = await serve(line_timing=True)
    client = await served.serial_client()
    try:
        assert await read(client, 0x2103) == 0x20
        assert not (await client.write_registers(0x2003, [40, 60], device_id=1)).isError()
        assert await read(client, 0x2004) == 60
    finally:
        client.close()


async def test_line_timing_splits_a_frame_at_a_pause(serve: ServeFactory) -> None:
    # 10 ms is far beyond t3.5 at 19200 baud (2 ms): with line timing the frame is two broken pieces, and silence.
    served = await serve(line_timing=True)
    fd = os.open(served.pty, os.O_RDWR | os.O_NOCTTY)
    try:
        tty.setraw(fd)
        os.write(fd, bytes.fromhex("01 03 21"))
        await asyncio.sleep(0.01)  # the pause under test, not a wait for a result
        os.write(fd, bytes.fromhex("03 00 01 7E 36"))
        await wait_for(lambda: len(served.sim.bus.records) == 2)
        assert [r.kind for r in served.sim.bus.records] == ["noise", "crc error"]  # 03 00 01 ...: no frame
    finally:
        os.close(fd)


async def test_a_baud_change_reaches_every_endpoint(serve: ServeFactory) -> None:
    served = await serve(line_timing=True)
    client = await served.rtu_tcp_client()
    try:
        assert not (await client.write_register(0x2009, 3, device_id=1)).isError()  # 9600 baud
        pty = served.server.endpoints.pty
        assert pty is not None
        await wait_for(lambda: pty.baud == 9600)  # the pty's framing follows a change made over TCP
        assert served.sim.bus.line_baud == 9600
        ack = [r for r in served.sim.bus.records if r.direction == "tx"][-1]
        assert ack.data == bytes.fromhex("01 06 20 09 00 03 12 09")
    finally:
        client.close()
