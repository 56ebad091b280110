"""What every operation starts from: :class:`ControlError`, the checks of JSON-like values, the drive by address.

Part of :mod:`c20sim.control.ops` (which re-exports it). Pure: no I/O.
"""

from __future__ import annotations

import difflib
import json
import math
import sys
from collections.abc import Mapping, Sequence

from ..core.simulator import Simulator
from ..drive.model import Drive
from ..wire.errors import C20SimError


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
