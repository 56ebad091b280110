"""The register map of the sheet (section 2), and the map of one drive.

The fixed registers (2000H-200FH, 2100H-2103H, 3000H-3011H) are defined here,
each with its access (W/R, W/R* = writable only while stopped, R), range,
unit and scale, straight from the sheet. Function-code parameters Fgg.nn live
at ``(gg << 8) | nn`` and come from the profile; some 20xxH registers mirror
one of them (2005H <-> F00.00 ...), and then both addresses share one storage
cell, the function code's: :meth:`RegisterMap.canonical` gives it.
"""

from __future__ import annotations

import enum
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

__all__ = [
    "COMMANDS",
    "FIXED_REGISTERS",
    "RUN_CHANNELS",
    "SPEED_SOURCES",
    "STATUS_WORDS",
    "Access",
    "Command",
    "Reg",
    "RegisterMap",
    "RegisterSpec",
    "RunChannel",
    "SpeedSource",
    "address_label",
    "fcode_address",
    "format_fcode",
    "is_fcode",
    "parse_fcode",
    "ram_alias_of",
    "status2_words",
]

#: The INVT family's RAM-only address of a function code: its address with the most significant bit set
#: (Goodrive350 manual 9.4.5.1; Goodrive100 7.3.4.1: P00.07 at 8007H). Write-only; not saved to EEPROM.
RAM_ONLY = 0x8000


class Access(enum.Enum):
    """R/W characteristics of the sheet ("Parameter Property Description")."""

    RW = "W/R"  #: read and written in any state
    RW_STOPPED = "W/R*"  #: written only while the drive is stopped
    R = "R"  #: read-only

    @property
    def writable(self) -> bool:
        return self is not Access.R


class Reg(enum.IntEnum):
    """Addresses of the fixed registers, named as in the sheet."""

    COMMAND = 0x2000
    SPEED_SETPOINT = 0x2001
    POLE_PAIRS = 0x2002
    ACCEL_TIME = 0x2003
    DECEL_TIME = 0x2004
    CONTROL_MODE = 0x2005
    RUN_CHANNEL = 0x2006
    SPEED_SOURCE = 0x2007
    ADDRESS = 0x2008
    BAUD = 0x2009
    VIRTUAL_INPUTS = 0x200A
    VIRTUAL_OUTPUTS = 0x200B
    WRITE_ENABLE = 0x200E
    RESTORE_DEFAULTS = 0x200F
    STATUS1 = 0x2100
    STATUS2 = 0x2101
    FAULT_CODE = 0x2102
    DRIVE_ID = 0x2103
    SET_FREQUENCY = 0x3000
    OUTPUT_FREQUENCY = 0x3001
    RAMP_FREQUENCY = 0x3002
    OUTPUT_VOLTAGE = 0x3003
    OUTPUT_CURRENT = 0x3004
    SET_SPEED = 0x3005
    MOTOR_SPEED = 0x3006
    OUTPUT_POWER = 0x3007
    BUS_VOLTAGE = 0x3008
    HALL = 0x3009
    SOFTWARE_VERSION = 0x300A
    CURRENT_FAULT = 0x300B
    TEMPERATURE = 0x300C
    INPUT_TERMINALS = 0x300D
    OUTPUT_TERMINALS = 0x300E
    AI1_VOLTAGE = 0x300F
    AI2_VOLTAGE = 0x3010
    AI3_VOLTAGE = 0x3011


class Command(enum.IntEnum):
    """2000H command values (sheet, section 2); a member's ``key`` is its name in every front end."""

    FORWARD = 1  #: 0001h forward running
    REVERSE = 2  #: 0002h reverse operation
    JOG_FORWARD = 3  #: 0003h forward turning inching
    JOG_REVERSE = 4  #: 0004h reverse jog
    STOP = 5  #: 0005h shutdown (ramp down)
    FREE_STOP = 6  #: 0006h free stop (emergency stop): output off, the motor coasts
    RESET = 7  #: 0007h fault reset
    JOG_STOP = 8  #: 0008h inching stop

    @property
    def key(self) -> str:
        """The name the API, ctl, scenarios, pytest and the dashboard use: ``forward``, ``free_stop``."""
        return self.name.lower()


class RunChannel(enum.IntEnum):
    """2006H / F00.01 values: where run commands come from (sheet, section 2)."""

    KEYPAD = 0  #: 0: keyboard operation command channel
    TERMINALS = 1  #: 1: terminal operation command channel
    COMMUNICATION = 2  #: 2: communication operation command channel
    DIAL_SWITCH = 3  #: 3: dial switch setting (SW3 valid), model related

    @property
    def key(self) -> str:
        return self.name.lower()


class SpeedSource(enum.IntEnum):
    """2007H / F00.02 values: where the speed reference comes from (sheet, section 2)."""

    KEYPAD = 0  #: 0: keyboard number setting
    AI1 = 1  #: 1: analog quantity AI1 setting (knob potentiometer)
    AI2 = 2  #: 2: analog quantity AI2 setting (external voltage)
    MODBUS = 3  #: 3: Modbus communication setting
    MULTI_SPEED = 4  #: 4: multi segment speed setting
    DIAL_SWITCH = 5  #: 5: dial switch setting (SW2, SW3 valid), model related
    SIMPLE_PLC = 6  #: 6: simple PLC setting

    @property
    def key(self) -> str:
        return self.name.lower()


#: 2000H command values in words.
COMMANDS: Mapping[int, str] = {
    Command.FORWARD: "forward run",
    Command.REVERSE: "reverse run",
    Command.JOG_FORWARD: "forward jog",
    Command.JOG_REVERSE: "reverse jog",
    Command.STOP: "stop",
    Command.FREE_STOP: "free stop (coast)",
    Command.RESET: "fault reset",
    Command.JOG_STOP: "jog stop",
}

#: 2006H / F00.01 values in words.
RUN_CHANNELS: Mapping[int, str] = {
    RunChannel.KEYPAD: "keypad",
    RunChannel.TERMINALS: "terminals",
    RunChannel.COMMUNICATION: "communication",
    RunChannel.DIAL_SWITCH: "dial switch (SW3)",
}

#: 2007H / F00.02 values in words.
SPEED_SOURCES: Mapping[int, str] = {
    SpeedSource.KEYPAD: "keypad",
    SpeedSource.AI1: "AI1 (knob)",
    SpeedSource.AI2: "AI2 (external voltage)",
    SpeedSource.MODBUS: "Modbus",
    SpeedSource.MULTI_SPEED: "multi-segment speed",
    SpeedSource.DIAL_SWITCH: "dial switch (SW2, SW3)",
    SpeedSource.SIMPLE_PLC: "simple PLC",
}

#: 2100H status word 1 values (sheet, section 2).
STATUS_WORDS: Mapping[int, str] = {
    1: "forward running",
    2: "reverse running",
    3: "stopped",
    4: "fault",
    5: "off (bus voltage not established)",
    6: "electronic brake",
}


def status2_words(raw: int) -> str:
    """Status word 2 (2101H) in words: bit 0 bus, bit 4 overload, bits 5-6 control source."""
    bus = "bus established" if raw & 0x01 else "bus not established"
    source = {0: "keypad control", 1: "terminal control", 2: "communication control"}.get(
        (raw >> 5) & 0b11, "control source 11 (undefined)"
    )  # bits 5-6 name the run channel F00.01 (0-2); 11 is undefined
    words = [bus, source]
    if raw & 0x10:
        words.append("overload")
    return ", ".join(words)


BAUD_RATES: tuple[int, ...] = (1200, 2400, 4800, 9600, 19200, 38400, 57600)


@dataclass(frozen=True, slots=True)
class RegisterSpec:
    """One register: where it is, who may write it, and what its value means.

    ``minimum``/``maximum`` bound the raw 16-bit value a write may carry (for
    R registers: the value it reports). ``scale`` is the engineering value of
    one raw unit in ``unit`` (0.01 for 0.01 Hz). ``signed`` registers carry
    two's complement. ``values`` names enumerated values, for the decoder.
    """

    address: int
    name: str
    access: Access
    minimum: int = 0
    maximum: int = 0xFFFF
    unit: str = ""
    scale: float = 1.0
    signed: bool = False
    values: Mapping[int, str] = field(default_factory=dict)
    #: the storage cell: a function code's address for a mirrored 20xxH register
    storage: int = -1
    source: str = "sheet"
    hex_display: bool = False  #: bit fields and codes read best in hex

    def __post_init__(self) -> None:
        if self.storage < 0:
            object.__setattr__(self, "storage", self.address)

    @property
    def label(self) -> str:
        """``2000H`` for a fixed register, ``F00.10`` for a function code."""
        return address_label(self.address)

    def engineering(self, raw: int) -> float:
        """The value in ``unit``."""
        if self.signed and raw >= 0x8000:
            raw -= 0x10000
        return raw * self.scale

    def describe(self, raw: int) -> str:
        """The value in words: ``forward run``, ``50.00 Hz``, ``1500 rpm``."""
        if raw in self.values:
            return self.values[raw]
        if self.hex_display:
            return f"0x{raw:04X}"
        if self.scale == 1.0 and not self.unit:
            return f"{raw}"
        decimals = max(0, len(f"{self.scale:g}".partition(".")[2]))
        text = f"{self.engineering(raw):.{decimals}f}"
        return f"{text} {self.unit}".rstrip()

    def accepts(self, raw: int) -> bool:
        value = raw - 0x10000 if self.signed and raw >= 0x8000 else raw
        return self.minimum <= value <= self.maximum


def _spec(
    address: int,
    name: str,
    access: Access,
    minimum: int = 0,
    maximum: int = 0xFFFF,
    unit: str = "",
    scale: float = 1.0,
    *,
    signed: bool = False,
    values: Mapping[int, str] | None = None,
    hex_display: bool = False,
) -> RegisterSpec:
    return RegisterSpec(
        address, name, access, minimum, maximum, unit, scale, signed, values or {}, hex_display=hex_display
    )


_RW, _RWS, _R = Access.RW, Access.RW_STOPPED, Access.R

#: The fixed registers, exactly as the sheet lists them (section 2).
FIXED_REGISTERS: Mapping[int, RegisterSpec] = {
    spec.address: spec
    for spec in (
        _spec(Reg.COMMAND, "communication control command", _RW, 1, 8, values=COMMANDS),
        _spec(Reg.SPEED_SETPOINT, "communication speed setting", _RW, 0, 3000, "rpm"),
        _spec(Reg.POLE_PAIRS, "motor pole pairs", _RWS, 1, 20),
        _spec(Reg.ACCEL_TIME, "acceleration time", _RW, 1, 6000, "s", 0.1),
        _spec(Reg.DECEL_TIME, "deceleration time", _RW, 1, 6000, "s", 0.1),
        _spec(
            Reg.CONTROL_MODE,
            "control mode",
            _RWS,
            0,
            3,
            values={0: "test mode", 1: "open loop", 2: "closed loop", 3: "dial switch (SW1)"},
        ),
        _spec(
            Reg.RUN_CHANNEL,
            "run command channel",
            _RW,
            0,
            4,  # sheet: "(0-4)", though it names 0-3 only
            values=RUN_CHANNELS,
        ),
        _spec(
            Reg.SPEED_SOURCE,
            "speed setting source",
            _RW,
            0,
            6,
            values=SPEED_SOURCES,
        ),
        _spec(Reg.ADDRESS, "communication address", _RWS, 1, 247),
        _spec(
            Reg.BAUD,
            "baud rate",
            _RWS,
            0,
            6,
            values={code: f"{rate} baud" for code, rate in enumerate(BAUD_RATES)},
        ),
        _spec(Reg.VIRTUAL_INPUTS, "virtual input terminals", _RW, 0, 0x1FF, hex_display=True),
        _spec(Reg.VIRTUAL_OUTPUTS, "virtual output terminals", _RW, 0, 0x0F, hex_display=True),
        _spec(
            Reg.WRITE_ENABLE,
            "function code write enable",
            _RW,
            0,
            1,
            values={0: "function codes locked", 1: "function codes writable"},
        ),
        _spec(
            Reg.RESTORE_DEFAULTS,
            "restore default parameters",
            _RWS,
            0,
            1,
            values={0: "no operation", 1: "restore defaults"},
        ),
        _spec(Reg.STATUS1, "status word 1", _R, 1, 6, values=STATUS_WORDS),
        _spec(Reg.STATUS2, "status word 2", _R, 0, 0x7F, hex_display=True),
        _spec(Reg.FAULT_CODE, "fault code", _R, 0, 0xFF, hex_display=True),
        _spec(Reg.DRIVE_ID, "drive ID", _R, 0x20, 0x20, hex_display=True),
        _spec(Reg.SET_FREQUENCY, "set frequency", _R, 0, 0xFFFF, "Hz", 0.01),
        _spec(Reg.OUTPUT_FREQUENCY, "output frequency", _R, 0, 0xFFFF, "Hz", 0.01),
        _spec(Reg.RAMP_FREQUENCY, "ramp frequency", _R, 0, 0xFFFF, "Hz", 0.01),
        _spec(Reg.OUTPUT_VOLTAGE, "output voltage", _R, 0, 20000, "V", 0.1),
        _spec(Reg.OUTPUT_CURRENT, "output current", _R, 0, 30000, "A", 0.01),
        _spec(Reg.SET_SPEED, "set speed", _R, 0, 3000, "rpm"),
        _spec(Reg.MOTOR_SPEED, "motor speed", _R, 0, 3000, "rpm"),
        _spec(Reg.OUTPUT_POWER, "output power", _R, 0, 2200, "W"),
        _spec(Reg.BUS_VOLTAGE, "DC bus voltage", _R, 0, 20000, "V", 0.1),
        _spec(Reg.HALL, "Hall value", _R, 0, 7),
        _spec(Reg.SOFTWARE_VERSION, "software version", _R, 100, 9900, "", 0.01),
        _spec(Reg.CURRENT_FAULT, "current fault type", _R, 0, 0xFF, hex_display=True),
        _spec(Reg.TEMPERATURE, "inverter temperature", _R, -200, 1200, "degC", 0.1, signed=True),
        _spec(Reg.INPUT_TERMINALS, "input terminals", _R, 0, 0x1FF, hex_display=True),
        _spec(Reg.OUTPUT_TERMINALS, "output terminals", _R, 0, 0x0F, hex_display=True),
        _spec(Reg.AI1_VOLTAGE, "AI1 voltage", _R, 0, 1000, "V", 0.01),
        _spec(Reg.AI2_VOLTAGE, "AI2 voltage", _R, 0, 1000, "V", 0.01),
        _spec(Reg.AI3_VOLTAGE, "AI3 voltage", _R, 0, 1000, "V", 0.01),
    )
}


def fcode_address(group: int, number: int) -> int:
    """Address of parameter Fgg.nn: ``(gg << 8) | nn`` (F00.10 is 000AH, F00.50 is 0032H)."""
    return (group << 8) | number


def ram_alias_of(address: int) -> int | None:
    """The function code whose RAM-only address ``address`` is (``address`` with bit 15 cleared), or None."""
    if address & RAM_ONLY and is_fcode(address & ~RAM_ONLY):
        return address & ~RAM_ONLY
    return None


def is_fcode(address: int) -> bool:
    """True for addresses in the function-code space (below 2000H)."""
    return address < 0x2000


def address_label(address: int) -> str:
    """``2000H`` for a fixed register, ``F00.10`` for a function code."""
    return format_fcode(address) if is_fcode(address) else f"{address:04X}H"


def format_fcode(address: int) -> str:
    return f"F{address >> 8:02d}.{address & 0xFF:02d}"


def parse_fcode(text: str) -> int:
    """``"F00.10"`` -> 0x000A. Raises ValueError for anything else."""
    body = text.strip().upper()
    if not body.startswith("F") or "." not in body:
        raise ValueError(f"{text!r} is not a function code such as F00.10")
    group, _, number = body[1:].partition(".")
    if not (group.isdigit() and number.isdigit()):
        raise ValueError(f"{text!r} is not a function code such as F00.10")
    g, n = int(group), int(number)
    if not (0 <= g <= 0x1F and 0 <= n <= 0xFF):
        raise ValueError(f"{text!r}: group must be 00-31 and number 00-255")
    return fcode_address(g, n)


class RegisterMap:
    """Every register one drive answers to: the fixed map plus the profile's function codes.

    A function code that names a 20xxH register as its mirror takes that
    register's storage: both addresses read and write one cell (the function
    code's), each with its own access rule, and with the function code's
    range, which is the profile's word on what the drive accepts.
    """

    def __init__(
        self,
        parameters: Iterable[RegisterSpec],
        mirrors: Mapping[int, int] | None = None,
        value_names: Mapping[int, Mapping[int, str]] | None = None,
    ) -> None:
        """``value_names`` names the values of fixed registers the profile defines (the fault codes of 2102H
        and 300BH), so every tool that describes a value says ``OC1: ...`` rather than ``0x0004``."""
        specs: dict[int, RegisterSpec] = dict(FIXED_REGISTERS)
        for register, names in (value_names or {}).items():
            fixed = specs[register]
            specs[register] = RegisterSpec(
                fixed.address,
                fixed.name,
                fixed.access,
                fixed.minimum,
                fixed.maximum,
                fixed.unit,
                fixed.scale,
                fixed.signed,
                {**fixed.values, **names},
                source=fixed.source,
                hex_display=fixed.hex_display,
            )
        for param in parameters:
            if not is_fcode(param.address):
                raise ValueError(f"{param.label} is not in the function-code space")
            specs[param.address] = param
        for register, fcode in (mirrors or {}).items():
            fixed, param = specs[register], specs[fcode]
            specs[register] = RegisterSpec(
                fixed.address,
                fixed.name,
                fixed.access,
                param.minimum,
                param.maximum,
                fixed.unit,
                fixed.scale,
                fixed.signed,
                fixed.values,
                storage=fcode,
                source=param.source,
                hex_display=fixed.hex_display,
            )
        self._specs = specs
        self.mirrors: Mapping[int, int] = dict(mirrors or {})
        #: function code -> the 20xxH register mirroring it
        self.mirrored_by: Mapping[int, int] = {f: r for r, f in self.mirrors.items()}

    def __contains__(self, address: object) -> bool:
        return address in self._specs

    def __getitem__(self, address: int) -> RegisterSpec:
        return self._specs[address]

    def get(self, address: int) -> RegisterSpec | None:
        return self._specs.get(address)

    def specs(self) -> list[RegisterSpec]:
        """Every register, in address order."""
        return sorted(self._specs.values(), key=lambda s: s.address)

    def canonical(self, address: int) -> int:
        """The storage cell behind ``address`` (the function code for a mirror)."""
        return self._specs[address].storage

    def parameters(self) -> list[RegisterSpec]:
        """The function codes, in address order."""
        return [s for s in self.specs() if is_fcode(s.address)]
