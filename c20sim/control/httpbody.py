"""A request body as the operations take it: JSON, an object, no number of thousands of digits."""

from __future__ import annotations

from .ops import ControlError

#: The most digits a JSON integer of a request may have: every value the API takes fits in far fewer.
MAX_DIGITS = 30


class _TooLong:
    """A JSON integer of more than :data:`MAX_DIGITS` digits, as parsed: its length only."""

    def __init__(self, digits: int) -> None:
        self.digits = digits


def _refuse_long_numbers(value: object, key: str = "") -> None:
    """400 naming the key of a number of thousands of digits (never a 500 from a float conversion)."""
    if isinstance(value, _TooLong):
        where = f"{key}: " if key else ""
        raise ControlError(f"{where}a number of {value.digits} digits; no value here has more than {MAX_DIGITS}")
    items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else ()
    for name, item in items:
        _refuse_long_numbers(item, f"{key}.{name}" if key else str(name))
