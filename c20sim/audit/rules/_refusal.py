"""What the refusal rules share: a refusal counted by drive, register and code, reported once it repeats."""

from __future__ import annotations

from ...wire.protocol import ExceptionCode, FunctionCode
from ...wire.registers import address_label
from ..findings import FrameRef, Severity
from ..state import _Request
from ..window import Window
from .base import Rule

__all__ = ["RefusalRule"]


class RefusalRule(Rule):
    """A refusal the rule :meth:`claims`, the same ``repeats`` times (a probe is once; a master that goes on
    asking ignores the answer): a warning with the rule's :meth:`advice`."""

    def advice(self, request: _Request) -> str:
        raise NotImplementedError

    def refused(self, audit: Window, request: _Request, code: int, ref: FrameRef) -> None:
        register = request.register
        count = audit.count((self.id, request.slave, register, code))
        if count is None:
            return
        count.n += 1
        count.first = count.first or audit.pending_ref()
        count.last = ref
        if count.n < audit.limits.repeats:
            return
        action = "read" if request.function == FunctionCode.READ_REGISTERS else "write"
        label = address_label(register) if register >= 0 else f"function 0x{request.function:02X}"
        try:
            meaning = ExceptionCode(code).meaning
        except ValueError:
            meaning = "not a code of the sheet"
        self.report(
            audit,
            Severity.WARNING,
            request.slave,
            label,
            (count.first, ref),
            f"{action} of {label} refused 0x{code:02X} ({meaning}) {count.n} times",
            float(count.n),
            self.advice(request),
        )
