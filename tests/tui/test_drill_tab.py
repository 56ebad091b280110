"""The dashboard's drill tab (F8): the incidents listed, one played on the master polling the serve with ``g``, its
verdict in the table; a virtual clock refused in words."""

from __future__ import annotations

import subprocess
import sys

import pytest
from textual.widgets import DataTable

from c20sim.core.clock import RealtimeClock
from c20sim.drill import INCIDENTS
from c20sim.tui.drill import DrillPanel
from tests.drill.conftest import RAW
from tests.tui.conftest import attached, serving, until

pytestmark = pytest.mark.serial  # the drill judges a master's real rhythm: .ci/run runs it alone


def _rows(panel: DrillPanel) -> list[list[str]]:
    table = panel.query_one(DataTable)
    return [[str(cell) for cell in table.get_row_at(i)] for i in range(table.row_count)]


async def test_g_plays_the_selected_incident_and_its_verdict_shows() -> None:
    with serving(clock=RealtimeClock()) as served:
        master = subprocess.Popen([sys.executable, str(RAW), "careful", "--tcp", f"127.0.0.1:{served.port}"])
        try:
            async with attached(served) as (app, pilot):
                await pilot.press("f8")
                panel = app.get_screen_main().query_one(DrillPanel)
                await until(lambda: len(_rows(panel)) == len(INCIDENTS), "the incidents listed")
                assert [row[0] for row in _rows(panel)] == list(INCIDENTS)
                assert _rows(panel)[1][2] == "-"
                await pilot.press("down", "g")  # the second row: no-reply
                await until(lambda: _rows(panel)[1][2] == "pass", "no-reply's verdict", timeout=60)
                assert _rows(panel)[1][3].startswith("retries: asked each of 3 failed requests again")
                state = str(panel.query_one("#drill-state").render())
                assert "drill done: 1 of 1 drills passed" in state
        finally:
            master.terminate()
            master.wait(5)


async def test_a_virtual_clock_is_refused_in_words() -> None:
    with serving() as served:
        async with attached(served) as (app, pilot):
            await pilot.press("f8", "g")
            await until(
                lambda: any("a drill needs the realtime clock" in str(n.message) for n in app._notifications),
                "the refusal",
            )
