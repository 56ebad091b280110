"""``write-enable-left-on``: 200EH left at 1 after the function-code writes."""

from __future__ import annotations

from ..findings import Severity
from ..window import Window
from .base import Rule

__all__ = ["WriteEnableLeftOnRule"]


class WriteEnableLeftOnRule(Rule):
    """200EH still 1 ``enable_hold`` s after the last function-code write (or after its enabling, with none);
    said once per enabling."""

    id = "write-enable-left-on"
    title = "200EH left at 1 after the function-code writes"
    source = "sheet 200EH"

    def idle(self, audit: Window, t: float) -> None:
        for address in sorted(audit.enabled):
            drive = audit.drives[address]
            if drive.enable_ref is None:
                continue
            since = drive.last_fcode_write if drive.last_fcode_write is not None else drive.enable_ref.t
            if t - since >= audit.limits.enable_hold:
                self.report(
                    audit,
                    Severity.WARNING,
                    address,
                    "200EH",
                    (drive.enable_ref,),
                    f"200EH = 1 (function codes writable) left on {t - since:.1f} s after the last function-code write",
                    t - since,
                    "write 200EH = 0 after the function-code writes, so that a stray write cannot change a parameter",
                )
                drive.enable_ref = None  # said once per enabling
