"""The fixture's ``host`` and ``port`` are the endpoint of the TCP transport asked for: Modbus TCP for
``transport="modbus-tcp"``, RTU over TCP for ``"tcp"``; with both, the first listed. A Modbus TCP master pointed
at ``host``/``port`` reads the drive."""

from __future__ import annotations

import pytest
from pymodbus import FramerType
from pymodbus.client import ModbusTcpClient

from c20sim.testing import C20Sim


def reads_status(host: str | None, port: int | None, framer: FramerType) -> list[int]:
    assert host is not None and port is not None
    client = ModbusTcpClient(host, port=port, framer=framer, timeout=2, retries=0)
    assert client.connect()
    try:
        return list(client.read_holding_registers(0x2100, count=1, device_id=1).registers)
    finally:
        client.close()


@pytest.mark.c20sim(transport="modbus-tcp")
def test_modbus_tcp_gives_host_and_port(c20sim: C20Sim) -> None:
    assert (c20sim.host, c20sim.port) == ("127.0.0.1", c20sim.modbus_tcp_port)
    assert c20sim.tcp_port is None and c20sim.pty is None
    assert reads_status(c20sim.host, c20sim.port, FramerType.SOCKET) == [3]  # Modbus TCP, as the user wrote it


@pytest.mark.c20sim(transport="tcp")
def test_tcp_gives_the_rtu_over_tcp_host_and_port(c20sim: C20Sim) -> None:
    assert (c20sim.host, c20sim.port) == ("127.0.0.1", c20sim.tcp_port)
    assert c20sim.modbus_tcp_port is None
    assert reads_status(c20sim.host, c20sim.port, FramerType.RTU) == [3]


@pytest.mark.parametrize(
    ("transport", "first"), [(("modbus-tcp", "tcp"), "modbus_tcp_port"), (("tcp", "modbus-tcp"), "tcp_port")]
)
def test_with_both_host_and_port_are_the_first_listed(transport: tuple[str, ...], first: str) -> None:
    with C20Sim.start(transport=transport) as sim:
        assert sim.tcp_port is not None and sim.modbus_tcp_port is not None and sim.tcp_port != sim.modbus_tcp_port
        assert sim.port == getattr(sim, first)
        framer = FramerType.SOCKET if first == "modbus_tcp_port" else FramerType.RTU
        assert reads_status(sim.host, sim.port, framer) == [3]


@pytest.mark.c20sim(transport="pty")
def test_a_pty_alone_has_no_host_or_port(c20sim: C20Sim) -> None:
    assert (c20sim.host, c20sim.port, c20sim.tcp_port, c20sim.modbus_tcp_port) == (None, None, None, None)
    assert c20sim.pty is not None and c20sim.pty.startswith("/dev/pts/")
