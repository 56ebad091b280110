"""The route table: an operation is its function plus one row, and every front end finds it with no other edit.

A throwaway operation is added to the table in the test: the HTTP API serves it (fields checked, errors in
words), ``GET /`` lists it, the OpenAPI document describes it, the dashboard's operations call it in this
process and over the API, and ``c20sim ctl`` has it as an action with its field as an argument.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any

import pytest

from c20sim import cli
from c20sim.control import ops, routes
from c20sim.control.client import ControlClient, RemoteOps
from c20sim.control.openapi import document
from c20sim.control.ops import ControlError
from c20sim.core.clock import VirtualClock
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile
from c20sim.tui.workbench import LocalOps
from tests.tui.conftest import serving


def spin(sim: Simulator, address: int, turns: object) -> dict[str, Any]:
    """The throwaway operation: check its field as ops do, and answer with what it was given."""
    count = ops.integer("turns", turns, 1, 10)
    return {"address": address, "turns": count, "t": sim.now()}


ROW = routes.Route(
    "POST",
    "/drives/{address}/spin",
    "spin",
    '{"turns": 3} (a test\'s throwaway operation)',
    spin,
    (routes.Field("turns", {"type": "integer", "minimum": 1, "maximum": 10}, True, "how many turns"),),
    missing='give the turns, such as {"turns": 3}',
    changes=True,
    help="spin the drive's test operation",
)


@pytest.fixture
def with_spin() -> Iterator[routes.Table]:
    table = routes.table()
    table.add(ROW)
    try:
        yield table
    finally:
        table.remove("spin")


def test_a_new_operation_reaches_every_front_end(with_spin: routes.Table, capsys: pytest.CaptureFixture[str]) -> None:
    # the OpenAPI document
    operation = document(with_spin)["paths"]["/drives/{address}/spin"]["post"]
    assert operation["requestBody"]["content"]["application/json"]["schema"] == {
        "type": "object",
        "properties": {"turns": {"type": "integer", "minimum": 1, "maximum": 10}},
        "additionalProperties": False,
        "required": ["turns"],
    }
    assert [p["name"] for p in operation["parameters"]] == ["address"]
    # the dashboard's operations in this process
    local = LocalOps(Simulator(load_profile(), (1,), clock=VirtualClock()))
    assert local.call("spin", address=1, turns=2) == {"address": 1, "turns": 2, "t": 0.0}
    with serving() as served:
        client = ControlClient(served.url)
        # the HTTP API, and GET /'s list
        assert client.call("POST", "/drives/1/spin", {"turns": 3}) == {"address": 1, "turns": 3, "t": 0.0}
        assert client.call("GET", "/")["routes"]["POST /drives/{address}/spin"] == ROW.doc
        with pytest.raises(ControlError, match=r'^give the turns, such as \{"turns": 3\}$'):
            client.call("POST", "/drives/1/spin", {})
        with pytest.raises(ControlError, match=r"^unknown field 'turn'; did you mean 'turns'\? \(known: turns\)$"):
            client.call("POST", "/drives/1/spin", {"turn": 3})
        with pytest.raises(ControlError, match=r"^turns: 11 is outside 1-10$"):
            client.call("POST", "/drives/1/spin", {"turns": 11})
        with pytest.raises(ControlError, match=r"^no drive at address 9; drives: 1$"):
            client.call("POST", "/drives/9/spin", {"turns": 1})
        # the dashboard's operations over the API
        assert RemoteOps(client).call("spin", address=1, turns=4) == {"address": 1, "turns": 4, "t": 0.0}
        # c20sim ctl: an action, its required field a positional argument, --drive for the address
        assert cli.main(["ctl", "--url", served.url, "--format", "json", "spin", "5", "--drive", "1"]) == 0
        assert json.loads(capsys.readouterr().out) == {"address": 1, "turns": 5, "t": 0.0}
        assert cli.main(["ctl", "--url", served.url, "spin", "7"]) == 0  # it changes state: one line of it
        assert capsys.readouterr().out == 'spin 7: {"address": 1, "turns": 7, "t": 0.0}\n'
        assert cli.main(["ctl", "--url", served.url, "--format", "text", "spin", "6"]) == 0
        assert capsys.readouterr().out == "address: 1\nturns: 6\nt: 0.0\n"
    with pytest.raises(SystemExit) as done:
        cli.main(["ctl", "spin", "--help"])
    assert done.value.code == 0
    assert ["turns", "how", "many", "turns"] in [line.split() for line in capsys.readouterr().out.splitlines()]


def test_ctl_help_lists_a_new_operation(with_spin: routes.Table, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        cli.main(["ctl", "--help"])
    assert done.value.code == 0
    lines = [line.split() for line in capsys.readouterr().out.splitlines()]
    assert ["spin", "spin", "the", "drive's", "test", "operation"] in lines


def test_without_the_row_no_front_end_has_it() -> None:
    assert "POST /drives/{address}/spin" not in routes.table()
    with pytest.raises(ControlError, match=r"^unknown operation 'spin'"):
        routes.table().named("spin")
    assert "/drives/{address}/spin" not in document(routes.table())["paths"]


def test_a_row_declared_twice_is_refused() -> None:
    with pytest.raises(ValueError, match=r"^route GET /time \(time\): declared twice$"):
        routes.table().add(routes.Route("GET", "/time", "time", "-", lambda sim: {}))


def test_every_row_is_served_and_every_served_route_is_a_row() -> None:
    from c20sim.control.http import ControlApi, make_app

    app = make_app(ControlApi(Simulator(load_profile(), (1,), clock=VirtualClock())))
    served = {f"{r.method} {r.resource.canonical}" for r in app.router.routes() if r.method != "HEAD" and r.resource}
    assert served == set(routes.table())


NEW_CAUSE = """
import json
from c20sim.control import causes
from c20sim.drive.profile import FaultCause

# the one row: a supply that sags below the undervoltage trip, and comes back
causes.CAUSES = {
    **causes.CAUSES,
    "brownout": causes.Cause(
        "brownout",
        "b",
        "brown-out",
        "the supply sags to 90 % of the undervoltage trip level",
        (FaultCause.UNDERVOLTAGE,),
        lambda p, c: {"supply_v": round(p.supply.undervoltage_v * 0.9, 1)},
        lambda p, c: {"supply_v": p.supply.voltage_v},
    ),
}

from c20sim.core.clock import VirtualClock
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile
from c20sim.scenario.timeline import parse_scenario
from c20sim.tui.workbench import DEVICE_SWITCHES, Workbench

sim = Simulator(load_profile(), (1,), clock=VirtualClock())
note = causes.request(sim, 1, {"cause": "brownout"})
step = parse_scenario({"step": [{"at": 0, "fault": {"cause": "brownout"}}]}, "s.toml").steps[0]
bench = Workbench(sim)
print(json.dumps({
    "note": note,
    "active": causes.active(sim, 1)["brownout"],
    "switch": [s.label for s in DEVICE_SWITCHES if s.key == "b"],
    "scenario": step.cause,
    "dashboard": bench.device_fault_active(1, "b"),
    "released": bench.toggle_device_fault(1, "b"),
    "after": causes.active(sim, 1)["brownout"],
}))
"""


def test_a_new_fault_cause_is_one_row() -> None:
    """A row added to causes.CAUSES (before the front ends are imported) is a cause of the API's fault request,
    of the scenarios, and a switch of the dashboard, with no other edit."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-c", NEW_CAUSE], capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout) == {
        "note": "drive 1: brownout: supply_v 18",
        "active": True,
        "switch": ["brown-out"],
        "scenario": "brownout",
        "dashboard": True,
        "released": "drive 1: brownout gone: supply_v 48 (reset to clear the fault)",
        "after": False,
    }


def test_clear_fault_without_a_cause_ends_every_cause_present_and_no_other_condition() -> None:
    """``ctl clear`` and the browser page's "end it and reset": the supply sag that tripped the drive ends, the
    load a user set stays, and a reset once the bus is back clears the fault (before, only an injected code was
    released: the drive stayed tripped, and the page said there was no fault to reset)."""
    sim = Simulator(load_profile(), (1,), clock=VirtualClock())
    table = routes.table()

    def call(name: str, data: dict[str, Any]) -> Any:
        return routes.invoke(sim, table.named(name), {"address": 1}, data)

    ops.set_conditions(sim, 1, {"load_torque_nm": 0.2})
    routes.invoke(sim, table.named("write_register"), {"address": 1, "register": "2001H"}, {"value": 1500})
    routes.invoke(sim, table.named("write_register"), {"address": 1, "register": "2000H"}, {"value": 1})
    sim.advance(1.0)
    call("fault", {"cause": "undervoltage"})
    sim.advance(2.0)
    assert (ops.drive_state(sim, 1)["status"], ops.drive_state(sim, 1)["fault_code"]) == (4, 0x0A)  # tripped
    answer = call("clear_fault", {})
    assert (answer["reset"], answer["note"]) == (
        False,
        "drive 1: undervoltage gone: supply_v 48 (reset to clear the fault); drive 1 kept its fault: its cause, "
        "undervoltage, has ended, but the drive has not recovered from it yet; let time pass (ctl advance 1 on a "
        "virtual clock) and reset again (ctl key reset)",
    )
    assert ops.conditions(sim, 1)["supply_v"] == 48.0
    assert ops.conditions(sim, 1)["load_torque_nm"] == 0.2  # not a cause that is present: left as set
    sim.advance(1.0)
    answer = call("clear_fault", {})
    assert (answer["reset"], answer["note"], answer["fault_code"]) == (True, "", 0)


def twirl(sim: Simulator, address: int, way: object = None, turns: object = None) -> dict[str, Any]:
    """A throwaway operation with an optional word and an option, answering with what it was given."""
    return {"address": address, "way": way, "turns": turns}


def test_an_optional_positional_field_is_a_word_for_ctl(capsys: pytest.CaptureFixture[str]) -> None:
    """A field marked ``positional`` (as write's value) is an optional word after the action, its siblings options,
    said as typed in the one-line answer; no other edit."""
    row = routes.Route(
        "POST",
        "/drives/{address}/twirl",
        "twirl",
        '{"way": "left", "turns": 2} (a test\'s throwaway operation)',
        twirl,
        (
            routes.Field("way", {"type": "string"}, doc="which way", positional=True),
            routes.Field("turns", {"type": "integer", "minimum": 1, "maximum": 10}),
        ),
        changes=True,
    )
    table = routes.table()
    table.add(row)
    try:
        with serving() as served:
            assert cli.main(["ctl", "--url", served.url, "twirl", "left", "--turns", "2"]) == 0
            assert capsys.readouterr().out == 'twirl left --turns 2: {"address": 1, "way": "left", "turns": 2}\n'
            assert cli.main(["ctl", "--url", served.url, "twirl"]) == 0  # the word left out: not sent
            assert capsys.readouterr().out == 'twirl: {"address": 1, "way": null, "turns": null}\n'
    finally:
        table.remove("twirl")
