"""The dashboard's tabs, one row each: its pane id, its key, its title, the panel it holds and its help line.

:data:`TABS` is the one place a tab is declared. The dashboard (:mod:`c20sim.tui.app`) iterates it for the tab
bar (the pane titled ``Title KEY``), the key that switches to it, the panel kept up to date while it is on show,
the drive pushed down to a panel that acts on one, the widget focused when it opens, and the help screen's
"Views" lines; docs/dashboard.md's "Views" table lists every row (a test checks). A new tab is its panel plus
one row here.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from textual.widget import Widget

from .audit import AuditPanel
from .drill import DrillPanel
from .registers import RegistersPanel
from .widgets import ConditionsPanel, DeviceFaultsPanel, FrameLog, LinkFaultsPanel
from .workbench import Workbench

__all__ = ["TABS", "Tab", "Tabs", "tabs"]


def _show(panel: Any, address: int) -> None:
    panel.show()


def _marks(panel: Any, address: int) -> None:
    panel.refresh_marks(address)


@dataclass(frozen=True)
class Tab:
    """One tab of the dashboard."""

    #: the pane's id, and the argument of the ``tab`` action
    id: str
    #: the key that switches to it (Textual's name: ``f2``); shown in its title as ``F2``
    key: str
    #: its title in the tab bar (before the key)
    title: str
    #: ``panel(bench, id=...)`` -> the widget the pane holds
    panel: Callable[..., Widget]
    #: the panel's widget id
    panel_id: str
    #: what it shows and its keys, in one line of the help screen's "Views" table
    help: str
    #: ``refresh(panel, selected address)`` while the tab is on show, at each telemetry update; None: it updates
    #: itself
    refresh: Callable[[Any, int], None] | None = _show
    #: whether the panel acts on the selected drive (its ``selected`` is set when another drive is chosen)
    follows_drive: bool = False
    #: the widget focused when the tab opens (a CSS selector); "" for the panel itself
    focus: str = ""

    @property
    def label(self) -> str:
        """Its title in the tab bar: ``Frames F2``."""
        return f"{self.title} {self.key.upper()}"

    @property
    def help_line(self) -> str:
        """Its row of the help screen's "Views" table."""
        return f"| `{self.key.upper()}` | {self.help} |"


class Tabs:
    """The rows, in the tab bar's order; :meth:`add` and :meth:`remove` (a test adds one and takes it away)."""

    def __init__(self, rows: list[Tab]) -> None:
        self._rows: dict[str, Tab] = {}
        for row in rows:
            self.add(row)

    def add(self, row: Tab) -> None:
        if row.id in self._rows or any(other.key == row.key for other in self._rows.values()):
            raise ValueError(f"tab {row.id} ({row.key}): declared twice")
        self._rows[row.id] = row

    def remove(self, id: str) -> None:
        del self._rows[id]

    def __iter__(self) -> Iterator[Tab]:
        return iter(list(self._rows.values()))

    def __getitem__(self, id: str) -> Tab:
        return self._rows[id]

    def get(self, id: str) -> Tab | None:
        return self._rows.get(id)

    def __len__(self) -> int:
        return len(self._rows)


def _frame_log(bench: Workbench, id: str) -> FrameLog:
    return FrameLog(list(bench.addresses), id=id)


TABS = Tabs(
    [
        Tab(
            "frames",
            "f2",
            "Frames",
            _frame_log,
            "framelog",
            "frame log: `space` pause, `a` drive, `n` function, `e` errors only, `w` save, `Del` clear",
            refresh=None,
        ),
        Tab(
            "conditions",
            "f3",
            "Conditions",
            ConditionsPanel,
            "conditions-panel",
            "conditions: supply, load, ambient, AI1/AI2, input terminals (Enter applies, up/down step)",
            follows_drive=True,
            focus="#cond-supply",
        ),
        Tab(
            "faults",
            "f4",
            "Device faults",
            DeviceFaultsPanel,
            "faults-panel",
            "device faults: one key each, the cause switched on or off (a letter: a physical cause, the drive trips "
            "by its model; a digit: a fault held on, the model has no physics for it); RESET (`x`, or a master's "
            "2000H = 7) clears a fault once its cause is off; `z` clears all",
            refresh=_marks,
            follows_drive=True,
        ),
        Tab(
            "link",
            "f5",
            "Link faults",
            LinkFaultsPanel,
            "link-panel",
            "link faults: one key each, on the selected drive's link or the whole bus (`b`)",
            refresh=_marks,
            follows_drive=True,
        ),
        Tab(
            "registers",
            "f6",
            "Registers",
            RegistersPanel,
            "registers-panel",
            "registers: every register and function code, live, with the drive's traffic counters; Enter edits one "
            "by a master's rules (a refusal names its exception code); `/` finds one by any name (speed, motor "
            "speed, 3006H, 12294, F00.10)",
            follows_drive=True,
            focus="#reg-table",
        ),
        Tab(
            "audit",
            "f7",
            "Audit",
            AuditPanel,
            "audit-panel",
            "audit: what the masters would do wrong on a real RS485 line, worst first, and the line-demand gauge "
            "(docs/audit.md)",
            focus="#audit-table",
        ),
        Tab(
            "drill",
            "f8",
            "Drill",
            DrillPanel,
            "drill-panel",
            "drill: the incidents and their last verdicts; `g` plays the selected one on the master polling the "
            "serve, `A` the standard plan, `C` stops (docs/drill.md)",
            focus="#drill-table",
        ),
    ]
)


def tabs() -> Tabs:
    """The dashboard's tabs (a test may add one, and every dashboard made after shows it)."""
    return TABS
