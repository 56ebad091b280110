"""The operations: everything a front end may do to a running simulator, checked, in one vocabulary.

The dashboard, the HTTP API, ``c20sim ctl``, the scenarios and the pytest
handle all call these functions and nothing below them: none of them touches
a :class:`~c20sim.drive.model.Drive` or a
:class:`~c20sim.core.linkfaults.LinkFaults` itself. Each function checks its
inputs (JSON-like values: the same check whoever asks) and raises
:class:`ControlError` with an HTTP status and a sentence saying what is wrong;
nothing is changed unless every input is right. The names come from the
register map (:class:`~c20sim.wire.registers.Command`, ...), the link faults'
:data:`~c20sim.core.linkfaults.KNOBS`, the :data:`CONDITIONS` table here and the
:mod:`~c20sim.control.causes` table: a new condition or link fault is defined
in one of those places and every front end has it.

Pure: no I/O, no clock of its own; time is the simulator's.
"""

from __future__ import annotations

import difflib
import itertools
import json
import math
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from ..core.bus import FrameRecord
from ..core.clock import RealtimeClock
from ..core.generators import GeneratorError, parse_generator
from ..core.linkfaults import KNOBS, LinkFaults
from ..core.simulator import Simulator, set_address
from ..drive.model import Drive, HallFault, Telemetry
from ..drive.params import ParameterStore, StateFileError
from ..wire.errors import C20SimError, ModbusError
from ..wire.protocol import ExceptionCode, ExceptionResponse, WriteSingleRequest
from ..wire.registers import Access, Command, Reg, RunChannel, address_label, is_fcode
from ..wire.vocabulary import UnknownRegister, resolve_register

__all__ = [
    "CONDITIONS",
    "KEYS",
    "LINK_CHECKS",
    "MAX_ADVANCE",
    "Condition",
    "ControlError",
    "Setup",
    "advance",
    "check_conditions",
    "check_fault",
    "check_link_faults",
    "clear_fault",
    "clear_generators",
    "clear_link_faults",
    "clock_state",
    "conditions",
    "counters",
    "drive",
    "drive_state",
    "frames",
    "generators",
    "inject_fault",
    "key_command",
    "keypad_edit",
    "link_state",
    "parse_register",
    "pause",
    "power_cycle",
    "press_key",
    "read_register",
    "read_setup",
    "register_address",
    "registers",
    "reset",
    "restore_defaults",
    "resume",
    "set_conditions",
    "set_link_faults",
    "set_run_channel",
    "set_speed",
    "telemetry",
    "unknown",
    "write_register",
]


class ControlError(C20SimError):
    """An operation that cannot be done: ``status`` is the HTTP status to answer with.

    ``exception`` is the Modbus exception code a master would have got for the same thing (a refused
    register edit), or None.
    """

    def __init__(self, message: str, status: int = 400, *, exception: int | None = None) -> None:
        super().__init__(message)
        self.status = status
        self.exception = exception


# --- Checking JSON-like values.


def number(key: str, value: object, low: float | None = None, high: float | None = None) -> float:
    """A finite number, within ``low``-``high`` where given."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ControlError(f"{key}: expected a number, got {_shown(value)}")
    bounds = f"{low:g}-{high:g}" if low is not None and high is not None else f">= {low:g}" if low is not None else ""
    if isinstance(value, int) and abs(value) >= _HUGE:  # beyond a float: said by its length, not printed
        raise ControlError(f"{key}: a number of {_digits(value)} is outside {bounds or 'a float'}")
    if not math.isfinite(value):
        raise ControlError(f"{key}: expected a finite number, got {value}")
    if (low is not None and value < low) or (high is not None and value > high):
        raise ControlError(f"{key}: {value:g} is outside {bounds}")
    return float(value)


def integer(key: str, value: object, low: int, high: int) -> int:
    """A whole number within ``low``-``high``."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise ControlError(f"{key}: expected an integer, got {_shown(value)}")
    if not low <= value <= high:
        raise ControlError(f"{key}: {_shown(value)} is outside {low}-{high}")
    return value


#: Numbers from 10^30 on are said by their length in an error, never printed (nor made floats): no value an
#: operation takes comes near, and a number of thousands of digits would fill the message.
_HUGE = 10**30


def _digits(value: int) -> str:
    """``4000 digits``: a whole number's length (past the interpreter's limit on printing one: said so)."""
    try:
        return f"{len(str(abs(value)))} digits"
    except ValueError:  # more digits than int -> str may make (sys.set_int_max_str_digits)
        return f"more than {sys.get_int_max_str_digits()} digits"


def _shown(value: object) -> str:
    """A JSON value for an error message: a number of thousands of digits said by its length, a long value cut."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= _HUGE:
        return f"a number of {_digits(value)}"
    text = json.dumps(value, default=str)
    return text if len(text) <= 80 else text[:77] + "..."


def flag(key: str, value: object) -> bool:
    if not isinstance(value, bool):
        raise ControlError(f"{key}: expected true or false, got {_shown(value)}")
    return value


def unknown(kind: str, key: str, known: Mapping[str, object] | Sequence[str]) -> ControlError:
    """The error for an unknown name: the closest known one, and all of them."""
    names = list(known)
    close = difflib.get_close_matches(key, names, n=1)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    return ControlError(f"unknown {kind} {key!r}{hint} (known: {', '.join(names)})")


# --- The drives.


def drive(sim: Simulator, address: int) -> Drive:
    """The drive at ``address``; 404 if there is none."""
    try:
        return sim.drives[address]
    except KeyError:
        raise ControlError(
            f"no drive at address {address}; drives: {', '.join(map(str, sim.drives))}", status=404
        ) from None


def _synced(sim: Simulator, address: int) -> Drive:
    """The drive at ``address``, brought to the clock's time: every change happens at 'now'."""
    found = drive(sim, address)
    sim.sync()
    return found


def telemetry(sim: Simulator, address: int) -> Telemetry:
    """The drive's telemetry now."""
    return _synced(sim, address).telemetry()


def drive_state(sim: Simulator, address: int) -> dict[str, Any]:
    """The drive's telemetry now, as JSON-ready values, with its conditions and link faults."""
    found = _synced(sim, address)
    state = asdict(found.telemetry())
    state["address"] = address
    state["conditions"] = _read_conditions(found)
    state["link_faults"] = link_state(sim.link_faults(address))
    state["generators"] = sim.generators(address)
    return state


# --- Registers.


def register_address(text: object) -> int:
    """A register's address from its spelling alone, in the one vocabulary of every tool
    (:func:`~c20sim.wire.vocabulary.resolve_register`): ``speed``, ``motor_speed``, ``motor speed``, ``3006H``,
    ``0x3006``, ``12294``, ``F00.10`` or an int.

    The spelling only: whether a profile has the register is :func:`parse_register`'s question.
    """
    try:
        return resolve_register(text)  # type: ignore[arg-type]  # anything else is refused in words
    except UnknownRegister as exc:
        raise ControlError(str(exc)) from None


def parse_register(sim: Simulator, text: str | int) -> int:
    """A register as :func:`register_address` reads it, which the simulator's profile must have (a did-you-mean
    where the spelling is close to one)."""
    try:
        return resolve_register(text, sim.profile.registers, f"the profile {sim.profile.name}")
    except UnknownRegister as exc:
        raise ControlError(str(exc)) from None


def read_register(sim: Simulator, address: int, register: str | int) -> dict[str, Any]:
    """A register's value as a master would read it, without counting as communication."""
    drive(sim, address)
    reg = parse_register(sim, register)
    spec = sim.profile.registers[reg]
    sim.sync()
    raw = sim.ports[address].read(sim.profile.registers.canonical(reg))  # through the profile's behaviours
    return {
        "register": spec.label,
        "address": reg,
        "name": spec.name,
        "raw": raw,
        "value": spec.engineering(raw),
        "unit": spec.unit,
        "text": spec.describe(raw),
    }


#: How the sheet groups its registers (section 2), in its order; function codes go by group, Fgg.
SHEET_GROUPS: tuple[tuple[str, range], ...] = (
    ("communication control command", range(0x2000, 0x2001)),
    ("communication set points", range(0x2001, 0x2100)),
    ("drive status", range(0x2100, 0x2200)),
    ("monitoring", range(0x3000, 0x3100)),
)


def register_group(address: int) -> str:
    """The sheet's group of a register: ``drive status``, ``monitoring``, ..., or ``function codes F08``."""
    for name, span in SHEET_GROUPS:
        if address in span:
            return name
    return f"function codes F{address >> 8:02d}"


def registers(sim: Simulator, address: int) -> list[dict[str, Any]]:
    """Every register of the drive's map (fixed registers, then the profile's function codes) with its value now:
    group, access class, whether it is locked now (W/R* while running), range, source, value in words."""
    found = _synced(sim, address)
    out = []
    regs = sim.profile.registers
    fixed = [s for s in regs.specs() if not is_fcode(s.address)]
    for spec in fixed + regs.parameters():
        raw = found.read(spec.storage) & 0xFFFF
        out.append(
            {
                "register": spec.label,
                "address": int(spec.address),
                "group": register_group(spec.address),
                "name": spec.name,
                "access": spec.access.value,
                "locked": spec.access is Access.RW_STOPPED and found.running,
                "minimum": spec.minimum,
                "maximum": spec.maximum,
                "raw": raw,
                "text": spec.describe(raw),
                "unit": spec.unit,
                "source": spec.source,
                "mirrors": address_label(regs.mirrors[spec.address]) if spec.address in regs.mirrors else None,
            }
        )
    return out


def write_register(sim: Simulator, address: int, register: str | int, value: object) -> dict[str, Any]:
    """Write a register from the bench by the rules a master meets (access, range, 200EH, password, W/R*).

    A refusal raises ControlError (409) whose ``exception`` is the code a master would have got. Not a frame on the
    line: nothing in the frame log, and the communication timeout is not fed.
    """
    drive(sim, address)
    reg = parse_register(sim, register)
    raw = integer("value", value, 0, 0xFFFF)
    sim.sync()
    response = sim.slaves[address].handle(WriteSingleRequest(address, reg, raw), sim.now(), communicated=False)
    if isinstance(response, ExceptionResponse):
        code = response.code
        spec = sim.profile.registers[reg]
        why = ""
        if code == ExceptionCode.ILLEGAL_VALUE and not spec.minimum <= raw <= spec.maximum:
            why = f": {spec.label} takes {spec.minimum}-{spec.maximum}"
        elif (
            code == ExceptionCode.OPERATION_FAILED
            and is_fcode(sim.profile.registers.canonical(reg))
            and sim.drives[address].read(Reg.WRITE_ENABLE) == 0
        ):
            why = ": function codes are locked while 200EH = 0 (write 200EH = 1 first)"
        raise ControlError(
            f"{spec.label} = {raw} refused: exception 0x{int(code):02X} ({code.meaning}), as a master would get it"
            + why,
            status=409,
            exception=int(code),
        )
    return read_register(sim, address, reg)


def counters(sim: Simulator, address: int) -> dict[str, object]:
    """The drive's traffic counters: requests, replies, exceptions by code, CRC and length errors, silences,
    and what link faults acted on."""
    drive(sim, address)
    return sim.bus.counters_of(address).as_dict()


# --- Conditions: the drive's physical surroundings.


@dataclass(frozen=True)
class Condition:
    """One physical condition: how a value is checked, set on a drive and read back from it."""

    name: str
    unit: str
    #: the range of a numeric condition (None for the others)
    low: float | None
    high: float | None
    read: Callable[[Drive], object]
    write: Callable[[Drive, Any], None]
    check: Callable[[str, object], object]
    help: str = ""
    #: a continuous quantity: it may be given a generator (c20sim.core.generators) instead of a value
    continuous: bool = False


def _ranged(
    name: str, unit: str, low: float, high: float, read: Callable[[Drive], float], write: Callable[[Drive, float], None]
) -> Condition:
    return Condition(name, unit, low, high, read, write, lambda k, v: number(k, v, low, high), continuous=True)


def _hall(key: str, value: object) -> str | None:
    choices = [f.value for f in HallFault]
    if value is not None and value not in choices:
        names = ", ".join(map(repr, choices[:-1])) + f" or {choices[-1]!r}"
        raise ControlError(f"{key}: expected null, {names}, got {_shown(value)}")
    return None if value is None else str(value)


def _hall_now(d: Drive) -> str | None:
    fault = d.hall_fault
    return None if fault is None else fault.value


#: Every condition, by the name all front ends use. To add one: a row here (and its setter on the Drive).
CONDITIONS: Mapping[str, Condition] = {
    c.name: c
    for c in (
        _ranged("supply_v", "V", 0, 2000, lambda d: d.telemetry().supply_v, lambda d, v: d.set_supply_voltage(v)),
        _ranged(
            "load_torque_nm", "N m", 0, 1000, lambda d: d.telemetry().load_torque_nm, lambda d, v: d.set_load_torque(v)
        ),
        _ranged("active_load_nm", "N m", -1000, 1000, lambda d: d.active_load, lambda d, v: d.set_active_load(v)),
        _ranged(
            "load_inertia_kg_m2",
            "kg m2",
            0,
            100,
            lambda d: d.telemetry().load_inertia_kg_m2,
            lambda d, v: d.set_load_inertia(v),
        ),
        _ranged("ambient_c", "°C", -50, 150, lambda d: d.telemetry().ambient_c, lambda d, v: d.set_ambient(v)),
        Condition(
            "hall_fault",
            "",
            None,
            None,
            _hall_now,
            lambda d, v: d.set_hall_fault(v),
            _hall,
            help="null, 'stuck0', 'stuck7' or 'sequence'",
        ),
        _ranged("ai1_v", "V", 0, 10, lambda d: d.ai(1), lambda d, v: d.set_ai(1, v)),
        _ranged("ai2_v", "V", 0, 10, lambda d: d.ai(2), lambda d, v: d.set_ai(2, v)),
        _ranged("ai3_v", "V", 0, 10, lambda d: d.ai(3), lambda d, v: d.set_ai(3, v)),
        Condition(
            "dial_switches",
            "",
            0,
            7,
            lambda d: sum(1 << i for i, on in enumerate(d.dial_switches) if on),
            lambda d, v: d.set_dial_switches(bool(v & 1), bool(v & 2), bool(v & 4)),
            lambda k, v: integer(k, v, 0, 7),
            help="the dial switches, bit 0 SW1, bit 1 SW2, bit 2 SW3 (they act where 2005H = 3, 2006H = 3, 2007H = 5)",
        ),
        Condition(
            "terminal_inputs",
            "",
            0,
            0x1FF,
            lambda d: d.physical_inputs,
            lambda d, v: d.set_terminal_inputs(v),
            lambda k, v: integer(k, v, 0, 0x1FF),
            help="the physical input terminals, bits 0-8",
        ),
    )
}


def check_conditions(values: object) -> dict[str, object]:
    """Check conditions by their :data:`CONDITIONS` names; returns the checked values.

    A continuous condition may be given a generator instead of a value, such as ``{"ramp": 30, "over": 5}``
    (:func:`c20sim.core.generators.parse_generator`): it is checked here, and started by :func:`set_conditions`.
    """
    if not isinstance(values, Mapping) or not values:
        raise ControlError(f'give conditions as an object, such as {{"supply_v": 30}}; known: {", ".join(CONDITIONS)}')
    checked: dict[str, object] = {}
    for key, value in values.items():
        condition = CONDITIONS.get(key)
        if condition is None:
            raise unknown("condition", key, CONDITIONS)
        if isinstance(value, Mapping):
            checked[key] = _check_generator(condition, value)
        else:
            checked[key] = condition.check(key, value)
    return checked


def _check_generator(condition: Condition, spec: Mapping[str, object]) -> Mapping[str, object]:
    if not condition.continuous or condition.low is None or condition.high is None:
        raise ControlError(
            f"{condition.name}: takes a value, not a generator; generators are for continuous conditions"
        )
    try:
        parse_generator(condition.name, spec, condition.low, condition.high, 0.0, condition.low)
    except GeneratorError as exc:
        raise ControlError(str(exc)) from None
    return spec


def set_conditions(sim: Simulator, address: int, values: Mapping[str, object]) -> None:
    """Set conditions at the drive's current time; all are checked before any is applied.

    A value stops a generator running on that condition; a generator (see :func:`check_conditions`)
    starts from the condition's value now and is applied as the drive is advanced.
    """
    found = drive(sim, address)
    checked = check_conditions(values)
    sim.sync()
    for key, value in checked.items():
        condition = CONDITIONS[key]
        if isinstance(value, Mapping):
            assert condition.low is not None and condition.high is not None
            current = condition.read(found)
            assert isinstance(current, int | float)
            generator = parse_generator(key, value, condition.low, condition.high, sim.now(), float(current))
            sim.set_generator(address, key, generator, condition.write, condition.low, condition.high)
        else:
            sim.clear_generator(address, key)
            condition.write(found, value)


def generators(sim: Simulator, address: int) -> dict[str, dict[str, Any]]:
    """The generators running on the drive's conditions, by condition."""
    drive(sim, address)
    sim.sync()
    return sim.generators(address)


def clear_generators(sim: Simulator, address: int, name: object = None) -> dict[str, dict[str, Any]]:
    """Stop the generator on condition ``name`` (all of the drive's for None); the conditions stay where
    they are. Returns the generators still running."""
    drive(sim, address)
    if name is not None and not isinstance(name, str):
        raise ControlError(f"condition: expected a condition's name, such as supply_v, got {_shown(name)}")
    if name is not None and name not in CONDITIONS:
        raise unknown("condition", name, CONDITIONS)
    sim.clear_generator(address, None if name is None else str(name))
    return sim.generators(address)


def _read_conditions(found: Drive) -> dict[str, object]:
    return {name: condition.read(found) for name, condition in CONDITIONS.items()}


def conditions(sim: Simulator, address: int) -> dict[str, object]:
    """The conditions the drive is in now, whoever set them, by their :data:`CONDITIONS` names."""
    return _read_conditions(_synced(sim, address))


# --- Device faults by code (by cause: c20sim.control.causes).


def check_fault(code: object, persistent: object = False) -> tuple[int, bool]:
    """A device fault to inject: ``code`` 1-255, and whether it is ``persistent``."""
    return integer("code", code, 1, 0xFF), flag("persistent", persistent)


def inject_fault(sim: Simulator, address: int, code: object, persistent: object = False) -> None:
    """Latch device fault ``code`` now; ``persistent`` makes resets fail until :func:`clear_fault`."""
    found = drive(sim, address)
    number_, hold = check_fault(code, persistent)
    sim.sync()
    found.force_fault(number_, persistent=hold)


def held_fault(sim: Simulator, address: int) -> int | None:
    """The code of a fault latched persistently and not yet released, or None."""
    return _synced(sim, address).held_fault


def clear_fault(sim: Simulator, address: int, reset: object = True) -> bool:
    """Release an injected fault's cause and (with ``reset``) press fault reset; True if the drive left the fault."""
    found = drive(sim, address)
    press = flag("reset", reset)
    sim.sync()
    found.release_fault()
    return found.keypad(Command.RESET) if press else False


# --- The keypad.

#: Keypad key name -> 2000H command, as the register map names them (``forward`` ... ``jog_stop``).
KEYS: Mapping[str, Command] = {command.key: command for command in Command}


def key_command(key: object) -> Command:
    """A keypad key (a name of :data:`KEYS` or a 2000H value 1-8) -> its 2000H command."""
    if isinstance(key, str):
        if key not in KEYS:
            raise unknown("key", key, KEYS)
        return KEYS[key]
    return Command(integer("key", key, 1, 8))


def press_key(sim: Simulator, address: int, key: object) -> bool:
    """Press a keypad key (a name of :data:`KEYS` or a 2000H value 1-8); False if the drive refused it."""
    found = drive(sim, address)
    command = key_command(key)
    sim.sync()
    return found.keypad(command)


def keypad_edit(sim: Simulator, address: int, register: str | int, value: object) -> dict[str, Any]:
    """Set a parameter from the drive's own panel: the slave's rules (range, W/R*, the model's own refusals)
    apply, the communication locks (200EH, password) do not, as on the drive's keypad. A refusal raises
    ControlError (409) naming the code a master would get for the same write."""
    drive(sim, address)
    reg = parse_register(sim, register)
    raw = integer("value", value, 0, 0xFFFF)
    sim.sync()
    try:
        sim.slaves[address].panel_write(reg, raw)
    except ModbusError as exc:
        label = sim.profile.registers[reg].label
        raise ControlError(
            f"{label} = {raw} refused: exception 0x{int(exc.code):02X} ({exc.code.meaning}) for a master",
            status=409,
            exception=int(exc.code),
        ) from None
    return read_register(sim, address, reg)


def set_run_channel(sim: Simulator, address: int, channel: object) -> RunChannel:
    """Set F00.01 (2006H) from the drive's own panel, as its keypad edits it."""
    if isinstance(channel, str):
        names = {c.key: c for c in RunChannel}
        if channel not in names:
            raise unknown("run channel", channel, names)
        value = names[channel]
    else:
        value = RunChannel(integer("channel", channel, 0, max(RunChannel)))
    keypad_edit(sim, address, Reg.RUN_CHANNEL, int(value))
    return value


def restore_defaults(sim: Simulator, address: int) -> None:
    """200FH = 1 from the panel: only while stopped (409 otherwise); the drive keeps its bus address."""
    found = _synced(sim, address)
    if found.running:
        raise ControlError("restore defaults refused: stop the motor first (200FH is W/R*)", status=409)
    found.write(Reg.RESTORE_DEFAULTS, 1)
    set_address(found, sim.profile, address)


def power_cycle(sim: Simulator, address: int) -> None:
    """Switch the drive's supply off and on."""
    _synced(sim, address).power_cycle()


# --- Time.

#: The longest step :func:`advance` takes: ten years of model time.
MAX_ADVANCE = 10 * 365 * 86400


def advance(sim: Simulator, seconds: object) -> float:
    """Move a virtual clock on by ``seconds`` (finite, 0 to ten years); returns the new time."""
    step = number("seconds", seconds, 0, MAX_ADVANCE)
    if not sim.virtual:
        raise ControlError("time runs on the wall clock; start the server with --clock virtual to advance it", 409)
    return sim.run_until(sim.now() + step)


# --- Link faults.


def links(sim: Simulator, address: int | None) -> LinkFaults:
    """The link faults of one drive (404 if there is none), or of the whole bus for None."""
    if address is not None:
        drive(sim, address)
    return sim.link_faults(address)


def link_state(link: LinkFaults) -> dict[str, Any]:
    """Link faults as JSON-ready values, with ``active``: the names of those switched on."""
    out: dict[str, Any] = {}
    for name in KNOBS:
        value = getattr(link, name)
        if isinstance(value, bytes):
            value = value.hex(" ").upper()
        elif isinstance(value, ExceptionCode):
            value = int(value)
        out[name] = value
    out["active"] = link.active
    return out


def _hex_bytes(key: str, value: object) -> bytes:
    if not isinstance(value, str):
        raise ControlError(f'{key}: expected hex bytes such as "FF 00", got {_shown(value)}')
    try:
        return bytes.fromhex(value)
    except ValueError:
        raise ControlError(f'{key}: {value!r} is not hex bytes such as "FF 00"') from None


def _exception_code(key: str, value: object) -> ExceptionCode | None:
    if value is None:
        return None
    if isinstance(value, str) and value.upper() in ExceptionCode.__members__:
        return ExceptionCode[value.upper()]
    code = integer(key, value, 1, 0xFF) if not isinstance(value, str) else -1
    try:
        return ExceptionCode(code)
    except ValueError:
        codes = ", ".join(f"{c.name} ({int(c)})" for c in ExceptionCode)
        raise ControlError(f"{key}: {_shown(value)} is not an exception code; use one of {codes}") from None


#: How a value of each kind of link fault is checked (the kinds of :class:`~c20sim.core.linkfaults.Knob`).
KIND_CHECKS: Mapping[str, Callable[[str, object], object]] = {
    "flag": flag,
    "count": lambda k, v: integer(k, v, 0, 1_000_000),
    "percent": lambda k, v: number(k, v, 0, 100),
    "seconds": lambda k, v: number(k, v, 0, 60),
    "bytes": _hex_bytes,
    "address": lambda k, v: None if v is None else integer(k, v, 0, 255),
    "exception": _exception_code,
}

#: Link fault name -> its checker, from the link faults' own knobs.
LINK_CHECKS: Mapping[str, Callable[[str, object], object]] = {
    name: KIND_CHECKS[knob.kind] for name, knob in KNOBS.items()
}


def check_link_faults(values: object) -> dict[str, object]:
    """Check link faults by their :data:`~c20sim.core.linkfaults.KNOBS` names; returns the values to set."""
    if not isinstance(values, Mapping) or not values:
        raise ControlError(f'give link faults as an object, such as {{"offline": true}}; known: {", ".join(KNOBS)}')
    checked = {}
    for key, value in values.items():
        check = LINK_CHECKS.get(key)
        if check is None:
            raise unknown("link fault", key, KNOBS)
        checked[key] = check(key, value)
    return checked


def set_link_faults(sim: Simulator, address: int | None, values: Mapping[str, object]) -> LinkFaults:
    """Switch link faults of one drive (or the bus for None); all are checked before any is set."""
    link = links(sim, address)
    for key, value in check_link_faults(values).items():
        setattr(link, key, value)
    return link


def clear_link_faults(sim: Simulator, address: int | None) -> LinkFaults:
    link = links(sim, address)
    link.clear()
    return link


# --- The frame log.


def frames(
    sim: Simulator,
    *,
    last: int | None = None,
    slave: int | None = None,
    since: int = 0,
    first_seq: int = 0,
    wall_offset: float | None = None,
) -> list[dict[str, Any]]:
    """The frame log, oldest first, each record with its sequence number ``seq`` (from ``first_seq``).

    ``last`` keeps the newest N (N >= 1) of the records left after ``since`` and ``slave``;
    only the records kept are put in words, which is what costs. ``wall_offset`` (from the I/O layer)
    adds each frame's wall-clock time.
    """
    return frames_in_words(select_frames(sim, last=last, slave=slave, since=since, first_seq=first_seq), wall_offset)


def select_frames(
    sim: Simulator, *, last: int | None = None, slave: int | None = None, since: int = 0, first_seq: int = 0
) -> list[tuple[int, FrameRecord]]:
    """The records :func:`frames` keeps, with their sequence numbers (cheap: the records are not copied)."""
    if last is not None and (isinstance(last, bool) or last < 1):
        raise ControlError(f"last={last} must be at least 1")
    records = sim.bus.records
    skip = min(max(0, since - first_seq), len(records))
    kept = [
        (first_seq + i, record)
        for i, record in enumerate(itertools.islice(records, skip, None), start=skip)
        if slave is None or record.slave == slave
    ]
    if last is not None:
        kept = kept[-last:]
    return kept


def frames_in_words(kept: list[tuple[int, FrameRecord]], wall_offset: float | None = None) -> list[dict[str, Any]]:
    """Selected records in words: what costs, and touches no simulator state (records are frozen), so a worker
    thread may do it."""
    return [{"seq": seq, **record.as_dict(wall_offset)} for seq, record in kept]


# --- Runtime control: the clock, and set-ups.

#: The speed factors :func:`set_speed` takes: model seconds per wall second.
SPEED_RANGE = (0.001, 1000.0)
#: The set-up :func:`reset` names the profile's defaults by.
DEFAULTS = "defaults"


def clock_state(sim: Simulator) -> dict[str, Any]:
    """The clock: ``clock`` (virtual or realtime), ``t``, ``paused`` and ``speed`` (None for virtual)."""
    clock = sim.clock
    realtime = clock if isinstance(clock, RealtimeClock) else None
    return {
        "clock": "virtual" if sim.virtual else "realtime",
        "t": sim.now(),
        "paused": realtime.paused if realtime is not None else False,
        "speed": realtime.speed if realtime is not None else None,
    }


def _realtime(sim: Simulator, what: str) -> RealtimeClock:
    if not isinstance(sim.clock, RealtimeClock):
        raise ControlError(
            f"{what}: the clock is virtual and moves only when advanced; {what} is for serve --clock realtime", 409
        )
    return sim.clock


def pause(sim: Simulator) -> dict[str, Any]:
    """Stop the model's time (realtime clock; 409 for a virtual one): the drives stand still, and still
    answer the bus, until :func:`resume`."""
    clock = _realtime(sim, "pause")
    sim.sync()
    clock.pause()
    return clock_state(sim)


def resume(sim: Simulator) -> dict[str, Any]:
    """Let a paused realtime clock run on from where it stopped."""
    _realtime(sim, "resume").resume()
    return clock_state(sim)


def set_speed(sim: Simulator, factor: object) -> dict[str, Any]:
    """Set the realtime clock's speed factor (model seconds per wall second), with no jump in time."""
    clock = _realtime(sim, "speed")
    value = number("speed", factor, *SPEED_RANGE)
    sim.sync()
    clock.speed = value
    return clock_state(sim)


@dataclass(frozen=True)
class Setup:
    """A set-up for :func:`reset`, read already: its name (``"defaults"`` or the state file's path) and the
    function codes it gives (None: the profile's defaults)."""

    name: str
    values: dict[int, int] | None


def read_setup(sim: Simulator, setup: object) -> Setup:
    """What :func:`reset` takes from ``setup``: ``"defaults"``, or the state file at that path, read (bounded,
    never a FIFO or a device) and checked against the served profile. Touches no drive, so it may run in a
    worker thread, off the serving loop (the ``POST /reset`` row's offload in :mod:`.routes`)."""
    if isinstance(setup, Setup):
        return setup
    if not isinstance(setup, str) or not setup:
        raise ControlError(f'setup: give "{DEFAULTS}" or the path of a state file, got {_shown(setup)}')
    if setup == DEFAULTS:
        return Setup(setup, None)
    try:
        return Setup(setup, ParameterStore(sim.profile)._read(Path(setup)))  # read only: no save, no tidying
    except StateFileError as exc:
        if not Path(setup).exists():
            raise ControlError(
                f'setup {setup!r}: no such state file; give "{DEFAULTS}" or the path of a file written by --state'
            ) from None
        raise ControlError(f"setup: {exc}") from None
    except C20SimError as exc:
        raise ControlError(f"setup: {exc}") from None


def reset(sim: Simulator, setup: object = DEFAULTS) -> dict[str, Any]:
    """Every drive anew without restarting (:meth:`Simulator.reset`), set up from ``setup``: ``"defaults"``
    (the profile's function codes), the path of a c20sim state file (``--state``) to take them from, or a
    :class:`Setup` read already (by :func:`read_setup`, off the loop). The file is only read. Returns
    ``{"setup": ..., "drives": [...]}``."""
    found = read_setup(sim, setup)
    sim.reset(found.values)
    return {"setup": found.name, "drives": [drive_state(sim, a) for a in sim.drives]}
