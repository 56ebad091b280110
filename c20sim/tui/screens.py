"""The dashboard's modal screens: the help (``?`` or F1) and the frame log's "save to" question."""

from __future__ import annotations

from typing import ClassVar

from textual import on
from textual.app import ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import Vertical, VerticalScroll
from textual.screen import ModalScreen
from textual.widgets import Input, Label, Markdown

from .tabs import tabs

__all__ = ["HelpScreen", "SaveLogScreen", "help_text"]

#: The help screen around its "Views" lines (one per tab row, :mod:`c20sim.tui.tabs`).
HELP_HEAD = """\
# c20sim dashboard

A virtual ZBLD.C20 drive on the bench. Point any Modbus RTU master at the
endpoints in the top line; the drive answers there while you watch it here.

## Keypad (works as on the drive)

| key | |
|---|---|
| `f` / `r` | RUN forward / reverse (only with the keypad run channel, F00.01 = 0) |
| `j` / `J` | JOG forward / reverse; press again to release |
| `s` | STOP (from any channel) |
| `x` | RESET a fault (refused while its cause is still there) |
| `m` | run channel: keypad -> terminals -> communication (F00.01) |
| `S` | speed source: keypad -> AI1 -> AI2 -> Modbus -> multi-speed -> dial switch (F00.02) |
| `+` / `-` | keypad speed reference, 1.00 Hz a press (F00.10; used with the keypad speed source) |
| `P` | power cycle |
| `D` | restore default parameters (200FH = 1; only while stopped) |

## Views

| key | |
|---|---|
"""
HELP_TAIL = """\
| `[` / `]` | previous / next drive |
| `t` / `T` | virtual clock only: time +1 s / +10 s (`T` in the footer from 100 columns) |
| `p`, `<` / `>` | realtime clock only: pause or resume the model; its speed halved / doubled (`<` `>` in the footer from 100 columns) |
| `ctrl+p` | the command palette: every action by name |
| `?`, `F1` | this help (either closes it, as Escape does); `q` quits |
"""


def help_text() -> str:
    """The help screen's Markdown: the keypad, then a line per tab, then the other keys."""
    return HELP_HEAD + "".join(f"{tab.help_line}\n" for tab in tabs()) + HELP_TAIL


class HelpScreen(ModalScreen[None]):
    BINDINGS: ClassVar[list[BindingType]] = [Binding("escape,q,question_mark,f1", "dismiss", "Close")]

    def compose(self) -> ComposeResult:
        with VerticalScroll(id="help"):
            yield Markdown(help_text())

    def on_mount(self) -> None:
        self.query_one("#help").focus()  # up/down, page up/down and the wheel scroll it

    def action_dismiss(self, result: None = None) -> None:  # type: ignore[override]
        self.dismiss(result)


class SaveLogScreen(ModalScreen[str | None]):
    """Ask where to save the frame log."""

    BINDINGS: ClassVar[list[BindingType]] = [Binding("escape", "cancel", "Cancel")]

    def __init__(self, default: str) -> None:
        super().__init__()
        self.default = default

    def compose(self) -> ComposeResult:
        with Vertical(id="save"):
            yield Label("Save the frames shown (with their filter) to:")
            yield Input(self.default, id="save-path")
            yield Label("Enter saves, Escape cancels", classes="hint")

    @on(Input.Submitted)
    def _submit(self, event: Input.Submitted) -> None:
        event.stop()
        self.dismiss(event.value.strip() or None)

    def action_cancel(self) -> None:
        self.dismiss(None)
