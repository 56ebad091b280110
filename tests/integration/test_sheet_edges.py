"""The sheet's edges (issue 18, items 5-7), through a real pty with --line-timing and pymodbus as the master."""

from __future__ import annotations

import asyncio
import os
import select
import tty

from c20sim.drive.model import Drive
from c20sim.wire.protocol import ExceptionCode, with_crc
from tests.integration.conftest import ServeFactory

X = ExceptionCode


def drive_of(served: object) -> Drive:
    drive = served.sim.drive(1)  # type: ignore[attr-defined]
    assert isinstance(drive, Drive)
    return drive


async def test_dial_switch_settings_are_taken_and_act(serve: ServeFactory) -> None:
    served = await serve(line_timing=True)
    client = await served.serial_client()
    try:
        # Sheet: 2005H "3: dial switch setting (SW1 valid)", 2006H "3: ... (SW3 valid)", 2007H "5: ... (SW2, SW3)".
        for register, value in ((0x2005, 3), (0x2006, 3), (0x2007, 5)):
            response = await client.write_register(register, value, device_id=1)
            assert not response.isError(), (hex(register), value, response)
        drive = drive_of(served)
        drive.set_dial_switches(False, True, True)  # SW3 on: terminals; SW2 + SW3: multi-segment speed
        status2 = (await client.read_holding_registers(0x2101, count=1, device_id=1)).registers[0]
        assert (status2 >> 5) & 0b11 == 0b01, hex(status2)  # terminal control
        response = await client.write_register(0x2000, 1, device_id=1)  # run from the bus: not the channel
        assert (response.function_code, response.exception_code) == (0x86, X.OPERATION_FAILED)
        drive.set_dial_switches(False, True, False)  # SW2 alone: the knob, AI1
        drive.set_ai(1, 5.0)
        assert (await client.read_holding_registers(0x3005, count=1, device_id=1)).registers[0] == 1500
        # 2006H = 4: a channel no sheet line names, refused with the profile's code; simple PLC (2007H = 6) is
        # taken (the F10 programme, issue 42).
        response = await client.write_register(0x2006, 4, device_id=1)
        assert (response.function_code, response.exception_code) == (0x86, X.ILLEGAL_VALUE)
        assert not (await client.write_register(0x2007, 6, device_id=1)).isError()
    finally:
        client.close()


async def test_a_run_command_while_faulted_is_answered_0x01(serve: ServeFactory) -> None:
    served = await serve(line_timing=True)
    client = await served.serial_client()
    try:
        drive_of(served).force_fault(0x11)  # EF, external fault
        for command in (1, 2, 3, 4):  # forward, reverse, and both jogs
            response = await client.write_register(0x2000, command, device_id=1)
            assert (response.function_code, response.exception_code) == (0x86, X.ILLEGAL_FUNCTION), command
        assert (await client.read_holding_registers(0x2100, count=1, device_id=1)).registers[0] == 4  # still fault
        assert not (await client.write_register(0x2000, 7, device_id=1)).isError()  # fault reset is taken
        assert not (await client.write_register(0x2000, 1, device_id=1)).isError()  # and now it runs
        assert (await client.read_holding_registers(0x2100, count=1, device_id=1)).registers[0] == 1
    finally:
        client.close()


def exchange(path: str, request: bytes, reply_length: int) -> bytes:
    """Write a raw request on the pty and read a reply of ``reply_length`` bytes (5 s deadline)."""
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        tty.setraw(fd)
        os.write(fd, request)
        reply = b""
        while len(reply) < reply_length:
            ready, _, _ = select.select([fd], [], [], 5.0)
            assert ready, f"no reply to {request.hex(' ')}; got {reply.hex(' ')}"
            reply += os.read(fd, 64)
        return reply
    finally:
        os.close(fd)


async def test_a_0x10_whose_byte_count_is_not_2n_is_answered_0x06(serve: ServeFactory) -> None:
    served = await serve(line_timing=True)
    # Two registers announced, a byte count of 2 and 2 data bytes: a frame of the right length for its byte count.
    request = with_crc(bytes.fromhex("01 10 20 03 00 02 02 00 14"))
    reply = await asyncio.to_thread(exchange, served.pty, request, 5)
    assert reply == with_crc(bytes.fromhex("01 90 06"))  # sheet 0x06: "The length of data frame is incorrect"
    assert drive_of(served).read(0x2003) != 0x14  # nothing written
