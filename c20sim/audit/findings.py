"""What the audit reports: findings and their severities (the rules are in :mod:`c20sim.audit.rules`).

A :class:`Finding` is frozen: the engine hands out a new one when a rule's
figure grows (a higher line demand, more repeats), under the same
:attr:`Finding.key`, so a consumer keeps the latest per key.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

__all__ = ["Finding", "FrameRef", "Severity"]


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

    rule: str  #: a key of :data:`c20sim.audit.rules.RULES`
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
