"""An example behaviours package: three quirks of a made-up C20 firmware and bench.

A real package declares them in its pyproject.toml::

    [project.entry-points."c20sim.behaviours"]
    quantised-speed = "c20_quirks:QuantisedSpeed"
    no-setpoint-in-fault = "c20_quirks:NoSetpointInFault"
    weak-supply = "c20_quirks:WeakSupply"

and a profile selects them by name, at its top::

    behaviours = ["quantised-speed", "no-setpoint-in-fault", "weak-supply"]

Each is a class called once per drive with the drive's bus address and the profile;
each defines only the hooks it needs (see c20sim.drive.behaviours).
"""

from __future__ import annotations

from c20sim.drive.model import Drive
from c20sim.drive.profile import Profile
from c20sim.wire.errors import ModbusError
from c20sim.wire.protocol import ExceptionCode

MOTOR_SPEED = 0x3006
SPEED_SETPOINT = 0x2001


class QuantisedSpeed:
    """The firmware reports the motor speed (3006H) rounded to 10 rpm."""

    def __init__(self, address: int, profile: Profile) -> None:
        self.address = address

    def on_read(self, drive: Drive, cell: int, value: int) -> int:
        return round(value / 10) * 10 if cell == MOTOR_SPEED else value


class NoSetpointInFault:
    """The firmware refuses a new speed setpoint (2001H) with exception 0x04 while a fault is latched."""

    def __init__(self, address: int, profile: Profile) -> None:
        pass

    def check_write(self, drive: Drive, cell: int, value: int) -> None:
        if cell == SPEED_SETPOINT and drive.telemetry().state == "fault":
            raise ModbusError(ExceptionCode.OPERATION_FAILED, "no setpoint while in fault")


class WeakSupply:
    """A bench supply that droops half a volt per amp the drive draws from it."""

    VOLTS_PER_AMP = 0.5

    def __init__(self, address: int, profile: Profile) -> None:
        self.nominal = profile.supply.voltage_v

    def on_step(self, drive: Drive, t: float) -> None:
        drive.set_supply_voltage(self.nominal - self.VOLTS_PER_AMP * max(0.0, drive.telemetry().current_a))
