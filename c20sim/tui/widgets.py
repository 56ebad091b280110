"""The dashboard's widgets: the frame log and the bench panels (the drive's state and the trend plots are in
status.py).

Views hold what they show in reactive attributes and render from them; the
panels act on the drives only through the app's :class:`Workbench`, and say
so with a :class:`ConditionsChanged` message so the views refresh at once.
What the bench refuses (a condition outside the control API's range) is
shown as an error notification.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, ClassVar

from rich.text import Text
from textual import events, on
from textual.app import ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import Grid, Horizontal, Vertical
from textual.reactive import reactive
from textual.widgets import Button, Checkbox, Input, Label, RichLog, Static

from ..control.ops import ControlError
from ..core.bus import Direction, FrameRecord, RecordKind
from ..drive import conditions
from ..drive.terminals import Input as Terminal
from .messages import ConditionsChanged, FramesLogged, SaveLogRequested
from .workbench import (
    DEVICE_SWITCHES,
    LINK_SWITCHES,
    Workbench,
    condition_range,
)

__all__ = [
    "ConditionsPanel",
    "DeviceFaultsPanel",
    "FrameLog",
    "LinkFaultsPanel",
    "format_record",
    "record_from_dict",
    "record_matches",
]

FUNCTIONS = {0x03: "read", 0x06: "write", 0x10: "write multiple"}


def record_matches(record: FrameRecord, drive: int | None, function: int | None, errors_only: bool) -> bool:
    """The frame log's filter: by drive (broadcasts shown for any), by function, or errors only."""
    if drive is not None and record.slave not in (drive, 0):
        return False
    if function is not None and (len(record.data) < 2 or record.data[1] & 0x7F != function):
        return False
    return not errors_only or record.kind.error or bool(record.note)


#: Wall-clock time of day minus the monotonic clock the ports stamp frames with (the event loop's, perf_counter).
WALL_OFFSET = time.time() - time.monotonic()


def time_of_day(wall: float) -> str:
    """A wall-clock time (Unix seconds) as the local time of day, to the millisecond."""
    return time.strftime("%H:%M:%S", time.localtime(wall)) + f".{int(wall % 1 * 1000):03d}"


def record_from_dict(data: Mapping[str, Any]) -> FrameRecord:
    """A frame record as the control API's stream sends it (``as_dict``) -> a record to show."""
    model_t = data.get("model_t")
    slave = data.get("slave")
    return FrameRecord(
        float(data["t"]),
        Direction(data["dir"]),
        bytes.fromhex(str(data["hex"])),
        RecordKind(data["kind"]),
        slave if isinstance(slave, int) else None,
        str(data["text"]),
        str(data.get("note", "")),
        float(model_t) if isinstance(model_t, int | float) else None,
        wall=float(data["wall"]) if isinstance(data.get("wall"), int | float) else None,
    )


def skipped_record(t: float, missed: int) -> FrameRecord:
    """The line that stands for frames the stream skipped: it says how many."""
    return FrameRecord(
        t, Direction.RX, b"", RecordKind.NOISE, None, f"{missed} frames skipped", "the log was behind the bus"
    )


def format_record(record: FrameRecord, *, hex_bytes: bool = True) -> Text:
    """One frame log line: time of day, model time, direction, drive, words (highlighted if wrong), hex."""
    arrow = "→" if record.direction is Direction.RX else "←"
    slave = "-" if record.slave is None else str(record.slave)
    model = "" if record.model_t is None else f" t={record.model_t:.3f}"
    wall = record.wall if record.wall is not None else record.t + WALL_OFFSET  # the server's word, else this clock's
    line = Text(f"{time_of_day(wall)}{model} {arrow} {slave:>3} ", style="dim")
    style = ""
    if record.kind is RecordKind.EXCEPTION:
        style = "bold yellow"
    elif record.kind.error:
        style = "bold red"
    if record.kind.error:
        line.append(f"[{record.kind}]", style=style or "bold")
    if record.text != record.kind:
        line.append(f" {record.text}" if record.kind.error else record.text, style=style)
    if record.note:
        line.append(f"  ! {record.note}", style="bold red")
    if hex_bytes and record.data:
        line.append(f"  {record.data.hex(' ').upper()}", style="dim")
    return line


class FrameLog(Vertical, can_focus=True):
    """Every frame on the line, live and in words; pause, filter and save."""

    BINDINGS: ClassVar[list[BindingType]] = [
        # not in the footer: the log's own header says "space pause", and at 80 columns it pushed q Quit off
        Binding("space", "pause", "Pause", show=False),
        Binding("a", "drive_filter", "Drive filter", show=False),
        Binding("n", "function_filter", "Function filter", show=False),
        Binding("e", "errors_only", "Errors only", show=False),
        Binding("w", "save", "Save log", show=False),
        Binding("delete", "clear", "Clear", show=False),
    ]

    paused = reactive(False)
    drive_filter: reactive[int | None] = reactive(None)
    function_filter: reactive[int | None] = reactive(None)
    errors_only = reactive(False)

    #: the records kept (as many as the log shows); older ones are let go
    KEEP = 2000

    def __init__(self, drives: Sequence[int], id: str | None = None) -> None:
        super().__init__(id=id)
        #: records serve's --log-frames writer lost (a slow or full sink), as the server counts them
        self.log_dropped = 0
        self.drives = list(drives)
        self.records: deque[FrameRecord] = deque(maxlen=self.KEEP)
        self._inbox: list[FrameRecord] = []
        self._posted = False
        self._held = 0
        #: frames the server's stream skipped because this log was behind (it says how many)
        self.missed = 0
        self._missed_shown = 0

    def compose(self) -> ComposeResult:
        yield Static(id="log-status")
        yield RichLog(max_lines=2000, id="log-lines", min_width=40)

    def on_mount(self) -> None:
        self.query_one(RichLog).can_focus = False
        self._show_status()
        self._rebuild()

    def show_log_dropped(self, dropped: int) -> None:
        """What --log-frames lost so far, from the telemetry; shown in the status line when it changes."""
        if dropped != self.log_dropped:
            self.log_dropped = dropped
            self._show_status()

    def add(self, record: FrameRecord, missed: int = 0) -> None:
        """A new record (after ``missed`` the stream skipped): queue it and ask for one merged refresh."""
        if missed:
            self.missed += missed
            self._inbox.append(skipped_record(record.t, missed))
        self._inbox.append(record)
        del self._inbox[: -self.KEEP]
        if not self._posted:
            self._posted = True
            self.post_message(FramesLogged())

    def on_frames_logged(self, message: FramesLogged) -> None:
        message.stop()
        self._posted = False
        records, self._inbox = self._inbox, []
        self.records.extend(records)
        if self.paused:
            self._held += len(records)
            self._show_status()
            return
        self._write([r for r in records if self._matches(r)])
        if self.missed != self._missed_shown:
            self._show_status()

    def _write(self, records: Sequence[FrameRecord]) -> None:
        """Append records to the log as one write: a line each, laid out once (a write a line costs ~1 ms)."""
        if records:
            self.query_one(RichLog).write(Text("\n").join(format_record(r) for r in records))

    def visible_records(self) -> list[FrameRecord]:
        """The records the filter shows, oldest first (what is saved)."""
        return [r for r in self.records if self._matches(r)]

    def _matches(self, record: FrameRecord) -> bool:
        return record_matches(record, self.drive_filter, self.function_filter, self.errors_only)

    def _rebuild(self) -> None:
        self.query_one(RichLog).clear()
        self._write(self.visible_records())

    def _show_status(self) -> None:
        parts = [
            f"drive {self.drive_filter}" if self.drive_filter is not None else "all drives",
            FUNCTIONS[self.function_filter] if self.function_filter is not None else "all functions",
        ]
        if self.errors_only:
            parts.append("errors only")
        text = Text("frames: " + ", ".join(parts), style="bold")
        self._missed_shown = self.missed
        if self.missed:
            text.append(f"  {self.missed} skipped (the log was behind the bus)", style="bold yellow")
        if self.log_dropped:
            text.append(f"  --log-frames lost {self.log_dropped}", style="bold yellow")
        if self.paused:
            text.append(f"  PAUSED ({self._held} new)", style="bold black on yellow")
        text.append("   space pause · a drive · n function · e errors · w save", style="dim")
        text.no_wrap = True
        text.overflow = "ellipsis"
        self.query_one("#log-status", Static).update(text)

    def _filters_changed(self) -> None:
        if self.is_mounted:
            self._show_status()
            if not self.paused:
                self._rebuild()

    def watch_drive_filter(self) -> None:
        self._filters_changed()

    def watch_function_filter(self) -> None:
        self._filters_changed()

    def watch_errors_only(self) -> None:
        self._filters_changed()

    def watch_paused(self, paused: bool) -> None:
        if not self.is_mounted:
            return
        if not paused:
            self._held = 0
            self._rebuild()
        self._show_status()

    def action_pause(self) -> None:
        self.paused = not self.paused

    def action_drive_filter(self) -> None:
        choices: list[int | None] = [None, *self.drives]
        self.drive_filter = choices[(choices.index(self.drive_filter) + 1) % len(choices)]

    def action_function_filter(self) -> None:
        choices: list[int | None] = [None, *FUNCTIONS]
        self.function_filter = choices[(choices.index(self.function_filter) + 1) % len(choices)]

    def action_errors_only(self) -> None:
        self.errors_only = not self.errors_only

    def action_clear(self) -> None:
        self.records.clear()
        self._held = 0
        self._rebuild()
        self._show_status()

    def action_save(self) -> None:
        self.post_message(SaveLogRequested())

    def save(self, path: Path) -> int:
        """Write the records the filter shows, one line each with hex; returns how many."""
        records = self.visible_records()
        with path.open("w", encoding="utf-8") as f:
            for record in records:
                f.write(format_record(record).plain + "\n")
        return len(records)


#: What a number field takes; any other printable key goes on to the dashboard (RESET, time, ...).
NUMBER_CHARACTERS = frozenset("0123456789+-.eE")


class NumberInput(Input):
    """A number that Enter applies, and up/down step like a slider.

    Keys that cannot be part of a number are left to the dashboard, so the
    keypad (``x`` RESET, ``s`` STOP), time and quit work while a field has focus.
    """

    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("up", "step(1)", "Up", show=False),
        Binding("down", "step(-1)", "Down", show=False),
        Binding("escape", "leave", "Leave field", show=False),
    ]

    def __init__(self, step: float, low: float, high: float, *, id: str | None = None) -> None:
        super().__init__(type="number", compact=True, id=id)
        self.step, self.low, self.high = step, low, high
        #: the drive's value, as last shown: a step starts here when the field holds no number
        self.current: float | None = None

    def show(self, value: float) -> None:
        """The drive's value now; the text is left alone while the user is typing in the field."""
        first = self.current is None  # a field that took the focus before any value came: fill it once
        self.current = value
        if (first or not self.has_focus) and self.value != f"{value:g}":
            self.value = f"{value:g}"

    def check_consume_key(self, key: str, character: str | None) -> bool:
        return character is not None and character in NUMBER_CHARACTERS

    async def _on_key(self, event: events.Key) -> None:
        if event.is_printable and event.character not in NUMBER_CHARACTERS:
            event.prevent_default()  # skip Input's handler: the key bubbles on to the app's bindings

    def action_leave(self) -> None:
        """Give the keys back to the dashboard (the keypad, time, tabs)."""
        self.screen.set_focus(None)

    def action_step(self, direction: int) -> None:
        """One step from the number in the field, or from the drive's value; never from nothing."""
        try:
            start = float(self.value)
        except ValueError:
            if self.current is None:
                return  # nothing known yet: a step must never invent a value (a blank field is not 0 V)
            start = self.current
        value = min(max(start + direction * self.step, self.low), self.high)
        self.value = f"{value:g}"
        self.post_message(Input.Submitted(self, self.value))


#: Conditions panel fields: id -> (label, unit, step, the control API's condition, which bounds it), one per
#: condition whose row (c20sim.drive.conditions) has a panel field.
CONDITION_FIELDS = {
    row.panel.id: (row.panel.label, row.unit, row.panel.step, name)
    for name, row in conditions.CONDITIONS.items()
    if row.panel is not None
}


class ConditionsPanel(Vertical):
    """The physical conditions: supply, load, ambient, the analog inputs and the input terminals."""

    #: the drive shown (the dashboard pushes it down)
    selected = reactive(0)

    def __init__(self, bench: Workbench, id: str | None = None) -> None:
        super().__init__(id=id)
        self.bench = bench

    def compose(self) -> ComposeResult:
        with Horizontal(classes="fields"):
            for name, (label, unit, step, condition) in CONDITION_FIELDS.items():
                yield Label(f"{label} ({unit})")
                yield NumberInput(step, *condition_range(condition), id=f"cond-{name}")
        with Horizontal(classes="terminals"):
            yield Label("input terminals")
            for terminal in Terminal:
                yield Checkbox(terminal.name or "", id=f"term-{terminal.name}", compact=True)
        yield Static(
            "Enter applies, up/down step (control API ranges). Terminals: the physical inputs.", classes="hint"
        )

    def show(self) -> None:
        """Show the conditions of the selected drive (fields being edited are left alone)."""
        cond = self.bench.conditions(self.selected)
        for name, (_, _, _, condition) in CONDITION_FIELDS.items():
            value = cond.values[condition]
            assert isinstance(value, int | float)
            self.query_one(f"#cond-{name}", NumberInput).show(float(value))
        for terminal in Terminal:
            box = self.query_one(f"#term-{terminal.name}", Checkbox)
            on_ = bool(cond.inputs & terminal)
            if box.value != on_:
                with box.prevent(Checkbox.Changed):
                    box.value = on_

    @on(Input.Submitted)
    def _apply(self, event: Input.Submitted) -> None:
        event.stop()
        name = (event.input.id or "").removeprefix("cond-")
        try:
            value = float(event.value)
        except ValueError:
            self.notify(f"{name}: not a number: {event.value!r}", severity="error")
            return
        address = self.selected
        try:
            self.bench.set_conditions(address, {CONDITION_FIELDS[name][3]: value})
        except ControlError as exc:
            self.notify(f"drive {address}: {exc}", severity="error", timeout=5)
            return
        self.post_message(ConditionsChanged(f"drive {address}: {name} {value:g}"))

    @on(Checkbox.Changed)
    def _terminal(self, event: Checkbox.Changed) -> None:
        event.stop()
        bits = 0
        for terminal in Terminal:
            if self.query_one(f"#term-{terminal.name}", Checkbox).value:
                bits |= terminal
        try:
            self.bench.set_inputs(self.selected, bits)
        except ControlError as exc:
            self.notify(f"drive {self.selected}: {exc}", severity="error", timeout=5)
        self.post_message(ConditionsChanged())


class _SwitchPanel(Vertical, can_focus=True):
    """A grid of one-key fault switches."""

    prefix = ""
    #: the drive they act on (the dashboard pushes it down)
    selected = reactive(0)

    def switches(self) -> list[tuple[str, str]]:
        """(key, label) of each switch."""
        raise NotImplementedError

    def compose(self) -> ComposeResult:
        yield Static(id=f"{self.prefix}-hint", classes="hint")
        with Grid(classes="switches"):
            for key, label in self.switches():
                yield Button(f"{key} {label}", id=f"{self.prefix}-{key}", compact=True)

    def on_button_pressed(self, event: Button.Pressed) -> None:
        event.stop()
        key = (event.button.id or "").removeprefix(f"{self.prefix}-")
        self.toggle(key)

    def action_switch(self, key: str) -> None:
        self.toggle(key)

    def toggle(self, key: str) -> None:
        raise NotImplementedError

    def mark(self, active: dict[str, bool]) -> None:
        for key, on_ in active.items():
            button = self.query_one(f"#{self.prefix}-{key}", Button)
            if button.has_class("-on") != on_:
                button.set_class(on_, "-on")


class DeviceFaultsPanel(_SwitchPanel):
    """Every device fault of the model, each one key: causes where the model has one, latched otherwise."""

    prefix = "dev"
    BINDINGS: ClassVar[list[BindingType]] = [
        Binding(key, f"switch('{key}')", show=False) for key in [s.key for s in DEVICE_SWITCHES] + [*"123456789z"]
    ]

    def __init__(self, bench: Workbench, id: str | None = None) -> None:
        super().__init__(id=id)
        self.bench = bench

    def switches(self) -> list[tuple[str, str]]:
        out = [(s.key, s.label) for s in self.bench.device_switches]
        out += [(key, f"{name} 0x{code:02X}") for key, (code, name) in self.bench.forced.items()]
        out.append(("z", "clear all"))
        return out

    def on_mount(self) -> None:
        self.query_one("#dev-hint", Static).update(
            "Each key switches a cause on or off; a digit holds a fault on (no physics).\n"
            "RESET (x, or a master's 2000H = 7) clears a fault once its cause is off."
        )

    def toggle(self, key: str) -> None:
        if key.isdigit() and key not in self.bench.forced:
            return
        try:
            note = self.bench.toggle_device_fault(self.selected, key)
        except ControlError as exc:
            self.notify(f"drive {self.selected}: {exc}", severity="error", timeout=5)
            return
        self.post_message(ConditionsChanged(note))

    def refresh_marks(self, address: int) -> None:
        self.mark({key: self.bench.device_fault_active(address, key) for key, _ in self.switches() if key != "z"})


class LinkFaultsPanel(_SwitchPanel):
    """Every link fault of the wire, each one key, on the selected drive's link or the whole bus."""

    prefix = "link"
    BINDINGS: ClassVar[list[BindingType]] = [
        Binding(key, f"switch('{key}')", show=False) for key in [s.key for s in LINK_SWITCHES] + ["z", "b"]
    ]
    on_bus = reactive(False)

    def __init__(self, bench: Workbench, id: str | None = None) -> None:
        super().__init__(id=id)
        self.bench = bench
        self._hint = ""

    def switches(self) -> list[tuple[str, str]]:
        return [(s.key, s.label) for s in LINK_SWITCHES] + [("z", "clear all"), ("b", "drive/bus")]

    def scope(self) -> int | None:
        return None if self.on_bus else self.selected

    def toggle(self, key: str) -> None:
        if key == "b":
            self.on_bus = not self.on_bus
            self.post_message(ConditionsChanged(f"link faults now act on {self._where()}"))
            return
        try:
            note = self.bench.toggle_link_fault(self.scope(), key)
        except ControlError as exc:
            self.notify(f"{self._where()}: {exc}", severity="error", timeout=5)
            return
        self.post_message(ConditionsChanged(note))

    def _where(self) -> str:
        scope = self.scope()
        return "the whole bus" if scope is None else f"drive {scope}'s link"

    def refresh_marks(self, address: int) -> None:
        scope = self.scope()
        self.mark({s.key: self.bench.link_fault_active(scope, s.key) for s in LINK_SWITCHES})
        self.query_one("#link-b", Button).set_class(self.on_bus, "-on")
        active = self.bench.link_active(scope)
        hint = f"On {self._where()} (b switches): " + (", ".join(active) if active else "no link fault")
        if hint != self._hint:
            self._hint = hint
            self.query_one("#link-hint", Static).update(hint)
