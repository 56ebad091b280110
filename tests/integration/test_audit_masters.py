"""Misbehaving masters on real ports, each judged by the live audit and by ``c20sim audit`` on its frame log.

Each master is a few lines of pymodbus or raw frames, over the pty and over RTU-over-TCP; each gets exactly
its finding, live (the serve's audit) and offline (the same frames written as a frame log, then read back
by ``c20sim audit``). A well-behaved master (pymodbus, and Debian's mbpoll) gets none.
"""

from __future__ import annotations

import asyncio
import json
import os
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest
from pymodbus.client import AsyncModbusSerialClient, AsyncModbusTcpClient

from c20sim.audit import Finding, Severity
from c20sim.cli import main
from c20sim.control import liveaudit
from c20sim.core.bus import FrameRecord
from c20sim.transport.wallclock import WALL_OFFSET
from c20sim.wire.protocol import ReadRequest, WriteSingleRequest, encode
from c20sim.wire.registers import Reg, fcode_address
from tests.integration.conftest import Served, ServeFactory, need

pytestmark = pytest.mark.serial  # the audit judges a master's real rhythm: .ci/run runs it alone

Client = AsyncModbusSerialClient | AsyncModbusTcpClient
F00_10, F00_11, F08_02 = fcode_address(0, 10), fcode_address(0, 11), fcode_address(8, 2)


class Bench:
    """A served simulator, a master's way in (pymodbus or raw bytes) on one transport, and the frames seen."""

    def __init__(self, served: Served, transport: str) -> None:
        self.served = served
        self.transport = transport
        self.records: list[FrameRecord] = []
        self.unsubscribe = served.sim.bus.subscribe(self.records.append)
        self._writer: asyncio.StreamWriter | None = None
        self._fd: int | None = None

    async def client(self) -> Client:
        if self.transport == "pty":
            return await self.served.serial_client()
        return await self.served.rtu_tcp_client()

    async def raw(self, frame: bytes) -> None:
        """Send bytes as they are, without waiting for a reply: a master with a timer of its own."""
        if self.transport == "pty":
            if self._fd is None:
                self._fd = os.open(self.served.pty, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
            os.write(self._fd, frame)
        else:
            if self._writer is None:
                _, self._writer = await asyncio.open_connection("127.0.0.1", self.served.tcp_port)
            self._writer.write(frame)
            await self._writer.drain()

    def close(self) -> None:
        self.unsubscribe()
        if self._fd is not None:
            os.close(self._fd)
        if self._writer is not None:
            self._writer.close()

    def live(self) -> list[Finding]:
        audit = liveaudit.of(self.served.sim)
        assert audit is not None
        return audit.findings()

    async def until(self, rule: str, timeout: float = 10.0) -> list[Finding]:
        """The live findings once ``rule`` is among them (waiting for the frames to be served)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            found = self.live()
            if any(f.rule == rule for f in found):
                return found
            await asyncio.sleep(0.01)
        raise AssertionError(f"no {rule} finding in {timeout} s: {[f.line() for f in self.live()]}")

    def offline(self, path: Path, capsys: pytest.CaptureFixture[str]) -> dict[str, Any]:
        """``c20sim audit --format json`` on these frames written as serve --log-frames writes them."""
        with path.open("w") as out:
            for record in self.records:
                out.write(json.dumps(record.as_dict(WALL_OFFSET)) + "\n")
        capsys.readouterr()
        code = main(["audit", str(path), "--format", "json", "--fail-on", "note"])
        report: dict[str, Any] = json.loads(capsys.readouterr().out)
        assert code == (1 if report["findings"] else 0)
        return report


@pytest.fixture(params=["pty", "tcp"])
async def bench(request: pytest.FixtureRequest, serve: ServeFactory) -> Any:
    made = Bench(await serve(), request.param)
    yield made
    made.close()


Master = Callable[[Bench], Awaitable[None]]


async def read(client: Client, register: int, slave: int = 1) -> None:
    await client.read_holding_registers(register, count=1, device_id=slave)


async def write(client: Client, register: int, value: int, slave: int = 1) -> bool:
    return not (await client.write_register(register, value, device_id=slave)).isError()


def exactly(found: list[Finding], rule: str) -> Finding:
    assert [f.rule for f in found] == [rule], [f.line() for f in found]
    return found[0]


def offline_exactly(report: dict[str, Any], rule: str) -> dict[str, Any]:
    assert [f["rule"] for f in report["findings"]] == [rule], report["findings"]
    finding: dict[str, Any] = report["findings"][0]
    return finding


async def test_a_poller_too_fast_for_the_line(bench: Bench, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    client = await bench.client()
    try:
        start = time.monotonic()
        while time.monotonic() - start < 1.3:  # as fast as the transport answers: hundreds a second
            await read(client, Reg.STATUS1)
    finally:
        client.close()
    finding = exactly(await bench.until("line-demand"), "line-demand")
    assert finding.severity is Severity.ERROR and finding.value > 100.0
    assert finding.figure.startswith(f"line demand {finding.value:.0f} % of 19200 8N1")
    offline = offline_exactly(bench.offline(tmp_path / "log.jsonl", capsys), "line-demand")
    assert offline["severity"] == "error" and offline["value"] == pytest.approx(finding.value, rel=0.02)


async def test_a_cyclic_function_code_writer(bench: Bench, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    client = await bench.client()
    try:
        assert await write(client, Reg.WRITE_ENABLE, 1)
        for i in range(10):
            assert await write(client, F00_10, 2000 + i)
            await asyncio.sleep(0.05)  # the master's own cycle: every 50 ms
        assert await write(client, Reg.WRITE_ENABLE, 0)
    finally:
        client.close()
    finding = exactly(await bench.until("eeprom-wear"), "eeprom-wear")
    assert (finding.severity, finding.subject) == (Severity.ERROR, "F00.10")
    assert 36_000 < finding.value < 80_000  # 9 writes in about 0.45 s: about 72,000 an hour
    assert "rated 100,000 writes reached in" in finding.figure
    offline = offline_exactly(bench.offline(tmp_path / "log.jsonl", capsys), "eeprom-wear")
    assert offline["value"] == pytest.approx(finding.value, rel=0.01)


async def write_many(client: Client, start: int, values: list[int], slave: int = 1) -> bool:
    """A 0x10 write (Write Multiple Registers), as many PLC masters send even one register."""
    return not (await client.write_registers(start, values, device_id=slave)).isError()


async def test_a_cyclic_function_code_writer_with_0x10(
    bench: Bench, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The audit follows function-code writes sent with 0x10 as it follows 0x06: F00.10 alone, every 50 ms."""
    client = await bench.client()
    try:
        assert await write_many(client, Reg.WRITE_ENABLE, [1])
        for i in range(10):
            assert await write_many(client, F00_10, [2000 + i])
            await asyncio.sleep(0.05)
        assert await write_many(client, Reg.WRITE_ENABLE, [0])
    finally:
        client.close()
    finding = exactly(await bench.until("eeprom-wear"), "eeprom-wear")
    assert (finding.severity, finding.subject) == (Severity.ERROR, "F00.10")
    assert 36_000 < finding.value < 80_000
    assert (
        finding.figure.startswith("F00.10 stored ")
        and " (10 writes): rated 100,000 writes reached in " in finding.figure
    )
    offline = offline_exactly(bench.offline(tmp_path / "log.jsonl", capsys), "eeprom-wear")
    assert (offline["subject"], offline["value"]) == ("F00.10", pytest.approx(finding.value, rel=0.01))


async def test_a_0x10_block_whose_second_register_is_kept_in_eeprom(
    bench: Bench, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """2001H (RAM) and 2002H (pole pairs, the EEPROM cell of F02.00) in one 0x10, every 50 ms: the wear is the
    second register's, which a 0x10 carries as surely as a 0x06 would."""
    client = await bench.client()
    try:
        for i in range(10):
            assert await write_many(client, Reg.SPEED_SETPOINT, [1000 + i, 4])
            await asyncio.sleep(0.05)
    finally:
        client.close()
    finding = exactly(await bench.until("eeprom-wear"), "eeprom-wear")
    assert (finding.severity, finding.subject) == (Severity.ERROR, "2002H")
    assert "the same value each time; 10 writes" in finding.figure
    offline = offline_exactly(bench.offline(tmp_path / "log.jsonl", capsys), "eeprom-wear")
    assert (offline["subject"], offline["value"]) == ("2002H", pytest.approx(finding.value, rel=0.01))


async def test_a_slow_poller_near_the_watchdog(
    bench: Bench, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    client = await bench.client()
    try:
        assert await write(client, Reg.WRITE_ENABLE, 1)
        assert await write(client, F08_02, 20)  # the communication timeout: 2.0 s
        assert await write(client, Reg.WRITE_ENABLE, 0)
        for _ in range(2):
            await asyncio.sleep(1.7)  # the master's poll period: 85 % of the timeout
            await read(client, Reg.STATUS1)
    finally:
        client.close()
    finding = exactly(await bench.until("comm-watchdog"), "comm-watchdog")
    assert finding.severity is Severity.WARNING and 84.0 < finding.value < 95.0
    assert finding.figure.endswith("of the communication timeout F08.02 = 2 s")
    offline = offline_exactly(bench.offline(tmp_path / "log.jsonl", capsys), "comm-watchdog")
    assert offline["value"] == pytest.approx(finding.value, abs=0.1)


async def test_an_early_retrier(bench: Bench, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    request = encode(ReadRequest(9, Reg.STATUS1, 1))  # nobody at 9: no reply will come
    await bench.raw(request)
    await asyncio.sleep(0.004)  # retried after 4 ms: the reply would need 13.5 ms on the line
    await bench.raw(request)
    finding = exactly(await bench.until("early-retry"), "early-retry")
    assert (finding.drive, finding.count) == (9, 1)
    assert finding.figure.endswith("before its reply could have finished (13.5 ms on 19200 8N1)")
    offline_exactly(bench.offline(tmp_path / "log.jsonl", capsys), "early-retry")


async def test_one_that_ignores_0x08(bench: Bench, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    client = await bench.client()
    try:
        assert await write(client, Reg.SPEED_SETPOINT, 1000)
        assert await write(client, Reg.COMMAND, 1)
        for _ in range(3):
            assert not await write(client, Reg.BAUD, 3)  # refused 0x08: the drive runs
        assert await write(client, Reg.COMMAND, 5)
    finally:
        client.close()
    finding = exactly(await bench.until("refused-while-running"), "refused-while-running")
    assert finding.figure == "write of 2009H refused 0x08 (parameter cannot be changed while running) 3 times"
    offline = offline_exactly(bench.offline(tmp_path / "log.jsonl", capsys), "refused-while-running")
    assert offline["figure"] == finding.figure


async def test_one_that_talks_right_after_a_broadcast(
    bench: Bench, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    await bench.raw(encode(WriteSingleRequest(0, Reg.SPEED_SETPOINT, 500)))  # broadcast: no reply
    await asyncio.sleep(0.01)  # 10 ms later: the drive needs 100 ms (the profile's broadcast_delay_ms)
    await bench.raw(encode(ReadRequest(1, Reg.STATUS1, 1)))
    finding = exactly(await bench.until("broadcast-turnaround"), "broadcast-turnaround")
    assert finding.figure.endswith("the drive needs 100 ms (the profile's broadcast_delay_ms)")
    assert 10.0 <= finding.value * 1000 < 90.0
    offline_exactly(bench.offline(tmp_path / "log.jsonl", capsys), "broadcast-turnaround")


async def test_one_that_leaves_200eh_enabled(bench: Bench, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    client = await bench.client()
    try:
        assert await write(client, Reg.WRITE_ENABLE, 1)
        assert await write(client, F00_11, 50)
        deadline = time.monotonic() + 10.0
        while not any(f.rule == "write-enable-left-on" for f in bench.live()):  # polls on, 200EH still 1
            assert time.monotonic() < deadline, [f.line() for f in bench.live()]
            await read(client, Reg.STATUS1)
            await asyncio.sleep(0.5)
        await read(client, Reg.STATUS1)
    finally:
        client.close()
    finding = exactly(bench.live(), "write-enable-left-on")
    assert (finding.drive, finding.subject) == (1, "200EH")
    offline_exactly(bench.offline(tmp_path / "log.jsonl", capsys), "write-enable-left-on")


async def test_a_well_behaved_pymodbus_master(bench: Bench, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    client = await bench.client()
    try:
        assert await write(client, Reg.SPEED_SETPOINT, 1500)
        assert await write(client, Reg.COMMAND, 1)
        for _ in range(15):  # status and speed every 100 ms: 20 transactions a second, 27 % of the line
            await read(client, Reg.STATUS1)
            await read(client, Reg.MOTOR_SPEED)
            await asyncio.sleep(0.1)
        assert await write(client, Reg.COMMAND, 5)
    finally:
        client.close()
    assert bench.live() == []
    audit = liveaudit.of(bench.served.sim)
    assert audit is not None and 10.0 < audit.line_demand().peak < 40.0
    assert bench.offline(tmp_path / "log.jsonl", capsys)["findings"] == []


async def test_mbpoll_at_a_sane_rate(serve: ServeFactory, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    mbpoll = need("mbpoll")
    bench = Bench(await serve(), "pty")
    try:
        # five polls of 2100H, 200 ms apart (-l), then mbpoll is stopped
        proc = await asyncio.create_subprocess_exec(
            *(mbpoll, "-m", "rtu", "-b", "19200", "-P", "none", "-a", "1", "-t", "4:hex", "-0"),
            *("-r", str(0x2100), "-c", "1", "-l", "200", "-o", "1", bench.served.pty),
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.STDOUT,
        )
        deadline = time.monotonic() + 10.0
        while sum(r.direction.value == "tx" for r in bench.records) < 5:
            assert time.monotonic() < deadline and proc.returncode is None, bench.records
            await asyncio.sleep(0.05)
        proc.terminate()
        await proc.communicate()
        assert bench.live() == []
        assert bench.offline(tmp_path / "log.jsonl", capsys)["findings"] == []
    finally:
        bench.close()


def test_a_sequential_master_against_c20sim_serve_is_no_early_retrier(tmp_path: Path) -> None:
    """c20sim serve runs on uvloop, whose timers count whole milliseconds: a sequential master polling as fast as
    the replies come gets the line-demand finding and nothing else (no collision, no early retry), and only as a
    warning: it keeps the line full, never more than full (docs/audit.md), though uvloop hands a reply over up
    to half a millisecond early."""
    import subprocess
    import sys
    import urllib.request

    from pymodbus import FramerType
    from pymodbus.client import ModbusTcpClient

    from tests.conftest import wait_for_ready_file

    ready = tmp_path / "ready.json"
    proc = subprocess.Popen(
        [
            *(sys.executable, "-m", "c20sim", "serve", "--tcp", "127.0.0.1:0", "--control", "127.0.0.1:0"),
            "--ready-file",
            str(ready),
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        where = wait_for_ready_file(ready, proc)
        host, port = where["tcp"].rsplit(":", 1)
        client = ModbusTcpClient(host, port=int(port), framer=FramerType.RTU, timeout=2, retries=0)
        assert client.connect()
        start = time.monotonic()
        while time.monotonic() - start < 1.5:
            assert not client.read_holding_registers(Reg.STATUS1, count=1, device_id=1).isError()
        client.close()
        with urllib.request.urlopen(f"{where['control']}/audit", timeout=10) as answer:
            report = json.loads(answer.read())
    finally:
        proc.terminate()
        proc.wait(10)
    assert [(f["rule"], f["severity"]) for f in report["findings"]] == [("line-demand", "warning")], report["findings"]
    assert 90.0 < report["findings"][0]["value"] < 100.2  # full, within the frames' times' jitter (2 ms a second)
