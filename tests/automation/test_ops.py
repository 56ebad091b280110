"""The operations (c20sim.control) as every front end meets them: one vocabulary, one check, one table each."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import fields

import pytest

from c20sim import control
from c20sim.control import causes, ops
from c20sim.core.clock import VirtualClock
from c20sim.core.linkfaults import KNOBS, LinkFaults
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile
from c20sim.tui.workbench import DEVICE_SWITCHES, LINK_SWITCHES
from c20sim.wire.registers import Command, Reg


def running(profile: str = "c20-400hr") -> Simulator:
    sim = Simulator(load_profile(profile), (1,), clock=VirtualClock())
    drive = sim.drive(1)
    drive.write(Reg.SPEED_SETPOINT, 1500)
    drive.write(Reg.COMMAND, Command.FORWARD)
    sim.run_until(2.0)
    assert drive.read(Reg.MOTOR_SPEED) == 1500
    return sim


@pytest.mark.parametrize(
    ("cause", "seconds", "code", "holds"),
    [
        ("undervoltage", 0.5, 0x0A, True),
        ("overvoltage", 0.5, 0x09, True),  # OV3: at constant speed
        ("overcurrent", 0.5, 0x06, True),  # a shock load while running: OC3; the load holds the fault
        ("stall", 4.0, 27, False),  # likewise
        ("overheat", 160.0, 0x10, True),
        ("hall", 0.5, 26, True),
        ("external", 0.1, 0x11, True),
        ("eeprom", 0.0, 0x15, True),  # no physical cause in the model: latched until released
    ],
)
def test_each_cause_trips_its_fault_and_releases(cause: str, seconds: float, code: int, holds: bool) -> None:
    sim = running()
    note = causes.trip(sim, 1, cause)
    assert note.startswith(f"drive 1: {cause}")
    assert causes.active(sim, 1)[cause]
    sim.run_until(sim.now() + seconds + 0.001)
    assert ops.read_register(sim, 1, "fault_code")["raw"] == code
    if holds:
        assert ops.press_key(sim, 1, "reset") is False  # the cause is still there: the drive refuses the reset
    causes.release(sim, 1, cause)
    assert not causes.active(sim, 1)[cause]
    sim.run_until(sim.now() + 120.0)  # the drive cools, the bus settles
    assert ops.press_key(sim, 1, "reset") is True
    assert ops.read_register(sim, 1, "fault_code")["raw"] == 0


def test_cause_levels_come_from_each_profile() -> None:
    for name in ("c20-400hr", "c20-2200hv"):
        sim = running(name)
        causes.trip(sim, 1, "undervoltage")
        assert ops.conditions(sim, 1)["supply_v"] == round(sim.profile.supply.undervoltage_v * 0.5, 1)


def test_unknown_cause_and_bad_values_are_refused_with_the_known_names() -> None:
    sim = running()
    with pytest.raises(ops.ControlError, match=r"^unknown cause 'overheet'; did you mean 'overheat'\? \(known: "):
        causes.trip(sim, 1, "overheet")
    with pytest.raises(ops.ControlError, match=r"^cause: expected a name such as 'undervoltage', got 3$"):
        causes.trip(sim, 1, 3)
    with pytest.raises(ops.ControlError, match=r"^no drive at address 7; drives: 1$") as caught:
        causes.trip(sim, 7, "overheat")
    assert caught.value.status == 404


def test_conditions_are_one_table_read_back_as_set() -> None:
    sim = running()
    values = {"supply_v": 40.0, "load_torque_nm": 0.1, "ambient_c": 30.0, "ai1_v": 2.5, "hall_fault": "stuck7"}
    ops.set_conditions(sim, 1, values)
    now = ops.conditions(sim, 1)
    assert set(now) == set(ops.CONDITIONS)
    assert {key: now[key] for key in values} == values
    with pytest.raises(ops.ControlError, match=r"^ai2_v: 11 is outside 0-10$"):
        ops.set_conditions(sim, 1, {"supply_v": 30.0, "ai2_v": 11})
    assert ops.conditions(sim, 1)["supply_v"] == 40.0  # nothing applied when one is refused


def test_link_faults_are_defined_once() -> None:
    """Every field of LinkFaults has its knob; the checks and the dashboard's switches are made from them."""
    names = [f.name for f in fields(LinkFaults)]
    assert list(KNOBS) == names == list(ops.LINK_CHECKS)
    assert [s.key for s in LINK_SWITCHES] == [k.key for k in KNOBS.values()]
    assert len({s.key for s in LINK_SWITCHES} | {"z", "b"}) == len(names) + 2  # keys unique, none taken by z or b
    assert [s.key for s in DEVICE_SWITCHES] == [c.key for c in causes.CAUSES.values()]
    sim = running()
    link = ops.set_link_faults(sim, 1, {"garbage_before": "FF 00", "forced_exception": "NOT_WHILE_RUNNING"})
    assert ops.link_state(link)["active"] == ["garbage_before", "forced_exception"]
    assert ops.link_state(link)["garbage_before"] == "FF 00"
    with pytest.raises(ops.ControlError, match=r"^drop_percent: 101 is outside 0-100$"):
        ops.set_link_faults(sim, None, {"drop_percent": 101})


def test_commands_have_one_name() -> None:
    assert list(ops.KEYS) == [
        "forward",
        "reverse",
        "jog_forward",
        "jog_reverse",
        "stop",
        "free_stop",
        "reset",
        "jog_stop",
    ]
    assert ops.key_command("free_stop") is Command.FREE_STOP
    assert ops.key_command(6) is Command.FREE_STOP
    assert control.KEYS is ops.KEYS


def test_run_until_is_the_one_way_time_moves() -> None:
    sim = Simulator(load_profile(), (1,), clock=VirtualClock())
    assert sim.run_until(1.5) == 1.5
    assert sim.run_until(1.0) == 1.5  # never backwards
    assert sim.wall_seconds_to(3.0) == 0.0 and sim.now() == 3.0  # a virtual clock is run to it
    assert ops.advance(sim, 0.5) == 3.5


def test_the_test_handle_needs_no_pytest() -> None:
    """c20sim.testing from a plain script: a context manager, a real port, and pytest never imported."""
    script = """
import sys
from pymodbus.client import ModbusTcpClient
from pymodbus import FramerType
from c20sim.testing import C20Sim
with C20Sim.start(transport="tcp") as sim:
    client = ModbusTcpClient(sim.host, port=sim.port, framer=FramerType.RTU, timeout=2, retries=0)
    assert client.connect()
    assert client.write_register(0x2001, 1500, device_id=1).isError() is False
    assert client.write_register(0x2000, 1, device_id=1).isError() is False
    client.close()
    sim.advance(2.0)
    sim.assert_written("2001H", 1500, count=1)
    sim.assert_written("F00.10", count=0)
    sim.trip("undervoltage")
    sim.advance(0.5)
    sim.assert_fault(0x0A)
print("pytest" in sys.modules)
"""
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60, check=False)
    assert (result.returncode, result.stdout, result.stderr) == (0, "False\n", "")


def test_the_tui_has_no_import_circle() -> None:
    """The dashboard's modules import each other one way only: widgets, messages and the bench know nothing
    of the app (the package's __init__ and the launcher, session.py, may import it)."""
    import ast
    from pathlib import Path

    import c20sim.tui

    folder = Path(c20sim.tui.__file__).parent
    imports: dict[str, set[str]] = {}
    for path in folder.glob("*.py"):
        names = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.level == 1 and node.module:
                names.add(node.module)
        imports[path.stem] = names

    def reaches(start: str, goal: str, seen: set[str]) -> bool:
        return any(n == goal or (n not in seen and reaches(n, goal, seen | {n})) for n in imports.get(start, ()))

    circles = [name for name in imports if name != "__init__" and reaches(name, name, {name})]
    assert circles == []
    assert {name for name, found in imports.items() if "app" in found} == {"__init__", "session"}


def test_registers_are_listed_as_the_sheet_groups_them() -> None:
    sim = running()
    table = {row["register"]: row for row in ops.registers(sim, 1)}
    assert [table[r]["group"] for r in ("2000H", "2005H", "2100H", "3006H", "F00.10", "F08.00")] == [
        "communication control command",
        "communication set points",
        "drive status",
        "monitoring",
        "function codes F00",
        "function codes F08",
    ]
    assert (table["2002H"]["access"], table["2002H"]["locked"]) == ("W/R*", True)  # pole pairs, while running
    assert (table["3006H"]["raw"], table["3006H"]["text"]) == (1500, "1500 rpm")
    assert (table["2005H"]["mirrors"], table["2100H"]["text"]) == ("F00.00", "forward running")


@pytest.mark.parametrize(
    ("register", "value", "code"),
    [("2100H", 1, 0x07), ("2001H", 3001, 0x03), ("F00.10", 2500, 0x04), ("2002H", 4, 0x08)],
)
def test_a_bench_edit_meets_the_masters_rules(register: str, value: int, code: int) -> None:
    sim = running()
    before = len(sim.bus.records)
    with pytest.raises(ops.ControlError) as caught:
        ops.write_register(sim, 1, register, value)
    assert (caught.value.status, caught.value.exception) == (409, code)
    assert str(caught.value).startswith(f"{register} = {value} refused: exception 0x{code:02X} (")
    assert len(sim.bus.records) == before  # a bench edit is not a frame on the line
    assert ops.write_register(sim, 1, "2001H", 1000)["text"] == "1000 rpm"


def test_an_active_load_regenerates_through_the_operations() -> None:
    """The active load (a hoist's weight) is one row of CONDITIONS: set and read back like any condition."""
    sim = running()
    ops.set_conditions(sim, 1, {"active_load_nm": 1.0})  # pushes forward while running forward: regenerates
    sim.run_until(sim.now() + 1.0)
    state = ops.drive_state(sim, 1)
    assert state["conditions"]["active_load_nm"] == 1.0
    assert state["bus_v"] > sim.profile.supply.voltage_v  # the bus rises above the supply: energy flows back
    with pytest.raises(ops.ControlError, match=r"^active_load_nm: -1001 is outside -1000-1000$"):
        ops.set_conditions(sim, 1, {"active_load_nm": -1001})


def test_the_dial_switches_are_a_condition_every_front_end_sets() -> None:
    """2006H = 3 hands the run channel to SW3 (on: terminals, off: keypad; assumed, as the profile says)."""
    sim = Simulator(load_profile(), (1,), clock=VirtualClock())
    assert ops.write_register(sim, 1, "2006H", 3)["text"] == "dial switch (SW3)"
    ops.set_conditions(sim, 1, {"dial_switches": 0b100})
    assert ops.conditions(sim, 1)["dial_switches"] == 4
    assert ops.telemetry(sim, 1).run_channel == 1  # SW3 on: the terminals
    ops.set_conditions(sim, 1, {"dial_switches": 0})
    assert ops.telemetry(sim, 1).run_channel == 0  # SW3 off: the keypad
    with pytest.raises(ops.ControlError, match=r"^dial_switches: 8 is outside 0-7$"):
        ops.set_conditions(sim, 1, {"dial_switches": 8})


def test_whether_a_cause_is_present_is_the_drives_answer_whoever_set_the_condition() -> None:
    sim = running()
    drive = sim.drive(1)
    drive.write(Reg.VIRTUAL_INPUTS, 0x008)  # EF through 200AH, as a master would: not a bench condition
    drive.set_load_torque(3.0)  # past the current limit: a stall, though not the stall cause's own level
    found = causes.active(sim, 1)
    assert {name for name, on in found.items() if on} == {"external", "stall"}
    for name, cause in causes.CAUSES.items():
        assert found[name] == any(drive.cause_present(fault) for fault in cause.faults)


def test_a_mended_hall_sensor_is_said_in_words() -> None:
    from c20sim.core.clock import VirtualClock
    from c20sim.core.simulator import Simulator
    from c20sim.drive.profile import load_profile

    sim = Simulator(load_profile(), (1,), clock=VirtualClock())
    assert causes.trip(sim, 1, "hall") == "drive 1: hall: hall_fault stuck0"
    assert causes.release(sim, 1, "hall") == "drive 1: hall gone: hall_fault none (reset to clear the fault)"
