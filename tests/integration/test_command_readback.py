"""2000H after a fault and a reset, through a real pty with pymodbus as the master (issue 30, item 10)."""

from __future__ import annotations

from tests.integration.conftest import ServeFactory


async def test_2000h_reads_0_after_a_trip_and_the_reset_written_after_it(serve: ServeFactory) -> None:
    served = await serve()
    client = await served.serial_client()

    async def read(register: int) -> int:
        response = await client.read_holding_registers(register, count=1, device_id=1)
        assert not response.isError(), response
        return int(response.registers[0])

    async def write(register: int, value: int) -> None:
        response = await client.write_register(register, value, device_id=1)
        assert not response.isError(), response

    try:
        await write(0x2001, 1500)
        await write(0x2000, 1)  # forward run
        served.sim.run_until(2.0)
        assert (await read(0x2000), await read(0x2100)) == (1, 1)
        await write(0x200A, 0x008)  # EF through the virtual inputs
        served.sim.run_until(2.01)
        assert (await read(0x2000), await read(0x2100), await read(0x2102)) == (0, 4, 0x11)
        await write(0x200A, 0)
        await write(0x2000, 7)  # fault reset
        served.sim.run_until(7.0)
        assert (await read(0x2000), await read(0x2100), await read(0x2102)) == (7, 3, 0)
    finally:
        client.close()
