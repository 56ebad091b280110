"""Snapshots of the main screen and the frame log: virtual clock, no endpoint, so every run draws the same."""

from __future__ import annotations

from typing import Any

import pytest
from textual.pilot import Pilot

from c20sim.clock import VirtualClock
from c20sim.profile import load_profile
from c20sim.protocol import RtuFramer
from c20sim.registers import Reg
from c20sim.simulator import Simulator
from c20sim.tui import Dashboard, widgets


def dashboard(drives: tuple[int, ...] = (1,)) -> Dashboard:
    return Dashboard(Simulator(load_profile(), drives, clock=VirtualClock(), seed=1))


def send(app: Dashboard, *frames: str) -> None:
    """Frames from a master, straight onto the bus at the virtual clock's time."""
    framer = RtuFramer(19200)
    for frame in frames:
        app.sim.advance(0.05)
        t = app.sim.now()
        framer.feed(bytes.fromhex(frame), t)
        framer.tick(t + 0.01)
        for event in framer.events():
            app.sim.handle(event)


async def running_at_1500(pilot: Pilot[Any]) -> None:
    app = pilot.app
    assert isinstance(app, Dashboard)
    drive = app.bench.sim.drive(1)
    drive.write(Reg.SPEED_SETPOINT, 1500)
    drive.write(Reg.COMMAND, 1)
    app.bench.set_load(1, 0.8)
    app.bench.advance(30.0)
    app.refresh_views()
    await pilot.pause()


def test_main_screen_running(snap_compare: Any) -> None:
    assert snap_compare(dashboard(), terminal_size=(80, 24), run_before=running_at_1500)


async def frames_with_errors(pilot: Pilot[Any]) -> None:
    app = pilot.app
    assert isinstance(app, Dashboard)
    send(
        app,
        "01 06 20 01 0B B8 D4 88",  # set speed 3000 rpm
        "01 06 20 00 00 01 43 CA",  # forward run
        "01 03 21 00 00 01 8E 36",  # status word 1
        "01 03 00 32 00 01 25 C5",  # F00.50: exception 0x02
        "01 03 21 00 00 01 8E 37",  # bad CRC: exception 0x06
        "02 03 21 00 00 01 8E 05",  # drive 2
    )
    app.sim.link_faults(1).corrupt_crc = True
    send(app, "01 03 21 02 00 01 2F F6")  # fault code, reply CRC corrupted
    app.refresh_views()
    await pilot.pause()


def test_frame_log(snap_compare: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    # frames show the time of day: fixed here, so every run draws the same
    monkeypatch.setattr(widgets, "time_of_day", lambda line_t: f"10:00:{line_t:06.3f}")
    assert snap_compare(dashboard((1, 2)), terminal_size=(100, 30), run_before=frames_with_errors)


async def undervoltage_tripped(pilot: Pilot[Any]) -> None:
    app = pilot.app
    assert isinstance(app, Dashboard)
    await running_at_1500(pilot)
    app.bench.toggle_device_fault(1, "u")
    app.bench.advance(1.0)
    await pilot.press("f4")
    app.refresh_views()
    await pilot.pause()


def test_device_faults_panel_after_undervoltage(snap_compare: Any) -> None:
    assert snap_compare(dashboard(), terminal_size=(80, 24), run_before=undervoltage_tripped)


async def registers_while_running(pilot: Pilot[Any]) -> None:
    await running_at_1500(pilot)
    await pilot.press("f6")
    pilot.app.refresh_views()  # type: ignore[attr-defined]
    await pilot.pause()


def test_register_view(snap_compare: Any) -> None:
    assert snap_compare(dashboard(), terminal_size=(80, 24), run_before=registers_while_running)
