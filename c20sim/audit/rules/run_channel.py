"""``run-channel``: run commands while the run channel is not communication."""

from __future__ import annotations

from ...wire.protocol import ExceptionCode
from ...wire.registers import Reg
from ..state import _Request
from ..window import Window
from ._refusal import RefusalRule

__all__ = ["RunChannelRule"]


class RunChannelRule(RefusalRule):
    """0x04 again and again on 2000H: the drive takes its run commands from another channel."""

    id = "run-channel"
    title = "run commands while the run channel is not communication"
    source = "sheet 2006H"

    def claims(self, audit: Window, request: _Request, code: int) -> bool:
        return code == ExceptionCode.OPERATION_FAILED and request.register == Reg.COMMAND

    def advice(self, request: _Request) -> str:
        return "select the communication run channel (2006H = 2, F00.01) before sending run commands"
