"""The register vocabulary: one set of names for every tool (moved out of registers.py as it was)."""

from __future__ import annotations

import difflib
import re
from collections.abc import Mapping

from .registers import FIXED_REGISTERS, Reg, RegisterMap, address_label, parse_fcode

__all__ = ["SHORT_NAMES", "UnknownRegister", "register_names", "resolve_register"]

#: Short names a person at a bench types, for the registers they read and write most. With the sheet's names
#: (``motor speed``), the names of :class:`Reg` (``motor_speed``), addresses (``3006H``, ``0x3006``, ``12294``) and
#: function codes (``F00.10``) they make the one vocabulary that ctl, exercise, scenarios, the control API, the
#: pytest handle and the dashboard take (:func:`resolve_register`).
SHORT_NAMES: Mapping[str, int] = {
    "command": Reg.COMMAND,
    "setpoint": Reg.SPEED_SETPOINT,
    "pole-pairs": Reg.POLE_PAIRS,
    "accel": Reg.ACCEL_TIME,
    "decel": Reg.DECEL_TIME,
    "control-mode": Reg.CONTROL_MODE,
    "run-channel": Reg.RUN_CHANNEL,
    "speed-source": Reg.SPEED_SOURCE,
    "address": Reg.ADDRESS,
    "baud": Reg.BAUD,
    "write-enable": Reg.WRITE_ENABLE,
    "status": Reg.STATUS1,
    "status2": Reg.STATUS2,
    "fault": Reg.FAULT_CODE,
    "id": Reg.DRIVE_ID,
    "set-frequency": Reg.SET_FREQUENCY,
    "frequency": Reg.OUTPUT_FREQUENCY,
    "ramp": Reg.RAMP_FREQUENCY,
    "voltage": Reg.OUTPUT_VOLTAGE,
    "current": Reg.OUTPUT_CURRENT,
    "set-speed": Reg.SET_SPEED,
    "speed": Reg.MOTOR_SPEED,
    "power": Reg.OUTPUT_POWER,
    "bus": Reg.BUS_VOLTAGE,
    "hall": Reg.HALL,
    "version": Reg.SOFTWARE_VERSION,
    "temperature": Reg.TEMPERATURE,
    "inputs": Reg.INPUT_TERMINALS,
    "outputs": Reg.OUTPUT_TERMINALS,
}

_SEPARATORS = re.compile(r"[\s_-]+")
_HELP = (
    "give a name such as speed or status, an address such as 3006H, 0x3006 or 12294, or a function code such as F00.10"
)


class UnknownRegister(ValueError):
    """A register that is not spelt as one, or that the map lacks: the message is one line, with a did-you-mean."""


def _key(text: str) -> str:
    """The spelling a name is looked up by: case, spaces, ``-`` and ``_`` do not count."""
    return _SEPARATORS.sub("_", text.strip().lower()).strip("_")


def register_names() -> dict[str, int]:
    """Every name a fixed register answers to, as it is written, -> its address: the short names first, then
    :class:`Reg`'s names, then the sheet's (a name already taken keeps its first register)."""
    out: dict[str, int] = {}
    seen: set[str] = set()
    rows = [
        *SHORT_NAMES.items(),
        *((reg.name.lower(), int(reg)) for reg in Reg),
        *((spec.name, spec.address) for spec in FIXED_REGISTERS.values()),
    ]
    for name, address in rows:
        if _key(name) not in seen:
            seen.add(_key(name))
            out[name] = int(address)
    return out


_NAMES = register_names()
_BY_KEY = {_key(name): address for name, address in _NAMES.items()}
_SHOWN = {_key(name): name for name in _NAMES}


def _spelt(text: str) -> int:
    """An address from its spelling alone (no map): a name, Fgg.nn, 2001H, 0x2001 or decimal 8193."""
    body = text.strip()
    if not body:
        raise UnknownRegister(f"register '': empty; {_HELP}")
    found = _BY_KEY.get(_key(body))
    if found is not None:
        return found
    upper = body.upper()
    if upper.startswith("F") and "." in upper:
        try:
            return parse_fcode(body)
        except ValueError as exc:
            raise UnknownRegister(f"register {text!r}: {exc}") from None
    hexdigits = "0123456789ABCDEF"
    if upper.startswith("0X") and len(upper) > 2 and all(c in hexdigits for c in upper[2:]):
        return int(upper[2:], 16)
    if upper.endswith("H") and len(upper) > 1 and all(c in hexdigits for c in upper[:-1]):
        return int(upper[:-1], 16)
    if body.isascii() and body.isdigit():
        return int(body)
    close = difflib.get_close_matches(_key(body), list(_BY_KEY), n=1, cutoff=0.6)
    hint = f"; did you mean {_SHOWN[close[0]]!r}?" if close else ""
    raise UnknownRegister(f"unknown register {text!r}{hint} ({_HELP})")


def resolve_register(text: str | int, registers: RegisterMap | None = None, owner: str = "the register map") -> int:
    """The address a register is called by in any tool, checked against ``registers`` where given.

    Takes a short name (``speed``), :class:`Reg`'s name (``motor_speed``), the sheet's name (``motor speed``;
    case, spaces, ``-`` and ``_`` do not count), an address as ``3006H``, ``0x3006`` or decimal ``12294``
    (a whole number is decimal, as Modbus tools count), a function code ``F00.10``, or an int. Raises
    :class:`UnknownRegister` with one line saying what is wrong, with a did-you-mean where one is close.
    """
    if isinstance(text, bool) or not isinstance(text, str | int):
        raise UnknownRegister(f"register: expected a name or an address, got {text!r}")
    address = text if isinstance(text, int) else _spelt(text)
    if not 0 <= address <= 0xFFFF:
        raise UnknownRegister(f"register {text!r}: an address is 0000H-FFFFH (0-65535)")
    if registers is not None and address not in registers:
        said = address_label(address)
        if isinstance(text, str) and text.strip().isdigit():  # a whole number is decimal: 2100 is 0834H (F08.52)
            said = f"{address} ({said})"
            if int(text.strip(), 16) in registers:
                said += f"; did you mean {address_label(int(text.strip(), 16))}? (a whole number is decimal)"
        raise UnknownRegister(f"register {text!r}: {owner} has no register {said}")
    return address
