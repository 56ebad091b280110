"""``answer-delay-timeout``: a master that gives up on a reply sooner than the drive's answer delay (F08.04)."""

from __future__ import annotations

from ...drive.profile import Profile
from ...wire.protocol import BROADCAST
from ...wire.registers import fcode_address
from ..findings import FrameRef, Severity
from ..limits import _EPSILON
from ..state import _Request
from ..window import Window
from ._fault import _cell
from .base import Rule

__all__ = ["F_ANSWER_DELAY", "AnswerDelayTimeoutRule"]

F_ANSWER_DELAY = fcode_address(8, 4)


class AnswerDelayTimeoutRule(Rule):
    """A request to a drive left unanswered, and the master's next request sent before the reply could have
    finished with the drive's answer delay (F08.04: the reply starts no sooner than that after the request): the
    master's timeout is shorter than the delay, so it never takes a reply. The delay: the profile's default, then
    what the master wrote (and the drive took) or read back."""

    id = "answer-delay-timeout"
    title = "gives up on a reply sooner than the drive's answer delay (F08.04)"
    source = (
        "INVT GD20 P14.03 (communication response delay: the family's, assumed for the C20's F08.04); "
        "Modbus over Serial Line V1.02 2.4.1 (the response timeout)"
    )

    def __init__(self) -> None:
        self.delay: dict[int, int] = {}  #: F08.04 of each drive, raw, as followed

    def source_for(self, profile: Profile) -> str:
        return f"{self.source}; the profile's F08.04 = {profile.defaults.get(F_ANSWER_DELAY, 0)}"

    def _seconds(self, audit: Window, slave: int) -> float:
        raw = self.delay.get(slave, audit.profile.defaults.get(F_ANSWER_DELAY, 0))
        spec = audit.profile.registers.get(F_ANSWER_DELAY)
        return raw * (spec.scale if spec is not None else 1.0) / 1000.0

    def request(self, audit: Window, request: _Request, seq: int, t: float) -> None:
        last = audit.previous
        if last is None or last.slave == BROADCAST or audit.previous_reply is not None:
            return
        delay = self._seconds(audit, last.slave)
        if delay <= audit.turnaround:
            return
        need = last.cost - audit.turnaround + delay  # the reply starts the delay after the request, not sooner
        waited = t - audit.previous_t
        if waited >= need - _EPSILON:
            return
        self.report(
            audit,
            Severity.ERROR,
            last.slave,
            "F08.04",
            (FrameRef(audit.previous_seq, audit.previous_t), FrameRef(seq, t)),
            f"a request {1000 * waited:.1f} ms after an unanswered one, whose reply could not have finished before "
            f"{1000 * need:.1f} ms: the answer delay F08.04 = {1000 * delay:g} ms is longer than the master waits",
            waited,
            "wait for a reply at least the answer delay (F08.04) plus the transaction's line time, or set F08.04 "
            "lower (0: the drive's own turnaround)",
            bump=True,
        )

    def stored(self, audit: Window, slave: int, register: int, value: int) -> None:
        if register == F_ANSWER_DELAY and len(self.delay) < 256:
            self.delay[slave] = value

    def watches(self, register: int, count: int) -> bool:
        return register <= F_ANSWER_DELAY < register + count

    def read(self, audit: Window, slave: int, register: int, values: tuple[int, ...], seq: int, t: float) -> None:
        value = _cell(register, values, F_ANSWER_DELAY)
        if value is not None and len(self.delay) < 256:
            self.delay[slave] = value
