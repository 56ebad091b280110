"""The status panel and the plots at the dashboard's top: one drive's state in words, its fault and what the
drive did by itself, and the last minute of its speed, current and bus.

Split from widgets.py (issue 42) when the fault record's row grew it: the panel and its plots are a job of
their own, and widgets.py keeps the tabs' widgets (frame log, conditions, faults).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from rich.text import Text
from textual.reactive import reactive
from textual.widget import Widget
from textual.widgets import Static

from ..drive.terminals import Input as Terminal
from ..drive.terminals import Output
from ..wire.registers import RUN_CHANNELS, SPEED_SOURCES, STATUS_WORDS
from .workbench import DriveView

__all__ = [
    "STATUS_STYLES",
    "DriveStatus",
    "TitleBar",
    "TrendPlot",
    "clock_forms",
    "record_row",
    "status2_short",
    "title_line",
]

#: Status word 1 -> the colour it is shown in.
STATUS_STYLES = {
    1: "bold black on green",
    2: "bold black on green",
    3: "bold white on dark_blue",
    4: "bold white on red",
    5: "bold black on yellow",
    6: "bold white on magenta",
}
BLOCKS = " ▁▂▃▄▅▆▇█"


def _bits(value: int, names: Iterable[tuple[str, int]]) -> Text:
    text = Text()
    for name, bit in names:
        if text:
            text.append(" ")
        text.append(name, style="bold black on bright_green" if value & bit else "bright_black")
    return text


class DriveStatus(Static):
    """One drive's state, set point, telemetry, fault, status word 2 and terminals."""

    view: reactive[DriveView | None] = reactive(None)

    def render(self) -> Text:
        view = self.view
        if view is None:
            return Text("waiting for the drive")
        tel = view.telemetry
        status = tel.status
        words = STATUS_WORDS.get(status, f"status {status}")
        # Each part is a span of its own: a base style on the whole Text would colour every row
        # (the state's background behind the fault text, the terminals, everything).
        out = Text()
        out.append(f" {words.upper()} ", style=STATUS_STYLES.get(status, "bold"))
        out.append(f" 2100H = {status}", style="dim")
        if tel.state not in words:
            out.append(f" ({tel.state})", style="dim")
        if tel.fault_code:
            fault = Text(f"0x{tel.fault_code:02X} {tel.fault_name}", style="bold bright_red")
        else:
            fault = Text("none", style="green")
        rows: list[tuple[str, Text | str]] = [
            (
                "channel",
                f"{RUN_CHANNELS.get(tel.run_channel, tel.run_channel)} · speed from "
                f"{SPEED_SOURCES.get(tel.speed_source, tel.speed_source)}",
            ),
            ("speed", f"{tel.speed_rpm:.0f} rpm of {tel.set_speed_rpm:.0f} · ramp {tel.ramp_rpm:.0f}"),
            ("freq", f"{view.output_hz:.2f} Hz of {view.set_hz:.2f} · {tel.output_voltage_v:.1f} V"),
            ("current", f"{abs(tel.current_a):.2f} A · {tel.output_power_w:.0f} W · bus {tel.bus_v:.1f} V"),
            ("temp", f"{tel.temperature_c:.1f} °C · Hall {tel.hall} · supply {tel.supply_v:g} V"),
            ("fault", fault),
            *record_row(view.record),
            *([("auto", Text(tel.auto_action, style="yellow"))] if tel.auto_action else []),
            ("status 2", f"{view.status2:04X} {status2_short(view.status2)}"),
            ("inputs", _bits(tel.input_terminals, ((t.name or "", t.value) for t in Terminal))),
            ("outputs", _bits(tel.output_terminals, ((o.name or "", o.value) for o in Output))),
        ]
        width = max(1, self.content_size.width)
        out.truncate(width, overflow="ellipsis")
        for label, value in rows:
            line = Text()
            line.append(f"{label:<9}", style="bold")
            line.append(value)
            line.truncate(width, overflow="ellipsis")  # one line each, whatever the width: never wrapped
            out.append("\n")
            out.append_text(line)
        out.no_wrap = True
        out.overflow = "ellipsis"
        return out


def record_row(record: tuple[int, ...]) -> list[tuple[str, Text | str]]:
    """Beside a fault, the fault record (F07): the state the trip met and the fault before; none if not faulted."""
    if not record:
        return []
    before, hz, amps, bus = record
    text = Text(f"{hz / 100:.2f} Hz · {amps / 100:.2f} A · bus {bus / 10:.1f} V", style="red")
    if before:
        text.append(f" · before 0x{before:02X}", style="dim")
    return [("at trip", text)]


def status2_short(raw: int) -> str:
    """Status word 2 in a few words: bus, overload, control source."""
    words = ["bus ok" if raw & 0x01 else "no bus"]
    if raw & 0x10:
        words.append("OVERLOAD")
    words.append({0: "keypad", 1: "terminal", 2: "comm"}.get((raw >> 5) & 0b11, "source 11") + " control")
    return " · ".join(words)


class TrendPlot(Widget):
    """A bar plot of the last minute of one quantity, newest on the right, scaled from zero to ``top``."""

    DEFAULT_CSS = """
    TrendPlot { height: 3; }
    """

    values: reactive[tuple[float, ...]] = reactive(())

    def __init__(self, label: str, unit: str, top: float, digits: int = 0, id: str | None = None) -> None:
        super().__init__(id=id)
        self.label = label
        self.unit = unit
        self.top = top
        self.digits = digits

    def render(self) -> Text:
        width, rows = max(1, self.size.width), max(1, self.size.height - 1)
        values = self.values
        last = values[-1] if values else 0.0
        head = Text(f"{self.label} ", style="bold")
        head.append(f"{last:.{self.digits}f} {self.unit}")
        head.append(f" (scale {self.top:g}, 1 min)", style="dim")
        head.truncate(width, overflow="ellipsis")
        columns = _resample([abs(v) for v in values], width)
        levels = [min(rows * 8, round(v / self.top * rows * 8)) if self.top > 0 else 0 for v in columns]
        lines = []
        for row in range(rows - 1, -1, -1):
            lines.append("".join(BLOCKS[min(8, max(0, level - row * 8))] for level in levels).rjust(width))
        head.append("\n")
        head.append("\n".join(lines), style="cyan")
        head.no_wrap = True
        head.overflow = "ellipsis"
        return head


def _resample(values: Sequence[float], width: int) -> list[float]:
    """At most ``width`` columns: the maximum of each bin, newest last."""
    if len(values) <= width:
        return list(values)
    out = []
    n = len(values)
    for i in range(width):
        lo, hi = i * n // width, (i + 1) * n // width
        out.append(max(values[lo:hi]))
    return out


#: The title's parts, given up in this order as the width shrinks (docs/dashboard.md, "The title"): the word
#: ``connect:``, the word ``realtime``, the profile's name, the model's time, the ``c20sim`` badge. Where a master
#: connects and how the clock runs (``paused``, ``×2``, ``virtual``) are kept to the last; ``server lost`` comes
#: first of all when it is said.
_TITLE_LEVELS = (
    # (the word "connect:", the clock's form (0 long, 1 short, 2 shortest), the profile, the badge)
    (True, 0, True, True),
    (False, 0, True, True),
    (False, 1, True, True),
    (False, 1, False, True),
    (False, 2, False, True),
    (False, 2, False, False),
)


def clock_forms(t: float, virtual: bool, speed: float = 1.0, paused: bool = False) -> tuple[str, str, str]:
    """How the clock runs, long to short: ``t 12.3 s ×2 realtime paused``, ``t 12.3 s ×2 paused``, ``paused``
    (running: ``×2``, or ``realtime`` at ×1; ``t 12.3 s virtual``, ``t 12.3 s virtual``, ``virtual``). The
    shortest fits beside a bare serve's three endpoints at 80 columns."""
    if virtual:
        return f"t {t:.1f} s virtual", f"t {t:.1f} s virtual", "virtual"
    state = " paused" if paused else ""
    return (
        f"t {t:.1f} s ×{speed:g} realtime{state}",
        f"t {t:.1f} s ×{speed:g}{state}",
        "paused" if paused else ("realtime" if speed == 1.0 else f"×{speed:g}"),
    )


def title_line(width: int, where: str, clock: tuple[str, str, str], profile: str, lost: bool) -> Text:
    """The title at ``width`` columns: every part whole at the first level that fits (:data:`_TITLE_LEVELS`); cut
    with an ellipsis only if even the last does not."""
    text = Text()
    for label, form, with_profile, badge in _TITLE_LEVELS:
        text = Text(" c20sim ", style="bold reverse") if badge else Text()
        if lost:
            text.append(" server lost ", style="bold white on red")
        text.append(" ")
        if label:
            text.append("connect: ", style="bold")
        text.append(where)
        text.append(" │ ")
        text.append(clock[form], style="bold")
        if with_profile:
            text.append(f" │ {profile}")
        if text.cell_len <= width:
            break
    text.truncate(max(1, width), overflow="ellipsis")
    text.no_wrap = True
    text.overflow = "ellipsis"
    return text


class TitleBar(Static):
    """The dashboard's top line: where a master connects, how the clock runs, the profile; fitted to its width
    (:func:`title_line`), so what is given up at 80 columns is a chosen part, never the end of the line."""

    def __init__(self, id: str | None = None) -> None:
        super().__init__(id=id)
        self._parts: tuple[str, tuple[str, str, str], str, bool] = ("", ("", "", ""), "", False)

    def show(self, where: str, clock: tuple[str, str, str], profile: str, lost: bool) -> None:
        parts = (where, clock, profile, lost)
        if parts != self._parts:  # the model's time moves on: redrawn when a part changed, not at each refresh
            self._parts = parts
            self.refresh()

    def render(self) -> Text:
        return title_line(self.size.width, *self._parts)
