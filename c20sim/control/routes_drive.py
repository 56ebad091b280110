"""A drive's routes: its state, registers, counters, conditions, faults and their causes, keypad, panel and
generators."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ..core.simulator import Simulator
from ..wire.amounts import parse_value
from ..wire.errors import C20SimError
from ..wire.registers import Command
from . import causes, liveaudit, ops
from .opscore import _shown
from .routing import Field, Route, Schema
from .schemas import Live, cause_schema, conditions_schema


def _state(sim: Simulator, address: int) -> dict[str, Any]:
    return ops.drive_state(sim, address)


def _counters(sim: Simulator, address: int) -> dict[str, object]:
    """The drive's traffic counters, and the line demand of the live audit (the line the drive is on)."""
    counters = ops.counters(sim, address)
    audit = liveaudit.of(sim)
    if audit is not None:
        counters["line_demand"] = audit.line_demand().as_dict()
    return counters


def _drives(sim: Simulator) -> dict[str, Any]:
    return {"drives": [ops.drive_state(sim, a) for a in sim.drives]}


def _registers(sim: Simulator, address: int) -> dict[str, Any]:
    return {"registers": ops.registers(sim, address)}


#: What to give when a write names no value (or both forms).
_GIVE = (
    'give the value in the register\'s units or by name, such as {"value": 2.5} or {"value": "forward"}, '
    'or the raw word, such as {"raw": 1500}; not both'
)


#: The longest text a written value may be (assumed: four times the stock profile's longest value name, the
#: 65 characters of "HALL: Hall sensor fault (...)"); a longer text is said by its length, never echoed back.
_LONGEST = 256


def written(sim: Simulator, register: str | int, value: object = None, raw: object = None) -> int:
    """The raw word a write asks for: ``raw`` as it is, or ``value`` as exercise reads it (:func:`parse_value`):
    a string or a fraction in the register's units or by a value's name (``"2.5"``, ``0.5``, ``"forward"``); a
    JSON integer ``value`` is the raw word, as it always was (the dashboard and the browser page send it)."""
    if (value is None) == (raw is None):
        raise ops.ControlError(_GIVE)
    if raw is not None:
        return ops.integer("raw", raw, 0, 0xFFFF)
    if isinstance(value, int) and not isinstance(value, bool):
        return ops.integer("value", value, 0, 0xFFFF)
    if isinstance(value, bool) or not isinstance(value, float | str):
        raise ops.ControlError(f"value: expected a number or a value's name, got {_shown(value)}")
    if isinstance(value, str) and len(value) > _LONGEST:
        raise ops.ControlError(f"value: a text of {len(value)} characters; an amount or a name is {_LONGEST} at most")
    spec = sim.profile.registers[ops.parse_register(sim, register)]
    try:
        return parse_value(spec, repr(value) if isinstance(value, float) else value)
    except C20SimError as exc:
        raise ops.ControlError(str(exc)) from None


def _write(sim: Simulator, address: int, register: str, value: object = None, raw: object = None) -> dict[str, Any]:
    ops.drive(sim, address)
    return ops.write_register(sim, address, register, written(sim, register, value, raw))


def _panel(sim: Simulator, address: int, register: str, value: object = None, raw: object = None) -> dict[str, Any]:
    ops.drive(sim, address)
    return ops.keypad_edit(sim, address, register, written(sim, register, value, raw))


def _conditions(sim: Simulator, address: int, values: Mapping[str, object]) -> dict[str, Any]:
    ops.set_conditions(sim, address, values)
    return ops.drive_state(sim, address)


def _fault(sim: Simulator, address: int, request: Mapping[str, object]) -> dict[str, Any]:
    note = causes.request(sim, address, request)
    return {"note": note, **ops.drive_state(sim, address)}


def _clear_fault(sim: Simulator, address: int, reset: object = True, cause: object = None) -> dict[str, Any]:
    """End ``cause`` (by default every cause present now, and no other condition) and press reset."""
    ending = [cause] if cause is not None else [name for name, on in causes.active(sim, address).items() if on]
    notes = [causes.release(sim, address, name) for name in ending]
    press = ops.flag("reset", reset)
    cleared = ops.clear_fault(sim, address, reset) if press else False
    refused = causes.reset_refusal(sim, address) if press and not cleared else None
    if refused:
        notes.append(f"drive {address} kept its fault: {refused}")
    state = ops.drive_state(sim, address)
    return {"reset": cleared, "note": "; ".join(notes), **state} | ({"refused": refused} if refused else {})


def _causes(sim: Simulator, address: int) -> dict[str, Any]:
    return {"causes": causes.active(sim, address)}


def _clear_causes(sim: Simulator, address: int) -> dict[str, Any]:
    causes.clear_all(sim, address)
    return {"causes": causes.active(sim, address)}


def _keypad(sim: Simulator, address: int, key: object) -> dict[str, Any]:
    accepted = ops.press_key(sim, address, key)
    resets = ops.key_command(key) is Command.RESET
    refused = causes.reset_refusal(sim, address) if resets and not accepted else None
    return {"accepted": accepted, **ops.drive_state(sim, address)} | ({"refused": refused} if refused else {})


def _power_cycle(sim: Simulator, address: int) -> dict[str, Any]:
    ops.power_cycle(sim, address)
    return ops.drive_state(sim, address)


def _run_channel(sim: Simulator, address: int, channel: object) -> dict[str, Any]:
    chosen = ops.set_run_channel(sim, address, channel)
    return {"channel": int(chosen), **ops.drive_state(sim, address)}


def _restore_defaults(sim: Simulator, address: int) -> dict[str, Any]:
    ops.restore_defaults(sim, address)
    return ops.drive_state(sim, address)


def _generators(sim: Simulator, address: int) -> dict[str, Any]:
    return {"generators": ops.generators(sim, address)}


def _clear_generators(sim: Simulator, address: int, condition: object = None) -> dict[str, Any]:
    return {"generators": ops.clear_generators(sim, address, condition)}


# --- Field schemas.

_VALUE = Field(
    "value",
    {"oneOf": [{"type": "integer", "minimum": 0, "maximum": 0xFFFF}, {"type": "number"}, {"type": "string"}]},
    doc='in the register\'s units or by a value\'s name: 2.5, "2.5", "forward" (a JSON integer: the raw word)',
    positional=True,
)
_RAW = Field("raw", {"type": "integer", "minimum": 0, "maximum": 0xFFFF}, doc="the raw word: 1500, 0x5DC")
_KEY = {"oneOf": [{"enum": list(ops.KEYS)}, {"type": "integer", "minimum": 1, "maximum": 8}]}


def _fault_schema() -> Schema:
    def obj(props: Mapping[str, Any], required: tuple[str, ...]) -> dict[str, Any]:
        return {"type": "object", "properties": dict(props), "additionalProperties": False, "required": list(required)}

    return {
        "oneOf": [
            obj({"cause": cause_schema()}, ("cause",)),
            obj(
                {"code": {"type": "integer", "minimum": 1, "maximum": 255}, "persistent": {"type": "boolean"}},
                ("code",),
            ),
        ]
    }


def _conditions_body() -> Schema:
    return conditions_schema()


_D = "/drives/{address}"

#: Every drive's state, and one drive's state, registers, counters, conditions, faults and keypad.
DRIVES: tuple[Route, ...] = (
    Route(
        "GET",
        "/drives",
        "drives",
        "-",
        _drives,
        cli="state",
        help="a drive's telemetry (every drive without --drive)",
    ),
    Route(
        "GET",
        _D,
        "drive",
        "-",
        _state,
        cli="state",
        help="one drive's telemetry: state, speeds, current, bus voltage, temperature, fault",
    ),
    Route(
        "GET",
        f"{_D}/registers",
        "registers",
        "- (every register and function code, grouped as the sheet groups them)",
        _registers,
        help="every register and function code with its value, access and group",
    ),
    Route(
        "GET",
        f"{_D}/registers/{{register}}",
        "read_register",
        "- (register: speed, motor_speed, 3006H, 0x3006, 12294 or F00.10)",
        ops.read_register,
        cli="read",
        help="read a register: a name (speed, status, fault), 3006H, 0x3006, 12294 or F00.10",
    ),
    Route(
        "PUT",
        f"{_D}/registers/{{register}}",
        "write_register",
        '{"value": 2.5} or {"value": "forward"} in its units or names, or {"raw": 1500} (a master\'s rules; a '
        "refusal is 409 with its exception)",
        _write,
        (_VALUE, _RAW),
        changes=True,
        cli="write",
        help="write a register by a master's rules (a refusal names its exception code)",
    ),
    Route(
        "GET",
        f"{_D}/counters",
        "counters",
        "- (requests, replies, exceptions by code, CRC errors, silences, injected; line_demand: the audit's)",
        _counters,
        help="the drive's traffic: requests, replies, exceptions by code, CRC errors, silences",
    ),
    Route(
        "PUT",
        f"{_D}/panel/{{register}}",
        "keypad_edit",
        '{"value": 3} or {"raw": 3}, as a write (the drive\'s own panel: a master\'s rules but 200EH and the password)',
        _panel,
        (_VALUE, _RAW),
        changes=True,
        cli="panel",
        help="edit a register from the drive's own panel (200EH allowed, no password)",
    ),
    Route(
        "PUT",
        f"{_D}/conditions",
        "set_conditions",
        '{"supply_v": 30, "load_torque_nm": 2, ...} (PATCH too)',
        _conditions,
        whole="values",
        body_schema=_conditions_body,
        changes=True,
        cli="set",
        help=f"set conditions: {', '.join(ops.CONDITIONS)}",
    ),
    Route(
        "PATCH",
        f"{_D}/conditions",
        "patch_conditions",
        '{"supply_v": 30, ...}: as PUT',
        _conditions,
        whole="values",
        body_schema=_conditions_body,
        changes=True,
        help="set conditions, as set_conditions does (the API's PATCH)",
        cli=None,
        listed=False,
    ),
    Route(
        "POST",
        f"{_D}/fault",
        "fault",
        '{"cause": "undervoltage"} or {"code": 16, "persistent": false}',
        _fault,
        whole="request",
        body_schema=_fault_schema,
        changes=True,
        help="bring about a fault's cause (--cause undervoltage), or latch a fault by code",
    ),
    Route(
        "DELETE",
        f"{_D}/fault",
        "clear_fault",
        '{"reset": true, "cause": "undervoltage"} (both optional)',
        _clear_fault,
        (Field("reset", {"type": "boolean"}), Field("cause", Live(cause_schema))),
        changes=True,
        cli="clear",
        help="end a fault's cause (--cause NAME; default: every cause) and press reset",
    ),
    Route(
        "GET",
        f"{_D}/causes",
        "causes",
        "- (every fault cause of the profile: whether it is there now)",
        _causes,
        help="every fault cause of the profile, and whether it is there now",
    ),
    Route(
        "POST",
        f"{_D}/keypad",
        "press_key",
        '{"key": "reset"} (forward, reverse, stop, free_stop, reset, ...)',
        _keypad,
        (Field("key", _KEY, True),),
        missing=f'give the key, such as {{"key": "reset"}}; keys: {", ".join(ops.KEYS)}',
        changes=True,
        cli="key",
        help=f"press a keypad key: {', '.join(ops.KEYS)}",
    ),
    Route(
        "POST",
        f"{_D}/power-cycle",
        "power_cycle",
        "-",
        _power_cycle,
        changes=True,
        help="switch the drive off and on",
    ),
    Route(
        "DELETE",
        f"{_D}/causes",
        "clear_causes",
        "- (ends every fault cause; faults stay until reset)",
        _clear_causes,
        changes=True,
        help="end every fault cause (the faults stay until reset)",
    ),
    Route(
        "POST",
        f"{_D}/run-channel",
        "set_run_channel",
        '{"channel": "keypad"} (F00.01 from the panel: a channel name or its number)',
        _run_channel,
        (Field("channel", {"oneOf": [{"type": "string"}, {"type": "integer", "minimum": 0, "maximum": 2}]}, True),),
        missing='give the run channel, such as {"channel": "keypad"} or {"channel": 0}',
        changes=True,
        cli="run-channel",
        help="set F00.01 from the panel: keypad, terminals or communication",
    ),
    Route(
        "POST",
        f"{_D}/restore-defaults",
        "restore_defaults",
        "- (200FH = 1 from the panel; 409 while running)",
        _restore_defaults,
        changes=True,
        help="restore the function codes' defaults from the panel (only while stopped)",
    ),
)

#: The generators on a drive's conditions.
GENERATORS: tuple[Route, ...] = (
    Route(
        "GET",
        f"{_D}/generators",
        "generators",
        "- (the generators running on the drive's conditions)",
        _generators,
        help="the generators on a drive's conditions; --clear [CONDITION] stops them",
    ),
    Route(
        "DELETE",
        f"{_D}/generators",
        "clear_generators",
        '{"condition": "supply_v"} (optional; all without)',
        _clear_generators,
        (Field("condition", {"enum": [n for n, c in ops.CONDITIONS.items() if c.continuous]}),),
        changes=True,
        help="stop the generators on a drive's conditions: one condition's, or all",
        cli="generators",
    ),
)
