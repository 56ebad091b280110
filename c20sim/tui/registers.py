"""The register view (F6): every register of the map and every function code, and the drive's traffic.

Grouped as the sheet groups them, each with its value in words, its access
class and whether it is locked now (W/R* while running). Enter on a row edits
it by a master's rules: a refusal shows the exception code a master would
get. ``/`` finds a register by any name of the one vocabulary (``speed``,
``motor speed``, ``3006H``, ``0x3006``, ``12294``, ``F00.10``), with a
did-you-mean for a misspelt one. The traffic counters of the drive sit above the table. Everything comes
through the :class:`~c20sim.tui.workbench.Workbench`, as the other panels.
"""

from __future__ import annotations

from typing import ClassVar

from rich.text import Text
from textual import on
from textual.app import ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import Horizontal, Vertical
from textual.reactive import reactive
from textual.widgets import DataTable, Input, Label, Static

from ..wire.registers import address_label
from ..wire.vocabulary import UnknownRegister, resolve_register
from .messages import ConditionsChanged
from .workbench import Workbench

__all__ = ["RegistersPanel", "counters_text"]

COLUMNS = ("register", "name", "value", "access", "raw", "source")


def counters_text(counters: dict[str, object]) -> Text:
    """One line of traffic: requests, replies, exceptions by code, CRC and length errors, silences, injected, and
    the line's time its transactions took (their share of the line's capacity)."""
    text = Text()
    exceptions = counters.get("exceptions") or {}
    assert isinstance(exceptions, dict)
    parts: list[tuple[str, str]] = [
        ("requests", f"{counters['requests']}"),
        ("replies", f"{counters['replies']}"),
        ("exceptions", " ".join(f"{code}×{n}" for code, n in exceptions.items()) or "0"),
        ("CRC", f"{counters['crc_errors']}"),
        ("length", f"{counters['length_errors']}"),
        ("silences", f"{counters['silences']}"),
        ("injected", f"{counters['injected']}"),
    ]
    if "line_busy_s" in counters:  # the line's time its transactions took at the drive's serial settings
        share = counters.get("line_share", 0.0)
        assert isinstance(share, float | int)
        parts.append(("line", f"{counters['line_busy_s']} s, {share:.0%}"))
    for label, value in parts:
        if text:
            text.append(" · ", style="dim")
        text.append(f"{label} ", style="bold")
        quiet = label in ("requests", "replies", "line") or value == "0"
        text.append(value, style="" if quiet else "bold yellow")
    text.no_wrap = True
    text.overflow = "ellipsis"
    return text


class RegistersPanel(Vertical, can_focus=False):
    """The whole register map of the selected drive, live, with in-place edits by a master's rules."""

    DEFAULT_CSS = """
    RegistersPanel { height: 1fr; }
    RegistersPanel #reg-counters { height: 1; }
    RegistersPanel DataTable { height: 1fr; }
    RegistersPanel #reg-editor { height: 1; display: none; }
    RegistersPanel #reg-editor.-editing { display: block; }
    RegistersPanel #reg-editor Label { padding: 0 1 0 0; }
    RegistersPanel #reg-editor Input { width: 12; }
    RegistersPanel #reg-finder { height: 1; display: none; }
    RegistersPanel #reg-finder.-finding { display: block; }
    RegistersPanel #reg-finder Label { padding: 0 1 0 0; }
    RegistersPanel #reg-finder Input { width: 24; }
    """

    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("escape", "cancel", "Cancel edit", show=False),
        # not in the footer: at 80 columns it would push q Quit off (the help, ?, lists it)
        # a priority key (on the table only: check_action): taken, and the finder focused, before the keys behind it
        # in a burst are passed on, so "/speed" typed at once (tmux send-keys, a paste) reaches the finder
        Binding("slash", "find", "Find register", show=False, priority=True),
    ]

    #: the drive shown (the dashboard pushes it down)
    selected = reactive(0)

    def __init__(self, bench: Workbench, id: str | None = None) -> None:
        super().__init__(id=id)
        self.bench = bench
        self._rows: list[str] = []  #: row keys in table order (registers; group headings start with "#")
        self._shown: dict[str, tuple[str, str, str]] = {}  #: register -> (value, access, raw) on screen
        self._editing: str | None = None

    def compose(self) -> ComposeResult:
        yield Static(id="reg-counters")
        yield DataTable(id="reg-table", cursor_type="row", zebra_stripes=True)
        with Horizontal(id="reg-editor"):
            yield Label("", id="reg-edit-label")
            yield Input(id="reg-edit", type="integer", compact=True)
            yield Label("Enter writes by a master's rules · Escape cancels", classes="hint")
        with Horizontal(id="reg-finder"):
            yield Label("find register:")
            yield Input(id="reg-find", placeholder="speed, 3006H, F00.10", compact=True)
            yield Label("Enter goes to it · Escape cancels", classes="hint")

    def on_mount(self) -> None:
        table = self.query_one(DataTable)
        for column in COLUMNS:
            table.add_column(column, key=column)

    def show(self) -> None:
        """Bring the table and the counters to the drive's values now (cells that changed only)."""
        if not self.selected:
            return
        self.query_one("#reg-counters", Static).update(counters_text(self.bench.counters(self.selected)))
        table = self.query_one(DataTable)
        rows = self.bench.registers(self.selected)
        if not self._rows:
            self._fill(table, rows)
            return
        for row in rows:
            register = str(row["register"])
            cells = self._cells(row)
            if self._shown.get(register) != cells:
                self._shown[register] = cells
                for column, value in zip(("value", "access", "raw"), cells, strict=True):
                    table.update_cell(register, column, value)

    def _fill(self, table: DataTable[str], rows: list[dict[str, object]]) -> None:
        group = None
        for row in rows:
            if row["group"] != group:
                group = row["group"]
                key = f"#{group}"
                table.add_row("", str(group).upper(), "", "", "", "", key=key)  # a heading row
                self._rows.append(key)
            register = str(row["register"])
            cells = self._cells(row)
            self._shown[register] = cells
            mirror = f" (= {row['mirrors']})" if row["mirrors"] else ""
            table.add_row(register, f"{row['name']}{mirror}", *cells, str(row["source"]), key=register)
            self._rows.append(register)

    @staticmethod
    def _cells(row: dict[str, object]) -> tuple[str, str, str]:
        raw = row["raw"]
        assert isinstance(raw, int)
        access = str(row["access"]) + (" lock" if row["locked"] else "")  # W/R* while running
        return str(row["text"]), access, f"{raw} (0x{raw:04X})"

    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        if action == "find":
            return self.screen.focused is self.query_one(DataTable)  # in the finder, / is typed
        return True

    @on(DataTable.RowSelected)
    def _edit(self, event: DataTable.RowSelected) -> None:
        register = event.row_key.value
        if register is None or register.startswith("#"):
            return
        self._editing = register
        raw = self._shown[register][2].split(" ")[0]
        self.query_one("#reg-edit-label", Label).update(f"{register} =")
        field = self.query_one("#reg-edit", Input)
        field.value = raw
        self.query_one("#reg-editor").add_class("-editing")
        self.screen.set_focus(field)  # now: the digits typed next are passed on to the field

    @on(Input.Submitted, "#reg-edit")
    def _write(self, event: Input.Submitted) -> None:
        event.stop()
        register = self._editing
        if register is None:
            return
        try:
            value = int(event.value, 0)
        except ValueError:
            self.notify(f"{register}: {event.value!r} is not a whole number", severity="error")
            return
        refused = self.bench.write_register(self.selected, register, value)
        if refused is not None:
            self.notify(f"drive {self.selected}: {refused}", severity="error", timeout=6)
            return
        self.action_cancel()
        self.post_message(ConditionsChanged(f"drive {self.selected}: {register} = {value}"))

    def action_find(self) -> None:
        """Open the finder: a register by any name of the vocabulary."""
        field = self.query_one("#reg-find", Input)
        field.value = ""
        self.query_one("#reg-finder").add_class("-finding")
        self.screen.set_focus(field)  # now: the name typed next is passed on to the field

    @on(Input.Submitted, "#reg-find")
    def _find(self, event: Input.Submitted) -> None:
        event.stop()
        found = self.find(event.value)
        if found is not None:
            self.action_cancel()
            table = self.query_one(DataTable)
            table.move_cursor(row=self._rows.index(found))

    def find(self, text: str) -> str | None:
        """The row key of the register ``text`` names, or None after saying (one line) why there is none."""
        try:
            label = address_label(resolve_register(text))
        except UnknownRegister as exc:
            self.notify(str(exc), severity="error", timeout=8)
            return None
        if label not in self._shown:
            self.notify(f"register {text!r}: drive {self.selected} has no register {label}", severity="error")
            return None
        return label

    def action_cancel(self) -> None:
        self._editing = None
        self.query_one("#reg-editor").remove_class("-editing")
        self.query_one("#reg-finder").remove_class("-finding")
        focused = self.screen.focused
        if focused is None or self in focused.ancestors:  # not when a key after it took the focus elsewhere (F8)
            self.screen.set_focus(self.query_one(DataTable))  # now, as the finder and the editor take it
