"""The bench around a drive: what a test bench sets on it (supply, loads, ambient, Hall sensor, analog inputs,
dial switches, input terminals), each a physical condition the model then answers to by its own physics.

:class:`BenchSetters` is a part of :class:`~c20sim.drive.model.Drive` (its conditions' setters); the
conditions' rows (:data:`c20sim.drive.conditions.CONDITIONS`), and through them the operations and the dashboard, set
conditions through it.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from .config import Conditions, Config
from .sensors import Hall, HallFault

if TYPE_CHECKING:
    from .protection import Machine

__all__ = ["BenchSetters"]


class BenchSetters:
    """The conditions' setters of a drive (a mixin of :class:`~c20sim.drive.model.Drive`)."""

    bench: Conditions
    hall: Hall
    machine: Machine

    @property
    def _cfg(self) -> Config:
        raise NotImplementedError  # the drive's

    def _changed(self) -> None:
        raise NotImplementedError  # the drive's

    def set_supply_voltage(self, volts: float) -> None:
        """The supply behind the DC bus (0 = switched off)."""
        self.bench.supply = max(0.0, float(volts))
        self._changed()

    def set_load_torque(self, nm: float) -> None:
        """Load torque on the shaft, opposing motion (N m)."""
        self.bench.load = max(0.0, float(nm))
        self._changed()

    def set_active_load(self, nm: float) -> None:
        """Signed load torque that acts whatever the motion (a hoist's weight), N m; positive pushes forward.

        Unlike :meth:`set_load_torque` it can drive the rotor: a forward run
        with a positive active load regenerates, and a held load draws current.
        """
        nm = float(nm)
        if not math.isfinite(nm):
            raise ValueError(f"active load must be a finite torque in N m, not {nm}")
        self.bench.active = nm
        self._changed()

    @property
    def active_load(self) -> float:
        """The signed active load torque as set (N m)."""
        return self.bench.active

    def set_load_inertia(self, kg_m2: float) -> None:
        """Inertia coupled to the shaft, added to the profile's (kg m^2)."""
        self.bench.load_inertia = max(0.0, float(kg_m2))
        self._changed()

    def set_ambient(self, celsius: float) -> None:
        self.bench.ambient = float(celsius)
        self._changed()

    def set_hall_fault(self, fault: HallFault | str | None) -> None:
        """Break the Hall sensor ('stuck0', 'stuck7', 'sequence') or mend it (None)."""
        self.hall.fault = None if fault is None else HallFault(fault)
        self._changed()

    def set_ai(self, channel: int, volts: float) -> None:
        """Analog input 1, 2 or 3 (0-10 V; AI1 is the knob)."""
        if channel not in (1, 2, 3):
            raise ValueError(f"analog input must be 1, 2 or 3, not {channel}")
        self.bench.ai[channel - 1] = min(max(float(volts), 0.0), 10.0)
        self._changed()

    @property
    def dial_switches(self) -> tuple[bool, bool, bool]:
        """The dial switches (SW1, SW2, SW3) as set; True is on."""
        return self.bench.dial

    def set_dial_switches(self, sw1: bool, sw2: bool, sw3: bool) -> None:
        """Set the dial switches SW1-SW3; they act where 2005H = 3, 2006H = 3 or 2007H = 5 select them.

        SW1 (2005H = 3) picks the control mode (on: open loop, off: closed loop; assumed); SW3 (2006H = 3)
        the run channel; SW2 and SW3 (2007H = 5) the speed source: see
        :data:`~c20sim.drive.config.DIAL_SPEED_SOURCE`.
        """
        self.bench.dial = (bool(sw1), bool(sw2), bool(sw3))
        self._changed()

    def set_extra(self, name: str, value: object) -> None:
        """A condition of a row with no setter of its own (:mod:`c20sim.drive.conditions`), kept by its name."""
        self.bench.extra[name] = value
        self._changed()

    def set_terminal_inputs(self, bits: int) -> None:
        """The physical input terminals (bits of :class:`~c20sim.drive.terminals.Input`)."""
        before = self._cfg.inputs
        self.bench.physical_inputs = int(bits) & 0x1FF
        self._changed()
        self.machine.inputs_changed(before)
