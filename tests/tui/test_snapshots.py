"""Snapshots of the main screen and the frame log: virtual clock, no Modbus endpoint, so every run draws the same.

The dashboard attaches to a simulator served on a background thread (only its control API listens).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest
from textual.pilot import Pilot
from textual.widgets import RichLog

from c20sim.control import httpstream
from c20sim.tui import Dashboard, widgets
from c20sim.tui.widgets import FrameLog
from c20sim.wire.framing import RtuFramer
from c20sim.wire.registers import Reg
from tests.tui.conftest import Served, serving, until


@pytest.fixture
def served() -> Iterator[Served]:
    with serving(tcp=False) as s:
        yield s


@pytest.fixture
def served2() -> Iterator[Served]:
    with serving((1, 2), tcp=False) as s:
        yield s


async def attached(pilot: Pilot[Any]) -> Dashboard:
    app = pilot.app
    assert isinstance(app, Dashboard)
    await until(lambda: app.streaming and app.received > 0, "the dashboard's stream")
    return app


def send(served: Served, *frames: str) -> None:
    """Frames from a master, straight onto the bus at the virtual clock's time (on the server's thread)."""

    def feed() -> None:
        sim = served.sim
        framer = RtuFramer(19200)
        for frame in frames:
            sim.advance(0.05)
            t = sim.now()
            framer.feed(bytes.fromhex(frame), t)
            framer.tick(t + 0.01)
            for event in framer.events():
                sim.handle(event)

    served.call(feed)


def runner_at_1500(served: Served) -> Any:
    async def run_before(pilot: Pilot[Any]) -> None:
        app = await attached(pilot)

        def start() -> None:
            drive = served.sim.drive(1)
            drive.write(Reg.SPEED_SETPOINT, 1500)
            drive.write(Reg.COMMAND, 1)

        served.call(start)
        app.bench.set_load(1, 0.8)
        app.bench.advance(30.0)
        app.refresh_views()
        await pilot.pause()

    return run_before


def test_main_screen_running(snap_compare: Any, served: Served) -> None:
    assert snap_compare(Dashboard(served.remote()), terminal_size=(80, 24), run_before=runner_at_1500(served))


def test_frame_log(snap_compare: Any, served2: Served, monkeypatch: pytest.MonkeyPatch) -> None:
    # frames show the time of day: fixed here (the server's wall offset 0, so "wall" is the line's time)
    monkeypatch.setattr(httpstream, "WALL_OFFSET", 0.0)
    monkeypatch.setattr(widgets, "time_of_day", lambda wall: f"10:00:{wall:06.3f}")

    async def frames_with_errors(pilot: Pilot[Any]) -> None:
        app = await attached(pilot)
        send(
            served2,
            "01 06 20 01 0B B8 D4 88",  # set speed 3000 rpm
            "01 06 20 00 00 01 43 CA",  # forward run
            "01 03 21 00 00 01 8E 36",  # status word 1
            "01 03 00 32 00 01 25 C5",  # F00.50: exception 0x02
            "01 03 21 00 00 01 8E 37",  # bad CRC: exception 0x06
            "02 03 21 00 00 01 8E 05",  # drive 2
        )
        app.bench.toggle_link_fault(1, "c")  # the reply's CRC corrupted, through the API
        send(served2, "01 03 21 02 00 01 2F F6")  # fault code
        log = app.get_screen_main().query_one(FrameLog)
        await until(lambda: len(log.records) >= 14, "14 frames in the log")
        assert len(log.records) == 14, [r.text for r in log.records]
        await until(lambda: app.remote.now() >= 0.35, "the telemetry after the frames")
        app.refresh_views()
        await pilot.pause()
        # the log scrolls to its last line when it next lays out, which a loaded machine puts off past a pause (and
        # a wait for it timed out once under load): the picture is of the log at its end, so it is put there
        lines = log.query_one(RichLog)
        await pilot.pause()
        lines.scroll_end(animate=False, immediate=True)
        await pilot.pause()

    assert snap_compare(Dashboard(served2.remote()), terminal_size=(100, 30), run_before=frames_with_errors)


def test_device_faults_panel_after_undervoltage(snap_compare: Any, served: Served) -> None:
    running = runner_at_1500(served)

    async def undervoltage_tripped(pilot: Pilot[Any]) -> None:
        await running(pilot)
        app = await attached(pilot)
        app.bench.toggle_device_fault(1, "u")
        app.bench.advance(1.0)
        await pilot.press("f4")
        app.refresh_views()
        await pilot.pause()

    assert snap_compare(Dashboard(served.remote()), terminal_size=(80, 24), run_before=undervoltage_tripped)


def test_register_view(snap_compare: Any, served: Served) -> None:
    running = runner_at_1500(served)

    async def registers_while_running(pilot: Pilot[Any]) -> None:
        await running(pilot)
        await pilot.press("f6")
        pilot.app.refresh_views()  # type: ignore[attr-defined]
        await pilot.pause()

    assert snap_compare(Dashboard(served.remote()), terminal_size=(80, 24), run_before=registers_while_running)


def test_audit_view(snap_compare: Any, served: Served) -> None:
    """F7: a master polling 20 times a second, reading an absent register every cycle, talking after a broadcast."""

    async def audited(pilot: Pilot[Any]) -> None:
        app = await attached(pilot)
        send(served, *["01 03 21 00 00 01 8E 36"] * 30)  # status word 1, every 50 ms: 27 % of the line
        send(served, *["01 03 00 32 00 01 25 C5"] * 3)  # F00.50: absent, refused 0x02 each time
        send(served, "00 06 20 01 05 DC D0 D2", "01 03 21 00 00 01 8E 36")  # a broadcast, then 50 ms later a read
        await pilot.press("f7")
        app.refresh_views()
        await pilot.pause()

    assert snap_compare(Dashboard(served.remote()), terminal_size=(100, 24), run_before=audited)
