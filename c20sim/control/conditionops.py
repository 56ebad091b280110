"""The conditions: the drive's physical surroundings, checked, set (or given a generator) and read back.

Part of :mod:`c20sim.control.ops` (which re-exports it). Pure: no I/O.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from ..core.generators import GeneratorError, parse_generator
from ..core.simulator import Simulator
from ..drive import conditions as rows
from ..drive.model import Drive
from .opscore import ControlError, _shown, _synced, drive, integer, number, unknown


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
    #: a choice's values (null is allowed too); None for a number
    choices: tuple[str, ...] | None = None


def _choice(choices: tuple[str, ...]) -> Callable[[str, object], object]:
    def check(key: str, value: object) -> str | None:
        if value is None or value is False:  # false is what a user means by none: set=hall_fault=false
            return None
        if value not in choices:
            names = ", ".join(map(repr, choices[:-1])) + f" or {choices[-1]!r}"
            raise ControlError(f"{key}: expected null or false (none), {names}, got {_shown(value)}")
        return str(value)

    return check


def _check(row: rows.Condition) -> Callable[[str, object], object]:
    """How a value of the row's kind is checked: a number or an integer in its range, or one of its choices."""
    low, high = row.low, row.high
    if row.kind == "choice":
        return _choice(row.choices)
    assert low is not None and high is not None
    if row.kind == "integer":
        return lambda k, v: integer(k, v, int(low), int(high))
    return lambda k, v: number(k, v, low, high)


def _condition(row: rows.Condition) -> Condition:
    choices = row.choices if row.kind == "choice" else None
    return Condition(
        row.name, row.unit, row.low, row.high, row.get, row.set, _check(row), row.help, row.continuous, choices
    )


#: Every condition, by the name all front ends use: one per row of :data:`c20sim.drive.conditions.CONDITIONS`.
#: To add one: a row there.
CONDITIONS: Mapping[str, Condition] = {name: _condition(row) for name, row in rows.CONDITIONS.items()}


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
