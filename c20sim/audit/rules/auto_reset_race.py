"""``auto-reset-race``: a fault reset (2000H = 7) while the drive's own automatic reset (F08.28, F08.29) counts."""

from __future__ import annotations

from ...drive.profile import Profile
from ...wire.registers import Command, Reg, fcode_address
from ..findings import FrameRef, Severity
from ..window import Window
from ._fault import FaultSeen, _cell

__all__ = ["F_AUTO_RESET_INTERVAL", "F_AUTO_RESET_TRIALS", "AutoResetRaceRule"]

F_AUTO_RESET_TRIALS = fcode_address(8, 28)
F_AUTO_RESET_INTERVAL = fcode_address(8, 29)


class AutoResetRaceRule(FaultSeen):
    """A master resets a fault it saw sooner after it saw it than the drive's automatic reset interval (F08.29),
    while the drive has automatic resets (F08.28 > 0). The drive's settings: the profile's defaults, then what the
    master wrote (and the drive took) or read back."""

    id = "auto-reset-race"
    title = "fault reset (2000H = 7) while the drive's automatic reset counts down"
    source = (
        "INVT GD20 P08.28/P08.29 (automatic fault reset: the family's, assumed for the C20's F08.28/F08.29); "
        "sheet 2000H, 2102H; docs/faults.md"
    )

    watched = (F_AUTO_RESET_TRIALS, F_AUTO_RESET_INTERVAL)

    def __init__(self) -> None:
        super().__init__()
        #: what the master told or was told of each drive: F08.28 (trials), F08.29 (seconds)
        self.trials: dict[int, int] = {}
        self.interval: dict[int, float] = {}

    def source_for(self, profile: Profile) -> str:
        return f"{self.source} (F08.28 = {profile.defaults.get(F_AUTO_RESET_TRIALS, 0)} as the profile ships it)"

    def _setting(self, audit: Window, slave: int) -> tuple[int, float]:
        """The drive's F08.28 (trials) and F08.29 (seconds), as followed."""
        defaults = audit.profile.defaults
        trials = self.trials.get(slave, defaults.get(F_AUTO_RESET_TRIALS, 0))
        interval = self.interval.get(slave)
        if interval is None:
            interval = defaults.get(F_AUTO_RESET_INTERVAL, 0) * _scale(audit)
        return trials, interval

    def judges(self, register: int, value: int) -> bool:
        return register == Reg.COMMAND and value == Command.RESET

    def written(self, audit: Window, slave: int, register: int, value: int, seq: int, t: float) -> None:
        seen = self.seen.get(slave)
        if seen is None:
            return
        trials, interval = self._setting(audit, slave)
        since = t - seen.ref.t
        if trials <= 0 or since >= interval:
            return
        fault = f"fault 0x{seen.code:02X}" if seen.code else "the fault (2100H = 4)"
        self.report(
            audit,
            Severity.WARNING,
            slave,
            "2000H",
            (seen.ref, FrameRef(seq, t)),
            f"fault reset 2000H = 7 sent {since:.2f} s after the master saw {fault}, within the automatic reset "
            f"interval F08.29 = {interval:g} s (F08.28 = {trials})",
            since,
            "with F08.28 > 0 the drive resets the fault itself F08.29 after the trip: wait that long (and read the "
            "fault record) before a reset of its own; an early reset races the drive and gives its trials back, so "
            "a fault that recurs is never left standing",
            bump=True,
        )

    def stored(self, audit: Window, slave: int, register: int, value: int) -> None:
        self._follow(audit, slave, register, (value,))

    def looked(self, audit: Window, slave: int, register: int, values: tuple[int, ...], ref: FrameRef) -> None:
        self._follow(audit, slave, register, values)

    def _follow(self, audit: Window, slave: int, register: int, values: tuple[int, ...]) -> None:
        trials = _cell(register, values, F_AUTO_RESET_TRIALS)
        if trials is not None and len(self.trials) < 256:
            self.trials[slave] = trials
        interval = _cell(register, values, F_AUTO_RESET_INTERVAL)
        if interval is not None and len(self.interval) < 256:
            self.interval[slave] = interval * _scale(audit)


def _scale(audit: Window) -> float:
    """F08.29's scale to seconds (0.1 s in the shipped profiles)."""
    spec = audit.profile.registers.get(F_AUTO_RESET_INTERVAL)
    return spec.scale if spec is not None else 0.1
