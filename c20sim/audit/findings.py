"""What the audit reports: findings, their severities, and the table of rules.

A :class:`Finding` is frozen: the engine hands out a new one when a rule's
figure grows (a higher line demand, more repeats), under the same
:attr:`Finding.key`, so a consumer keeps the latest per key.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass

__all__ = ["RULES", "Finding", "FrameRef", "Rule", "Severity"]


class Severity(enum.IntEnum):
    """How bad a finding is; ordered, so ``--fail-on warning`` means warning or error."""

    NOTE = 1
    WARNING = 2
    ERROR = 3

    @property
    def label(self) -> str:
        return self.name.lower()

    @classmethod
    def parse(cls, text: str) -> Severity:
        """``"error"`` -> ERROR; ValueError naming the allowed words."""
        try:
            return cls[text.strip().upper()]
        except KeyError:
            raise ValueError(f"severity {text!r}: expected one of note, warning, error") from None


@dataclass(frozen=True, slots=True)
class FrameRef:
    """A frame that shows a finding: its place in the stream (from 1) and its time."""

    seq: int
    t: float


@dataclass(frozen=True, slots=True)
class Finding:
    """One thing the master does that would fail in the field."""

    rule: str  #: a key of :data:`RULES`
    severity: Severity
    drive: int | None  #: the drive's address; None: the whole line
    subject: str  #: what it is about within the drive: "F00.10", "2009H", "" for the drive or line
    frames: tuple[FrameRef, ...]  #: the frames that show it (a few: first, worst, last)
    figure: str  #: the measure, in words
    value: float  #: the figure's number (percent, writes an hour, seconds, a count)
    count: int  #: how many times it was seen
    advice: str
    source: str  #: where the figure's facts come from: the sheet, a spec, a manual, or "assumed"

    @property
    def key(self) -> tuple[str, int | None, str]:
        return (self.rule, self.drive, self.subject)

    @property
    def where(self) -> str:
        return "line" if self.drive is None else f"drive {self.drive}"

    def as_dict(self) -> dict[str, object]:
        return {
            "rule": self.rule,
            "severity": self.severity.label,
            "drive": self.drive,
            "subject": self.subject,
            "frames": [{"seq": f.seq, "t": round(f.t, 6)} for f in self.frames],
            "figure": self.figure,
            "value": round(self.value, 6),
            "count": self.count,
            "advice": self.advice,
            "source": self.source,
        }

    def line(self) -> str:
        """One line of text: ``error line-demand line: line demand 573 % ... -> advice``."""
        subject = f" {self.subject}" if self.subject else ""
        advice = self.advice[:1].upper() + self.advice[1:]
        return f"{self.severity.label} {self.rule} {self.where}{subject}: {self.figure}. {advice}. [{self.source}]"


@dataclass(frozen=True, slots=True)
class Rule:
    """A rule of the audit: what it looks for and where its facts come from."""

    id: str
    title: str
    source: str


#: Every rule, by id: docs/audit.md has a section for each.
RULES: Mapping[str, Rule] = {
    rule.id: rule
    for rule in (
        Rule("line-demand", "polls faster than the RS485 line can carry", "Modbus over Serial Line V1.02 2.5.1"),
        Rule("eeprom-wear", "writes a function code (EEPROM) cyclically", "INVT Goodrive350 9.4.5.1; profile"),
        Rule("comm-watchdog", "longest silence towards a drive near its comm timeout", "profile F08.02"),
        Rule("collision", "a request before the previous reply could have finished", "Modbus over Serial Line"),
        Rule("early-retry", "a retry sooner than the reply could have come", "Modbus over Serial Line"),
        Rule("broadcast-turnaround", "a request too soon after a broadcast", "Modbus over Serial Line 2.4.1"),
        Rule("refused-while-running", "a W/R* write repeated while running (0x08)", "sheet 1.4, 0x08"),
        Rule("fcode-locked", "function-code writes without 200EH = 1 (0x04)", "sheet 200EH"),
        Rule("write-enable-left-on", "200EH left at 1 after the function-code writes", "sheet 200EH"),
        Rule("absent-register", "an absent register read again and again (0x02)", "sheet 1.4, 0x02"),
        Rule("run-channel", "run commands while the run channel is not communication", "sheet 2006H"),
        Rule("refused-repeat", "the same request refused again and again", "sheet 1.4"),
        Rule("reset-loop", "fault reset (2000H = 7) in a loop", "sheet 2000H; docs/faults.md"),
        Rule("speed-above-max", "speed reference above the maximum speed", "sheet 2001H; profile F00.03"),
    )
}
