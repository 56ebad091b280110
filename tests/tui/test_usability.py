"""What a SCADA developer living in the dashboard needs: colours that read in every terminal, rows that never
wrap at 80x24, help that scrolls, fields that never change a value by themselves, the model's time in sight."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from rich.color import Color, ColorSystem
from rich.style import Style
from textual.widgets import Markdown, Static

from c20sim.tui import app as app_module
from c20sim.tui.app import HelpScreen
from c20sim.tui.status import STATUS_STYLES, DriveStatus
from tests.tui.conftest import Bench, attached, running, serving, until

#: Colour systems a terminal may have: 16 colours, 256, truecolor.
SYSTEMS = (ColorSystem.STANDARD, ColorSystem.EIGHT_BIT, ColorSystem.TRUECOLOR)
#: WCAG's minimum contrast for large or bold text.
MINIMUM = 3.0


def luminance(color: Color, system: ColorSystem) -> float:
    def channel(value: int) -> float:
        c = value / 255
        return c / 12.92 if c <= 0.03928 else ((c + 0.055) / 1.055) ** 2.4

    r, g, b = color.downgrade(system).get_truecolor()
    return 0.2126 * channel(r) + 0.7152 * channel(g) + 0.0722 * channel(b)


def contrast(fg: Color, bg: Color, system: ColorSystem) -> float:
    a, b = sorted((luminance(fg, system), luminance(bg, system)), reverse=True)
    return (a + 0.05) / (b + 0.05)


@pytest.mark.parametrize("system", SYSTEMS, ids=lambda s: s.name)
@pytest.mark.parametrize("status", sorted(STATUS_STYLES))
def test_each_state_reads_in_each_colour_system(status: int, system: ColorSystem) -> None:
    style = Style.parse(STATUS_STYLES[status])
    assert style.color is not None and style.bgcolor is not None
    ratio = contrast(style.color, style.bgcolor, system)
    assert ratio >= MINIMUM, f"status {status} ({STATUS_STYLES[status]}) in {system.name}: contrast {ratio:.2f}"


async def test_no_row_wraps_or_shares_the_states_background_at_80x24() -> None:
    """Faulted with the longest words (a fault name, status word 2 with its flags, the fault record's "at trip"
    line): twelve lines, one each."""
    async with running(size=(80, 24)) as bench:
        await bench.write(0x2001, 1500)
        await bench.write(0x2000, 1)
        await bench.press("t", "f4", "u", "t")
        assert await bench.read(0x2102) == 0x0A
        status = bench.app.get_screen_main().query_one(DriveStatus)
        lines = status.render().split("\n")
        assert [line.plain.split()[0] for line in lines[1:]] == [
            "channel", "speed", "freq", "current", "temp", "fault", "at", "status", "inputs", "outputs",
        ]  # fmt: skip
        width = status.content_size.width
        assert all(line.cell_len <= width for line in lines)
        fault_line = lines[6]
        styles = [(Style.parse(s.style) if isinstance(s.style, str) else s.style, s) for s in fault_line.spans]
        assert all(style.bgcolor is None for style, _ in styles), "the fault row must not take the state's background"
        panel_bg = Color.from_rgb(*status.styles.background.rgb)
        fault_fg = next(
            style.color for style, s in styles if "0x0A" in fault_line.plain[s.start : s.end] and style.color
        )
        assert fault_fg is not None
        for system in SYSTEMS:
            assert contrast(fault_fg, panel_bg, system) >= MINIMUM, system.name


async def test_help_scrolls_to_its_last_line() -> None:
    async with running(size=(80, 24)) as bench:
        await bench.press("question_mark")
        screen = bench.app.screen
        assert isinstance(screen, HelpScreen)
        box = screen.query_one("#help")
        assert box.max_scroll_y > 0  # longer than the box: it must scroll
        await bench.press("end")
        await until(lambda: box.scroll_y == box.max_scroll_y, "the help to scroll to its last line")
        assert screen.query_one(Markdown).region.bottom <= box.region.bottom + box.max_scroll_y


async def test_a_field_never_changes_a_value_by_itself(bench: Bench) -> None:
    """F3 focuses the supply field: it shows the supply, and Up steps from it (48 -> 49 V), never from 0."""
    await bench.press("f3")
    field = bench.app.get_screen_main().query_one("#cond-supply")
    assert field.has_focus and field.value == "48"  # type: ignore[attr-defined]
    await bench.press("up")
    assert bench.app.bench.conditions(1).supply_v == 49.0
    assert await bench.read(0x2100) == 3


async def test_the_models_time_and_clock_are_always_in_sight(bench: Bench) -> None:
    await bench.press("t", "T")
    title = str(bench.app.get_screen_main().query_one("#title", Static).render())
    assert "│ t 11.0 s virtual │" in title
    assert [str(n.message) for n in bench.app._notifications][-2:] == [
        "virtual time +1 s: t = 1.0 s",
        "virtual time +10 s: t = 11.0 s",
    ]


async def test_a_screenshot_with_no_downloads_folder_goes_to_the_current_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(app_module, "user_downloads_path", lambda: tmp_path / "no-such-Downloads")
    monkeypatch.chdir(tmp_path)
    async with running(size=(80, 24)) as bench:
        bench.app.action_screenshot()
        deadline = time.monotonic() + 10
        # done when the app says so (its file thread has finished): "Saved screenshot to '...'", or a failure
        while not any("screenshot" in str(n.message).lower() for n in bench.app._notifications):
            assert time.monotonic() < deadline, "no word of the screenshot"
            await bench.pilot.pause(0.05)
        said = [
            (n.severity, str(n.message)) for n in bench.app._notifications if "screenshot" in str(n.message).lower()
        ]
        assert said[0][0] != "error" and str(tmp_path) in said[0][1], said
    (shot,) = tmp_path.glob("*.svg")
    assert "FORWARD" in shot.read_text() or "STOPPED" in shot.read_text()


async def test_the_realtime_clock_is_paused_sped_up_and_reset_from_the_dashboard() -> None:
    from c20sim.core.clock import RealtimeClock

    with serving(clock=RealtimeClock()) as served:
        async with attached(served) as (app, pilot):
            await pilot.press("p")
            await until(lambda: app.remote.latest.get("paused") is True, "the clock paused")
            t = app.remote.now()
            await pilot.press("greater_than_sign", "greater_than_sign")
            await until(lambda: app.remote.latest.get("speed") == 4.0, "the clock at x4")
            assert app.remote.now() == t  # paused: the model stands still
            title = app.get_screen_main().query_one("#title", Static)
            await until(lambda: "×4 realtime paused" in str(title.render()), "the title to say so")
            await pilot.press("p")
            await until(lambda: app.remote.latest.get("paused") is False, "the clock running")
            await until(lambda: app.remote.now() > t, "the model's time moving again")
            app.bench.set_supply(1, 30.0)
            app.action_reset_setup()
            await pilot.pause()
            assert app.bench.conditions(1).supply_v == 48.0  # the profile's set-up again


async def test_the_frame_logs_losses_are_shown_in_the_dashboard() -> None:
    """--log-frames into a slow or full sink loses records, counted by its writer: the dashboard says how many."""
    from types import SimpleNamespace

    from c20sim.tui.widgets import FrameLog

    with serving() as served:
        async with attached(served) as (app, _):
            status = app.get_screen_main().query_one("#log-status", Static)
            assert "--log-frames lost" not in str(status.render())
            control = served.server.control
            assert control is not None
            served.call(lambda: setattr(control, "frame_log", SimpleNamespace(dropped=7)))
            await until(lambda: "--log-frames lost 7" in str(status.render()), "the loss in the status line")
            assert app.get_screen_main().query_one(FrameLog).log_dropped == 7
