"""A tcpdump capture of a pymodbus master polling the Modbus TCP gateway too fast gets the same line-demand finding
as the frame log of the same run (Debian's tcpdump on the loopback interface; .ci/run installs it)."""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path
from typing import Any

import pytest
from pymodbus.client import AsyncModbusTcpClient

from c20sim.cli import main
from c20sim.core.bus import FrameRecord
from c20sim.traffic.pcap import read_capture
from c20sim.transport.wallclock import WALL_OFFSET
from c20sim.wire.errors import C20SimError
from c20sim.wire.registers import Reg
from tests.integration.conftest import ServeFactory, need

pytestmark = pytest.mark.serial  # the audit judges a master's real rhythm, from a capture: .ci/run runs it alone


def audit(path: Path, capsys: pytest.CaptureFixture[str], *more: str) -> dict[str, Any]:
    capsys.readouterr()
    code = main(["audit", str(path), "--format", "json", *more])
    report: dict[str, Any] = json.loads(capsys.readouterr().out)
    assert code == (1 if report["findings"] else 0)
    return report


def captured(path: Path) -> int:
    """The Modbus frames tcpdump has written so far (the file may end in a packet half written)."""
    try:
        with path.open("rb") as f:
            return sum(1 for _ in read_capture(f, str(path)))
    except (C20SimError, OSError):
        return 0


async def test_a_tcpdump_capture_gets_the_frame_logs_finding(
    serve: ServeFactory, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    tcpdump = need("tcpdump")
    served = await serve()
    port = served.modbus_tcp_port
    records: list[FrameRecord] = []
    unsubscribe = served.sim.bus.subscribe(records.append)
    capture = tmp_path / "modbus.pcap"
    proc = await asyncio.create_subprocess_exec(
        *(tcpdump, "-i", "lo", "-n", "--immediate-mode", "-U", "-w", str(capture), f"tcp port {port}"),
        stdout=asyncio.subprocess.DEVNULL,
        stderr=asyncio.subprocess.PIPE,
    )
    try:
        assert proc.stderr is not None
        line = (await asyncio.wait_for(proc.stderr.readline(), 10)).decode()
        if "not permitted" in line or "permission" in line.lower():
            pytest.skip(f"tcpdump cannot capture here: {line.strip()}")
        assert "listening on lo" in line, line
        client = AsyncModbusTcpClient("127.0.0.1", port=port, timeout=1, retries=0)
        assert await client.connect()
        try:
            start = time.monotonic()
            while time.monotonic() - start < 1.3:  # as fast as the gateway answers
                assert not (await client.read_holding_registers(Reg.STATUS1, count=1, device_id=1)).isError()
        finally:
            client.close()
        deadline = time.monotonic() + 10.0
        while captured(capture) < len(records):  # tcpdump has written every frame the bus saw
            assert time.monotonic() < deadline, (captured(capture), len(records))
            await asyncio.sleep(0.05)
    finally:
        proc.terminate()
        await proc.wait()
        unsubscribe()
    log = tmp_path / "frames.jsonl"
    log.write_text("".join(json.dumps(r.as_dict(WALL_OFFSET)) + "\n" for r in records))

    from_log = audit(log, capsys)
    from_capture = audit(capture, capsys)
    assert [f["rule"] for f in from_log["findings"]] == ["line-demand"]
    assert [f["rule"] for f in from_capture["findings"]] == ["line-demand"]
    assert from_capture["frames"] == from_log["frames"] == len(records)
    peak_log, peak_capture = from_log["findings"][0]["value"], from_capture["findings"][0]["value"]
    assert peak_log > 100.0
    assert peak_capture == pytest.approx(peak_log, rel=0.05)  # the same frames, stamped by the kernel instead
