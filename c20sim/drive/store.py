"""A drive that stores what it is told and reports stopped: no physics.

It keeps the RAM registers and the function codes, computes the status words
from its settings, and reads 0 for every measurement. The behavioural model
(:mod:`c20sim.drive.model`) replaces it behind the same :class:`DrivePort`.
"""

from __future__ import annotations

from ..wire.registers import FIXED_REGISTERS, Reg
from .params import ParameterStore
from .profile import Profile

__all__ = ["RegisterStoreDrive"]

#: Registers held in RAM (not function codes): they read back what was written.
RAM_REGISTERS = (Reg.COMMAND, Reg.SPEED_SETPOINT, Reg.VIRTUAL_INPUTS, Reg.VIRTUAL_OUTPUTS, Reg.WRITE_ENABLE)

STATUS_STOPPED = 3
STATUS2_BUS_ESTABLISHED = 0x0001


class RegisterStoreDrive:
    """A :class:`~c20sim.drive.base.DrivePort` that stores values and never runs."""

    def __init__(self, profile: Profile) -> None:
        self.profile = profile
        self.parameters = ParameterStore(profile)
        self.ram: dict[int, int] = dict.fromkeys(RAM_REGISTERS, 0)
        self.t = 0.0

    def advance_to(self, t: float) -> None:
        self.t = max(self.t, t)

    def communicated(self, t: float) -> None:
        return None

    @property
    def running(self) -> bool:
        return False

    def read(self, address: int) -> int:
        if address in self.ram:
            return self.ram[address]
        if address in self.parameters:
            return self.parameters.get(address)
        if address == Reg.STATUS1:
            return STATUS_STOPPED
        if address == Reg.STATUS2:
            channel = self.parameters.get(Reg.RUN_CHANNEL)
            return STATUS2_BUS_ESTABLISHED | (channel & 0b11) << 5
        if address == Reg.DRIVE_ID:
            return 0x0020
        if address == Reg.SOFTWARE_VERSION:
            return self.profile.software_version
        if address in FIXED_REGISTERS:
            return 0
        raise KeyError(address)

    def check_write(self, address: int, value: int) -> None:
        return None

    def write(self, address: int, value: int) -> None:
        if address == Reg.RESTORE_DEFAULTS:
            if value == 1:
                self.parameters.restore_defaults()
            return
        if address in self.ram:
            self.ram[address] = value
        else:
            self.parameters.set(address, value)

    def write_ram(self, address: int, value: int) -> None:
        self.parameters.set_ram(address, value)
