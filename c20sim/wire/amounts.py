"""A register's value as a person types it: in its units (``2.5`` s, ``1500`` rpm) or by name (``forward``),
read into the raw word a master writes (moved out of traffic/master.py as it was, for the control API and ctl).
"""

from __future__ import annotations

import math

from .errors import C20SimError
from .registers import Command, Reg, RegisterSpec

__all__ = ["parse_value"]


def parse_value(spec: RegisterSpec, text: str) -> int:
    """A value for ``spec`` in its units (``1500``, ``2.5`` s) or by name (``stop``, ``forward-run``): raw.

    Never a value other than the one typed: a number outside the register's range, one that would wrap in 16 bits
    (65536), one between the register's steps (2.55 s where it counts 0.1 s) or not finite (nan, inf) is refused
    in one line.
    """
    wanted = text.strip().lower().replace("_", " ").replace("-", " ")
    for raw, name in spec.values.items():
        if name.lower().replace("-", " ") == wanted or name.lower().split(" (")[0] == wanted:
            return raw
    if spec.address == Reg.COMMAND:
        for command in Command:
            if command.key.replace("_", " ") == wanted:
                return int(command)
    where = f"{spec.label} {spec.name}"
    try:
        number = float(int(text, 16)) if spec.hex_display and text.lower().startswith("0x") else float(text)
    except ValueError:
        names = ", ".join(f"{raw} = {name}" for raw, name in spec.values.items())
        raise C20SimError(
            f"{where}: {text!r} is not a number" + (f" nor a value's name ({names})" if names else "")
        ) from None
    low, high = _amount(spec, spec.minimum), _amount(spec, spec.maximum)
    if not math.isfinite(number):
        raise C20SimError(f"{where}: {text} is not a finite number; give one from {low} to {high}")
    raw = round(number / spec.scale)
    if not spec.minimum <= raw <= spec.maximum or not (-0x8000 if spec.signed else 0) <= raw <= 0xFFFF:
        raise C20SimError(f"{where}: {text} is outside {low} to {high}")
    if not math.isclose(raw * spec.scale, number, rel_tol=1e-9, abs_tol=1e-9):
        step = f"{spec.scale:g} {spec.unit}".rstrip()
        raise C20SimError(
            f"{where}: {text} is not a whole number of its steps of {step}; the nearest is {_amount(spec, raw)}"
        )
    return raw & 0xFFFF


def _amount(spec: RegisterSpec, raw: int) -> str:
    """A raw value as a number in the register's units, with its name where it has one: ``8 (jog stop)``."""
    if spec.hex_display:
        text = f"0x{raw & 0xFFFF:04X}"
    else:
        decimals = max(0, len(f"{spec.scale:g}".partition(".")[2]))
        text = f"{raw * spec.scale:.{decimals}f} {spec.unit}".rstrip()
    name = spec.values.get(raw & 0xFFFF)
    return f"{text} ({name})" if name else text
