"""The drill view (F8): the incidents, the drill's state, and each incident's last verdict.

The served simulator's drill (``GET /drill``, docs/drill.md), read through the
:class:`~c20sim.tui.workbench.Workbench` as the other panels: a line with the
drill's state (idle, running and what it plays now, done, failed), then one row
an incident (its group, what c20sim does, its last verdict and figure). Keys:
``g`` plays the selected incident on the master polling the serve, ``A`` the
standard plan, ``C`` stops the running drill.
"""

from __future__ import annotations

import time
from typing import Any, ClassVar

from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import Vertical
from textual.widgets import DataTable, Static

from ..control.ops import ControlError
from ..drill import INCIDENTS
from .workbench import Workbench

__all__ = ["DrillPanel"]

COLUMNS = ("incident", "group", "verdict", "what c20sim does / the figure")
#: The most times a second the panel asks the server for the drill's state.
REFRESH_HZ = 2.0


class DrillPanel(Vertical, can_focus=False):
    """The incidents and the drill's verdicts; keys start and stop a drill."""

    DEFAULT_CSS = """
    DrillPanel { height: 1fr; }
    DrillPanel #drill-state { height: 1; }
    DrillPanel DataTable { height: 1fr; }
    """
    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("g", "play", "Play incident"),
        Binding("A", "play_all", "Standard plan"),
        Binding("C", "stop", "Stop drill"),
    ]

    def __init__(self, bench: Workbench, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.bench = bench
        self._asked = 0.0
        self._shown: list[tuple[str, ...]] = []

    def compose(self) -> ComposeResult:
        yield Static(id="drill-state")
        table: DataTable[Text | str] = DataTable(id="drill-table", cursor_type="row", zebra_stripes=True)
        table.add_columns(*COLUMNS)
        yield table

    def show(self, *, now: bool = False) -> None:
        clock = time.monotonic()
        if not now and clock - self._asked < 1.0 / REFRESH_HZ:
            return
        self._asked = clock
        state = self.bench.drill()
        line = self.query_one("#drill-state", Static)
        if state is None:
            line.update(Text("no drill here (a drill needs c20sim serve with the realtime clock)", style="dim"))
            state = {"state": "idle", "report": None}
        else:
            line.update(self._state(state))
        verdicts: dict[str, dict[str, Any]] = {}
        report = state.get("report") or {}
        for verdict in report.get("verdicts", []):
            verdicts[verdict["incident"]] = verdict  # the last played of each incident
        rows = [self._cells(name, verdicts.get(name)) for name in INCIDENTS]
        if rows == self._shown:
            return
        self._shown = rows
        table = self.query_one(DataTable)
        row = table.cursor_row
        table.clear()
        for cells in rows:
            verdict = cells[2]
            style = "green" if verdict == "pass" else "bold red" if verdict == "FAIL" else "dim"
            table.add_row(cells[0], cells[1], Text(verdict, style=style), cells[3])
        table.move_cursor(row=min(max(row, 0), len(rows) - 1))

    @staticmethod
    def _state(state: dict[str, Any]) -> Text:
        name = state["state"]
        text = Text(f"drill {name}", style="bold")
        if name == "running":
            text.append(f": {state.get('progress') or ''} ({state.get('running_s') or 0:.0f} s)")
        elif name == "failed":
            text.append(f": {state.get('error')}", style="red")
        elif name == "done" and state.get("report"):
            report = state["report"]
            passed = sum(v["passed"] for v in report["verdicts"])
            text.append(
                f": {passed} of {len(report['verdicts'])} drills passed", style="green" if report["passed"] else "red"
            )
        else:
            text.append(": g plays the selected incident on the master polling the serve, A the standard plan")
        return text

    @staticmethod
    def _cells(name: str, verdict: dict[str, Any] | None) -> tuple[str, ...]:
        incident = INCIDENTS[name]
        if verdict is None:
            return (name, incident.group, "-", incident.does)
        failed = [c for c in verdict["checks"] if not c["passed"]]
        figure = "; ".join(f"{c['check']}: {c['figure']}" for c in (failed or verdict["checks"][:1]))
        return (name, incident.group, "pass" if verdict["passed"] else "FAIL", figure)

    def _start(self, plan: list[str] | None) -> None:
        try:
            self.bench.start_drill(plan)
        except ControlError as exc:
            self.notify(str(exc), severity="error", timeout=5)
            return
        self.notify(f"drill started: {', '.join(plan) if plan else 'the standard plan'}", timeout=3)
        self.show(now=True)

    def action_play(self) -> None:
        table = self.query_one(DataTable)
        names = list(INCIDENTS)
        if 0 <= table.cursor_row < len(names):
            self._start([names[table.cursor_row]])

    def action_play_all(self) -> None:
        self._start(None)

    def action_stop(self) -> None:
        try:
            self.bench.stop_drill()
        except ControlError as exc:
            self.notify(str(exc), severity="error", timeout=5)
            return
        self.notify("drill stopping", timeout=3)
        self.show(now=True)
