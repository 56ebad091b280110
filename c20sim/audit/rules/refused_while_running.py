"""``refused-while-running``: a W/R* write repeated while running (0x08)."""

from __future__ import annotations

from ...wire.protocol import ExceptionCode
from ...wire.registers import address_label
from ..state import _Request
from ..window import Window
from ._refusal import RefusalRule

__all__ = ["RefusedWhileRunningRule"]


class RefusedWhileRunningRule(RefusalRule):
    """0x08 again and again: a W/R* register written while the drive runs."""

    id = "refused-while-running"
    title = "a W/R* write repeated while running (0x08)"
    source = "sheet 1.4, 0x08"

    def claims(self, audit: Window, request: _Request, code: int) -> bool:
        return code == ExceptionCode.NOT_WHILE_RUNNING

    def advice(self, request: _Request) -> str:
        return f"stop the drive before writing {address_label(request.register)} (W/R*: written only while stopped)"
