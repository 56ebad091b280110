"""The service routes: /health, /openapi.json against the routes really served, the clock, set-ups, generators."""

from __future__ import annotations

import json
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path
from typing import Any

import aiohttp
import jsonschema
import pytest
from aiohttp.test_utils import TestClient, TestServer

from c20sim.control import ops
from c20sim.control.http import ROUTES, ControlApi, make_app
from c20sim.control.openapi import document
from c20sim.core.clock import RealtimeClock, VirtualClock
from c20sim.core.simulator import Simulator
from c20sim.drive.params import ParameterStore
from c20sim.drive.profile import load_profile
from c20sim.serve import ServeOptions, Server

Api = Callable[..., Awaitable[tuple[int, Any]]]


@pytest.fixture
async def client() -> AsyncIterator[Callable[[Simulator], Awaitable[Api]]]:
    clients: list[TestClient[Any, Any]] = []

    async def start(sim: Simulator) -> Api:
        api = ControlApi(sim)
        api.serving = True
        test_client: TestClient[Any, Any] = TestClient(TestServer(make_app(api)))
        await test_client.start_server()
        clients.append(test_client)

        async def call(method: str, path: str, body: Any = None) -> tuple[int, Any]:
            # state changes go as JSON, as ctl sends them (the guard refuses anything else with 415)
            headers = {"Content-Type": "application/json"} if method != "GET" else {}
            kwargs: dict[str, Any] = {"json": body} if body is not None else {"headers": headers}
            response = await test_client.request(method, path, **kwargs)
            return response.status, await response.json()

        return call

    yield start
    for each in clients:
        await each.close()


def virtual() -> Simulator:
    return Simulator(load_profile(), (1,), clock=VirtualClock(), seed=1)


class FakeWall:
    """A wall clock the test moves."""

    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


# --- The OpenAPI document.


def served_routes() -> set[tuple[str, str]]:
    app = make_app(ControlApi(virtual()))
    return {(r.method, r.resource.canonical) for r in app.router.routes() if r.method != "HEAD" and r.resource}


def test_openapi_describes_exactly_the_routes_the_app_serves() -> None:
    doc = document(ROUTES)
    documented = {(method.upper(), path) for path, item in doc["paths"].items() for method in item}
    served = served_routes()
    assert documented == served, (
        f"served, not described: {served - documented}; described, not served: {documented - served}"
    )
    assert doc["openapi"] == "3.1.0"
    ids = [op["operationId"] for item in doc["paths"].values() for op in item.values()]
    assert len(ids) == len(set(ids))
    for path, item in doc["paths"].items():
        for op in item.values():
            declared = {p["name"] for p in op.get("parameters", []) if p["in"] == "path"}
            assert declared == {part[1:-1] for part in path.split("/") if part.startswith("{")}, path
            schema = op.get("requestBody", {}).get("content", {}).get("application/json", {}).get("schema")
            if schema is not None:
                jsonschema.Draft202012Validator.check_schema(schema)


def test_the_document_is_valid_openapi() -> None:
    from openapi_spec_validator import validate

    validate(document(ROUTES))  # raises, saying where, if it is not


def test_get_routes_lists_the_service_routes_too() -> None:
    for key in (
        "GET /health",
        "GET /openapi.json",
        "POST /clock/pause",
        "POST /reset",
        "GET /drives/{address}/generators",
    ):
        assert key in ROUTES


def body_schema(method: str, path: str) -> dict[str, Any]:
    schema: dict[str, Any] = document(ROUTES)["paths"][path][method]["requestBody"]["content"]["application/json"][
        "schema"
    ]
    return schema


@pytest.mark.parametrize(
    ("body", "valid"),
    [
        ({"supply_v": 30}, True),
        ({"supply_v": {"ramp": 30, "over": 5}}, True),
        ({"ambient_c": {"sine": 2, "period": 0.5}}, True),
        ({"load_torque_nm": {"noise": 0.1, "seed": 7, "every": 0.05}}, True),
        ({"hall_fault": "stuck0", "terminal_inputs": 3}, True),
        ({"supply_v": 5000}, False),
        ({"supply_v": {"ramp": 30}}, False),
        ({"supply_v": {"sine": 2, "period": 0.001}}, False),
        ({"hall_fault": {"ramp": 1, "over": 1}}, False),
        ({"suply_v": 30}, False),
    ],
)
async def test_the_conditions_schema_agrees_with_the_api(
    client: Callable[[Simulator], Awaitable[Api]], body: dict[str, Any], valid: bool
) -> None:
    schema = body_schema("put", "/drives/{address}/conditions")
    errors = list(jsonschema.Draft202012Validator(schema).iter_errors(body))
    assert (not errors) == valid, errors
    api = await client(virtual())
    status, answer = await api("PUT", "/drives/1/conditions", body)
    assert (status == 200) == valid, answer


async def test_openapi_json_is_served(client: Callable[[Simulator], Awaitable[Api]]) -> None:
    api = await client(virtual())
    assert await api("GET", "/openapi.json") == (200, json.loads(json.dumps(document(ROUTES))))


# --- /health.


async def test_health_is_503_until_the_server_has_started_every_endpoint() -> None:
    sim = virtual()
    api = ControlApi(sim)
    test_client: TestClient[Any, Any] = TestClient(TestServer(make_app(api)))
    await test_client.start_server()
    try:
        response = await test_client.get("/health")
        assert (response.status, await response.json()) == (503, {"status": "starting"})
    finally:
        await test_client.close()


async def test_health_over_a_real_port_once_serving() -> None:
    server = Server(virtual(), ServeOptions(tcp="127.0.0.1:0", control="127.0.0.1:0"))
    await server.start()
    try:
        assert server.control is not None
        async with aiohttp.ClientSession() as session, session.get(f"{server.control.url}/health") as response:
            assert response.status == 200
            assert await response.json() == {"status": "serving", "profile": "c20-400hr", "drives": [1], "t": 0.0}
    finally:
        await server.aclose()


# --- The clock.


async def test_pause_resume_and_speed_of_a_realtime_clock(client: Callable[[Simulator], Awaitable[Api]]) -> None:
    wall = FakeWall()
    sim = Simulator(load_profile(), (1,), clock=RealtimeClock(source=wall))
    api = await client(sim)
    assert await api("GET", "/clock") == (200, {"clock": "realtime", "t": 0.0, "paused": False, "speed": 1.0})
    wall.t += 2
    assert await api("POST", "/clock/pause") == (200, {"clock": "realtime", "t": 2.0, "paused": True, "speed": 1.0})
    wall.t += 50  # paused: the model's time stands still, and the drive with it
    assert (await api("GET", "/drives/1"))[1]["t"] == 2.0
    assert await api("POST", "/clock/resume") == (200, {"clock": "realtime", "t": 2.0, "paused": False, "speed": 1.0})
    wall.t += 1
    assert await api("PUT", "/clock/speed", {"speed": 10}) == (
        200,
        {"clock": "realtime", "t": 3.0, "paused": False, "speed": 10.0},
    )
    wall.t += 0.5
    assert (await api("GET", "/clock"))[1]["t"] == 8.0
    assert await api("PUT", "/clock/speed", {"speed": 0}) == (400, {"error": "speed: 0 is outside 0.001-1000"})
    assert await api("PUT", "/clock/speed", {}) == (400, {"error": 'give the speed factor, such as {"speed": 10}'})


async def test_the_clock_of_a_virtual_simulator_cannot_be_paused(client: Callable[[Simulator], Awaitable[Api]]) -> None:
    api = await client(virtual())
    assert await api("GET", "/clock") == (200, {"clock": "virtual", "t": 0.0, "paused": False, "speed": None})
    assert await api("POST", "/clock/pause") == (
        409,
        {"error": "pause: the clock is virtual and moves only when advanced; pause is for serve --clock realtime"},
    )
    assert (await api("PUT", "/clock/speed", {"speed": 2}))[0] == 409
    assert await api("POST", "/clock/resume", {"now": True}) == (
        400,
        {"error": "POST /clock/resume takes no fields; got 'now'"},
    )


# --- Set-ups.


async def test_reset_to_defaults_without_restarting(client: Callable[[Simulator], Awaitable[Api]]) -> None:
    sim = virtual()
    api = await client(sim)
    await api("PUT", "/drives/1/conditions", {"supply_v": 20, "ambient_c": {"sine": 5, "period": 1}})
    await api("PATCH", "/link", {"drop_next": 3})
    await api("POST", "/drives/1/keypad", {"key": "forward"})
    ops.set_run_channel(sim, 1, 0)
    await api("POST", "/time/advance", {"seconds": 1})
    before = (await api("GET", "/drives/1"))[1]
    assert (before["run_channel"], before["supply_v"], before["generators"] != {}) == (0, 20.0, True)
    status, answer = await api("POST", "/reset", {"setup": "defaults"})
    assert status == 200 and answer["setup"] == "defaults"
    state = answer["drives"][0]
    assert (state["t"], state["state"], state["run_channel"], state["supply_v"], state["ambient_c"]) == (
        1.0,
        "stopped",
        2,
        48.0,
        25.0,
    )
    assert state["generators"] == {} and state["link_faults"]["active"] == []
    assert (await api("GET", "/link"))[1]["active"] == []
    assert ops.read_register(sim, 1, "2006H")["raw"] == 2  # F00.01 back at the profile's default


async def test_reset_to_a_state_file_reads_it_and_leaves_it_alone(
    client: Callable[[Simulator], Awaitable[Api]], tmp_path: Path
) -> None:
    profile = load_profile()
    path = tmp_path / "bench.json"
    store = ParameterStore(profile, path)
    store.set(0x0001, 0)  # F00.01 = 0: keypad run channel
    written = path.read_bytes()
    sim = virtual()
    api = await client(sim)
    status, answer = await api("POST", "/reset", {"setup": str(path)})
    assert status == 200, answer
    assert answer["drives"][0]["run_channel"] == 0
    assert (await api("GET", "/drives/1/registers/2006H"))[1]["raw"] == 0
    assert path.read_bytes() == written
    assert await api("POST", "/reset", {"setup": str(tmp_path / "none.json")}) == (
        400,
        {
            "error": f'setup {str(tmp_path / "none.json")!r}: no such state file; give "defaults" or the path '
            "of a file written by --state"
        },
    )
    (tmp_path / "bad.json").write_text("{")
    status, answer = await api("POST", "/reset", {"setup": str(tmp_path / "bad.json")})
    assert status == 400 and answer["error"].startswith(f"setup: {tmp_path / 'bad.json'}: corrupt state file")


# --- Generators.


async def test_generators_through_the_api(client: Callable[[Simulator], Awaitable[Api]]) -> None:
    api = await client(virtual())
    status, state = await api("PUT", "/drives/1/conditions", {"supply_v": {"ramp": 30, "over": 5}})
    assert status == 200 and state["generators"] == {
        "supply_v": {"kind": "ramp", "from": 48.0, "to": 30.0, "over": 5.0, "start": 0.0}
    }
    await api("POST", "/time/advance", {"seconds": 2.5})
    assert (await api("GET", "/drives/1"))[1]["supply_v"] == 39.0
    await api("PUT", "/drives/1/conditions", {"ambient_c": {"sine": 10, "period": 1}})
    await api("POST", "/time/advance", {"seconds": 0.25})
    state = (await api("GET", "/drives/1"))[1]
    assert (state["ambient_c"], state["supply_v"]) == (35.0, 38.1)
    assert await api("DELETE", "/drives/1/generators", {"condition": "ambient_c"}) == (
        200,
        {"generators": {"supply_v": {"kind": "ramp", "from": 48.0, "to": 30.0, "over": 5.0, "start": 0.0}}},
    )
    await api("POST", "/time/advance", {"seconds": 0.25})
    state = (await api("GET", "/drives/1"))[1]
    assert (state["ambient_c"], state["supply_v"]) == (35.0, 37.2)  # ambient held where it was stopped
    await api("PUT", "/drives/1/conditions", {"supply_v": 47})  # a value stops the ramp
    assert await api("GET", "/drives/1/generators") == (200, {"generators": {}})
    assert await api("PUT", "/drives/1/conditions", {"supply_v": {"ramp": 30}}) == (
        400,
        {"error": "supply_v: a ramp needs over = SECONDS, such as { ramp = 30, over = 5 }"},
    )
    assert await api("PUT", "/drives/1/conditions", {"supply_v": {"ramp": 30, "over": 1, "sine": 2}}) == (
        400,
        {
            "error": "supply_v: give one generator, such as { ramp = 30, over = 5 }, { sine = 2, period = 0.5 } or { noise = 0.5, seed = 1 }"
        },
    )
    assert await api("DELETE", "/drives/1/generators", {"condition": "suply_v"}) == (
        400,
        {"error": "unknown condition 'suply_v'; did you mean 'supply_v'? (known: " + ", ".join(ops.CONDITIONS) + ")"},
    )
