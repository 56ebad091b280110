"""The behavioural C20: state machine, ramps, motor, DC bus, heat and faults, in virtual time.

The model never reads a clock. :meth:`Drive.advance_to` integrates in fixed
steps of :data:`STEP` from the last step to ``t``, so the state at a time does
not depend on how often anyone looks; reads never change it. When every input
is constant and the drive has settled (stopped, or running at its set speed
without the current limit), it enters a :class:`~c20sim.drive.physics.Segment`
whose closed forms give the state at any later step directly: an idle or
steady drive skips ahead at no cost, and bit for bit as if it had stepped.

The drive behaves as an INVT-family drive does where it matters for trips:
a speed loop of finite bandwidth (the ramp's torque fed forward, a PI on the
rest) drives a current clamped at the current limit; overcurrent trips on the
current the loop asks before the limit acts (a too-short ramp of a heavy
load), not on load torque; overvoltage stall prevention (F11.03/F11.04) holds
the ramp while braking would lift the bus above its level; the motor and the
drive each have an inverse-time overload curve with thermal memory (F02.27
scales the motor's); inverter losses and so heating come from the current;
the bus has an undervoltage recover level; loads can be passive (opposing
motion) or active (signed, such as a hoist's weight); 3006H is measured from
the Hall edges and 3009H from the rotor's angle at the moment it is read.

Faults are causes: each protection watches a physical condition, trips by a
transition of the state table with the profile's code, and the latch is
released by fault reset only once the cause is gone. Conditions are set by
the injection methods (``set_supply_voltage``, ``set_load_torque``, ...), at
the drive's current time: call :meth:`Drive.advance_to` first.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

from ..wire.errors import ModbusError
from ..wire.protocol import ExceptionCode
from ..wire.registers import FIXED_REGISTERS, RUN_CHANNELS, Reg, RunChannel, SpeedSource, fcode_address
from . import physics
from .params import ParameterStore
from .physics import ACCEL, CONSTANT, DECEL, RPM, Segment
from .profile import FaultCause, Profile
from .statemachine import DRIVEN, STATUS_WORD, Event, State, next_state
from .terminals import Input, Output, multi_speed_index

__all__ = ["STEP", "Drive", "HallFault", "Telemetry"]

#: The fixed internal step, seconds.
STEP = 0.001

#: Registers held in RAM (not function codes): they read back what was written; a power cycle clears them.
RAM_REGISTERS = (Reg.COMMAND, Reg.SPEED_SETPOINT, Reg.VIRTUAL_INPUTS, Reg.VIRTUAL_OUTPUTS, Reg.WRITE_ENABLE)

DRIVE_ID = 0x0020
STATUS2_BUS = 0x0001
STATUS2_OVERLOAD = 0x0010

# Function codes the model reads beyond the mirrored ones (absent in a profile: the [motor] value is used).
F_MAX_SPEED = fcode_address(0, 3)
F_KEYPAD_SPEED = fcode_address(0, 10)
F_JOG_SPEED = fcode_address(0, 13)
F_COMM_TIMEOUT = fcode_address(8, 2)
F_COMM_ACTION = fcode_address(8, 3)
F_MULTI_SPEED = fcode_address(5, 0)
F_MOTOR_OVERLOAD_COEFFICIENT = fcode_address(2, 27)
F_OV_STALL = fcode_address(11, 3)
F_OV_STALL_LEVEL = fcode_address(11, 4)

#: F08.03, the action on a communication timeout (INVT GD20 P14.03).
COMM_TRIP, COMM_CONTINUE, COMM_STOP, COMM_STOP_ANY = 0, 1, 2, 3

CHANNEL_KEYPAD, CHANNEL_TERMINAL, CHANNEL_COMM = RunChannel.KEYPAD, RunChannel.TERMINALS, RunChannel.COMMUNICATION
# The dial switches SW1-SW3 (sheet: 2005H "3: dial switch setting (SW1 valid), model related", 2006H "3: dial
# switch setting (SW3 valid)", 2007H "5: dial switch setting (SW2, SW3 valid)"). What each position selects is
# not in the sheet: assumed, each switch on or off.
#: 2006H = 3: SW3 on takes run commands from the terminals, off from the keypad (assumed).
CHANNEL_DIAL = RunChannel.DIAL_SWITCH
#: 2007H = 5: (SW2, SW3) select the speed source: keypad, AI1 knob, AI2 voltage, multi-segment (assumed).
SOURCE_DIAL = SpeedSource.DIAL_SWITCH
DIAL_SPEED_SOURCE = {(False, False): 0, (True, False): 1, (False, True): 2, (True, True): 4}
RUN_COMMANDS = frozenset({Event.FORWARD, Event.REVERSE, Event.JOG_FORWARD, Event.JOG_REVERSE})
RUNNING = frozenset({State.FORWARD, State.REVERSE, State.JOG_FORWARD, State.JOG_REVERSE})
#: States in which a bus below the undervoltage level trips (fault 0x0A) instead of powering off.
TRIPS_ON_UNDERVOLTAGE = RUNNING | {State.DECELERATING}
#: Speed errors below this (rpm) while running at a constant set speed are settled: the loop is at rest.
SETTLED_RPM = 1e-6
#: Stopping on the ramp, the drive takes the rotor as stopped below this speed (rpm; assumed).
ZERO_RPM = 1.0
#: 3006H reads 0 when no Hall edge came for this long (s; assumed): 25 rpm at 4 pole pairs.
HALL_TIMEOUT = 0.1

_BY_PHASE = {
    "overcurrent": {
        ACCEL: FaultCause.OVERCURRENT_ACCEL,
        DECEL: FaultCause.OVERCURRENT_DECEL,
        CONSTANT: FaultCause.OVERCURRENT_CONSTANT,
    },
    "overvoltage": {
        ACCEL: FaultCause.OVERVOLTAGE_ACCEL,
        DECEL: FaultCause.OVERVOLTAGE_DECEL,
        CONSTANT: FaultCause.OVERVOLTAGE_CONSTANT,
    },
}


class HallFault(enum.Enum):
    """A broken Hall sensor, as injected."""

    STUCK0 = "stuck0"  #: all three sensors read 0
    STUCK7 = "stuck7"  #: all three sensors read 1
    SEQUENCE = "sequence"  #: codes come out of order (a bad sensor or wiring)


@dataclass(frozen=True, slots=True)
class Telemetry:
    """What the drive is doing, in engineering units, for a dashboard."""

    t: float
    state: str
    status: int  #: 2100H
    fault_code: int  #: 2102H
    fault_name: str
    speed_rpm: float  #: signed: negative is reverse
    set_speed_rpm: float
    ramp_rpm: float
    current_a: float  #: signed torque-producing current
    output_voltage_v: float
    output_power_w: float
    bus_v: float
    supply_v: float
    temperature_c: float
    ambient_c: float
    hall: int
    motor_overload: float  #: fraction of the motor's overload budget used (trips at 1)
    drive_overload: float  #: fraction of the drive's overload budget used (trips at 1)
    load_torque_nm: float
    load_inertia_kg_m2: float
    input_terminals: int  #: 300DH
    output_terminals: int  #: 300EH
    run_channel: int
    speed_source: int
    steady: bool  #: skipping ahead in closed form


@dataclass(frozen=True, slots=True)
class _Config:
    """Everything the step needs that only changes when an input changes."""

    pole_pairs: int
    max_rpm: float
    up: float  #: rpm per step while accelerating
    down: float  #: rpm per step while decelerating
    reference_rpm: float
    jog_rpm: float
    channel: int
    source: int
    comm_timeout: float
    inertia: float
    hold: float  #: Coulomb friction plus load torque, N m
    viscous: float  #: N m per rpm
    active: float  #: signed load torque, N m, positive pushing forward
    inputs: int  #: effective input terminals
    kp: float  #: speed loop, N m per rad/s
    ki: float  #: speed loop, N m per rad
    stall_v: float  #: overvoltage stall level, V; 0 = off
    motor_rated_a: float  #: rated current times the overload coefficient
    comm_action: int


def _u16(value: float) -> int:
    return min(max(round(value), 0), 0xFFFF)


class Drive:
    """A ZBLD.C20 brushless drive in virtual time; a :class:`~c20sim.drive.base.DrivePort`."""

    state: State
    _ram: dict[int, int]
    _cfg: _Config
    _cause: FaultCause | None
    _last_comm: float | None
    _segment: Segment | None

    def __init__(self, profile: Profile, *, t0: float = 0.0, state_path: str | Path | None = None) -> None:
        self.profile = profile
        self.parameters = ParameterStore(profile, state_path)
        self.t0 = float(t0)
        self.t = self.t0
        self._k = 0
        s, p, th = profile.supply, profile.protection, profile.thermal
        self._codes: Mapping[FaultCause, int] = {
            spec.cause: spec.code for spec in profile.faults.values() if spec.cause is not None
        }
        # Constants of the step.
        self._capacitance = s.bus_capacitance_uf * 1e-6
        self._inv_source = 1.0 / max(s.source_resistance_ohm, 1e-3)
        self._inv_bleed = self._capacitance / s.bleed_time_constant_s
        self._inv_brake = 1.0 / s.brake_resistor_ohm
        self._temp_rate = STEP / th.time_constant_s
        self._temp_decay = math.exp(-self._temp_rate)
        self._motor_budget = self._drive_budget = 1.0
        self._recover_v = s.undervoltage_recover_v or s.undervoltage_v
        self._stall_steps_limit = max(1, round(p.stall_time_s / STEP))
        self._brake_steps_limit = round(p.brake_hold_s / STEP)
        # Conditions set by injection.
        self._supply = s.voltage_v
        self._load = 0.0
        self._active = 0.0
        self._load_inertia = 0.0
        self._ambient = th.ambient_c
        self._hall_fault: HallFault | None = None
        self._ai = [0.0, 0.0, 0.0]
        self._physical_inputs = 0
        self._dial = (False, False, False)  # SW1, SW2, SW3
        self._temp = self._ambient
        self._power_up()

    # --- DrivePort.

    def advance_to(self, t: float) -> None:
        """Integrate to time ``t`` (seconds); earlier times are ignored."""
        if t <= self.t:
            return
        self.t = t
        target = int((t - self.t0) / STEP + 1e-6)
        while self._k < target:
            if self._segment is not None:
                self._advance_segment(target)
            else:
                self._step()

    def communicated(self, t: float) -> None:
        self._last_comm = t

    @property
    def running(self) -> bool:
        """True while the inverter drives the motor (W/R* registers are locked)."""
        return self.state in DRIVEN

    def read(self, address: int) -> int:
        if address in self._ram:
            return self._ram[address]
        if address in self.parameters:
            return self.parameters.get(address)
        reader = _READERS.get(address)
        if reader is not None:
            return reader(self)
        if address in FIXED_REGISTERS:
            return 0  # 200FH reads 0
        raise KeyError(address)

    def check_write(self, address: int, value: int) -> None:
        if address == Reg.COMMAND and value in {e.value for e in RUN_COMMANDS}:
            channel = self._cfg.channel
            if channel != CHANNEL_COMM:
                raise ModbusError(
                    ExceptionCode.OPERATION_FAILED,
                    f"run commands come from the {RUN_CHANNELS.get(channel, channel)} (F00.01 = {channel})",
                )

    def write(self, address: int, value: int) -> None:
        self._segment = None
        if address == Reg.COMMAND:
            self._ram[address] = value
            self._apply(Event(value))
        elif address == Reg.VIRTUAL_INPUTS:
            before = self._cfg.inputs
            self._ram[address] = value
            self._reconfigure()
            self._inputs_changed(before)
        elif address in self._ram:
            self._ram[address] = value
        elif address == Reg.RESTORE_DEFAULTS:
            if value == 1:
                self.parameters.restore_defaults()
        else:
            self.parameters.set(address, value)
        self._reconfigure()

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
        self._segment = None
        if event is Event.RESET:
            return self._reset()
        self._apply(event)
        return True

    # --- Read-outs of the conditions set by injection (telemetry has supply, load, inertia, ambient).

    @property
    def physical_inputs(self) -> int:
        """The physical input terminals as set (300DH and telemetry add the virtual ones, 200AH)."""
        return self._physical_inputs

    @property
    def hall_fault(self) -> HallFault | None:
        """The Hall sensor fault injected, or None if the sensor is sound."""
        return self._hall_fault

    def ai(self, channel: int) -> float:
        """Analog input 1, 2 or 3 as set (V)."""
        if channel not in (1, 2, 3):
            raise ValueError(f"analog input must be 1, 2 or 3, not {channel}")
        return self._ai[channel - 1]

    @property
    def held_fault(self) -> int | None:
        """The code of a fault forced with ``persistent`` and not yet released (resets fail), else None."""
        return self._fault if self._forced_hold and self._cause is None and self._fault else None

    def set_supply_voltage(self, volts: float) -> None:
        """The supply behind the DC bus (0 = switched off)."""
        self._supply = max(0.0, float(volts))
        self._changed()

    def set_load_torque(self, nm: float) -> None:
        """Load torque on the shaft, opposing motion (N m)."""
        self._load = max(0.0, float(nm))
        self._changed()

    def set_active_load(self, nm: float) -> None:
        """Signed load torque that acts whatever the motion (a hoist's weight), N m; positive pushes forward.

        Unlike :meth:`set_load_torque` it can drive the rotor: a forward run
        with a positive active load regenerates, and a held load draws current.
        """
        nm = float(nm)
        if not math.isfinite(nm):
            raise ValueError(f"active load must be a finite torque in N m, not {nm}")
        self._active = nm
        self._changed()

    @property
    def active_load(self) -> float:
        """The signed active load torque as set (N m)."""
        return self._active

    def set_load_inertia(self, kg_m2: float) -> None:
        """Inertia coupled to the shaft, added to the profile's (kg m^2)."""
        self._load_inertia = max(0.0, float(kg_m2))
        self._changed()

    def set_ambient(self, celsius: float) -> None:
        self._ambient = float(celsius)
        self._changed()

    def set_hall_fault(self, fault: HallFault | str | None) -> None:
        """Break the Hall sensor ('stuck0', 'stuck7', 'sequence') or mend it (None)."""
        self._hall_fault = None if fault is None else HallFault(fault)
        self._changed()

    def set_ai(self, channel: int, volts: float) -> None:
        """Analog input 1, 2 or 3 (0-10 V; AI1 is the knob)."""
        if channel not in (1, 2, 3):
            raise ValueError(f"analog input must be 1, 2 or 3, not {channel}")
        self._ai[channel - 1] = min(max(float(volts), 0.0), 10.0)
        self._changed()

    @property
    def dial_switches(self) -> tuple[bool, bool, bool]:
        """The dial switches (SW1, SW2, SW3) as set; True is on."""
        return self._dial

    def set_dial_switches(self, sw1: bool, sw2: bool, sw3: bool) -> None:
        """Set the dial switches SW1-SW3; they act where 2005H = 3, 2006H = 3 or 2007H = 5 select them.

        SW1 (2005H = 3) picks the control mode, which the model does not simulate; SW3 (2006H = 3)
        the run channel; SW2 and SW3 (2007H = 5) the speed source: see :data:`DIAL_SPEED_SOURCE`.
        """
        self._dial = (bool(sw1), bool(sw2), bool(sw3))
        self._changed()

    def set_terminal_inputs(self, bits: int) -> None:
        """The physical input terminals (bits of :class:`~c20sim.drive.terminals.Input`)."""
        before = self._cfg.inputs
        self._physical_inputs = int(bits) & 0x1FF
        self._changed()
        self._inputs_changed(before)

    def force_fault(self, code: int, *, persistent: bool = False) -> None:
        """Latch fault ``code`` now; with ``persistent`` a reset fails until :meth:`release_fault`."""
        if not 1 <= code <= 0xFF:
            raise ValueError(f"fault code must be 1-255, not {code}")
        self._segment = None
        self._forced_hold = persistent
        if self.state is State.FAULT:
            self._fault, self._cause = code, None
        else:
            self._trip(code, None)

    def release_fault(self) -> None:
        """The cause of a persistent forced fault is gone (a reset is still needed)."""
        self._forced_hold = False

    def power_cycle(self) -> None:
        """Switch the drive off and on: RAM registers and faults clear, the EEPROM stays."""
        self._power_up()

    def telemetry(self) -> Telemetry:
        speed, current = self._speed, self._current
        volts = self._output_volts()
        return Telemetry(
            t=self.t,
            state=self.state.value,
            status=self._status1(),
            fault_code=self._fault_reported(),
            fault_name=self.profile.fault_name(self._fault_reported()) if self._fault_reported() else "",
            speed_rpm=speed,
            set_speed_rpm=self._set_rpm(),
            ramp_rpm=self._ramp,
            current_a=current,
            output_voltage_v=volts,
            output_power_w=self._output_watts(),
            bus_v=self._bus,
            supply_v=self._supply,
            temperature_c=self._temp,
            ambient_c=self._ambient,
            hall=self._hall_now(),
            motor_overload=self._motor_i2t / self._motor_budget,
            drive_overload=self._drive_i2t / self._drive_budget,
            load_torque_nm=self._load,
            load_inertia_kg_m2=self._load_inertia,
            input_terminals=self._cfg.inputs,
            output_terminals=self._outputs(),
            run_channel=self._cfg.channel,
            speed_source=self._cfg.source,
            steady=self._segment is not None,
        )

    # --- State changes.

    def _power_up(self) -> None:
        self._ram = dict.fromkeys(RAM_REGISTERS, 0)
        self._reconfigure()
        self._speed = self._speed_before = self._ramp = self._current = 0.0
        self._integ = self._demand = 0.0
        self._power = self._loss = 0.0
        self._bus = self._bus_rest(self._supply)
        self._bus_ok = self._bus >= self._recover_v
        self._bus_settled = True
        self._limited = False
        self._phase = CONSTANT
        self._motor_i2t = self._drive_i2t = 0.0
        self._theta = 0.0
        self._edge_t: float | None = None  # time of the last Hall edge
        self._edge_rpm = 0.0  # the speed measured at it, from the time since the edge before
        self._seg_edge: tuple[float | None, float] = (None, 0.0)  # the two at a segment's start
        self._hall_before = self._hall()
        self._hall_glitch = False
        self._stall_steps = self._brake_steps = 0
        self._fault = 0
        self._cause = None
        self._forced_hold = False
        self._last_comm = None
        self.state = State.STOPPED if self._bus_ok else State.OFF
        self._segment = None
        self._try_segment()

    def _changed(self) -> None:
        self._segment = None
        self._reconfigure()

    def _apply(self, event: Event) -> None:
        """Feed one event to the state table."""
        if event is Event.RESET:
            self._reset()
            return
        new = next_state(self.state, event)
        if new is not self.state:
            self._enter(new)

    def _enter(self, new: State) -> None:
        if new in DRIVEN and self.state not in DRIVEN:
            self._ramp = self._speed  # catch a turning rotor where it is
        if new not in DRIVEN:
            self._ramp = self._current = self._power = self._loss = 0.0
            self._integ = self._demand = 0.0
        self._brake_steps = 0
        self._stall_steps = 0
        self._segment = None
        self.state = new

    def _trip(self, code: int, cause: FaultCause | None) -> None:
        if self.state is State.FAULT:
            return
        self._fault, self._cause = code, cause
        if cause is FaultCause.COMMUNICATION:
            self._last_comm = None  # re-armed by the next request
        self._enter(next_state(self.state, Event.TRIP))

    def _trip_on(self, cause: FaultCause) -> bool:
        code = self._codes.get(cause)
        if code is None:
            return False  # the profile has no code for it: this drive lacks the protection
        self._trip(code, cause)
        return True

    def _reset(self) -> bool:
        if self.state is not State.FAULT or self._cause_persists():
            return False
        self._fault, self._cause = 0, None
        self._enter(next_state(self.state, Event.RESET))
        return True

    def _cause_persists(self) -> bool:
        cause, s, p = self._cause, self.profile.supply, self.profile.protection
        if cause is None:
            return self._forced_hold
        if cause is FaultCause.UNDERVOLTAGE:
            return not self._bus_ok
        if cause in _BY_PHASE["overvoltage"].values():
            return self._bus > s.overvoltage_v
        if cause in _BY_PHASE["overcurrent"].values():  # a load that needs more than the trip level to hold
            return (self._cfg.hold + abs(self._cfg.active)) / self.profile.motor.kt_nm_per_a > p.overcurrent_a
        if cause is FaultCause.MOTOR_OVERLOAD:
            return self._motor_i2t > p.overload_warning * self._motor_budget
        if cause is FaultCause.DRIVE_OVERLOAD:
            return self._drive_i2t > p.overload_warning * self._drive_budget
        if cause is FaultCause.OVERHEAT:
            return self._temp > self.profile.thermal.overheat_c - self.profile.thermal.overheat_reset_k
        if cause is FaultCause.EXTERNAL:
            return bool(self._cfg.inputs & Input.EF)
        if cause is FaultCause.HALL:
            return self._hall_fault is not None
        return False  # stall, communication: the reset itself is the retry

    def _inputs_changed(self, before: int) -> None:
        after = self._cfg.inputs
        if after & ~before & Input.CLR:
            self._reset()
        run_bits = Input.FWD | Input.REV | Input.JOGF | Input.JOGR
        if self._cfg.channel != CHANNEL_TERMINAL or not (before ^ after) & run_bits:
            return
        fwd, rev = bool(after & Input.FWD), bool(after & Input.REV)
        jogf, jogr = bool(after & Input.JOGF), bool(after & Input.JOGR)
        if fwd != rev:
            self._apply(Event.FORWARD if fwd else Event.REVERSE)
        elif not fwd and jogf != jogr:
            self._apply(Event.JOG_FORWARD if jogf else Event.JOG_REVERSE)
        else:
            self._apply(Event.STOP)

    # --- Settings derived from parameters and conditions.

    def _reconfigure(self) -> None:
        m, P, regs = self.profile.motor, self.parameters, self.profile.registers
        max_rpm = float(P.get(F_MAX_SPEED)) if F_MAX_SPEED in P else m.rated_speed_rpm
        accel = max(P.get(Reg.ACCEL_TIME), 1) * 0.1
        decel = max(P.get(Reg.DECEL_TIME), 1) * 0.1
        pole_pairs = max(P.get(Reg.POLE_PAIRS), 1)
        inputs = (self._physical_inputs | self._ram[Reg.VIRTUAL_INPUTS]) & 0x1FF
        source = P.get(Reg.SPEED_SOURCE)
        if source == SOURCE_DIAL:
            source = DIAL_SPEED_SOURCE[self._dial[1], self._dial[2]]
        channel = P.get(Reg.RUN_CHANNEL)
        if channel == CHANNEL_DIAL:
            channel = CHANNEL_TERMINAL if self._dial[2] else CHANNEL_KEYPAD
        reference = 0.0
        if source == 0 and F_KEYPAD_SPEED in P:
            reference = P.get(F_KEYPAD_SPEED) * regs[F_KEYPAD_SPEED].scale * 60.0 / pole_pairs
        elif source in (1, 2):
            reference = self._ai[source - 1] / 10.0 * max_rpm
        elif source == 3:
            reference = float(self._ram[Reg.SPEED_SETPOINT])
        elif source == 4:
            segment = F_MULTI_SPEED + multi_speed_index(inputs)
            reference = float(P.get(segment)) if segment in P else 0.0
        jog = float(P.get(F_JOG_SPEED)) if F_JOG_SPEED in P else m.jog_speed_rpm
        timeout = P.get(F_COMM_TIMEOUT) * regs[F_COMM_TIMEOUT].scale if F_COMM_TIMEOUT in P else 0.0
        inertia = m.inertia_kg_m2 + self._load_inertia
        bandwidth = physics.TWO_PI * self.profile.control.speed_loop_hz
        stall_on = P.get(F_OV_STALL) if F_OV_STALL in P else 1
        stall_pct = P.get(F_OV_STALL_LEVEL) if F_OV_STALL_LEVEL in P else 120
        coefficient = (
            P.get(F_MOTOR_OVERLOAD_COEFFICIENT) * regs[F_MOTOR_OVERLOAD_COEFFICIENT].scale / 100.0
            if F_MOTOR_OVERLOAD_COEFFICIENT in P
            else 1.0
        )
        self._cfg = _Config(
            pole_pairs=pole_pairs,
            max_rpm=max_rpm,
            up=max_rpm / accel * STEP,
            down=max_rpm / decel * STEP,
            reference_rpm=self._limit_speed(reference, max_rpm),
            jog_rpm=self._limit_speed(jog, max_rpm),
            channel=channel,
            source=source,
            comm_timeout=timeout,
            inertia=inertia,
            hold=m.friction_nm + self._load,
            viscous=m.viscous_nm_per_krpm / 1000.0,
            active=self._active,
            inputs=inputs,
            kp=inertia * bandwidth,
            ki=inertia * bandwidth * bandwidth / 4.0,
            stall_v=self.profile.supply.voltage_v * stall_pct / 100.0 if stall_on else 0.0,
            motor_rated_a=m.rated_current_a * max(coefficient, 0.01),
            comm_action=P.get(F_COMM_ACTION) if F_COMM_ACTION in P else COMM_TRIP,
        )

    def _limit_speed(self, rpm: float, max_rpm: float) -> float:
        """A set speed within 0 to the maximum; a set speed above zero runs at least at the minimum speed."""
        rpm = min(max(rpm, 0.0), max_rpm)
        floor = min(self.profile.control.min_speed_rpm, max_rpm)
        return floor if 0.0 < rpm < floor else rpm

    def _target(self) -> float:
        s, cfg = self.state, self._cfg
        if s is State.FORWARD:
            return cfg.reference_rpm
        if s is State.REVERSE:
            return -cfg.reference_rpm
        if s is State.JOG_FORWARD:
            return cfg.jog_rpm
        if s is State.JOG_REVERSE:
            return -cfg.jog_rpm
        return 0.0

    def _bus_rest(self, supply: float) -> float:
        """The bus of a stopped drive: the supply divided by the source and bleed resistances."""
        if supply <= 0.0:
            return 0.0
        return supply * self._inv_source / (self._inv_source + self._inv_bleed)

    # --- The step.

    def _step(self) -> None:
        self._k += 1
        cfg, m, prot, th = self._cfg, self.profile.motor, self.profile.protection, self.profile.thermal
        kt, resistance = m.kt_nm_per_a, m.resistance_ohm
        speed = self._speed
        state = self.state
        limited = False
        emf = kt * speed * RPM
        if state in DRIVEN:
            target = self._target()
            ramp, phase = physics.ramp_toward(self._ramp, target, cfg.up, cfg.down)
            if phase == DECEL and cfg.stall_v and self._bus > cfg.stall_v:
                ramp = self._ramp  # overvoltage stall prevention: hold the output frequency, stretching the ramp
            ramp, current, new_speed, integ, limited, wanted = self._control(state, ramp, target, speed, emf)
            if phase == DECEL and cfg.stall_v and ramp != self._ramp:
                ramp, current, new_speed, integ, limited, wanted = self._stall_limited(
                    state, (ramp, current, new_speed, integ, limited, wanted), target, speed, emf
                )
            self._integ, self._demand = integ, wanted
        else:
            target, ramp, phase = 0.0, 0.0, CONSTANT
            # Output off: only the freewheeling diodes conduct, once the back-EMF exceeds the bus.
            current = 0.0 if abs(emf) <= self._bus else -math.copysign(abs(emf) - self._bus, emf) / resistance
            new_speed = physics.free_motion(speed, kt * current + cfg.active, cfg.hold, cfg.viscous, cfg.inertia, STEP)
        bus, power, loss = self._bus_after(new_speed, current)
        self._bus_settled = abs(bus - self._bus) <= 1e-9  # a chopper at its threshold never settles
        temp_ss = self._ambient + loss * th.resistance_k_per_w
        self._temp = temp_ss + (self._temp - temp_ss) * self._temp_decay
        self._motor_i2t = max(0.0, self._motor_i2t + STEP * self._motor_rate(current))
        self._drive_i2t = max(0.0, self._drive_i2t + STEP * self._drive_rate(current))
        self._hall_edges(self._theta, new_speed * RPM * cfg.pole_pairs * STEP, self.t0 + (self._k - 1) * STEP, 1)
        self._theta = (self._theta + new_speed * RPM * cfg.pole_pairs * STEP) % physics.TWO_PI
        hall = self._hall()
        # Healthy codes step through the sequence; an out-of-order sensor shows itself at its first edge.
        self._hall_glitch = hall in (0, 7) or (self._hall_fault is HallFault.SEQUENCE and hall != self._hall_before)
        self._hall_before = hall
        if state in RUNNING and abs(target) > prot.stall_speed_rpm and abs(new_speed) < prot.stall_speed_rpm:
            self._stall_steps += 1
        else:
            self._stall_steps = 0
        if state is State.BRAKING:
            self._brake_steps += 1
        self._speed_before, self._speed, self._ramp, self._current = speed, new_speed, ramp, current
        self._power, self._loss, self._bus, self._phase, self._limited = power, loss, bus, phase, limited
        self._protect()
        self._auto_events()
        if self.state is state:
            self._try_segment()

    def _control(
        self, state: State, ramp: float, target: float, speed: float, emf: float
    ) -> tuple[float, float, float, float, bool, float]:
        """One step of the speed loop toward ``ramp``: (ramp, current, new speed, integrator, limited, demand).

        The ramp's acceleration torque is fed forward and a PI on the speed error does the rest; the
        current limit clamps the current and holds the ramp back to the rotor. Nothing is changed.
        """
        cfg, m, prot = self._cfg, self.profile.motor, self.profile.protection
        kt, resistance = m.kt_nm_per_a, m.resistance_ohm
        error = (self._ramp - speed) * RPM  # where the rotor should be now; the feedforward takes it on
        integ = self._integ + cfg.ki * error * STEP
        wanted = (cfg.inertia * (ramp - self._ramp) * RPM / STEP + cfg.kp * error + integ) / kt
        high = min(prot.current_limit_a, (self._bus - emf) / resistance)
        low = max(-prot.current_limit_a, (-self._bus - emf) / resistance)
        limited = not low <= wanted <= high
        if limited:  # the integrator holds (no wind-up)
            integ = self._integ
            current = high if wanted > high else low
        else:
            current = wanted
        new_speed = physics.free_motion(speed, kt * current + cfg.active, cfg.hold, cfg.viscous, cfg.inertia, STEP)
        if limited:
            ramp = new_speed  # the current limit holds the ramp back
        elif ramp == target and new_speed != ramp and abs(new_speed - ramp) < self._settled_rpm(state):
            # The loop has settled on a constant set speed: at rest exactly, so the drive can skip ahead.
            new_speed = ramp
            integ = (math.copysign(cfg.hold, ramp) if ramp else 0.0) + cfg.viscous * ramp - cfg.active
            current = integ / kt
        return ramp, current, new_speed, integ, limited, wanted

    def _stall_limited(
        self,
        state: State,
        full: tuple[float, float, float, float, bool, float],
        target: float,
        speed: float,
        emf: float,
    ) -> tuple[float, float, float, float, bool, float]:
        """Overvoltage stall prevention, looking one step ahead as the drive's fast stall loop does.

        The bus rises by volts per millisecond under hard braking: the ramp's step down is cut to what
        brings the bus to the stall level, and held if the bus is there already.
        """
        stall_v = self._cfg.stall_v
        full_bus = self._bus_after(full[2], full[1])[0]
        if full_bus <= stall_v:
            return full
        held = self._control(state, self._ramp, target, speed, emf)
        held_bus = self._bus_after(held[2], held[1])[0]
        if held_bus >= stall_v or full[0] == held[0]:
            return held
        share = (stall_v - held_bus) / (full_bus - held_bus)
        return self._control(state, self._ramp + share * (full[0] - self._ramp), target, speed, emf)

    def _bus_after(self, speed: float, current: float) -> tuple[float, float, float]:
        """The bus after this step with the motor at ``speed`` drawing ``current``: (bus, power, loss)."""
        m, th = self.profile.motor, self.profile.thermal
        power = (m.kt_nm_per_a * speed * RPM + current * m.resistance_ohm) * current
        loss = th.conduction_resistance_ohm * current * current + th.switching_loss_w_per_a * abs(current)
        bus = physics.bus_step(
            self._bus,
            self._supply,
            (power + loss) / max(self._bus, 1.0),
            inv_source=self._inv_source,
            inv_bleed=self._inv_bleed,
            inv_brake=self._inv_brake,
            chopper_v=self.profile.supply.brake_chopper_v,
            capacitance=self._capacitance,
            dt=STEP,
        )
        return bus, power, loss

    @staticmethod
    def _settled_rpm(state: State) -> float:
        """How close to its set speed the rotor counts as there; stopping, zero speed is detected at 1 rpm."""
        return SETTLED_RPM if state in RUNNING else ZERO_RPM

    def _motor_rate(self, current: float) -> float:
        """The motor's overload budget used per second at ``current`` (negative: cooling)."""
        p = self.profile.protection
        return physics.overload_rate(
            abs(current) / self._cfg.motor_rated_a, p.motor_overload_curve, p.overload_cooling_s
        )

    def _drive_rate(self, current: float) -> float:
        p = self.profile.protection
        return physics.overload_rate(
            abs(current) / p.drive_rated_current_a, p.drive_overload_curve, p.overload_cooling_s
        )

    def _protect(self) -> None:
        """Trip on the first cause present, in a fixed order; handle the bus coming and going."""
        state = self.state
        supply, prot = self.profile.supply, self.profile.protection
        if self._bus < supply.undervoltage_v:
            self._bus_ok = False
        elif self._bus >= self._recover_v:
            self._bus_ok = True  # back only above the recover level: no flicker around the trip level
        if state is State.FAULT:
            return
        if not self._bus_ok:
            if state in TRIPS_ON_UNDERVOLTAGE:
                self._trip_on(FaultCause.UNDERVOLTAGE)
            elif state is not State.OFF:
                self._apply(Event.POWER_LOST)
            return
        if state is State.OFF:
            self._apply(Event.POWER_BACK)
            return
        driven = state in DRIVEN
        if self._bus > supply.overvoltage_v and self._trip_on(_BY_PHASE["overvoltage"][self._phase]):
            return
        # The current the loop asks this step flows for the microseconds the limit takes to act: a ramp of a
        # heavy load that asks more than the trip level trips here, a load beyond the limit slows the rotor.
        if driven and abs(self._demand) > prot.overcurrent_a and self._trip_on(_BY_PHASE["overcurrent"][self._phase]):
            return
        if self._hall_glitch and self._trip_on(FaultCause.HALL):  # a bad code trips whenever the bus is up
            return
        if self._stall_steps >= self._stall_steps_limit and self._trip_on(FaultCause.STALL):
            return
        if self._motor_i2t >= self._motor_budget and self._trip_on(FaultCause.MOTOR_OVERLOAD):
            return
        if self._drive_i2t >= self._drive_budget and self._trip_on(FaultCause.DRIVE_OVERLOAD):
            return
        if self._temp >= self.profile.thermal.overheat_c and self._trip_on(FaultCause.OVERHEAT):
            return
        if self._cfg.inputs & Input.EF and self._trip_on(FaultCause.EXTERNAL):
            return
        if self._comm_expired(self._k):
            if self._cfg.comm_action == COMM_TRIP:
                self._trip_on(FaultCause.COMMUNICATION)
            else:  # F08.03 = 2 or 3: no alarm, ramp to stop; re-armed by the next request
                self._last_comm = None
                self._apply(Event.STOP if state not in (State.JOG_FORWARD, State.JOG_REVERSE) else Event.JOG_STOP)

    def _comm_expired(self, k: int) -> bool:
        cfg = self._cfg
        return (
            cfg.comm_timeout > 0.0
            and cfg.comm_action != COMM_CONTINUE
            and (cfg.channel == CHANNEL_COMM or cfg.comm_action == COMM_STOP_ANY)
            and self._last_comm is not None
            and self.state not in (State.FAULT, State.OFF)
            and self.t0 + k * STEP - self._last_comm > cfg.comm_timeout
        )

    def _auto_events(self) -> None:
        state = self.state
        if state is State.DECELERATING and self._speed == 0.0 and self._ramp == 0.0:
            self._apply(Event.AT_ZERO)
        elif state is State.BRAKING and self._brake_steps >= self._brake_steps_limit:
            self._apply(Event.HOLD_DONE)
        elif state is State.COASTING and self._speed == 0.0:
            self._apply(Event.AT_ZERO)

    # --- Steady segments: skipping ahead exactly.

    def _try_segment(self) -> None:
        state = self.state
        if state in (State.DECELERATING, State.BRAKING, State.COASTING) or not self._bus_settled:
            return
        if self._speed != self._speed_before:
            return
        if state in DRIVEN:
            if self._limited or self._stall_steps or self._hall_fault is not None:
                return
            if self._ramp != self._target() or self._speed != self._ramp:
                return
        elif self._speed != 0.0:
            return
        elif self._current != 0.0:
            return  # the diodes still conduct
        watch = state not in (State.FAULT, State.OFF)
        temp_ss = self._ambient + self._loss * self.profile.thermal.resistance_k_per_w
        motor_rate = STEP * self._motor_rate(self._current)
        drive_rate = STEP * self._drive_rate(self._current)
        self._seg_edge = (self._edge_t, self._edge_rpm)
        self._segment = Segment(
            k0=self._k,
            temp0=self._temp,
            temp_ss=temp_ss,
            temp_rate=self._temp_rate,
            motor_i2t0=self._motor_i2t,
            motor_rate=motor_rate,
            drive_i2t0=self._drive_i2t,
            drive_rate=drive_rate,
            theta0=self._theta,
            theta_rate=self._speed * RPM * self._cfg.pole_pairs * STEP,
            watch_heat=watch and temp_ss > self.profile.thermal.overheat_c,
            watch_overload=watch and (motor_rate > 0.0 or drive_rate > 0.0),
        )

    def _segment_event(self, seg: Segment, n: int) -> bool:
        """True if a protection trips at step ``n`` of the segment (monotone in ``n``)."""
        if seg.watch_heat and seg.temp(n) >= self.profile.thermal.overheat_c:
            return True
        if seg.watch_overload and (seg.motor_i2t(n) >= self._motor_budget or seg.drive_i2t(n) >= self._drive_budget):
            return True
        return self._comm_expired(seg.k0 + n)

    def _advance_segment(self, target: int) -> None:
        seg = self._segment
        assert seg is not None
        first, last = self._k + 1 - seg.k0, target - seg.k0
        event = self._segment_event(seg, last)
        n = last
        if event:  # find the first step that trips: the same step a 1 ms poll would find
            low, high = first, last
            while low < high:
                mid = (low + high) // 2
                if self._segment_event(seg, mid):
                    high = mid
                else:
                    low = mid + 1
            n = low
        self._k = seg.k0 + n
        self._temp = seg.temp(n)
        self._motor_i2t = seg.motor_i2t(n)
        self._drive_i2t = seg.drive_i2t(n)
        self._edge_t, self._edge_rpm = self._seg_edge
        self._hall_edges(seg.theta0, seg.theta_rate * n, self.t0 + seg.k0 * STEP, n)
        self._theta = seg.theta(n)
        self._hall_before = self._hall()
        if event:
            self._protect()
            self._segment = None

    # --- Register values.

    def _status1(self) -> int:
        if self.state is State.DECELERATING:
            return 1 if self._speed >= 0.0 else 2
        return STATUS_WORD[self.state]

    def _status2(self) -> int:
        p = self.profile.protection
        word = (self._cfg.channel & 0b11) << 5
        if self._bus_ok:
            word |= STATUS2_BUS
        if (
            self._motor_i2t > p.overload_warning * self._motor_budget
            or self._drive_i2t > p.overload_warning * self._drive_budget
        ):
            word |= STATUS2_OVERLOAD
        return word

    def _fault_reported(self) -> int:
        """2102H/300BH: the latched fault; while off, undervoltage (as the sheet's example pair reads)."""
        if self.state is State.FAULT:
            return self._fault
        if self.state is State.OFF:
            return self._codes.get(FaultCause.UNDERVOLTAGE, 0)
        return 0

    def _set_rpm(self) -> float:
        if self.state in (State.JOG_FORWARD, State.JOG_REVERSE):
            return self._cfg.jog_rpm
        return self._cfg.reference_rpm

    def _hz100(self, rpm: float) -> int:
        return _u16(abs(rpm) * self._cfg.pole_pairs * 100.0 / 60.0)

    def _hall(self, theta: float | None = None) -> int:
        """The Hall code at the last step's angle, or at electrical angle ``theta``."""
        if theta is None:
            theta = self._theta
        fault = self._hall_fault
        if fault is HallFault.STUCK0:
            return 0
        if fault is HallFault.STUCK7:
            return 7
        if fault is HallFault.SEQUENCE:  # every other code: each change flips two bits
            return physics.hall_code((2.0 * theta) % physics.TWO_PI)
        return physics.hall_code(theta)

    def _hall_now(self) -> int:
        """3009H: the code at the rotor's angle at the drive's time, between steps too (no code skipped)."""
        since = self.t - (self.t0 + self._k * STEP)
        theta = (self._theta + self._speed * RPM * self._cfg.pole_pairs * since) % physics.TWO_PI
        return self._hall(theta)

    def _hall_edges(self, theta: float, move: float, t_start: float, steps: int) -> None:
        """Record the Hall edges crossed moving ``move`` electrical radians from ``theta`` over ``steps`` steps."""
        self._edge_t, self._edge_rpm = self._edges_after(theta, move, t_start, steps * STEP)

    def _edges_after(self, theta: float, move: float, t_start: float, span: float) -> tuple[float | None, float]:
        """The last Hall edge and the speed measured at it, after moving ``move`` rad from ``theta`` in ``span`` s.

        The speed is measured from the time between the last two edges, as a drive with Hall sensors
        does: at low speed the reading steps once per edge and lags; two or more edges in the stretch
        (whose speed is constant) measure that speed exactly.
        """
        if move == 0.0:
            return self._edge_t, self._edge_rpm
        sector = physics.SECTOR
        end = theta + move
        if move > 0.0:
            crossed = math.floor(end / sector) - math.floor(theta / sector)
            last = math.floor(end / sector) * sector
        else:
            crossed = math.ceil(theta / sector) - math.ceil(end / sector)
            last = math.ceil(end / sector) * sector
        if crossed <= 0:
            return self._edge_t, self._edge_rpm
        t_edge = t_start + (last - theta) / move * span
        if crossed >= 2:  # the speed was constant over the stretch: its edges are evenly spaced
            return t_edge, abs(move) / span / (RPM * self._cfg.pole_pairs)
        if self._edge_t is not None and t_edge > self._edge_t:
            return t_edge, 60.0 / (6 * self._cfg.pole_pairs) / (t_edge - self._edge_t)
        return t_edge, 0.0

    def _hall_rpm(self) -> float:
        """The speed the Halls give at the drive's time: the last edge's, bounded by the time since it."""
        t_step = self.t0 + self._k * STEP
        since_step = self.t - t_step
        move = self._speed * RPM * self._cfg.pole_pairs * since_step
        edge_t, measured = self._edges_after(self._theta, move, t_step, since_step)  # edges since the last step
        since = self.t - edge_t if edge_t is not None else math.inf
        if since > HALL_TIMEOUT:
            return 0.0
        per_rpm = 60.0 / (6 * self._cfg.pole_pairs)  # rpm x seconds per sector
        return min(measured, per_rpm / since) if since > 0.0 else measured

    def _speed_read(self) -> int:
        """3006H, from the Halls, with the profile's read noise while the rotor turns."""
        speed = self._hall_rpm()
        amplitude = self.profile.control.speed_noise_rpm
        if amplitude and speed:
            speed = max(0.0, speed + amplitude * _noise(self.profile.control.noise_seed, self._k))
        return _u16(speed)

    def _outputs(self) -> int:
        own = Output.RUN if self.state in DRIVEN else 0
        if self.state is State.FAULT:
            own |= Output.FAULT
        return (int(own) | self._ram[Reg.VIRTUAL_OUTPUTS]) & 0x0F

    def _output_volts(self) -> float:
        """The inverter's output voltage: 0 while the output stage is off, whatever the rotor does."""
        if self.state not in DRIVEN:
            return 0.0
        m = self.profile.motor
        return abs(m.kt_nm_per_a * self._speed * RPM + self._current * m.resistance_ohm)

    def _output_hz100(self) -> int:
        return self._hz100(self._speed) if self.state in DRIVEN else 0

    def _output_amps(self) -> float:
        return abs(self._current) if self.state in DRIVEN else 0.0

    def _output_watts(self) -> float:
        return max(0.0, self._power) if self.state in DRIVEN else 0.0


def _noise(seed: int, k: int) -> float:
    """A uniform value in [-1, 1) fixed by ``seed`` and step ``k``: the same at every look (splitmix64)."""
    z = (seed * 0x9E3779B97F4A7C15 + k * 0xBF58476D1CE4E5B9 + 0x94D049BB133111EB) & 0xFFFFFFFFFFFFFFFF
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & 0xFFFFFFFFFFFFFFFF
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & 0xFFFFFFFFFFFFFFFF
    z ^= z >> 31
    return z / 2.0**63 - 1.0


_READERS: dict[int, Callable[[Drive], int]] = {
    Reg.STATUS1: Drive._status1,
    Reg.STATUS2: Drive._status2,
    Reg.FAULT_CODE: Drive._fault_reported,
    Reg.DRIVE_ID: lambda d: DRIVE_ID,
    Reg.SET_FREQUENCY: lambda d: d._hz100(d._set_rpm()),
    Reg.OUTPUT_FREQUENCY: Drive._output_hz100,
    Reg.RAMP_FREQUENCY: lambda d: d._hz100(d._ramp),
    Reg.OUTPUT_VOLTAGE: lambda d: _u16(d._output_volts() * 10.0),
    Reg.OUTPUT_CURRENT: lambda d: _u16(d._output_amps() * 100.0),
    Reg.SET_SPEED: lambda d: _u16(d._set_rpm()),
    Reg.MOTOR_SPEED: Drive._speed_read,
    Reg.OUTPUT_POWER: lambda d: _u16(d._output_watts()),
    Reg.BUS_VOLTAGE: lambda d: _u16(d._bus * 10.0),
    Reg.HALL: Drive._hall_now,
    Reg.SOFTWARE_VERSION: lambda d: d.profile.software_version,
    Reg.CURRENT_FAULT: Drive._fault_reported,
    Reg.TEMPERATURE: lambda d: round(d._temp * 10.0) & 0xFFFF,
    Reg.INPUT_TERMINALS: lambda d: d._cfg.inputs,
    Reg.OUTPUT_TERMINALS: Drive._outputs,
    Reg.AI1_VOLTAGE: lambda d: _u16(d._ai[0] * 100.0),
    Reg.AI2_VOLTAGE: lambda d: _u16(d._ai[1] * 100.0),
    Reg.AI3_VOLTAGE: lambda d: _u16(d._ai[2] * 100.0),
}
