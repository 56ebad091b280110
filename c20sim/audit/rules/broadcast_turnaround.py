"""``broadcast-turnaround``: a request too soon after a broadcast."""

from __future__ import annotations

from ...drive.profile import Profile
from ...wire.protocol import BROADCAST
from ..findings import FrameRef, Severity
from ..window import Window
from .base import Rule

__all__ = ["BroadcastTurnaroundRule"]


class BroadcastTurnaroundRule(Rule):
    """A request sooner after a broadcast than the drive's turnaround delay (the profile's broadcast_delay_ms)."""

    id = "broadcast-turnaround"
    title = "a request too soon after a broadcast"
    source = "Modbus over Serial Line 2.4.1"

    def source_for(self, profile: Profile) -> str:
        return f"{self.source} (broadcast_delay_ms = {profile.protocol.broadcast_delay_ms:g}, assumed)"

    def gap(self, audit: Window, seq: int, t: float, data: bytes) -> None:
        last = audit.pending
        if last is None or last.slave != BROADCAST:
            return
        gap = t - audit.pending_t
        if gap < audit.broadcast_delay:
            self.report(
                audit,
                Severity.WARNING,
                None,
                "",
                (audit.pending_ref(), FrameRef(seq, t)),
                f"a request {gap * 1000:.1f} ms after a broadcast; the drive needs "
                f"{audit.broadcast_delay * 1000:.0f} ms (the profile's broadcast_delay_ms)",
                gap,
                "wait the turnaround delay after every broadcast before the next request",
            )
