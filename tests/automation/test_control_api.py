"""The control API in process: every route's answer, and the 4xx that says what was wrong."""

from __future__ import annotations

from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Any

import pytest
from aiohttp.test_utils import TestClient, TestServer

from c20sim.control.http import ControlApi, make_app
from c20sim.core.clock import RealtimeClock, VirtualClock
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile

Api = Callable[..., Awaitable[tuple[int, Any]]]


@pytest.fixture
async def client() -> AsyncIterator[Callable[[Simulator], Awaitable[Api]]]:
    clients: list[TestClient[Any, Any]] = []

    async def start(sim: Simulator) -> Api:
        test_client: TestClient[Any, Any] = TestClient(TestServer(make_app(ControlApi(sim))))
        await test_client.start_server()
        clients.append(test_client)

        async def api(
            method: str, path: str, body: Any = None, *, raw: str | None = None, headers: dict[str, str] | None = None
        ) -> tuple[int, Any]:
            kwargs: dict[str, Any] = {"data": raw} if raw is not None else {"json": body} if body is not None else {}
            if headers is None and method != "GET":
                headers = {"Content-Type": "application/json"}  # as every client of the API sends
            response = await test_client.request(method, path, headers=headers, **kwargs)
            return response.status, await response.json()

        return api

    yield start
    for each in clients:
        await each.close()


def virtual(*addresses: int) -> Simulator:
    return Simulator(load_profile(), addresses or (1,), clock=VirtualClock(), seed=1)


async def test_advancing_a_realtime_clock_is_a_conflict(client: Callable[[Simulator], Awaitable[Api]]) -> None:
    api = await client(Simulator(load_profile(), (1,), clock=RealtimeClock()))
    assert await api("POST", "/time/advance", {"seconds": 1}) == (
        409,
        {"error": "time runs on the wall clock; start the server with --clock virtual to advance it"},
    )


async def test_bad_bodies_and_fields(client: Callable[[Simulator], Awaitable[Api]]) -> None:
    api = await client(virtual(1, 2))
    status, data = await api("POST", "/time/advance", raw="{seconds: 1}")
    assert status == 400 and data["error"].startswith("the body is not JSON: Expecting property name")
    assert await api("POST", "/time/advance", [1]) == (400, {"error": "the body must be a JSON object, not list"})
    assert await api("POST", "/time/advance", {"secs": 1}) == (
        400,
        {"error": "unknown field 'secs'; did you mean 'seconds'? (known: seconds)"},
    )
    assert await api("POST", "/time/advance", {"seconds": -1}) == (
        400,
        {"error": "seconds: -1 is outside 0-3.1536e+08"},
    )
    assert await api("GET", "/drives/3") == (404, {"error": "no drive at address 3; drives: 1, 2"})
    assert await api("GET", "/drives/x") == (404, {"error": "drive address 'x' is not a number"})
    assert await api("GET", "/nowhere") == (404, {"error": "GET /nowhere: Not Found; see GET / for the routes"})
    assert await api("POST", "/drives/1/fault", {"code": 300}) == (400, {"error": "code: 300 is outside 1-255"})
    assert await api("POST", "/drives/1/fault", {"code": 16, "persistent": 1}) == (
        400,
        {"error": "persistent: expected true or false, got 1"},
    )
    assert await api("GET", "/drives/1/registers/F00.50") == (
        400,
        {"error": "register 'F00.50': the profile c20-400hr has no register F00.50"},
    )
    assert await api("PATCH", "/link", {"forced_exception": 9}) == (
        400,
        {
            "error": "forced_exception: 9 is not an exception code; use one of ILLEGAL_FUNCTION (1), "
            "ILLEGAL_ADDRESS (2), ILLEGAL_VALUE (3), OPERATION_FAILED (4), PASSWORD_ERROR (5), "
            "FRAME_ERROR (6), READ_ONLY (7), NOT_WHILE_RUNNING (8)"
        },
    )
    # nothing is half-applied: the good key before the bad one did not take
    assert await api("PUT", "/drives/1/conditions", {"supply_v": 30, "ambient_c": "hot"}) == (
        400,
        {"error": 'ambient_c: expected a number, got "hot"'},
    )
    status, state = await api("GET", "/drives/1")
    assert (status, state["supply_v"]) == (200, 48.0)


async def test_faults_keypad_power_cycle_and_registers(client: Callable[[Simulator], Awaitable[Api]]) -> None:
    sim = virtual()
    api = await client(sim)
    status, state = await api("POST", "/drives/1/fault", {"code": 17, "persistent": True})
    assert (status, state["state"], state["fault_code"]) == (200, "fault", 17)
    status, state = await api("POST", "/drives/1/keypad", {"key": "reset"})
    assert (status, state["accepted"], state["state"]) == (200, False, "fault")  # persistent: the cause is still there
    status, state = await api("DELETE", "/drives/1/fault")
    assert (status, state["reset"], state["fault_code"]) == (200, True, 0)
    assert await api("GET", "/drives/1/registers/status1") == (
        200,
        {
            "register": "2100H",
            "address": 0x2100,
            "name": "status word 1",
            "raw": 3,
            "value": 3.0,
            "unit": "",
            "text": "stopped",
        },
    )
    status, register = await api("GET", "/drives/1/registers/F00.10")
    assert (status, register["text"]) == (200, "50.00 Hz")
    status, register = await api("GET", "/drives/1/registers/0x3008")
    assert (status, register["raw"]) == (200, 480)
    status, register = await api("GET", "/drives/1/registers/fault code")
    assert (status, register["address"]) == (200, 0x2102)
    sim.drive(1).write(0x2001, 1000)  # RAM: a power cycle clears it
    status, state = await api("POST", "/drives/1/power-cycle")
    assert status == 200 and sim.drive(1).read(0x2001) == 0


async def test_link_faults_and_frames(client: Callable[[Simulator], Awaitable[Api]]) -> None:
    sim = virtual(1, 2)
    api = await client(sim)
    status, link = await api("PATCH", "/drives/2/link", {"drop_next": 2, "garbage_after": "ff 00"})
    assert (status, link["active"], link["garbage_after"]) == (200, ["drop_next", "garbage_after"], "FF 00")
    assert sim.link_faults(2).garbage_after == b"\xff\x00" and sim.link_faults(1).active == []
    status, link = await api("PATCH", "/link", {"offline": True})
    assert (status, link["active"]) == (200, ["offline"])
    assert sim.bus.link.offline
    status, link = await api("DELETE", "/link")
    assert (status, link["active"]) == (200, [])
    status, link = await api("DELETE", "/drives/2/link")
    assert (status, link["active"]) == (200, [])

    from tests.conftest import Line

    line = Line(sim.bus)
    line.send("01 03 21 03 00 01 7E 36")
    line.send("02 03 21 03 00 01 7E 05")
    status, log = await api("GET", "/frames?slave=2")
    assert status == 200
    assert [(r["seq"], r["dir"], r["hex"]) for r in log["frames"]] == [
        (2, "rx", "02 03 21 03 00 01 7E 05"),
        (3, "tx", "02 03 02 00 20 FD 9C"),
    ]
    assert log["next"] == 4
    assert await api("DELETE", "/frames") == (200, {"frames": [], "next": 4})
    line.send("02 03 21 03 00 01 7E 05")
    status, log = await api("GET", "/frames?since=5")
    assert (status, [r["seq"] for r in log["frames"]]) == (200, [5])
    assert await api("GET", "/frames?last=x") == (400, {"error": "last='x' is not a number"})
    assert await api("GET", "/frames?limit=3") == (
        400,
        {"error": "unknown query parameter 'limit' (known: last, slave, since)"},
    )


async def test_non_finite_numbers_are_refused(client: Callable[[Simulator], Awaitable[Api]]) -> None:
    sim = virtual()
    api = await client(sim)
    json_header = {"Content-Type": "application/json"}
    for constant in ("NaN", "Infinity", "-Infinity"):
        status, data = await api("POST", "/time/advance", raw=f'{{"seconds": {constant}}}', headers=json_header)
        assert (status, data) == (
            400,
            {"error": f"the body is not JSON: {constant} is not a JSON number; give a finite number"},
        )
        status, data = await api("PUT", "/drives/1/conditions", raw=f'{{"supply_v": {constant}}}', headers=json_header)
        assert status == 400
    assert sim.now() == 0.0
    status, state = await api("GET", "/drives/1")
    assert (status, state["supply_v"]) == (200, 48.0)  # still served, the supply untouched


def test_the_checks_refuse_nan_and_infinity() -> None:
    from c20sim import control

    sim = virtual()
    with pytest.raises(control.ControlError, match=r"^seconds: expected a finite number, got nan$"):
        control.advance(sim, float("nan"))
    with pytest.raises(control.ControlError, match=r"^supply_v: expected a finite number, got inf$"):
        control.set_conditions(sim, 1, {"supply_v": float("inf")})
    with pytest.raises(control.ControlError, match=r"^delay: expected a finite number, got nan$"):
        control.set_link_faults(sim, 1, {"delay": float("nan")})
    assert (sim.now(), sim.drive(1).telemetry().supply_v, sim.link_faults(1).delay) == (0.0, 48.0, 0.0)


async def test_a_bug_answers_json_500_and_logs_the_traceback(
    client: Callable[[Simulator], Awaitable[Api]], monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    from c20sim import control

    api = await client(virtual())

    def broken(sim: Simulator, address: int) -> dict[str, Any]:
        raise RuntimeError("boom")

    monkeypatch.setattr(control.ops, "drive_state", broken)
    assert await api("GET", "/drives/1") == (
        500,
        {"error": "GET /drives/1: internal error (RuntimeError: boom); see the server's log"},
    )
    assert [(r.levelname, r.getMessage()) for r in caplog.records] == [
        ("ERROR", "control API: bug while serving GET /drives/1")
    ]
    assert caplog.records[0].exc_info is not None
    monkeypatch.undo()
    assert (await api("GET", "/drives/1"))[0] == 200


async def test_last_frames_are_the_newest_and_only_they_are_put_in_words(
    client: Callable[[Simulator], Awaitable[Api]], monkeypatch: pytest.MonkeyPatch
) -> None:
    from c20sim.core.bus import FrameRecord
    from tests.conftest import Line

    sim = virtual()
    api = await client(sim)
    line = Line(sim.bus)
    for _ in range(5):
        line.send("01 03 21 03 00 01 7E 36")
    assert await api("GET", "/frames?last=0") == (400, {"error": "last=0 must be at least 1"})
    assert await api("GET", "/frames?last=-1") == (400, {"error": "last=-1 must be at least 1"})
    rendered: list[FrameRecord] = []
    as_dict = FrameRecord.as_dict

    def counting(record: FrameRecord, wall_offset: float | None = None) -> dict[str, object]:
        rendered.append(record)
        return as_dict(record, wall_offset)

    monkeypatch.setattr(FrameRecord, "as_dict", counting)
    status, log = await api("GET", "/frames?last=1")
    assert (status, [(r["seq"], r["dir"]) for r in log["frames"]], log["next"]) == (200, [(9, "tx")], 10)
    assert rendered == [sim.bus.records[-1]]
    rendered.clear()
    status, log = await api("GET", "/frames?since=6&last=3")
    assert [r["seq"] for r in log["frames"]] == [7, 8, 9]
    assert len(rendered) == 3
    status, log = await api("GET", "/frames?since=20")
    assert (status, log["frames"], rendered[3:]) == (200, [], [])


async def test_fault_by_cause(client: Callable[[Simulator], Awaitable[Api]]) -> None:
    sim = virtual()
    api = await client(sim)
    sim.drive(1).write(0x2001, 1500)  # as a master would, over the communication channel
    sim.drive(1).write(0x2000, 1)
    await api("POST", "/time/advance", {"seconds": 2})
    status, state = await api("POST", "/drives/1/fault", {"cause": "overheat"})
    assert (status, state["conditions"]["ambient_c"], state["fault_code"]) == (200, 150.0, 0)
    assert (await api("GET", "/drives/1/causes"))[1]["causes"]["overheat"] is True
    await api("POST", "/time/advance", {"seconds": 160})
    assert (await api("GET", "/drives/1"))[1]["fault_code"] == 0x10
    status, state = await api("DELETE", "/drives/1/fault", {"cause": "overheat", "reset": False})
    assert (status, state["conditions"]["ambient_c"], state["reset"]) == (200, 25.0, False)
    status, body = await api("POST", "/drives/1/fault", {"cause": "overheat", "code": 3})
    assert (status, body) == (400, {"error": "unknown field 'code' (known: cause)"})
    status, body = await api("POST", "/drives/1/fault", {})
    assert status == 400 and body["error"].startswith('give the fault by cause, such as {"cause": "undervoltage"}')


async def test_register_table_edit_and_counters(client: Callable[[Simulator], Awaitable[Api]]) -> None:
    api = await client(virtual())
    status, table = await api("GET", "/drives/1/registers")
    assert status == 200 and len(table["registers"]) == 113  # the fixed map and the profile's 77 function codes
    assert await api("PUT", "/drives/1/registers/F00.10", {"value": 2500}) == (
        409,
        {
            "error": "F00.10 = 2500 refused: exception 0x04 (operation failed), as a master would get it: "
            "function codes are locked while 200EH = 0 (write 200EH = 1 first)",
            "exception": 4,
        },
    )
    assert (await api("PUT", "/drives/1/registers/200EH", {"value": 1}))[1]["text"] == "function codes writable"
    status, info = await api("PUT", "/drives/1/registers/F00.10", {"value": 2500})
    assert (status, info["text"]) == (200, "25.00 Hz")
    assert await api("GET", "/drives/1/counters") == (
        200,
        {
            "requests": 0,
            "replies": 0,
            "exceptions": {},
            "crc_errors": 0,
            "length_errors": 0,
            "silences": 0,
            "injected": 0,
            "line_busy_s": 0.0,
            "line_share": 0.0,
        },
    )
