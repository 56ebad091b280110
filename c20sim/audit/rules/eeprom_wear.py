"""``eeprom-wear``: a function code (EEPROM) written cyclically."""

from __future__ import annotations

from ...drive.profile import Profile
from ...wire.registers import address_label
from ..findings import Severity
from ..window import Window
from .base import Rule

__all__ = ["EepromWearRule"]


class EepromWearRule(Rule):
    """The stores of one function code an hour against the EEPROM's rated endurance (the profile's
    eeprom_endurance_writes): an error if it is reached within ``wear_error_h``, a warning within
    ``wear_warning_h``."""

    id = "eeprom-wear"
    title = "writes a function code (EEPROM) cyclically"
    source = "INVT Goodrive350 9.4.5.1; profile"

    def source_for(self, profile: Profile) -> str:
        return f"{self.source} (eeprom_endurance_writes = {profile.protocol.eeprom_endurance_writes:,}, assumed)"

    def stored(self, audit: Window, slave: int, register: int, value: int) -> None:
        count = audit.count((self.id, slave, register, 0))
        if count is None:
            return
        count.n += 1
        count.same_value = count.same_value and (count.value in (-1, value))
        count.value = value
        count.first = count.first or audit.pending_ref()
        count.last = audit.pending_ref()
        limits = audit.limits
        if count.n < limits.cyclic_writes:
            return
        span = count.last.t - count.first.t
        if span <= 0.0:
            return
        per_hour = (count.n - 1) / span * 3600.0
        hours = audit.endurance / per_hour
        if hours >= limits.wear_warning_h:
            return
        label = address_label(register)
        ram = register | 0x8000
        same = "the same value each time; " if count.same_value else ""
        self.report(
            audit,
            Severity.ERROR if hours < limits.wear_error_h else Severity.WARNING,
            slave,
            label,
            (count.first, count.last),
            f"{label} stored {per_hour:,.0f} times an hour ({same}{count.n} writes): rated "
            f"{audit.endurance:,} writes reached in {_duration(hours)}",
            per_hour,
            f"write {label} only when it changes; a value that changes all the time belongs in RAM: "
            f"2001H for the speed reference, or {ram:04X}H ({label}, RAM only) where the drive has the "
            "INVT family's RAM-only addresses",
        )


def _duration(hours: float) -> str:
    if hours < 1.0:
        return f"{hours * 60:.0f} min"
    if hours < 48.0:
        return f"{hours:.1f} h"
    if hours < 24 * 365:
        return f"{hours / 24:.0f} days"
    return f"{hours / 8760:.1f} years"
