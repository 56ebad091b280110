"""The dashboard's top line and footer as a new user meets them at 80 and at 120 columns (a tmux pane).

The title gives up parts in a chosen order as the width shrinks (docs/dashboard.md, "The title and the
footer"); the footer shows the keys of the clock there is, its second keys where there is room, and always
``q Quit``. F1 opens the help as ``?`` does.
"""

from __future__ import annotations

import pytest
from textual.widgets import Markdown

from c20sim.core.clock import Clock, RealtimeClock, VirtualClock
from c20sim.tui import Dashboard
from c20sim.tui.screens import HelpScreen
from c20sim.tui.status import clock_forms, title_line
from tests.tui.conftest import attached, serving, until
from tests.tui.test_first_hour import footer

THREE = "pty /dev/pts/12 · RTU/TCP 127.0.0.1:5020 · Modbus TCP 127.0.0.1:1502"
PAUSED = clock_forms(1234.5, False, 2.0, True)


def screen_line(app: Dashboard, row: int) -> str:
    """One row of the screen as drawn, its runs of spaces squeezed to one."""
    strips = app.screen._compositor.render_strips()
    return " ".join(strips[row].text.split())


@pytest.mark.parametrize(
    ("width", "lost", "shown"),
    [
        (140, False, f" c20sim  connect: {THREE} │ t 1234.5 s ×2 realtime paused │ c20-400hr"),
        (120, False, f" c20sim  {THREE} │ t 1234.5 s ×2 paused │ c20-400hr"),
        (100, False, f" c20sim  {THREE} │ t 1234.5 s ×2 paused"),
        (94, False, f" c20sim  {THREE} │ paused"),
        (86, False, f" c20sim  {THREE} │ paused"),
        (85, False, f" {THREE} │ paused"),
        (80, False, f" {THREE} │ paused"),
        (70, False, f" {THREE}…"),
        (100, True, f" c20sim  server lost  {THREE} │ paused"),
        (80, True, f" server lost  {THREE[:65]}…"),
    ],
)
def test_the_title_gives_up_parts_in_order_never_the_addresses_first(width: int, lost: bool, shown: str) -> None:
    text = title_line(width, THREE, PAUSED, "c20-400hr", lost)
    assert text.plain == shown
    assert text.cell_len <= width


def test_the_clock_in_three_lengths() -> None:
    assert clock_forms(12.34, False, 1.0, False) == ("t 12.3 s ×1 realtime", "t 12.3 s ×1", "realtime")
    assert clock_forms(12.34, False, 2.0, False) == ("t 12.3 s ×2 realtime", "t 12.3 s ×2", "×2")
    assert clock_forms(12.34, False, 0.5, True) == ("t 12.3 s ×0.5 realtime paused", "t 12.3 s ×0.5 paused", "paused")
    assert clock_forms(3.0, True) == ("t 3.0 s virtual", "t 3.0 s virtual", "virtual")


@pytest.mark.parametrize(
    ("clock", "width", "keys"),
    [
        (RealtimeClock(), 80, "p Pause"),
        (RealtimeClock(), 120, "p Pause < Slower > Faster"),
        (VirtualClock(), 80, "t +1s"),
        (VirtualClock(), 120, "t +1s T +10s"),
    ],
)
async def test_the_footer_shows_the_clocks_keys_and_keeps_quit(clock: Clock, width: int, keys: str) -> None:
    """On screen, the last row: the keypad, the clock's keys (its second ones from 100 columns), help and quit."""
    with serving(clock=clock, modbus_tcp=True) as served:
        async with attached(served, (width, 40 if width > 80 else 24)) as (app, pilot):
            await pilot.pause()
            assert screen_line(app, -1) == f"f Fwd r Rev s Stop j Jog x Reset {keys} ? Help q Quit ▏^p palette"
            title = screen_line(app, 0)
            where = f"RTU/TCP 127.0.0.1:{served.port} · Modbus TCP {served.server.endpoints.modbus_tcp.name}"  # type: ignore[union-attr]
            if width == 120:  # every part whole
                assert title.startswith(f"c20sim connect: {where} │ t "), title
                assert title.endswith(" │ c20-400hr"), title
                assert ("realtime" if isinstance(clock, RealtimeClock) else "virtual") in title
            else:  # the addresses and the clock's state; the profile given up
                assert title.startswith(f"c20sim {where} │ "), title
                assert "c20-400hr" not in title


async def test_the_clocks_second_keys_leave_the_footer_when_narrowed_and_still_work() -> None:
    with serving(clock=RealtimeClock()) as served:
        async with attached(served, (120, 40)) as (app, pilot):
            assert {"less_than_sign", "greater_than_sign"} <= set(footer(app))
            await pilot.resize_terminal(80, 24)
            await until(lambda: "less_than_sign" not in footer(app), "< gone from the footer")
            assert "greater_than_sign" not in footer(app) and footer(app)["p"] == "Pause"
            assert screen_line(app, -1).endswith("q Quit ▏^p palette")
            await pilot.press("greater_than_sign")
            await until(lambda: app.remote.latest.get("speed") == 2.0, "the clock at x2, from > at 80 columns")
            await pilot.press("less_than_sign", "less_than_sign")
            await until(lambda: app.remote.latest.get("speed") == 0.5, "the clock at x0.5")
            await pilot.resize_terminal(120, 40)
            await until(lambda: "less_than_sign" in footer(app), "< back in the footer")


async def test_the_title_on_screen_says_server_lost_first_at_80_columns() -> None:
    with serving(clock=RealtimeClock(), modbus_tcp=True) as served:
        async with attached(served, (80, 24)) as (app, pilot):
            app.streaming = False  # as the stream's reader says when the server goes
            app._show_title(app.get_screen_main())
            await pilot.pause()
            assert screen_line(app, 0).startswith(f"server lost RTU/TCP 127.0.0.1:{served.port} · "), screen_line(
                app, 0
            )


@pytest.mark.parametrize("key", ["f1", "question_mark"])
async def test_f1_and_question_mark_open_the_help_and_close_it(key: str) -> None:
    with serving() as served:
        async with attached(served) as (app, pilot):
            await pilot.press(key)
            await until(lambda: isinstance(app.screen, HelpScreen), "the help")
            assert "`?`, `F1`" in app.screen.query_one(Markdown).source
            await pilot.press(key)
            await until(lambda: not isinstance(app.screen, HelpScreen), "the help closed")


async def test_every_endpoint_the_server_has_is_in_the_title_a_new_transport_by_its_key() -> None:
    with serving(modbus_tcp=True) as served:
        async with attached(served) as (app, _pilot):
            where = dict(app.remote.endpoints)
            assert list(where) == ["tcp", "modbus_tcp"]
            assert app.connect_text() == f"RTU/TCP {where['tcp']} · Modbus TCP {where['modbus_tcp']}"
            app.remote.endpoints = {"pty": "/dev/pts/9", **where, "loop_tcp": "127.0.0.1:9"}  # as a new row's server
            assert app.connect_text() == (
                f"pty /dev/pts/9 · RTU/TCP {where['tcp']} · Modbus TCP {where['modbus_tcp']} · loop_tcp 127.0.0.1:9"
            )
