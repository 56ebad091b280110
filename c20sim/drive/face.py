"""The register face: what the drive's cells read and what a write to them does.

The slave owns the access rules (who may write what, ranges, write enable,
password); this module turns a drive's state into register values and a
checked write into a change of the drive. RAM registers (2001H, 200AH, 200BH,
200EH) read back what was written and clear at power-up; 2000H reads the
command in force, which the machine drops on a trip (see :func:`write`); function
codes live in the :class:`~c20sim.drive.params.ParameterStore`; every other
cell is computed when read (:data:`READERS`), from the parts of a
:class:`~c20sim.drive.model.Drive`: 2100H-2102H the status words, 3000H-300EH
the running values, 3006H and 3009H from the Hall sensors. Reads change
nothing.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol

from ..wire.errors import ModbusError
from ..wire.protocol import ExceptionCode
from ..wire.registers import FIXED_REGISTERS, RUN_CHANNELS, Reg, SpeedSource
from .config import CHANNEL_COMM, limit_speed
from .counters import F_POWER_ON_HOURS, F_RUNNING_HOURS
from .faultrecord import RECORD
from .physics import BUDGET, RPM, STEP
from .profile import FaultCause, Profile
from .sensors import noise
from .statemachine import DRIVEN, RUN_COMMANDS, STATUS_WORD, Event, State
from .terminals import Output

if TYPE_CHECKING:
    from .config import Conditions
    from .integrator import Integrator
    from .params import ParameterStore
    from .plc import Plc
    from .protection import Machine
    from .sensors import Hall


class Drive(Protocol):
    """What the register face reads and writes of a drive: its parts (:class:`~c20sim.drive.model.Drive`
    has them). A protocol, so the face needs no import of the model that composes it."""

    profile: Profile
    t0: float
    t: float
    ram: dict[int, int]
    parameters: ParameterStore
    bench: Conditions
    hall: Hall
    machine: Machine
    motion: Integrator
    plc: Plc

    def _reconfigure(self) -> None: ...


__all__ = [
    "DRIVE_ID",
    "RAM_REGISTERS",
    "READERS",
    "STATUS2_BUS",
    "STATUS2_OVERLOAD",
    "check_write",
    "read",
    "write",
]

#: Registers held in RAM (not function codes): they read back what was written; a power cycle clears them.
#: 2000H is volatile too, but it is the command in force, which the machine keeps (see :func:`write`).
RAM_REGISTERS = (Reg.SPEED_SETPOINT, Reg.VIRTUAL_INPUTS, Reg.VIRTUAL_OUTPUTS, Reg.WRITE_ENABLE)

DRIVE_ID = 0x0020
#: 3006H reads within the sheet's 0-3000 rpm: a rotor an overhauling load drives faster reads the top (assumed).
MOTOR_SPEED_MAX = FIXED_REGISTERS[Reg.MOTOR_SPEED].maximum
STATUS2_BUS = 0x0001
STATUS2_OVERLOAD = 0x0010
_RUN_VALUES = frozenset(e.value for e in RUN_COMMANDS)
#: What a restore of the defaults keeps: the fault record and the hour counters.
KEPT = RECORD | {F_POWER_ON_HOURS, F_RUNNING_HOURS}


def read(d: Drive, address: int) -> int:
    """The raw 16-bit value of storage cell ``address``; KeyError if the drive has no such cell."""
    if address in d.ram:
        return d.ram[address]
    if address in d.parameters:
        return d.parameters.get(address)
    reader = READERS.get(address)
    if reader is not None:
        return reader(d)
    if address in FIXED_REGISTERS:
        return 0  # 200FH reads 0
    raise KeyError(address)


def check_write(d: Drive, address: int, value: int) -> None:
    """Refuse (0x04) a run command from the communication port while another run channel is selected."""
    if address == Reg.COMMAND and value in _RUN_VALUES:
        channel = d.motion.cfg.channel
        if channel != CHANNEL_COMM:
            raise ModbusError(
                ExceptionCode.OPERATION_FAILED,
                f"run commands come from the {RUN_CHANNELS.get(channel, channel)} (F00.01 = {channel})",
            )


def write(d: Drive, address: int, value: int, *, ram_only: bool = False) -> None:
    """Store a checked value: 2000H is a command, 200AH the virtual inputs, 200FH = 1 restores the defaults.

    2000H reads back the command in force (**assumed**; the sheet says only that it can be read and written
    in any state): the last command written, until the drive drops it. A trip, a fault reset (whoever gives
    it) and the end of a run or jog other than by a 2000H write (the keypad, the terminals, the
    communication timeout's stop) drop it: 2000H then reads 0000h, as at power-up. A C20 does not restart
    by itself after a reset, so "forward run" would no longer be true.
    """
    if d.ram.get(address) == value and address != Reg.VIRTUAL_INPUTS:
        # A RAM register written with the value it holds (a master that writes its set speed every cycle)
        # changes nothing: the settings and the steady stretch the drive is in stay as they are.
        return
    d.motion.segment = None
    if address == Reg.COMMAND:
        d.machine.apply(Event(value))
        d.machine.command = value  # after the transition it causes, which may drop the one before
    elif address == Reg.VIRTUAL_INPUTS:
        before = d.motion.cfg.inputs
        d.ram[address] = value
        d._reconfigure()
        d.machine.inputs_changed(before)
    elif address == Reg.SPEED_SETPOINT:
        # The set speed is in the settings only as the reference, and only where 2007H takes it from
        # communication: that one field, not the whole of configure (17 parameter reads) at every new value.
        d.ram[address] = value
        cfg = d.motion.cfg
        if cfg.source == SpeedSource.MODBUS:
            d.motion.cfg = dataclasses.replace(cfg, reference_rpm=limit_speed(d.profile, float(value), cfg.max_rpm))
        return
    elif address in d.ram:
        d.ram[address] = value
    elif address == Reg.RESTORE_DEFAULTS:
        if value == 1:
            d.parameters.restore_defaults(keep=KEPT)
    elif ram_only:  # a function code written at its RAM-only address: acts now, never saved
        d.parameters.set_ram(address, value)
    else:
        d.parameters.set(address, value)
    d._reconfigure()


def u16(value: float) -> int:
    return min(max(round(value), 0), 0xFFFF)


# --- Register values.


def status1(d: Drive) -> int:
    """2100H: the state's status word; decelerating, the direction of rotation."""
    state = d.machine.state
    if state is State.DECELERATING:
        return 1 if d.motion.speed >= 0.0 else 2
    return STATUS_WORD[state]


def status2(d: Drive) -> int:
    """2101H: the run channel, bus ready and the overload pre-warning."""
    p, motion = d.profile.protection, d.motion
    word = (motion.cfg.channel & 0b11) << 5
    if d.machine.bus_ok:
        word |= STATUS2_BUS
    if motion.motor_i2t > p.overload_warning * BUDGET or motion.drive_i2t > p.overload_warning * BUDGET:
        word |= STATUS2_OVERLOAD
    return word


def fault_reported(d: Drive) -> int:
    """2102H/300BH: the latched fault; while off, undervoltage (as the sheet's example pair reads)."""
    machine = d.machine
    if machine.state is State.FAULT:
        return machine.fault
    if machine.state is State.OFF:
        return machine.codes.get(FaultCause.UNDERVOLTAGE, 0)
    return 0


def set_rpm(d: Drive) -> float:
    """The set speed: the jog speed while jogging, else the reference."""
    if d.machine.state in (State.JOG_FORWARD, State.JOG_REVERSE):
        return d.motion.cfg.jog_rpm
    return d.motion.cfg.reference_rpm


def hz100(d: Drive, rpm: float) -> int:
    """A speed as an electrical frequency in 0.01 Hz, saturated at the maximum speed's (F00.03): the inverter
    puts out no higher frequency, whatever an overhauling load does to the rotor."""
    cfg = d.motion.cfg
    return u16(min(abs(rpm), cfg.max_rpm) * cfg.pole_pairs * 100.0 / 60.0)


def hall_now(d: Drive) -> int:
    """3009H: the code at the rotor's angle at the drive's time, between steps too (no code skipped)."""
    motion = d.motion
    since = d.t - (d.t0 + motion.k * STEP)
    return d.hall.now(since, motion.speed, motion.cfg.pole_pairs)


def speed_read(d: Drive) -> int:
    """3006H, from the Halls, with the profile's read noise while the rotor turns."""
    motion = d.motion
    speed = d.hall.rpm(d.t, d.t0 + motion.k * STEP, motion.speed, motion.cfg.pole_pairs)
    amplitude = d.profile.control.speed_noise_rpm
    if amplitude and speed:
        speed = max(0.0, speed + amplitude * noise(d.profile.control.noise_seed, motion.k))
    return min(u16(speed), MOTOR_SPEED_MAX)


def outputs(d: Drive) -> int:
    """300EH: the drive's own outputs (RUN, FAULT) ORed with the virtual ones (200BH)."""
    state = d.machine.state
    own = Output.RUN if state in DRIVEN else 0
    if state is State.FAULT:
        own |= Output.FAULT
    own |= d.plc.flags(d.motion.k)  # the simple PLC's stage and cycle flags (Y3, Y4)
    return (int(own) | d.ram[Reg.VIRTUAL_OUTPUTS]) & 0x0F


def output_volts(d: Drive) -> float:
    """The inverter's output voltage: 0 while the output stage is off, whatever the rotor does."""
    if d.machine.state not in DRIVEN:
        return 0.0
    m, motion = d.profile.motor, d.motion
    return abs(m.kt_nm_per_a * motion.speed * RPM + motion.current * m.resistance_ohm)


def output_hz100(d: Drive) -> int:
    return hz100(d, d.motion.speed) if d.machine.state in DRIVEN else 0


def output_amps(d: Drive) -> float:
    return abs(d.motion.current) if d.machine.state in DRIVEN else 0.0


def output_watts(d: Drive) -> float:
    return max(0.0, d.motion.power) if d.machine.state in DRIVEN else 0.0


#: The computed cells: address -> its value for a drive.
READERS: dict[int, Callable[[Drive], int]] = {
    Reg.COMMAND: lambda d: d.machine.command,
    Reg.STATUS1: status1,
    Reg.STATUS2: status2,
    Reg.FAULT_CODE: fault_reported,
    Reg.DRIVE_ID: lambda d: DRIVE_ID,
    Reg.SET_FREQUENCY: lambda d: hz100(d, set_rpm(d)),
    Reg.OUTPUT_FREQUENCY: output_hz100,
    Reg.RAMP_FREQUENCY: lambda d: hz100(d, d.motion.ramp),
    Reg.OUTPUT_VOLTAGE: lambda d: u16(output_volts(d) * 10.0),
    Reg.OUTPUT_CURRENT: lambda d: u16(output_amps(d) * 100.0),
    Reg.SET_SPEED: lambda d: u16(set_rpm(d)),
    Reg.MOTOR_SPEED: speed_read,
    Reg.OUTPUT_POWER: lambda d: u16(output_watts(d)),
    Reg.BUS_VOLTAGE: lambda d: u16(d.motion.bus * 10.0),
    Reg.HALL: hall_now,
    Reg.SOFTWARE_VERSION: lambda d: d.profile.software_version,
    Reg.CURRENT_FAULT: fault_reported,
    Reg.TEMPERATURE: lambda d: round(d.motion.temp * 10.0) & 0xFFFF,
    Reg.INPUT_TERMINALS: lambda d: d.motion.cfg.inputs,
    Reg.OUTPUT_TERMINALS: outputs,
    Reg.AI1_VOLTAGE: lambda d: u16(d.bench.ai[0] * 100.0),
    Reg.AI2_VOLTAGE: lambda d: u16(d.bench.ai[1] * 100.0),
    Reg.AI3_VOLTAGE: lambda d: u16(d.bench.ai[2] * 100.0),
}
