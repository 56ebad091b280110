"""The behavioural C20: state machine, ramps, motor, DC bus, heat and faults, in virtual time.

The model never reads a clock. :meth:`Drive.advance_to` integrates in fixed
steps of :data:`STEP` from the last step to ``t``, so the state at a time does
not depend on how often anyone looks; reads never change it. A settled drive
skips ahead in closed form, bit for bit as if it had stepped.

The drive behaves as an INVT-family drive does where it matters for trips
(see the integrator): current limiting holds the ramp where the speed loop
would ask more than its level, overcurrent trips on the current the loop asks
(limiting off, or a load step faster than the limit), overvoltage stall
prevention regulates the braking current to hold the bus at its level, overload curves have thermal
memory, 3006H is measured from the Hall edges.

Faults are causes: each protection watches a physical condition, trips by a
transition of the state table with the profile's code, and the latch is
released by fault reset only once the cause is gone. Conditions are set by
the injection methods (``set_supply_voltage``, ``set_load_torque``, ...), at
the drive's current time: call :meth:`Drive.advance_to` first.

:class:`Drive` is a composition, one part a job: the bench's conditions and
the settings derived from them (:mod:`~c20sim.drive.config`), the integrator
with its steady segments (:mod:`~c20sim.drive.integrator`), the Hall sensors
(:mod:`~c20sim.drive.sensors`), the state machine's protections and guards
(:mod:`~c20sim.drive.protection`, beside the table in
:mod:`~c20sim.drive.statemachine`), the register face
(:mod:`~c20sim.drive.face`) and telemetry (:mod:`~c20sim.drive.telemetry`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ..wire.registers import SpeedSource
from . import face, faultrecord
from .bench import BenchSetters
from .config import (
    CHANNEL_KEYPAD,
    F_COMM_ACTION,
    F_COMM_TIMEOUT,
    F_CURRENT_LIMIT_LEVEL,
    F_CURRENT_LIMITING,
    F_MOTOR_OVERLOAD_COEFFICIENT,
    F_OV_STALL,
    Conditions,
    Config,
    configure,
    limit_speed,
)
from .counters import F_POWER_ON_HOURS, F_RUNNING_HOURS, Counters
from .integrator import Integrator
from .params import ParameterStore
from .physics import STEP
from .plc import F_STAGE_TIME, Plc
from .profile import FaultCause, Profile
from .protection import Machine
from .sensors import Hall, HallFault
from .statemachine import DRIVEN, RUN_COMMANDS, Event, State
from .telemetry import Telemetry, snapshot

#: The states in which the simple PLC runs its programme (a jog or a stop is not a programme's run).
PLC_RUNS = frozenset({State.FORWARD, State.REVERSE})

__all__ = [
    "F_COMM_ACTION",
    "F_COMM_TIMEOUT",
    "F_CURRENT_LIMITING",
    "F_CURRENT_LIMIT_LEVEL",
    "F_MOTOR_OVERLOAD_COEFFICIENT",
    "F_OV_STALL",
    "STEP",
    "Drive",
    "HallFault",
    "Telemetry",
]


class Drive(BenchSetters):
    """A ZBLD.C20 brushless drive in virtual time; a :class:`~c20sim.drive.base.DrivePort`.

    Its parts: ``bench`` (the conditions as set), ``hall``, ``motion`` (the integrator and its config),
    ``machine`` (state, fault latch, protections, guards) and ``ram``, which the face reads as registers.
    """

    profile: Profile
    parameters: ParameterStore
    t0: float
    t: float
    bench: Conditions
    hall: Hall
    motion: Integrator
    machine: Machine
    ram: dict[int, int]

    def __init__(self, profile: Profile, *, t0: float = 0.0, state_path: str | Path | None = None) -> None:
        self.profile = profile
        self.parameters = ParameterStore(profile, state_path)
        self.t0 = float(t0)
        self.t = self.t0
        self.bench = Conditions(supply=profile.supply.voltage_v, ambient=profile.thermal.ambient_c)
        self.hall = Hall()
        self.motion = Integrator(profile, self.bench, self.hall, self.t0)
        self.machine = Machine(profile, self.motion, self.hall, self.t0)
        self.plc = Plc()
        #: the PLC stage times' scale (s per count); 0 where the profile has no simple PLC programme
        self._plc_scale = profile.registers[F_STAGE_TIME[0]].scale if F_STAGE_TIME[0] in profile.defaults else 0.0
        if faultrecord.has_record(profile.defaults):
            self.machine.on_trip = self._record_trip
        #: the power-on and running hours (F07.13, F07.14), where the profile has them
        self.counters: Counters | None = None
        if F_POWER_ON_HOURS in profile.defaults and F_RUNNING_HOURS in profile.defaults:
            self.counters = Counters(self.parameters.get, self.parameters.record)
            self.machine.on_drive = self._driven
        self._power_up()

    # --- DrivePort.

    def advance_to(self, t: float) -> None:
        """Integrate to time ``t`` (seconds); earlier times are ignored."""
        if t <= self.t:
            return
        self.t = t
        target = int((t - self.t0) / STEP + 1e-6)
        motion, machine, plc, counters = self.motion, self.machine, self.plc, self.counters
        while motion.k < target:
            if motion.segment is not None:
                if motion.advance_segment(target, self._due):
                    machine.protect()
                    machine.auto_events()
                    self._plc_watch()
                    self._count()
                    motion.segment = None
            else:
                state = machine.state
                motion.step(state)
                machine.protect()
                machine.auto_events()
                if plc.active or motion.cfg.source == SpeedSource.SIMPLE_PLC:
                    self._plc_watch()
                if counters is not None and motion.k >= counters.mark:
                    counters.tick(motion.k)
                if machine.state is state:
                    self._try_segment()

    def communicated(self, t: float) -> None:
        self.machine.last_comm = t

    @property
    def running(self) -> bool:
        """True while the inverter drives the motor (W/R* registers are locked)."""
        return self.machine.state in DRIVEN

    @property
    def state(self) -> State:
        """What the drive is doing."""
        return self.machine.state

    def read(self, address: int) -> int:
        return face.read(self, address)

    def check_write(self, address: int, value: int) -> None:
        face.check_write(self, address, value)

    def write(self, address: int, value: int) -> None:
        face.write(self, address, value)

    def write_ram(self, address: int, value: int) -> None:
        face.write(self, address, value, ram_only=True)

    # --- Local controls and injection.

    def keypad(self, command: int) -> bool:
        """Press a keypad key (a 2000H command value). False if refused.

        Run and jog keys work only with the keypad run channel (F00.01 = 0);
        stop, free stop and fault reset work from any channel (assumed). A
        reset is refused while the fault's cause persists.
        """
        event = Event(command)
        if event in RUN_COMMANDS and self._cfg.channel != CHANNEL_KEYPAD:
            return False
        self.motion.segment = None
        if event is Event.RESET:
            return self.machine.reset()
        self.machine.apply(event)
        return True

    # --- Read-outs of the conditions set by injection (telemetry has supply, load, inertia, ambient).

    @property
    def physical_inputs(self) -> int:
        """The physical input terminals as set (300DH and telemetry add the virtual ones, 200AH)."""
        return self.bench.physical_inputs

    @property
    def hall_fault(self) -> HallFault | None:
        """The Hall sensor fault injected, or None if the sensor is sound."""
        return self.hall.fault

    def ai(self, channel: int) -> float:
        """Analog input 1, 2 or 3 as set (V)."""
        if channel not in (1, 2, 3):
            raise ValueError(f"analog input must be 1, 2 or 3, not {channel}")
        return self.bench.ai[channel - 1]

    def cause_present(self, cause: FaultCause) -> bool:
        """Whether the condition that trips ``cause`` is there now, whoever set it; the reset may still be
        refused while the fault outlasts it (a hot module, a bus still low)."""
        return self.machine.present(cause)

    @property
    def held_fault(self) -> int | None:
        """The code of a fault forced with ``persistent`` and not yet released (resets fail), else None."""
        return self.machine.held_fault

    def force_fault(self, code: int, *, persistent: bool = False) -> None:
        """Latch fault ``code`` now; with ``persistent`` a reset fails until :meth:`release_fault`."""
        if not 1 <= code <= 0xFF:
            raise ValueError(f"fault code must be 1-255, not {code}")
        self.motion.segment = None
        self.machine.force(code, persistent)

    def release_fault(self) -> None:
        """The cause of a persistent forced fault is gone (a reset is still needed)."""
        self.machine.forced_hold = False

    def power_cycle(self) -> None:
        """Switch the drive off and on: RAM registers and faults clear, the EEPROM stays."""
        self._power_up()

    def telemetry(self) -> Telemetry:
        return snapshot(self)

    # --- The composition's own.

    @property
    def _cfg(self) -> Config:
        return self.motion.cfg

    @property
    def _k(self) -> int:
        """The number of the last internal step taken."""
        return self.motion.k

    def _power_up(self) -> None:
        self.ram = dict.fromkeys(face.RAM_REGISTERS, 0)
        self.plc = Plc()
        self.parameters.power_up()  # RAM-only function-code writes are lost
        self._reconfigure()
        self.motion.power_up()
        self.hall.reset()
        self.machine.power_up()
        if self.counters is not None:
            self.counters.power_up(self.motion.k)
        self._try_segment()

    def _due(self, k: int) -> bool:
        """Whether the drive does something by itself by step ``k``: a steady segment stops there."""
        counters = self.counters
        return self.machine.due(k) or self.plc.due(k) or (counters is not None and counters.due(k))

    def _driven(self, on: bool) -> None:
        if self.counters is not None:
            self.counters.driven(self.motion.k, on)

    def _count(self) -> None:
        """The hour counters, at their whole hours."""
        counters = self.counters
        if counters is not None and counters.due(self.motion.k):
            counters.tick(self.motion.k)

    def _plc_watch(self) -> None:
        """The simple PLC (speed source 6): its start with a run, its stages, its end, its reset with a stop."""
        plc, cfg, machine = self.plc, self.motion.cfg, self.machine
        if cfg.source != SpeedSource.SIMPLE_PLC or machine.state not in PLC_RUNS:
            if plc.active:
                plc.reset()
                self._reconfigure()
            return
        get, k = self.parameters.get, self.motion.k
        if not plc.active:
            plc.start(k, get, self._plc_scale)
            self._reconfigure()
        elif plc.due(k):
            stop = plc.next_stage(k, get, self._plc_scale)
            self._reconfigure()
            if stop:
                machine.apply(Event.STOP)

    def _record_trip(self, code: int) -> None:
        """A trip with ``code``: the fault record shifts and keeps the state now, in EEPROM."""
        stored = self.parameters.stored()
        self.parameters.record(faultrecord.shifted(stored, code, self.read))

    def _changed(self) -> None:
        self.motion.segment = None
        self._reconfigure()

    def _reconfigure(self) -> None:
        """Derive the step's settings again from the parameters, RAM registers and conditions (and the simple
        PLC's stage, where it is the speed source)."""
        cfg = configure(self.profile, self.parameters, self.ram, self.bench)
        if cfg.source == SpeedSource.SIMPLE_PLC and self._plc_scale:
            speed = limit_speed(self.profile, self.plc.speed(self.parameters.get), cfg.max_rpm)
            cfg = dataclasses.replace(cfg, reference_rpm=speed)
        self.motion.cfg = cfg

    def _try_segment(self) -> None:
        self.motion.try_segment(self.machine.state)
