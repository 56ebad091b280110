"""The control API answers 400 with one clear line, never 500, for a number of thousands of digits on every route
and key, and for a list or an object where a name belongs; through HTTP on a real port."""

from __future__ import annotations

import json
from collections.abc import AsyncIterator
from typing import Any

import pytest
from aiohttp.test_utils import TestClient, TestServer

from c20sim.control import ops, routes
from c20sim.control.http import ControlApi, make_app
from c20sim.core.clock import VirtualClock
from c20sim.core.linkfaults import KNOBS
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile

#: raw JSON numbers: within Python's int-from-text limit (4,300 digits), and beyond it
HUGE = {4000: "9" * 4000, 5000: "-" + "9" * 5000}


@pytest.fixture
async def http() -> AsyncIterator[TestClient[Any, Any]]:
    sim = Simulator(load_profile(), (1,), clock=VirtualClock(), seed=1)
    client: TestClient[Any, Any] = TestClient(TestServer(make_app(ControlApi(sim))))
    await client.start_server()
    yield client
    await client.close()


def bodies() -> list[tuple[str, str, str, str]]:
    """(method, path, key, JSON body template with {N} for the number) for every key of every route with a body."""
    out = []
    for row in routes.table().values():
        if row.method == "GET":
            continue
        path = row.path.replace("{address}", "1").replace("{register}", "2001H")
        keys = [f.name for f in row.fields]
        if row.path.endswith("/conditions"):
            keys += list(ops.CONDITIONS)
        if row.path.endswith("/link"):
            keys += list(KNOBS)
        if row.path.endswith("/fault") and row.method == "POST":
            keys += ["code"]
        for key in keys:
            out.append((row.method, path, key, '{"' + key + '": {N}}'))
    out.append(("PATCH", "/drives/1/conditions", "supply_v.sine", '{"supply_v": {"sine": {N}, "period": 1}}'))
    out.append(("PATCH", "/drives/1/conditions", "supply_v.period", '{"supply_v": {"sine": 1, "period": {N}}}'))
    return out


CASES = bodies()


@pytest.mark.parametrize(("method", "path", "key", "template"), CASES, ids=[f"{m} {p} {k}" for m, p, k, _ in CASES])
async def test_a_number_of_thousands_of_digits_is_a_400_naming_its_key(
    http: TestClient[Any, Any], method: str, path: str, key: str, template: str
) -> None:
    for digits, text in HUGE.items():
        response = await http.request(
            method, path, data=template.replace("{N}", text), headers={"Content-Type": "application/json"}
        )
        assert response.status == 400, (digits, await response.text())
        assert await response.json() == {"error": f"{key}: a number of {digits} digits; no value here has more than 30"}


async def test_the_largest_numbers_taken_still_reach_the_checks(http: TestClient[Any, Any]) -> None:
    """30 digits pass the body's check, and the route's own check says what is wrong with the value."""
    headers = {"Content-Type": "application/json"}
    response = await http.post("/time/advance", data='{"seconds": %s}' % ("9" * 30), headers=headers)
    assert (response.status, (await response.json())["error"]) == (400, "seconds: 1e+30 is outside 0-3.1536e+08")
    response = await http.put("/drives/1/registers/2001H", data='{"value": %s}' % ("9" * 30), headers=headers)
    assert (response.status, (await response.json())["error"]) == (
        400,
        "value: 999999999999999999999999999999 is outside 0-65535",
    )


@pytest.mark.parametrize("value", [["supply_v"], {"name": "supply_v"}, 7, True])
async def test_a_condition_that_is_not_a_name_is_a_400(http: TestClient[Any, Any], value: object) -> None:
    response = await http.request(
        "DELETE", "/drives/1/generators", json={"condition": value}, headers={"Content-Type": "application/json"}
    )
    assert response.status == 400
    assert await response.json() == {
        "error": f"condition: expected a condition's name, such as supply_v, got {json.dumps(value)}"
    }


async def test_path_and_query_numbers_of_thousands_of_digits_are_not_500(http: TestClient[Any, Any]) -> None:
    for digits, text in HUGE.items():
        for path in (f"/drives/{text}/state", f"/drives/1/registers/{text}", f"/frames?last={text}"):
            response = await http.get(path)  # a 4xx saying what is wrong, or all the frames for last=N
            assert response.status in (200, 400, 404), (digits, path[:40], response.status, await response.text())
            assert "error" in await response.json() or path.startswith("/frames")


def test_the_handle_says_a_number_of_thousands_of_digits_in_one_line() -> None:
    """The same checks in process (the pytest handle), past the interpreter's limit on printing a number too."""
    from c20sim.testing import C20Sim
    from c20sim.wire.errors import C20SimError

    with C20Sim.start() as sim:
        for value, said in ((10**3999, "4000 digits"), (-(10**5000), "more than 4300 digits")):
            with pytest.raises(C20SimError) as caught:
                sim.set(supply_v=value)
            assert str(caught.value) == f"supply_v: a number of {said} is outside 0-2000"
            with pytest.raises(C20SimError) as caught:
                sim.set(supply_v={"sine": value, "period": 1})
            assert str(caught.value) == f"supply_v.sine: a number of {said} is outside 0-2000"
