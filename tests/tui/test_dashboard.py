"""The dashboard driven by keys and clicks, checked on the wire by a pymodbus master."""

from __future__ import annotations

from pathlib import Path

import pytest
from pymodbus import FramerType
from pymodbus.client import AsyncModbusTcpClient
from pymodbus.exceptions import ModbusIOException
from textual.widgets import Checkbox, DataTable, Input, RichLog, Static

from c20sim import control
from c20sim.serve import ServeOptions, Server
from c20sim.tui.app import Dashboard, HelpScreen, SaveLogScreen
from c20sim.tui.messages import TelemetryUpdated
from c20sim.tui.widgets import DeviceFaultsPanel, FrameLog, LinkFaultsPanel, NumberInput
from tests.tui.conftest import Bench, attached, running, serving, until

STATUS1, STATUS2, FAULT, SPEED, INPUTS = 0x2100, 0x2101, 0x2102, 0x3006, 0x300D


async def run_forward(bench: Bench, rpm: int = 1500) -> None:
    await bench.write(0x2001, rpm)
    await bench.write(0x2000, 1)
    await bench.press("t")
    assert await bench.read(SPEED) == rpm


async def test_undervoltage_while_running_trips_0x0A(bench: Bench) -> None:
    await run_forward(bench)
    await bench.press("f4", "u")  # device faults, undervoltage: the supply drops
    assert bench.app.bench.conditions(1).supply_v == 10.0  # half the 20 V trip level
    await bench.press("t")
    assert await bench.read(FAULT) == 0x000A
    assert await bench.read(STATUS1) == 4
    assert "0x0A UV: bus undervoltage" in bench.screen_text()
    # Beside the fault, the fault record (F07.33, F07.36, F07.37): what the trip met, as a master reads it.
    hz, amps, bus = await bench.read(0x0721), await bench.read(0x0724), await bench.read(0x0725)
    assert hz == 10000 and 195 <= bus <= 200  # running at 100.00 Hz, the bus at the 20 V trip level
    assert f"at trip  100.00 Hz · {amps / 100:.2f} A · bus {bus / 10:.1f} V" in bench.screen_text()
    await bench.press("x")  # reset refused: the supply is still low
    assert await bench.read(FAULT) == 0x000A
    await bench.press("u", "t", "x", "t", "t")  # supply back, reset, the rotor coasts to rest
    assert await bench.read(FAULT) == 0
    assert await bench.read(STATUS1) == 3


async def test_keypad_runs_only_on_the_keypad_channel(bench: Bench) -> None:
    await bench.write(0x2001, 1000)
    await bench.press("f", "t")
    assert await bench.read(STATUS1) == 3  # refused: communication channel (F00.01 = 2)
    assert any("FWD refused" in str(n.message) for n in bench.app._notifications)
    await bench.press("m")  # channel 2 -> 0: keypad
    assert await bench.read(0x0001) == 0
    assert await bench.read(STATUS2) == 0x0001  # bits 5-6 = 00: keypad control
    await bench.press("f", "t")
    assert (await bench.read(STATUS1), await bench.read(SPEED)) == (1, 1000)
    await bench.press("r", "t")
    assert (await bench.read(STATUS1), await bench.read(SPEED)) == (2, 1000)
    await bench.press("s", "t", "t")
    assert (await bench.read(STATUS1), await bench.read(SPEED)) == (3, 0)
    await bench.press("j", "t")  # jog forward at the jog speed, until released
    assert (await bench.read(STATUS1), await bench.read(SPEED)) == (1, 300)
    await bench.press("j", "t", "t")
    assert (await bench.read(STATUS1), await bench.read(SPEED)) == (3, 0)
    assert "keypad · speed from Modbus" in bench.screen_text()


async def test_clicking_fault_buttons(bench: Bench) -> None:
    await bench.press("f4")
    await bench.pilot.click("#dev-e")  # external fault: the EF terminal
    await bench.press("t")
    assert await bench.read(FAULT) == 17
    assert await bench.read(INPUTS) & 0x008
    await bench.pilot.click("#dev-e")
    await bench.press("x", "t")
    assert await bench.read(FAULT) == 0
    await bench.pilot.click("#dev-5")  # a latched fault with no physical cause: SPO
    await bench.press("t")
    assert await bench.read(FAULT) == 0x0E
    await bench.press("x")
    assert await bench.read(FAULT) == 0x0E  # persistent until switched off
    await bench.pilot.click("#dev-5")
    await bench.press("x")
    assert await bench.read(FAULT) == 0


async def test_link_faults_offline_and_forced_exception(bench: Bench) -> None:
    await bench.press("f5", "o")
    assert bench.served.call(lambda: bench.served.sim.link_faults(1).offline)
    with pytest.raises(ModbusIOException):
        await bench.client.read_holding_registers(STATUS1, count=1, device_id=1)
    await bench.press("o", "e", "e")  # online; forced exception 0x01, then 0x02
    response = await bench.client.read_holding_registers(STATUS1, count=1, device_id=1)
    assert (response.function_code, response.exception_code) == (0x83, 0x02)
    await bench.press("b", "c")  # the whole bus: bad CRC
    assert bench.served.call(lambda: bench.served.sim.link_faults(None).corrupt_crc)
    await bench.press("z", "b", "z")  # clear the bus, back to the drive, clear it
    assert await bench.read(STATUS1) == 3


async def test_conditions_supply_and_terminals(bench: Bench) -> None:
    await bench.press("f3")
    field = bench.app.get_screen_main().query_one("#cond-supply")
    assert field.has_focus
    await bench.press("home", "ctrl+k", "1", "5", "enter", "escape", "t", "t")
    assert await bench.read(STATUS1) == 5  # bus below 20 V while stopped: off
    assert await bench.read(0x3008) < 200
    await bench.press("f3", *["up"] * 10, "escape", "t", "t")  # 25 V, above the 22 V recover level: back
    assert await bench.read(STATUS1) == 3
    await bench.pilot.click("#term-S1")
    await bench.press("t")
    assert await bench.read(INPUTS) == 0x010


async def test_frame_log_shows_filters_pauses_and_saves(bench: Bench, tmp_path: Path) -> None:
    log = bench.app.get_screen_main().query_one(FrameLog)
    lines = log.query_one(RichLog)
    assert await bench.read(STATUS1) == 3
    response = await bench.client.read_holding_registers(0x0032, count=1, device_id=1)
    assert response.exception_code == 0x02
    await until(lambda: len(log.records) == 4, "4 frames in the log over the stream")
    await bench.pilot.pause()
    text = "\n".join(line.text for line in lines.lines)
    assert "read 2100H (status word 1)" in text
    assert "exception 0x02 to read: illegal data address" in text
    await bench.press("f2", "e")  # errors only
    assert [r.kind for r in log.visible_records()] == ["exception"]
    await bench.press("e", "space")  # all again; paused
    before = len(lines.lines)
    assert await bench.read(STATUS1) == 3
    await until(lambda: "PAUSED (2 new)" in str(log.query_one("#log-status").render()), "2 frames held while paused")
    assert len(lines.lines) == before
    await bench.press("space")
    assert len(lines.lines) == before + 2
    path = tmp_path / "frames.log"
    await bench.press("w")
    assert isinstance(bench.app.screen, SaveLogScreen)
    bench.app.screen.query_one("#save-path").value = str(path)  # type: ignore[attr-defined]
    await bench.press("enter")
    saved = path.read_text().splitlines()
    assert len(saved) == 6
    assert "exception 0x02 to read: illegal data address  01 83 02 C0 F1" in saved[3]


async def test_power_cycle_and_restore_defaults(bench: Bench) -> None:
    await bench.write(0x2001, 1234)  # RAM
    await bench.write(0x2003, 20)  # F00.11, EEPROM
    await bench.press("P")
    assert (await bench.read(0x2001), await bench.read(0x2003)) == (0, 20)
    await bench.press("D")
    assert await bench.read(0x2003) == 5


async def test_restore_defaults_refused_while_running(bench: Bench) -> None:
    await run_forward(bench)
    await bench.write(0x2003, 20)  # after the run: a 2 s ramp would still trail 1500 rpm at 1 s
    await bench.press("D")
    assert await bench.read(0x2003) == 20
    assert any("stop the motor first" in str(n.message) for n in bench.app._notifications)


async def test_several_drives_each_its_own() -> None:
    async with running(drives=(1, 2)) as bench:
        await bench.press("]", "f4", "e", "t")
        assert bench.app.selected == 2
        assert await bench.read(FAULT, device=2) == 17
        assert await bench.read(FAULT, device=1) == 0
        await bench.press("[")
        assert bench.app.selected == 1
        assert "fault    none" in bench.screen_text()


async def test_help_screen_and_palette_commands(bench: Bench) -> None:
    await bench.press("question_mark")
    assert isinstance(bench.app.screen, HelpScreen)
    await bench.press("escape")
    assert not isinstance(bench.app.screen, HelpScreen)
    titles = [c.title for c in bench.app.get_system_commands(bench.app.screen)]
    assert "Device fault: undervoltage" in titles
    assert "Link fault: offline" in titles
    assert "Device fault: EEP (0x15)" in titles
    assert "Keypad: STOP" in titles


async def test_every_device_switch_key_switches_its_cause(bench: Bench) -> None:
    workbench, panel = bench.app.bench, bench.app.get_screen_main().query_one(DeviceFaultsPanel)
    await bench.press("f4")
    for key, _ in panel.switches():
        assert panel.query_one(f"#dev-{key}")
        if key == "z":
            continue
        before = workbench.device_fault_active(1, key)
        await bench.press(key)
        assert workbench.device_fault_active(1, key) != before, f"device switch {key!r}"
    await bench.press("z")
    assert not any(workbench.device_fault_active(1, key) for key, _ in panel.switches())


async def test_every_link_switch_key_switches_its_fault(bench: Bench) -> None:
    workbench, panel = bench.app.bench, bench.app.get_screen_main().query_one(LinkFaultsPanel)
    await bench.press("f5")
    for key, _ in panel.switches():
        assert panel.query_one(f"#link-{key}")
        if key in ("z", "b"):
            continue
        before = workbench.link_fault_active(1, key)
        await bench.press(key)
        assert workbench.link_fault_active(1, key) != before, f"link switch {key!r}"
    await bench.press("z")
    assert not workbench.link_active(1)
    await bench.press("b", "c")
    assert panel.on_bus
    assert workbench.link_fault_active(None, "c")


@pytest.mark.parametrize("tab", ["f2", "f3", "f4", "f5"])
async def test_x_resets_a_fault_on_every_tab(bench: Bench, tab: str) -> None:
    await bench.press(tab)
    bench.served.call(control.inject_fault, bench.served.sim, 1, 0x15)
    assert await bench.read(FAULT) == 0x15
    await bench.press("x")
    assert await bench.read(FAULT) == 0
    assert not bench.served.call(lambda: bench.served.sim.link_faults(1).active)  # the key did nothing else


async def test_no_panel_binding_shadows_a_dashboard_key(bench: Bench) -> None:
    app_keys = {key for binding in Dashboard.BINDINGS for key in binding.key.split(",")}  # type: ignore[union-attr]
    assert {"x", "f", "J", "t", "q"} <= app_keys
    screen = bench.app.get_screen_main()
    for node in (screen, *screen.walk_children()):
        shadowed = app_keys & set(node._bindings.key_to_bindings)
        assert not shadowed, f"{node!r} binds {shadowed}, the dashboard's own keys"


async def test_jog_reverse_key_pressed_again_releases(bench: Bench) -> None:
    await bench.write(0x2001, 1000)
    await bench.press("m", "J", "t")  # keypad channel; jog reverse
    assert (await bench.read(STATUS1), await bench.read(SPEED)) == (2, 300)
    await bench.press("J", "t", "t")
    assert (await bench.read(STATUS1), await bench.read(SPEED)) == (3, 0)


async def test_dashboard_shows_conditions_set_by_the_control_api(bench: Bench) -> None:
    sim = bench.served.sim
    await bench.press("f3", "escape")  # the conditions, no field being edited
    bench.served.call(
        control.set_conditions, sim, 1, {"supply_v": 18, "load_torque_nm": 0.5, "ai1_v": 2.5, "terminal_inputs": 0x010}
    )
    screen = bench.app.get_screen_main()

    def shown() -> dict[str, str]:
        return {name: screen.query_one(f"#cond-{name}", Input).value for name in ("supply", "load", "ai1")}

    await until(lambda: shown() == {"supply": "18", "load": "0.5", "ai1": "2.5"}, "the conditions over the stream")
    assert screen.query_one("#term-S1", Checkbox).value
    await bench.press("f4")
    assert bench.app.get_screen_main().query_one("#dev-u").has_class("-on")
    await bench.press("u")  # the undervoltage the API made, switched off here
    assert bench.served.call(lambda: sim.drives[1].telemetry().supply_v) == sim.profile.supply.voltage_v


async def test_condition_fields_take_the_control_api_range(bench: Bench) -> None:
    await bench.press("f3")
    screen = bench.app.get_screen_main()
    supply = screen.query_one("#cond-supply", NumberInput)
    assert (supply.low, supply.high) == (0.0, 2000.0)
    ambient = screen.query_one("#cond-ambient", NumberInput)
    assert (ambient.low, ambient.high) == (-50.0, 150.0)
    await bench.press("home", "ctrl+k", "5", "0", "0", "0", "enter")
    assert bench.served.call(lambda: bench.served.sim.drives[1].telemetry().supply_v) == 48.0  # refused, as the API
    errors = [str(n.message) for n in bench.app._notifications if n.severity == "error"]
    assert any("supply_v: 5000 is outside 0-2000" in e for e in errors)


async def test_closing_an_attached_dashboard_leaves_the_server_serving() -> None:
    with serving() as served:
        async with attached(served) as (app, pilot):
            await pilot.press("f4", "u")  # act: undervoltage, through the API
            supply = lambda: served.call(lambda: served.sim.drives[1].telemetry().supply_v)  # noqa: E731
            await until(lambda: supply() == 10.0, "the undervoltage to reach the server")
            await pilot.press("q")
        assert not app.is_running
        client = AsyncModbusTcpClient("127.0.0.1", port=served.port, framer=FramerType.RTU, timeout=0.5, retries=0)
        assert await client.connect()
        try:
            response = await client.read_holding_registers(0x3007, count=1, device_id=1)  # 3007H: the supply
            assert not response.isError(), response
            assert served.call(lambda: served.sim.drives[1].telemetry().supply_v) == 10.0
            async with attached(served) as (again, _):  # and another dashboard attaches to it
                assert again.bench.conditions(1).supply_v == 10.0
        finally:
            client.close()


async def test_a_server_gone_is_said_and_keys_answer_with_an_error_until_it_is_back() -> None:
    with serving() as served:
        async with attached(served) as (app, pilot):
            port = int(served.url.rsplit(":", 1)[1])
            served.thread.run(served.server.aclose())
            await until(lambda: not app.streaming, "the dashboard to see the server gone")
            assert "server lost" in str(app.get_screen_main().query_one("#title").render())
            await pilot.press("f")  # a key while the server is gone: an error notification, no traceback
            await pilot.pause()
            errors = [str(n.message) for n in app._notifications if n.severity == "error"]
            assert any("lost the server" in e for e in errors), errors
            assert any("does not answer" in e for e in errors), errors
            assert app.is_running
            # the server back on the same address: the dashboard attaches again by itself
            served.server = Server(served.sim, ServeOptions(control=f"127.0.0.1:{port}"))
            served.thread.run(served.server.start())
            before = app.received
            await until(lambda: app.streaming and app.received > before, "the dashboard to attach again")
            assert "server lost" not in str(app.get_screen_main().query_one("#title").render())


async def test_register_view_edits_by_a_masters_rules(bench: Bench) -> None:
    """F6: every register, live; Enter edits one as a master would, and a refusal names its exception code."""
    await bench.press("f6")
    screen = bench.app.get_screen_main()
    table = screen.query_one("#reg-table", DataTable)
    assert table.has_focus
    assert str(table.get_cell("2100H", "value")) == "stopped"
    assert str(table.get_cell("2002H", "name")) == "motor pole pairs (= F02.00)"
    await bench.press("down", "down", "down", "enter")  # 2001H: the communication speed setting
    editor = screen.query_one("#reg-edit", Input)
    await until(lambda: editor.has_focus and editor.value == "0", "the editor of 2001H, focused")
    await bench.press("ctrl+u", *"1500", "enter")
    assert await bench.read(0x2001) == 1500
    await bench.write(0x2000, 1)
    await bench.press("t")
    assert str(table.get_cell("2002H", "access")) == "W/R* lock"  # pole pairs, while running
    table.move_cursor(row=table.get_row_index("2002H"))
    await bench.press("enter")
    await until(lambda: editor.has_focus and editor.value == "4", "the editor of 2002H, focused")
    await bench.press("ctrl+u", "8", "enter")
    errors = [str(n.message) for n in bench.app._notifications if n.severity == "error"]
    assert errors[-1] == (
        "drive 1: 2002H = 8 refused: exception 0x08 (parameter cannot be changed while running), "
        "as a master would get it"
    )
    assert await bench.read(0x2002) == 4
    bench.app.refresh_views()
    await bench.pilot.pause()
    counters = str(screen.query_one("#reg-counters", Static).render())
    assert counters.startswith("requests 3 · replies 3 · exceptions 0 · CRC 0")


async def test_speed_source_and_keypad_speed_from_the_panel(bench: Bench) -> None:
    await bench.press("m")  # run channel: keypad
    await bench.press("S", "S", "S")  # speed source: Modbus -> multi-speed -> dial switch -> simple PLC
    assert await bench.read(0x0002) == 6  # the simple PLC runs its F10 programme (issue 42)
    await bench.press("S", "S")  # keypad -> AI1
    assert await bench.read(0x0002) == 1
    await bench.press("S", "S", "S", "S", "S", "S")  # AI2, Modbus, multi-speed, dial switch, simple PLC, keypad
    assert await bench.read(0x0002) == 0
    await bench.press("minus", "minus")  # keypad reference 50.00 Hz -> 48.00 Hz
    assert await bench.read(0x000A) == 4800
    assert "keypad · speed from keypad" in bench.screen_text()


async def test_telemetry_left_when_the_screens_are_gone_is_dropped() -> None:
    """q while the stream delivers: a telemetry message handled after the last screen went is dropped, not a
    traceback on the way out (seen in a loaded run: ScreenStackError from the message queue)."""
    with serving() as served:
        async with attached(served) as (app, pilot):
            await pilot.pause()
        assert not app.screen_stack
        app.on_telemetry_updated(TelemetryUpdated(app.bench.sample()))
        assert app.views  # taken; nothing shown, nothing raised


async def test_register_view_finds_a_register_by_any_name_of_the_vocabulary(bench: Bench) -> None:
    """F6, then /: a register by the name ctl, exercise and scenarios take; a misspelt one gets a did-you-mean."""
    await bench.press("f6")
    screen = bench.app.get_screen_main()
    table = screen.query_one("#reg-table", DataTable)
    finder = screen.query_one("#reg-find", Input)
    for name, register in (("speed", "3006H"), ("motor speed", "3006H"), ("8193", "2001H"), ("F00.10", "F00.10")):
        await bench.press("slash")
        await until(lambda: finder.has_focus, "the finder, focused")
        await bench.press(*["space" if c == " " else c for c in name], "enter")
        await until(lambda: table.has_focus, "the table, focused again")
        row = table.get_row_at(table.cursor_row)
        assert str(row[0]) == register, name
    await bench.press("slash")
    await until(lambda: finder.has_focus, "the finder, focused")
    await bench.press(*"sped", "enter")
    errors = [str(n.message) for n in bench.app._notifications if n.severity == "error"]
    assert errors[-1] == (
        "unknown register 'sped'; did you mean 'speed'? (give a name such as speed or status, an address such as "
        "3006H, 0x3006 or 12294, or a function code such as F00.10)"
    )
    assert str(table.get_row_at(table.cursor_row)[0]) == "F00.10"  # where it was
    await bench.press("escape")
    await until(lambda: table.has_focus, "the table, focused again")
    assert await bench.read(0x3006) == 0
    # the fault code's value in its name, as ctl and the frame log say it
    assert str(table.get_cell("2102H", "value")) == "no fault"


async def test_a_digit_holds_a_fault_on_and_a_masters_reset_clears_it_once_released(bench: Bench) -> None:
    """F4: the screen says what a digit does, and a master's 2000H = 7 (over the wire) does what the screen says."""
    await bench.press("f4")
    hint = str(bench.app.get_screen_main().query_one("#dev-hint", Static).render())
    assert hint == (  # two lines, each whole at 80 columns
        "Each key switches a cause on or off; a digit holds a fault on (no physics).\n"
        "RESET (x, or a master's 2000H = 7) clears a fault once its cause is off."
    )
    await bench.press("1")  # OUt1, held on
    assert await bench.read(FAULT) == 0x01
    await bench.write(0x2000, 7)  # a master's reset while the digit holds it on: the fault stays, as the hint says
    assert await bench.read(FAULT) == 0x01
    await bench.press("x")
    said = [str(n.message) for n in bench.app._notifications if n.severity == "warning"]
    assert said[-1] == "RESET refused: OUt1 (0x01) is held on by F4 key 1; press 1 to release it, then reset"
    await bench.press("1")  # released: the fault stays until a reset
    assert await bench.read(FAULT) == 0x01
    await bench.write(0x2000, 7)  # the master's reset now clears it
    assert await bench.read(FAULT) == 0
    await bench.press("e", "t")  # a letter: the external fault terminal, the drive trips by its model
    assert await bench.read(FAULT) == 0x11
    await bench.press("x")
    said = [str(n.message) for n in bench.app._notifications if n.severity == "warning"]
    assert said[-1] == "RESET refused: its cause, external, is still present; press e (F4) to end it"
    await bench.press("e", "t")
    await bench.write(0x2000, 7)
    assert await bench.read(FAULT) == 0
