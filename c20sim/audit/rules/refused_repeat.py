"""``refused-repeat``: the same request refused again and again (any refusal no other rule claims).

Not a repeat after a refusal that says the request reached the drive damaged: the sheet's 0x06, data frame
error ("the length of data frame is incorrect or the CRC check bit of RTU format is incorrect", sheet 1.4), to
a request whose bytes were intact on the wire (a CRC that checks, the length of its function, a 0x10's byte
count twice its register count). The fault was then on the line, between the master and the drive, and asking
again is right: the drill's ``retries`` check (:mod:`c20sim.drill.checks`: a 0x06 reply is a failed request,
not a refusal) requires it, so the audit must not warn of what the drill demands. A 0x06 to a request that is
itself malformed comes back every time, and its repeats are counted.
"""

from __future__ import annotations

import struct

from ...wire.protocol import ExceptionCode, FunctionCode, expected_length
from ..state import _Request
from ..window import Window
from ._refusal import RefusalRule

__all__ = ["RETRIED", "RefusedRepeatRule", "intact"]

#: The exception codes that, to an intact request, say it was damaged on the line: asking again is right (the
#: drill's ``retries`` check requires it after each; tests/unit/test_audit_refusals.py holds the two together).
RETRIED = frozenset({ExceptionCode.FRAME_ERROR})


def intact(request: bytes) -> bool:
    """The request's bytes are a whole frame of its function (its CRC is checked before a rule hears of it):
    the length its function code gives, and a 0x10's byte count twice its register count."""
    if len(request) < 4 or expected_length(request, "request") != len(request):
        return False
    if request[1] == FunctionCode.WRITE_MULTIPLE:
        count: int = struct.unpack_from(">H", request, 4)[0]
        return request[6] == 2 * count
    return True


class RefusedRepeatRule(RefusalRule):
    """Any refusal no other rule claims, repeated; not a 0x06 to an intact request (a line fault: retried)."""

    id = "refused-repeat"
    title = "the same request refused again and again"
    source = "sheet 1.4"
    fallback = True

    def claims(self, audit: Window, request: _Request, code: int) -> bool:
        return code not in RETRIED or not intact(audit.pending_data)

    def advice(self, request: _Request) -> str:
        return "read the refusal: repeating the request gets the same answer"
