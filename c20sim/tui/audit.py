"""The audit view (F7): what the masters would do wrong on a real line, and the line-demand gauge.

The served simulator's live audit (``GET /audit``, docs/audit.md), read
through the :class:`~c20sim.tui.workbench.Workbench` as the other panels: a
gauge of the line demand (now and at its peak, against the real RS485 line),
then one row a finding, worst first; the selected finding's advice and source
below. A server started with ``--no-audit`` says so.
"""

from __future__ import annotations

import time
from typing import Any

from rich.text import Text
from textual import on
from textual.app import ComposeResult
from textual.containers import Vertical
from textual.widgets import DataTable, Static

from ..audit import Limits
from .workbench import Workbench

__all__ = ["AuditPanel", "gauge_text"]

COLUMNS = ("severity", "rule", "where", "figure")
#: The most times a second the panel asks the server for the report.
REFRESH_HZ = 2.0
SEVERITY_STYLES = {"error": "bold red", "warning": "yellow", "note": "cyan"}
GAUGE_WIDTH = 30
#: the line demand (percent) the gauge turns red at: serve's audit calls it an error from there
_ERROR_AT = Limits().demand_error_at()


def gauge_text(demand: dict[str, Any]) -> Text:
    """``line  [██████░░░░]  27 % now, peak 31 % of 19200 8N1 (100 % full)``: green, yellow from 80 %, red beyond a
    full line (where the audit's line-demand is an error)."""
    now, peak = float(demand["now_percent"]), float(demand["peak_percent"])
    style = "green" if now < 80.0 else "yellow" if now < _ERROR_AT else "bold red"
    filled = min(GAUGE_WIDTH, round(GAUGE_WIDTH * now / 100.0))
    text = Text("line demand ", style="bold")
    text.append("█" * filled, style=style)
    text.append("░" * (GAUGE_WIDTH - filled), style="dim")
    text.append(f" {now:.0f} %", style=style)
    text.append(f"  peak {peak:.0f} % of {demand['baud']} {demand['format']}", style="")
    text.no_wrap = True
    text.overflow = "ellipsis"
    return text


class AuditPanel(Vertical, can_focus=False):
    """The live audit's findings and the line-demand gauge."""

    DEFAULT_CSS = """
    AuditPanel { height: 1fr; }
    AuditPanel #audit-gauge { height: 1; }
    AuditPanel DataTable { height: 1fr; }
    AuditPanel #audit-advice { height: 3; color: $text-muted; }
    """

    def __init__(self, bench: Workbench, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.bench = bench
        self._asked = 0.0
        self._findings: list[dict[str, Any]] = []
        self._shown: list[tuple[str, ...]] = []

    def compose(self) -> ComposeResult:
        yield Static(id="audit-gauge")
        table: DataTable[Text | str] = DataTable(id="audit-table", cursor_type="row", zebra_stripes=True)
        table.add_columns(*COLUMNS)
        yield table
        yield Static(id="audit-advice")

    def show(self, *, now: bool = False) -> None:
        """Bring the gauge and the findings to the server's report (at most :data:`REFRESH_HZ` a second)."""
        clock = time.monotonic()
        if not now and clock - self._asked < 1.0 / REFRESH_HZ:
            return
        self._asked = clock
        report = self.bench.audit()
        gauge = self.query_one("#audit-gauge", Static)
        if report is None:
            gauge.update(Text("the audit is off (serve --no-audit)", style="dim"))
            return
        gauge.update(gauge_text(report["line_demand"]))
        findings: list[dict[str, Any]] = report["findings"]
        rows = [self._cells(f) for f in findings]
        if rows == self._shown:
            return
        self._findings, self._shown = findings, rows
        table = self.query_one(DataTable)
        row = table.cursor_row
        table.clear()
        for finding, cells in zip(findings, rows, strict=True):
            severity = finding["severity"]
            table.add_row(Text(severity, style=SEVERITY_STYLES.get(severity, "")), *cells[1:])
        if findings:
            table.move_cursor(row=min(max(row, 0), len(findings) - 1))
            self._advise(table.cursor_row)
        else:
            self.query_one("#audit-advice", Static).update(Text("no findings: nothing here would fail on the line"))

    @staticmethod
    def _cells(finding: dict[str, Any]) -> tuple[str, ...]:
        drive = finding["drive"]
        where = "line" if drive is None else f"drive {drive}"
        if finding["subject"]:
            where += f" {finding['subject']}"
        count = f" (x{finding['count']})" if finding["count"] > 1 else ""
        return (finding["severity"], finding["rule"], where, f"{finding['figure']}{count}")

    @on(DataTable.RowHighlighted)
    def _highlighted(self, event: DataTable.RowHighlighted) -> None:
        self._advise(event.cursor_row)

    def _advise(self, row: int) -> None:
        if not 0 <= row < len(self._findings):
            return
        finding = self._findings[row]
        text = Text(finding["advice"])
        text.append(f"  [{finding['source']}]", style="dim")
        self.query_one("#audit-advice", Static).update(text)
