"""``fcode-locked``: function-code writes without 200EH = 1 (0x04)."""

from __future__ import annotations

from ...wire.protocol import ExceptionCode
from ...wire.registers import Reg
from ..state import _Request
from ..window import Window
from ._refusal import RefusalRule

__all__ = ["FcodeLockedRule"]


class FcodeLockedRule(RefusalRule):
    """0x04 again and again on a function code (or a register mirroring one): 200EH was not set to 1."""

    id = "fcode-locked"
    title = "function-code writes without 200EH = 1 (0x04)"
    source = "sheet 200EH"

    def claims(self, audit: Window, request: _Request, code: int) -> bool:
        register = request.register
        # 0x04 on 2000H is run-channel's
        return code == ExceptionCode.OPERATION_FAILED and register != Reg.COMMAND and register in audit.eeprom

    def advice(self, request: _Request) -> str:
        return "write 200EH = 1 before function-code writes, and 200EH = 0 after them"
