"""The live audit over the control API: GET and DELETE /audit, the telemetry's summary, the counters' line demand."""

from __future__ import annotations

import time
from collections.abc import AsyncIterator
from typing import Any

import pytest
from aiohttp.test_utils import TestClient, TestServer

from c20sim.control import liveaudit, routes
from c20sim.control.http import ControlApi, make_app
from c20sim.control.openapi import document
from c20sim.core.clock import VirtualClock
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile
from c20sim.wire.protocol import FrameEvent, FrameKind, ReadRequest, encode, transaction_time

READ = encode(ReadRequest(1, 0x2100, 1))


@pytest.fixture
async def served() -> AsyncIterator[tuple[Simulator, TestClient[Any, Any]]]:
    sim = Simulator(load_profile(), (1,), clock=VirtualClock(), seed=1)
    audit = liveaudit.start(sim)
    client: TestClient[Any, Any] = TestClient(TestServer(make_app(ControlApi(sim))))
    await client.start_server()
    yield sim, client
    await client.close()
    audit.close()
    assert liveaudit.of(sim) is None


def poll(sim: Simulator, every: float, n: int) -> None:
    """A master reading 2100H every ``every`` s, each after its reply: frames stamped on the monotonic clock, as
    the ports stamp them (from now on: the live gauge's "now" is the last window's until the clock catches up)."""
    t = time.monotonic()
    for k in range(n):
        assert sim.bus.handle(FrameEvent(FrameKind.FRAME, READ, t + k * every), sim.now()) is not None


async def test_get_audit_reports_the_findings(served: tuple[Simulator, TestClient[Any, Any]]) -> None:
    sim, client = served
    poll(sim, 1 / 256, 600)
    response = await client.get("/audit")
    report = await response.json()
    assert response.status == 200
    assert (report["frames"], report["worst"]) == (1200, "error")
    (finding,) = report["findings"]
    assert (finding["rule"], finding["severity"], finding["drive"]) == ("line-demand", "error", None)
    read = transaction_time(8, 7, 19200, 10, 0.002)
    expected = 256 * read * 100 / (255 / 256 + read)  # a window's 256 reads, first request to last one's end
    assert finding["value"] == pytest.approx(expected)
    assert report["line_demand"]["peak_percent"] == pytest.approx(expected, abs=0.05)

    telemetry = await (await client.get("/telemetry")).json()
    assert telemetry["audit"] == {
        "findings": {"error": 1, "warning": 0, "note": 0},
        "rules": ["line-demand"],
        "line_demand_percent": pytest.approx(expected, abs=0.05),
        "line_demand_peak_percent": pytest.approx(expected, abs=0.05),
    }
    counters = await (await client.get("/drives/1/counters")).json()
    assert counters["requests"] == 600
    assert counters["line_demand"]["transactions"] == 600
    assert counters["line_demand"]["peak_percent"] == report["line_demand"]["peak_percent"]

    response = await client.delete("/audit", headers={"Content-Type": "application/json"})
    assert response.status == 200
    assert (await response.json())["findings"] == []
    poll(sim, 0.5, 4)
    assert (await (await client.get("/audit")).json())["findings"] == []


async def test_the_audit_off_is_a_conflict() -> None:
    sim = Simulator(load_profile(), (1,), clock=VirtualClock(), seed=1)
    client: TestClient[Any, Any] = TestClient(TestServer(make_app(ControlApi(sim))))
    await client.start_server()
    try:
        response = await client.get("/audit")
        assert (response.status, await response.json()) == (409, {"error": "the audit is off (serve --no-audit)"})
        assert (await (await client.get("/telemetry")).json())["audit"] is None
        assert "line_demand" not in await (await client.get("/drives/1/counters")).json()
    finally:
        await client.close()


def test_the_audit_is_in_the_openapi_document() -> None:
    paths = document(routes.TABLE)["paths"]
    assert {"get", "delete"} <= set(paths["/audit"])
