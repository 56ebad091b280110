"""The test handle's audit: audit(), clear_audit() and assert_master_clean(), with a pymodbus master on RTU over TCP."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest
from pymodbus import FramerType
from pymodbus.client import ModbusTcpClient

from c20sim.audit import Severity
from c20sim.testing import C20Sim
from c20sim.wire.errors import C20SimError


@pytest.fixture
def sim() -> Iterator[tuple[C20Sim, ModbusTcpClient]]:
    with C20Sim.start() as handle:
        assert handle.host is not None and handle.port is not None
        client = ModbusTcpClient(handle.host, port=handle.port, framer=FramerType.RTU, timeout=2, retries=0)
        assert client.connect()
        yield handle, client
        client.close()


def absent_register_every_cycle(client: ModbusTcpClient) -> None:
    for _ in range(3):
        assert client.read_holding_registers(0x2100, count=1, device_id=1).registers == [3]
        assert client.read_holding_registers(0x0032, count=1, device_id=1).exception_code == 0x02
        time.sleep(0.1)  # the master's own cycle


def test_assert_master_clean_lists_each_finding(sim: tuple[C20Sim, ModbusTcpClient]) -> None:
    handle, client = sim
    absent_register_every_cycle(client)
    (finding,) = handle.audit()
    assert (finding.rule, finding.severity, finding.drive, finding.subject) == (
        "absent-register",
        Severity.WARNING,
        1,
        "F00.50",
    )
    with pytest.raises(AssertionError) as caught:
        handle.assert_master_clean()
    assert str(caught.value) == (
        "the audit found 1 thing(s) the master would do wrong on a real line:\n"
        "warning absent-register drive 1 F00.50: read of F00.50 refused 0x02 (illegal data address) 3 times. "
        "Drop F00.50 from the poll list: the drive has no such register. [sheet 1.4, 0x02]"
    )
    handle.assert_master_clean(ignore=["absent-register"])
    handle.assert_master_clean(severity="error")
    assert handle.audit(ignore=["absent-register"]) == []


def test_clear_audit_judges_only_what_comes_next(sim: tuple[C20Sim, ModbusTcpClient]) -> None:
    handle, client = sim
    absent_register_every_cycle(client)
    handle.clear_audit()
    for _ in range(3):
        assert client.read_holding_registers(0x2100, count=1, device_id=1).registers == [3]
        time.sleep(0.1)
    handle.assert_master_clean()


def test_bad_arguments_are_one_line(sim: tuple[C20Sim, ModbusTcpClient]) -> None:
    handle, _ = sim
    with pytest.raises(C20SimError, match=r"^ignore: unknown rule 'line-demnad'; the rules are line-demand, "):
        handle.assert_master_clean(ignore=["line-demnad"])
    with pytest.raises(C20SimError, match=r"^assert_master_clean: severity 'fatal': expected one of note"):
        handle.assert_master_clean(severity="fatal")
