"""The operations: everything a front end may do to a running simulator, checked, in one vocabulary.

The dashboard, the HTTP API, ``c20sim ctl``, the scenarios and the pytest
handle all call these functions and nothing below them: none of them touches
a :class:`~c20sim.drive.model.Drive` or a
:class:`~c20sim.core.linkfaults.LinkFaults` itself. Each function checks its
inputs (JSON-like values: the same check whoever asks) and raises
:class:`ControlError` with an HTTP status and a sentence saying what is wrong;
nothing is changed unless every input is right. The names come from the
register map (:class:`~c20sim.wire.registers.Command`, ...), the link faults'
:data:`~c20sim.core.linkfaults.KNOBS`, the conditions' rows
(:data:`c20sim.drive.conditions.CONDITIONS`, checked here as :data:`CONDITIONS`)
and the fault causes' rows (:data:`c20sim.drive.trips.TRIPS`, brought about by
:mod:`~c20sim.control.causes`): a new condition, cause or link fault is one row
in one of those places and every front end has it.

Pure: no I/O, no clock of its own; time is the simulator's.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from ..core.simulator import Simulator, set_address
from ..drive.model import Telemetry
from ..drive.params import ParameterStore, StateFileError
from ..wire.errors import C20SimError, ModbusError
from ..wire.protocol import ExceptionCode, ExceptionResponse, WriteSingleRequest
from ..wire.registers import (
    Access,
    Command,
    Reg,
    RunChannel,
    address_label,
    is_fcode,
)
from ..wire.vocabulary import UnknownRegister, resolve_register
from .conditionops import (
    CONDITIONS,
    Condition,
    _read_conditions,
    check_conditions,
    clear_generators,
    conditions,
    generators,
    set_conditions,
)
from .linkops import (
    KIND_CHECKS,
    LINK_CHECKS,
    check_link_faults,
    clear_link_faults,
    link_state,
    links,
    set_link_faults,
)
from .opscore import ControlError, _shown, _synced, drive, flag, integer, number, unknown
from .runtimeops import SPEED_RANGE, clock_state, frames, frames_in_words, pause, resume, select_frames, set_speed

__all__ = [
    "CONDITIONS",
    "KEYS",
    "KIND_CHECKS",
    "LINK_CHECKS",
    "MAX_ADVANCE",
    "SPEED_RANGE",
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
    "flag",
    "frames",
    "frames_in_words",
    "generators",
    "held_fault",
    "inject_fault",
    "integer",
    "key_command",
    "keypad_edit",
    "link_state",
    "links",
    "number",
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
    "select_frames",
    "set_conditions",
    "set_link_faults",
    "set_run_channel",
    "set_speed",
    "telemetry",
    "unknown",
    "write_register",
]

# --- The drives.


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


# --- Set-ups.

#: The set-up :func:`reset` names the profile's defaults by.
DEFAULTS = "defaults"


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
