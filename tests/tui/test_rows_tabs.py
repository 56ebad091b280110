"""A dashboard tab is one row (:mod:`c20sim.tui.tabs`): a throwaway row, added here and nowhere else, reaches the
tab bar, its key, the panel refresh and drive selection, the help screen, the key list, the command palette and the
docs check.

The docs check lives here too: docs/dashboard.md's "Views" table names every tab row, key and title."""

from __future__ import annotations

import re
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import pytest
from textual.reactive import reactive
from textual.widgets import Markdown, Static, TabbedContent

from c20sim.tui.screens import HelpScreen, help_text
from c20sim.tui.tabs import Tab, tabs
from c20sim.tui.workbench import Workbench
from tests.tui.conftest import attached, serving, until

DOCS = Path(__file__).resolve().parents[2] / "docs" / "dashboard.md"


def undocumented(rows: Iterable[Tab], text: str) -> list[str]:
    """The tab rows docs/dashboard.md's "Views" table does not name (``| `F2` | Frames |``), as ``F2 Frames``."""
    views = text[text.index("\n## Views\n") :]
    views = views[: views.index("\n## ", 1)]
    lines = set(re.findall(r"^\| `(F\d+)` \| ([^|]+?) \|", views, flags=re.M))
    return [f"{row.key.upper()} {row.title}" for row in rows if (row.key.upper(), row.title) not in lines]


def test_the_docs_name_every_tab() -> None:
    assert [f"{row.key.upper()} {row.title}" for row in tabs()] == [
        "F2 Frames",
        "F3 Conditions",
        "F4 Device faults",
        "F5 Link faults",
        "F6 Registers",
        "F7 Audit",
        "F8 Drill",
    ]
    assert undocumented(tabs(), DOCS.read_text()) == []


class Scratch(Static, can_focus=True):
    """The throwaway tab's panel: it counts its refreshes and keeps the drive pushed to it."""

    selected = reactive(0)

    def __init__(self, bench: Workbench, id: str | None = None) -> None:
        super().__init__(f"scratch of {len(bench.addresses)} drives", id=id)
        self.refreshed: list[int] = []


def _refresh(panel: Any, address: int) -> None:
    panel.refreshed.append(address)


SCRATCH = Tab(
    "scratch",
    "f9",
    "Scratch",
    Scratch,
    "scratch-panel",
    "scratch: a throwaway row of the tests",
    refresh=_refresh,
    follows_drive=True,
)


@pytest.fixture
def scratch() -> Iterator[Tab]:
    tabs().add(SCRATCH)
    try:
        yield SCRATCH
    finally:
        tabs().remove(SCRATCH.id)


async def test_a_new_tab_row_reaches_every_front_end(scratch: Tab) -> None:
    assert [row.id for row in tabs()][-1] == "scratch"
    with serving((1, 2), tcp=False) as served:
        async with attached(served) as (app, pilot):
            screen = app.get_screen_main()
            tabbed = screen.query_one(TabbedContent)
            assert tabbed.get_tab("scratch").label.plain == "Scratch F9"  # the tab bar
            assert tabbed.active == "frames"
            panel = screen.query_one("#scratch-panel", Scratch)
            assert str(panel.render()) == "scratch of 2 drives"  # made by the row's factory from the bench
            assert panel.refreshed == []  # not on show: not kept up to date

            await pilot.press("f9")  # its key
            assert tabbed.active == "scratch"
            assert app.focused is panel
            await until(lambda: panel.refreshed[-1:] == [1], "the tab refreshed with drive 1")

            await pilot.press("right_square_bracket")  # the next drive is pushed down to it
            await until(lambda: panel.selected == 2, "drive 2 pushed to the panel")
            app.refresh_views()
            await until(lambda: panel.refreshed[-1:] == [2], "the tab refreshed with drive 2")

            binding = app.active_bindings["f9"].binding  # the key list (the palette's "Keys") names it
            assert (binding.action, binding.description, binding.show) == ("tab('scratch')", "Scratch", False)

            await pilot.press("question_mark")  # the help screen
            assert isinstance(app.screen, HelpScreen)
            shown = app.screen.query_one(Markdown).source
            assert "| `F8` | drill: " in shown
            assert "| `F9` | scratch: a throwaway row of the tests |\n| `[` / `]` |" in shown
            await pilot.press("escape")

            await pilot.press("f2")  # and back
            assert tabbed.active == "frames"

            commands = {c.title: c for c in app.get_system_commands(app.screen)}  # the command palette
            assert commands["View: Scratch (F9)"].help == "scratch"
            assert commands["View: Frames (F2)"].help == "frame log"
            commands["View: Scratch (F9)"].callback()
            assert tabbed.active == "scratch"
    assert help_text().count("`F9`") == 1
    assert undocumented(tabs(), DOCS.read_text()) == ["F9 Scratch"]  # the docs check sees the row, undocumented


def test_the_row_goes_as_it_came(scratch: Tab) -> None:
    tabs().remove(scratch.id)
    try:
        assert "`F9`" not in help_text()
        assert undocumented(tabs(), DOCS.read_text()) == []
        with pytest.raises(ValueError, match=r"tab drill \(f8\): declared twice"):
            tabs().add(tabs()["drill"])
    finally:
        tabs().add(scratch)  # for the fixture to take away
