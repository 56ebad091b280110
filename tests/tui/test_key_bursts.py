"""Keys that arrive in one burst (a paste, ``tmux send-keys F6 / speed Enter``): each reaches the widget the key
before it focused.

Textual's pilot waits for the app to be idle after each key, so it never sends a burst; :func:`burst` does what
the terminal driver does with one read of several keys: it posts their events back to back, none handled yet.
Before the tab keys, ``/`` and Enter were taken at once (priority bindings) and the focus moved at once
(``screen.set_focus``, not ``Widget.focus``, which waits for the queue), the keys behind them were passed on to
the widget they were leaving: ``s`` of ``speed`` stopped the drive, the finder stayed empty.
"""

from __future__ import annotations

import asyncio

import pytest
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
    written = "drive 1: 2001H = 1500"  # said once the write is done (it may land just after F8 took the focus)
    await until(lambda: written in [str(n.message) for n in app._notifications], written)
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


async def test_keys_held_are_bounded_and_go_on_in_order(bench: Bench, monkeypatch: pytest.MonkeyPatch) -> None:
    """While a key is on its way the next ones wait, at most KEY_BACKLOG of them; the rest are dropped, said once."""
    from c20sim.tui import keys

    monkeypatch.setattr(keys, "KEY_BACKLOG", 3)
    app = bench.app
    t0 = bench.served.sim.now()
    app._on_way = events.Key("f13", None)  # a key still on its way (never seen back: released by hand below)
    burst(app, *"ttttt")
    await until(lambda: app.keys_dropped == 2, "two keys dropped")
    assert len(app._held) == 3
    said = [str(n.message) for n in app._notifications if n.severity == "warning"]
    assert said == ["keys come faster than they are handled: dropped beyond 3"]
    assert bench.served.sim.now() == t0  # held: none has acted yet
    app._next()  # the key on its way is done: the held ones go on, in turn
    await until(lambda: bench.served.sim.now() == t0 + 3.0, "the virtual clock 3 s on (t three times)")
    await until(lambda: app._on_way is None and not app._held, "no key left waiting")


async def test_a_key_never_seen_back_holds_the_next_one_only_so_long(bench: Bench) -> None:
    """A key stopped or handled where KeysInTurn cannot see it: the next key goes on after KEY_TURN_S at most."""
    from c20sim.tui.keys import KEY_TURN_S

    app = bench.app
    t0 = bench.served.sim.now()
    stuck = events.Key("f13", None)
    app._on_way = stuck
    app._watch = asyncio.create_task(app._until_handled(stuck))  # as on_event starts it for a key passed on
    burst(app, "t")
    await until(lambda: len(app._held) == 1, "t held behind the stuck key")
    assert bench.served.sim.now() == t0
    await until(lambda: bench.served.sim.now() == t0 + 1.0, f"t handled once the stuck key's {KEY_TURN_S} s ran out")
    assert app._on_way is None and not app._held
