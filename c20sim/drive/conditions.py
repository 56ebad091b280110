"""The conditions: what a bench does to a drive, one row each, the one table every front end is built from.

A :class:`Condition` row names a physical condition (the supply, the load, the ambient, an analog input, the
terminals, ...) by the name every front end uses (``supply_v``), with its unit, its range or its choices, its
words for help texts, how it is read from a :class:`~c20sim.drive.model.Drive` and set on it, and, where the
dashboard shows it as a field of its conditions view, that field. The operations
(:data:`c20sim.control.ops.CONDITIONS`: the checks, the API, OpenAPI, ``ctl``, the scenarios' ``set``) and the
dashboard's conditions view (:mod:`c20sim.tui.workbench`, :mod:`c20sim.tui.widgets`) are built from
:data:`CONDITIONS`: a new condition is a row here (:func:`register`), and every front end has it.

The physics reads its conditions from :class:`~c20sim.drive.config.Conditions`, set through the drive's
setters (:class:`~c20sim.drive.bench.BenchSetters`); a row with no setter of its own (``write`` None) is kept
in ``Conditions.extra`` by its name, at ``initial`` until set, for whatever part of the model reads it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from .sensors import HallFault

__all__ = ["CONDITIONS", "Condition", "Panel", "register", "unregister"]

#: The kinds of value a condition takes: a number in a range (continuous: a generator may drive it), a whole
#: number in a range (bits, a switch position), or one of its choices or null.
KINDS = ("number", "integer", "choice")


@dataclass(frozen=True)
class Panel:
    """A field of the dashboard's conditions view: its id (``#cond-<id>``), its label and the up/down step."""

    id: str
    label: str
    step: float


@dataclass(frozen=True)
class Condition:
    """One physical condition: its name, unit and range or choices, and how it is read from a drive and set."""

    name: str
    unit: str
    #: the range of a number or an integer (None for a choice)
    low: float | None
    high: float | None
    #: (drive) -> the value now; None: kept in the drive's ``Conditions.extra``
    read: Callable[[Any], object] | None = None
    #: (drive, the checked value) -> None; None: kept in the drive's ``Conditions.extra``
    write: Callable[[Any, Any], None] | None = None
    help: str = ""
    kind: str = "number"
    #: a choice's values (null is always allowed)
    choices: tuple[str, ...] = ()
    #: the value of a condition kept in ``Conditions.extra`` until it is set
    initial: object = 0.0
    #: its field on the dashboard's conditions view, if it has one
    panel: Panel | None = None

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"condition {self.name}: kind {self.kind!r} is not one of {', '.join(KINDS)}")
        if self.kind != "choice" and (self.low is None or self.high is None):
            raise ValueError(f"condition {self.name}: a {self.kind} needs its range, low and high")

    @property
    def continuous(self) -> bool:
        """A continuous quantity: it may be given a generator (c20sim.core.generators) instead of a value."""
        return self.kind == "number"

    def get(self, drive: Any) -> object:
        """The value on ``drive`` now."""
        if self.read is not None:
            return self.read(drive)
        return drive.bench.extra.get(self.name, self.initial)

    def set(self, drive: Any, value: Any) -> None:
        """Set the (checked) value on ``drive``."""
        if self.write is not None:
            self.write(drive, value)
        else:
            drive.set_extra(self.name, value)


def _hall_now(d: Any) -> str | None:
    fault = d.hall_fault
    return None if fault is None else str(fault.value)


def _ranged(
    name: str, unit: str, low: float, high: float, read: Any, write: Any, panel: Panel | None = None
) -> Condition:
    return Condition(name, unit, low, high, read, write, panel=panel)


#: Every condition, by the name all front ends use, in the order they list them. To add one: :func:`register`.
CONDITIONS: dict[str, Condition] = {
    c.name: c
    for c in (
        _ranged(
            "supply_v",
            "V",
            0,
            2000,
            lambda d: d.telemetry().supply_v,
            lambda d, v: d.set_supply_voltage(v),
            Panel("supply", "supply", 1.0),
        ),
        _ranged(
            "load_torque_nm",
            "N m",
            0,
            1000,
            lambda d: d.telemetry().load_torque_nm,
            lambda d, v: d.set_load_torque(v),
            Panel("load", "load", 0.1),
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
        _ranged(
            "ambient_c",
            "°C",
            -50,
            150,
            lambda d: d.telemetry().ambient_c,
            lambda d, v: d.set_ambient(v),
            Panel("ambient", "ambient", 5.0),
        ),
        Condition(
            "hall_fault",
            "",
            None,
            None,
            _hall_now,
            lambda d, v: d.set_hall_fault(v),
            help="null, 'stuck0', 'stuck7' or 'sequence'",
            kind="choice",
            choices=tuple(f.value for f in HallFault),
        ),
        _ranged("ai1_v", "V", 0, 10, lambda d: d.ai(1), lambda d, v: d.set_ai(1, v), Panel("ai1", "AI1 knob", 0.5)),
        _ranged("ai2_v", "V", 0, 10, lambda d: d.ai(2), lambda d, v: d.set_ai(2, v), Panel("ai2", "AI2", 0.5)),
        _ranged("ai3_v", "V", 0, 10, lambda d: d.ai(3), lambda d, v: d.set_ai(3, v)),
        Condition(
            "dial_switches",
            "",
            0,
            7,
            lambda d: sum(1 << i for i, on in enumerate(d.dial_switches) if on),
            lambda d, v: d.set_dial_switches(bool(v & 1), bool(v & 2), bool(v & 4)),
            help="the dial switches, bit 0 SW1, bit 1 SW2, bit 2 SW3 (they act where 2005H = 3, 2006H = 3, 2007H = 5)",
            kind="integer",
        ),
        Condition(
            "terminal_inputs",
            "",
            0,
            0x1FF,
            lambda d: d.physical_inputs,
            lambda d, v: d.set_terminal_inputs(v),
            help="the physical input terminals, bits 0-8",
            kind="integer",
        ),
    )
}


def register(condition: Condition) -> Condition:
    """Add a condition row (before the front ends are imported: they build their tables from this one)."""
    if condition.name in CONDITIONS:
        raise ValueError(f"condition {condition.name}: declared twice")
    CONDITIONS[condition.name] = condition
    return condition


def unregister(name: str) -> None:
    """Take a row away again (a test's throwaway row)."""
    del CONDITIONS[name]
