"""The link faults of a drive or of the whole bus, checked and switched.

Part of :mod:`c20sim.control.ops` (which re-exports it). Pure: no I/O.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from ..core.linkfaults import KNOBS, LinkFaults
from ..core.simulator import Simulator
from ..wire.protocol import ExceptionCode
from .opscore import ControlError, _shown, drive, flag, integer, number, unknown


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
