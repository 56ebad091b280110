"""``comm-watchdog``: the longest silence towards a drive near its communication timeout (F08.02)."""

from __future__ import annotations

from ...drive.profile import Profile
from ...wire.protocol import BROADCAST
from ..findings import FrameRef, Severity
from ..limits import Limits
from ..state import _Drive, _Request
from ..window import Window
from .base import Rule

__all__ = ["CommWatchdogRule"]


class CommWatchdogRule(Rule):
    """The longest silence towards each drive (a broadcast feeds every drive's timer), against its F08.02 as the
    profile gives it, a state file told, or the master wrote it."""

    id = "comm-watchdog"
    title = "longest silence towards a drive near its comm timeout"
    source = "profile F08.02"

    def source_for(self, profile: Profile) -> str:
        # an instance's: a compiled (mypyc) dataclass has no class-level default
        return f"{self.source} (its margin {Limits().watchdog_margin:g} assumed)"

    def request(self, audit: Window, request: _Request, seq: int, t: float) -> None:
        slave = request.slave
        if slave == BROADCAST:
            drives = audit.drives
            for address in list(drives):
                self._silence(audit, drives[address], address, seq, t)
        else:
            drive = audit.drives.get(slave)
            self._silence(audit, drive if drive is not None else audit.drive(slave), slave, seq, t)

    def _silence(self, audit: Window, drive: _Drive, address: int, seq: int, t: float) -> None:
        last = drive.last_t
        drive.last_t, last_seq, drive.last_seq = t, drive.last_seq, seq
        if last is None or drive.comm_timeout <= 0.0:
            return
        gap = t - last
        if gap <= drive.longest:
            return
        drive.longest = gap
        ratio = gap / drive.comm_timeout
        if ratio < audit.limits.watchdog_margin:
            return
        tripped = ratio > 1.0
        self.report(
            audit,
            Severity.ERROR if tripped else Severity.WARNING,
            address,
            "",
            (FrameRef(last_seq, last), FrameRef(seq, t)),
            f"longest silence {gap:.2f} s is {100 * ratio:.0f} % of the communication timeout "
            f"F08.02 = {drive.comm_timeout:g} s" + (": the drive trips CE" if tripped else ""),
            100.0 * ratio,
            "talk to the drive well within its timeout (a poll at most half of F08.02 apart), or raise F08.02",
        )
