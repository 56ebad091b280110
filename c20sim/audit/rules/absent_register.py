"""``absent-register``: an absent register read again and again (0x02)."""

from __future__ import annotations

from ...wire.protocol import ExceptionCode, FunctionCode
from ...wire.registers import address_label
from ..state import _Request
from ..window import Window
from ._refusal import RefusalRule

__all__ = ["AbsentRegisterRule"]


class AbsentRegisterRule(RefusalRule):
    """0x02 again and again on a read: the poll list holds a register the drive does not have."""

    id = "absent-register"
    title = "an absent register read again and again (0x02)"
    source = "sheet 1.4, 0x02"

    def claims(self, audit: Window, request: _Request, code: int) -> bool:
        return code == ExceptionCode.ILLEGAL_ADDRESS and request.function == FunctionCode.READ_REGISTERS

    def advice(self, request: _Request) -> str:
        return f"drop {address_label(request.register)} from the poll list: the drive has no such register"
