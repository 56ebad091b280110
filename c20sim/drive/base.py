"""The narrow interface between the Modbus slave and a drive model.

The slave owns the access rules of the register map (who may write what,
ranges, write enable, password); a drive owns values and state. Addresses
given to a drive are storage cells: a mirrored 20xxH register arrives as its
function code's address (:meth:`RegisterMap.canonical`).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

__all__ = ["DrivePort"]


@runtime_checkable
class DrivePort(Protocol):
    """What the slave needs of a drive: time, the running flag, reads and writes."""

    def advance_to(self, t: float) -> None:
        """Bring the drive to time ``t`` (seconds) before a request is served."""

    def communicated(self, t: float) -> None:
        """A valid request for this drive was served at ``t`` (feeds the communication timeout)."""

    @property
    def running(self) -> bool:
        """True while the motor is driven: W/R* registers are then locked (0x08)."""

    def read(self, address: int) -> int:
        """Raw 16-bit value of a storage cell."""

    def check_write(self, address: int, value: int) -> None:
        """Raise ModbusError if the drive's state refuses this write (e.g. 0x04)."""

    def write(self, address: int, value: int) -> None:
        """Store a value that the slave has checked."""

    def write_ram(self, address: int, value: int) -> None:
        """Store a checked function-code value in RAM only (written at its RAM-only address, code | 8000H):
        it acts at once, is not saved to EEPROM, and is lost at power-off."""
