"""Keys that arrive in one burst (a paste, ``tmux send-keys F6 / speed Enter``): each reaches the widget the key
before it focused.

Textual's pilot waits for the app to be idle after each key, so it never sends a burst; :func:`burst` does what
the terminal driver does with one read of several keys: it posts their events back to back, none handled yet.
Before the tab keys, ``/`` and Enter were taken at once (priority bindings) and the focus moved at once
(``screen.set_focus``, not ``Widget.focus``, which waits for the queue), the keys behind them were passed on to
the widget they were leaving: ``s`` of ``speed`` stopped the drive, the finder stayed empty.
"""

from __future__ import annotations

from textual import events
from textual.widgets import DataTable, Input, TabbedContent

from c20sim.tui import Dashboard
from tests.tui.conftest import Bench, until

#: the characters of the keys that have one (Textual's key names otherwise)
CHARACTERS = {"slash": "/", "enter": "\r", "space": " ", "ctrl+u": "\x15", "home": None, "down": None}


def burst(app: Dashboard, *keys: str) -> None:
    """Post every key's event at once, as the driver does for the keys of one read from the terminal."""
    assert app._driver is not None
    for key in keys:
        event = events.Key(key, CHARACTERS.get(key, key if len(key) == 1 else None))
        event.set_sender(app)
        app._driver.send_message(event)


def typed(text: str) -> list[str]:
    return ["space" if c == " " else c for c in text]


def errors(app: Dashboard) -> list[str]:
    return [str(n.message) for n in app._notifications if n.severity == "error"]


async def test_f6_slash_and_a_name_typed_at_once_find_the_register(bench: Bench) -> None:
    app = bench.app
    screen = app.get_screen_main()
    table = screen.query_one("#reg-table", DataTable)
    burst(app, "f6", "slash", *typed("motor speed"), "enter")
    await until(lambda: table.row_count > 0 and str(table.get_row_at(table.cursor_row)[0]) == "3006H", "3006H")
    await until(lambda: table.has_focus, "the table focused again")
    assert screen.query_one(TabbedContent).active == "registers"
    assert screen.query_one("#reg-find", Input).value == "motor speed"
    assert errors(app) == []
    assert [str(n.message) for n in app._notifications] == []  # no key went to the dashboard (s: Stop, p, e, d...)


async def test_f3_and_a_supply_typed_at_once_set_the_supply(bench: Bench) -> None:
    """The F3 edit that ended blank: the field was filled with the drive's value after the keys typed into it."""
    app = bench.app
    screen = app.get_screen_main()
    supply = screen.query_one("#cond-supply", Input)
    burst(app, "f3", "home", "ctrl+k", *"36", "enter")
    await until(lambda: app.bench.conditions(1).supply_v == 36.0, "the supply at 36 V")
    assert screen.query_one(TabbedContent).active == "conditions"
    assert supply.has_focus and supply.value == "36"
    assert errors(app) == []


async def test_an_edit_typed_at_once_writes_the_value(bench: Bench) -> None:
    """F6, the cursor down to 2001H, Enter, the value, Enter, F8: one burst, written as a master would."""
    app = bench.app
    screen = app.get_screen_main()
    editor = screen.query_one("#reg-edit", Input)
    burst(app, "f6", "down", "down", "down", "enter", "ctrl+u", *"1500", "enter", "f8")
    await until(lambda: screen.query_one(TabbedContent).active == "drill", "the drill tab")
    assert await bench.read(0x2001) == 1500
    assert editor.value == "1500" and not editor.has_focus
    assert screen.query_one("#drill-table", DataTable).has_focus
    assert errors(app) == []


async def test_f3_a_supply_and_f8_typed_at_once_set_the_supply_and_end_on_the_drill(bench: Bench) -> None:
    """The user's F3 edit that ended on the F8 tab with the field blank."""
    app = bench.app
    screen = app.get_screen_main()
    burst(app, "f3", "home", "ctrl+k", *"36", "enter", "f8")
    await until(lambda: screen.query_one(TabbedContent).active == "drill", "the drill tab")
    await until(lambda: app.bench.conditions(1).supply_v == 36.0, "the supply at 36 V")
    assert screen.query_one("#cond-supply", Input).value == "36"
    assert screen.query_one("#drill-table", DataTable).has_focus
    assert errors(app) == []


async def test_a_tab_key_does_not_switch_the_tab_behind_the_help(bench: Bench) -> None:
    app = bench.app
    await bench.press("question_mark")
    await bench.press("f6")
    assert app.get_screen_main().query_one(TabbedContent).active == "frames"
    await bench.press("escape", "f6")
    assert app.get_screen_main().query_one(TabbedContent).active == "registers"
