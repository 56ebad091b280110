"""The dashboard's own messages, as dataclasses.

Telemetry and frame-log messages *merge*: a newer one replaces an older one
still waiting in the queue (``can_replace``), so a fast model or a busy bus
can never flood the UI; the handler always reads the latest state.
"""

from __future__ import annotations

from dataclasses import dataclass

from textual.message import Message

from .workbench import DriveView

__all__ = ["ConditionsChanged", "FramesLogged", "SaveLogRequested", "TelemetryUpdated"]


@dataclass
class TelemetryUpdated(Message):
    """What the drives show now (address -> view)."""

    views: dict[int, DriveView]

    def can_replace(self, message: Message) -> bool:
        return isinstance(message, TelemetryUpdated)


@dataclass
class FramesLogged(Message):
    """New frames are waiting in the frame log's inbox."""

    def can_replace(self, message: Message) -> bool:
        return isinstance(message, FramesLogged)


@dataclass
class ConditionsChanged(Message):
    """A panel changed a drive's conditions or faults: refresh the views now."""

    note: str = ""


@dataclass
class SaveLogRequested(Message):
    """The frame log asks for its records to be saved (the dashboard asks where)."""
