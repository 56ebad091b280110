"""One drive of the test handle (:class:`c20sim.testing.C20Sim`): its state, registers, fault record, conditions
and device faults, each an operation of the control layer run on the handle's serving thread.

Split from testing.py (issue 42) when the fault record's read grew it past 600 lines; ``c20sim.testing``
exports it as before.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol, TypeVar

from .control import causes, ops
from .core.simulator import Simulator
from .drive import faultrecord
from .drive.model import Telemetry

__all__ = ["DriveHandle"]

T = TypeVar("T")


class Owner(Protocol):
    """What a drive's handle asks of the test handle that made it (:class:`c20sim.testing.C20Sim`)."""

    def _op(self, fn: Callable[..., T], *args: Any) -> T: ...

    def link_faults(self, drive: int | None = None, **switches: object) -> dict[str, Any]: ...


class DriveHandle:
    """One drive of a :class:`C20Sim`: its state, registers, conditions and device faults."""

    def __init__(self, owner: Owner, address: int) -> None:
        self._owner = owner
        self.address = address

    def __repr__(self) -> str:
        return f"<c20sim drive {self.address}>"

    def state(self) -> Telemetry:
        """Telemetry now (speed, bus voltage, state, fault, ...)."""

        def telemetry(sim: Simulator) -> Telemetry:
            found = ops.drive(sim, self.address)
            sim.sync()
            return found.telemetry()

        return self._owner._op(telemetry)

    def read(self, register: str | int) -> int:
        """A register's raw value, as a master reads it (``2100H``, ``0x2100``, ``F00.10`` or ``status1``)."""
        value: int = self._owner._op(ops.read_register, self.address, register)["raw"]
        return value

    def fault_record(self) -> dict[str, Any]:
        """The fault record (F07.27-F07.48) as an alarm screen reads it: ``faults`` (six codes, newest first),
        ``at_fault`` and ``at_previous`` (running_hz, ramp_hz, output_v, current_a, bus_v, temperature_c, inputs,
        outputs). Read through the registers, as a master reads them."""

        def record(sim: Simulator) -> dict[str, Any]:
            found = ops.drive(sim, self.address)
            sim.sync()
            return faultrecord.decode(found.read)

        return self._owner._op(record)

    def set(self, **conditions: object) -> None:
        """Set conditions now: ``supply_v``, ``load_torque_nm``, ``ambient_c``, ``hall_fault``, ...

        A continuous condition may be given a generator: ``set(supply_v={"ramp": 30, "over": 5})``,
        ``{"sine": 2, "period": 0.5}`` or ``{"noise": 0.5, "seed": 1}`` (c20sim.core.generators).
        """
        self._owner._op(ops.set_conditions, self.address, conditions)

    def generators(self) -> dict[str, dict[str, Any]]:
        """The generators running on this drive's conditions, by condition."""
        return self._owner._op(ops.generators, self.address)

    def clear_generators(self, condition: str | None = None) -> None:
        """Stop the generator on ``condition`` (all for None); the conditions stay where they are."""
        self._owner._op(ops.clear_generators, self.address, condition)

    def inject_fault(self, code: int, *, persistent: bool = False) -> None:
        self._owner._op(causes.request, self.address, {"code": code, "persistent": persistent})

    def clear_fault(self, *, reset: bool = True) -> bool:
        """Release an injected fault and (with ``reset``) press reset; True if the drive left the fault."""
        return self._owner._op(ops.clear_fault, self.address, reset)

    def trip(self, cause: str) -> None:
        """Bring a fault's cause about (``undervoltage``, ``overheat``, ``eeprom``, ...); the drive trips by its model."""
        self._owner._op(causes.request, self.address, {"cause": cause})

    def release(self, cause: str) -> None:
        """End a fault's cause; the fault stays until reset."""
        self._owner._op(causes.release, self.address, cause)

    def conditions(self) -> dict[str, object]:
        """The conditions the drive is in now, by the names :meth:`set` takes."""
        return self._owner._op(ops.conditions, self.address)

    def press(self, key: str | int) -> bool:
        """Press a keypad key (``forward``, ``stop``, ``reset``, ... or a 2000H value); False if refused."""
        return self._owner._op(ops.press_key, self.address, key)

    def power_cycle(self) -> None:
        self._owner._op(ops.power_cycle, self.address)

    def link_faults(self, **switches: object) -> dict[str, Any]:
        return self._owner.link_faults(self.address, **switches)
