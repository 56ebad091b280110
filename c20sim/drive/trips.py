"""The fault causes: what the model trips on, one row each, the one table protection and every front end iterate.

A :class:`Trip` row is one cause of device faults: its name (the profile's ``cause``, with ``_accel``,
``_decel`` and ``_constant`` for one that trips by the ramp's phase), its line in the docs, and its parts:

- ``detect``: whether the step trips on it now (:meth:`~c20sim.drive.protection.Machine.protect` tries the
  rows by ``check``, the fixed order, in the ``states`` they can trip in, and trips on the first whose cause
  the profile has a code for);
- ``present``: whether the condition that trips it is there now, whoever set it (the control layer's causes,
  the dashboard's marks);
- ``persists``: the reset guard, whether a latched fault of it still holds (none: the reset is the retry);
- ``foresee``: for a steady segment (:mod:`~c20sim.drive.segments`), whether it can trip there, and at which
  step of the segment it does (``trips_at``): a row whose ``detect`` reads what moves along a segment (the
  temperature, an I²t budget) needs them, or the segment jumps past its trip; one that reads only conditions
  needs none (a condition set ends the segment);
- ``levels``: the profile keys it reads (:class:`Level`: ``[section] name``, its type, range, default, unit and
  source), which the profile's parser checks (``Profile.level("section.name")`` gives the value), the profile's
  JSON schema describes and docs/profile-format.md must name; a row's levels take no edit elsewhere;
- ``bench``: how a bench brings it about (:class:`Bench`: the dashboard's key, the conditions it sets and
  ends), from which :data:`c20sim.control.causes.CAUSES`, the API's and the scenarios' causes and the
  dashboard's fault switches are built.

A row with no ``detect``, ``present`` and ``bench`` (a power stage, the EEPROM, ...) is a fault the model
has no physical cause for: latched by a bench, held until released. Every cause a profile may map to a code
(:class:`FaultCause`) comes from these rows: a new cause is :func:`register` of one row.

The parts take the :class:`~c20sim.drive.protection.Machine` (``m``) and read the profile, the integrator
(``m.motion``), the Hall sensor and the bench's conditions from it. The bus coming and going (undervoltage:
off while stopped, a trip while running, on again above the recover level) and the communication timeout's
actions other than a trip stay written out in ``Machine.protect``: they are transitions of their own, not
only trips; their rows give the rest (present, persists, the bench's cause, the trip itself).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

from .conditions import CONDITIONS
from .physics import ACCEL, BUDGET, CONSTANT, DECEL, RPM, STEP
from .statemachine import DRIVEN
from .terminals import Input

__all__ = [
    "COMM_CONTINUE",
    "COMM_STOP",
    "COMM_STOP_ANY",
    "COMM_TRIP",
    "HOT_AMBIENT",
    "PHASES",
    "TRIPS",
    "Bench",
    "Cycle",
    "FaultCause",
    "Level",
    "Trip",
    "checked",
    "docs_table",
    "foreseen",
    "levels",
    "overheat_seconds",
    "register",
    "unregister",
]

#: F08.03, the action on a communication timeout (INVT GD20 P14.05, remembered: P14.03 is the answer delay).
COMM_TRIP, COMM_CONTINUE, COMM_STOP, COMM_STOP_ANY = 0, 1, 2, 3

#: The ramp's phases a cause may trip by, in the order of their profile causes.
PHASES = (ACCEL, DECEL, CONSTANT)

Conditions = Mapping[str, object]
#: (profile, the conditions now) -> the conditions to set
Change = Callable[[Any, Conditions], dict[str, object]]
#: (machine, integrator) -> whether the step trips on a cause now
Detect = Callable[[Any, Any], bool]


class _Causes(type):
    """FaultCause's class: iterable over the causes the rows declare, in the rows' order, like an enum."""

    _members: dict[str, FaultCause]

    def __iter__(cls) -> Iterator[FaultCause]:
        return iter(list(cls._members.values()))

    def __len__(cls) -> int:
        return len(cls._members)

    def __getattr__(cls, name: str) -> FaultCause:
        """``FaultCause.UNDERVOLTAGE``: a cause by its name in capitals (its value's)."""
        member = cls._members.get(name.lower()) if name.isupper() else None
        if member is None:
            raise AttributeError(name)
        return member


class FaultCause(metaclass=_Causes):
    """One cause the profile maps to a wire code: ``FaultCause("undervoltage")``, ``FaultCause.UNDERVOLTAGE``.

    One per row of :data:`TRIPS` (one per phase for a row that trips by the ramp's phase); unique, so ``is``
    compares them, and unknown names raise ValueError, as an enum's would.
    """

    __slots__ = ("name", "phase", "trip", "value")
    _members: ClassVar[dict[str, FaultCause]] = {}
    name: str
    value: str
    trip: Trip
    phase: str | None

    def __new__(cls, value: str) -> FaultCause:
        try:
            return cls._members[value]
        except (KeyError, TypeError):
            raise ValueError(f"{value!r} is not a valid FaultCause") from None

    @classmethod
    def _make(cls, value: str, trip: Trip, phase: str | None) -> FaultCause:
        member = object.__new__(cls)
        member.name, member.value, member.trip, member.phase = value.upper(), value, trip, phase
        return member

    def __repr__(self) -> str:
        return f"<FaultCause.{self.name}: {self.value!r}>"

    def __reduce__(self) -> tuple[type[FaultCause], tuple[str]]:
        return FaultCause, (self.value,)

    def __copy__(self) -> FaultCause:
        return self

    def __deepcopy__(self, memo: object) -> FaultCause:
        return self


@dataclass(frozen=True)
class Cycle:
    """A switch that steps one condition through values instead of on and off (the Hall sensor's faults)."""

    condition: str
    #: the values in turn; the first is the healthy one
    values: tuple[object, ...]
    #: what the healthy value is called
    off: str


@dataclass(frozen=True)
class Bench:
    """How a bench brings a cause about and ends it: the dashboard's switch, and the conditions it sets."""

    #: its name in every front end (``trip("undervoltage")``, a scenario's ``fault = { cause = ... }``)
    name: str
    #: its key on the dashboard's fault panel
    key: str
    label: str
    #: what it does, in words, for help texts
    how: str
    #: (profile, conditions now) -> the conditions that bring it about
    on: Change
    #: (profile, conditions now) -> the conditions that end it
    off: Change
    #: its place among the bench's causes (the dashboard's fault panel, the API's list of causes)
    rank: float
    #: (profile, the module's temperature or None for the profile's ambient) -> seconds from the conditions on to
    #: the trip (inf: never); None: the trip's time is the step's to find
    eta: Callable[[Any, float | None], float] | None = None
    #: its words on the dashboard where it has an ``eta``: "{when}" stands for "trips in about N s"
    dashboard: str = ""
    #: the dashboard's switch steps one condition through values instead of on and off
    cycle: Cycle | None = None


@dataclass(frozen=True)
class Level:
    """One profile key a cause row reads: ``[section] name = value``, checked against its range by the parser.

    ``section`` is one of the profile's tables (``protection``, ``supply``, ...) or a table of the row's own; the
    key is optional in a profile (``default`` is taken), so a profile written before the row stays valid.
    """

    section: str
    name: str
    #: its value where the profile does not give it; its type (bool, int or float) is the key's type
    default: bool | int | float
    #: its range (None: a bool, which has none)
    low: float | None = None
    high: float | None = None
    unit: str = ""
    #: what it sets, for the schema and the errors
    doc: str = ""
    #: where the default comes from: ``assumed`` or its source (the sheet, the notes, a field measurement)
    source: str = "assumed"

    @property
    def key(self) -> str:
        """``section.name``: its name in errors and in ``Profile.level``."""
        return f"{self.section}.{self.name}"

    @property
    def kind(self) -> type:
        return type(self.default)

    def allowed(self) -> str:
        """Its allowed values, in words: "allowed 50 to 100 %", or "true or false"."""
        if self.kind is bool:
            return "true or false"
        return f"allowed {self.low:g} to {self.high:g}{' ' + self.unit if self.unit else ''}"


@dataclass(frozen=True)
class Trip:
    """One cause of device faults: a row (see the module's words)."""

    name: str
    #: its line in docs/faults.md: what trips it
    doc: str
    #: the ramp's phases it trips by: one profile cause each, ``<name>_<phase>`` (none: one cause, ``<name>``)
    phases: tuple[str, ...] = ()
    #: its place in the step's fixed order (None: the step does not trip on it by this row)
    check: float | None = None
    #: the drive's states it can trip in (None: every state the step watches, all but off and faulted)
    states: frozenset[Any] | None = None
    #: (profile) -> (machine, integrator) -> whether the step trips on it now: armed once per drive, so the
    #: profile's levels are bound before the step (it runs every millisecond of model time)
    detect: Callable[[Any], Detect] | None = None
    present: Callable[[Any], bool] | None = None
    persists: Callable[[Any], bool] | None = None
    #: (the integrator, the segment) -> whether it can trip there; then ``trips_at``
    foresee: Callable[[Any, Any], bool] | None = None
    #: (the integrator, the segment, step n of it) -> whether it trips by then (monotone in n)
    trips_at: Callable[[Any, Any, int], bool] | None = None
    bench: Bench | None = None
    #: the profile keys it reads (see :class:`Level`)
    levels: tuple[Level, ...] = ()

    @functools.cached_property
    def causes(self) -> tuple[str, ...]:
        """The profile causes of this row."""
        return tuple(f"{self.name}_{phase}" for phase in self.phases) if self.phases else (self.name,)


# --- The parts of the rows.


def _overcurrent_present(m: Any) -> bool:
    """Holding the load, or starting or stopping it on the ramp, asks more than the trip level."""
    cfg, p = m.motion.cfg, m.profile.protection
    if cfg.limit_a:  # current limiting: the ramp never asks more than the level, below the trip
        return bool(m.load_current() > p.overcurrent_a)
    ramp = cfg.inertia * max(cfg.up, cfg.down) / STEP * RPM / m.profile.motor.kt_nm_per_a
    return bool(m.load_current() + ramp > p.overcurrent_a)


# The detectors, armed with the profile's levels (see Trip.detect).


def _overcurrent(p: Any) -> Detect:
    level = p.protection.overcurrent_a
    return lambda m, mo: abs(mo.demand) > level


def _overvoltage(p: Any) -> Detect:
    level = p.supply.overvoltage_v
    return lambda m, mo: bool(mo.bus > level)


def _overheat(p: Any) -> Detect:
    level = p.thermal.overheat_c
    return lambda m, mo: bool(mo.temp >= level)


def _external(p: Any) -> Detect:
    ef = int(Input.EF)
    return lambda m, mo: bool(mo.cfg.inputs & ef)


def _load_levels(p: Any) -> dict[str, float]:
    kt, prot = p.motor.kt_nm_per_a, p.protection
    return {
        "overload": round(prot.current_limit_a * kt * 0.9, 2),
        "stall": round(prot.current_limit_a * kt * 1.5, 2),
    }


def _shock_load(p: Any) -> float:
    """A load torque step that the speed loop answers, within one step, with 125 % of the overcurrent trip.

    A heavy ramp cannot do it while current limiting is on (the default, as INVT ships it): the ramp holds at
    the limiting level. What still trips OC is a load step faster than the limit can act (a jam hit at speed):
    the loop answers the speed lost in one step with kp = inertia x 2 pi x the loop's bandwidth, so a step of
    T N m asks T x 2 pi f x STEP / kt amps, whatever the inertia.
    """
    per_nm = 2 * math.pi * p.control.speed_loop_hz * STEP / p.motor.kt_nm_per_a
    return float(round(1.25 * p.protection.overcurrent_a / per_nm, 1))


def _load(name: str) -> tuple[Change, Change]:
    return (lambda p, c: {"load_torque_nm": _load_levels(p)[name]}), (lambda p, c: {"load_torque_nm": 0.0})


def _inputs(c: Conditions) -> int:
    value = c["terminal_inputs"]
    assert isinstance(value, int)
    return value


#: The hottest ambient any front end may set: the overheat cause's.
HOT_AMBIENT = float(CONDITIONS["ambient_c"].high or 0.0)


def overheat_seconds(profile: Any, from_c: float | None = None) -> float:
    """Seconds to the overheat trip at :data:`HOT_AMBIENT` from ``from_c`` (the profile's ambient).

    Self-heating left out: T(t) = A - (A - T0) exp(-t / tau) reaching the trip level.
    """
    th = profile.thermal
    start = th.ambient_c if from_c is None else from_c
    if start > th.overheat_c:
        return 0.0
    if th.overheat_c >= HOT_AMBIENT:
        return math.inf
    return float(th.time_constant_s * math.log((HOT_AMBIENT - start) / (HOT_AMBIENT - th.overheat_c)))


def _latched(name: str, doc: str) -> Trip:
    return Trip(name, doc)


#: Every cause of device faults, by its name, in the profile format's order. To add one: :func:`register`.
TRIPS: dict[str, Trip] = {
    t.name: t
    for t in (
        _latched("power_stage_u", "power stage, phase U: no physical cause in the model, only latched"),
        _latched("power_stage_v", "power stage, phase V: only latched"),
        _latched("power_stage_w", "power stage, phase W: only latched"),
        Trip(
            "overcurrent",
            "the current the speed loop asks is past `protection.overcurrent_a` while driving (by the ramp's phase)",
            PHASES,
            check=2,
            states=DRIVEN,  # the current the loop asks flows only while the inverter drives
            detect=_overcurrent,
            present=_overcurrent_present,
            # a load that needs more than the trip level to hold
            persists=lambda m: m.load_current() > m.profile.protection.overcurrent_a,
            bench=Bench(
                "overcurrent",
                "c",
                "overcurrent",
                "a shock load: a load torque step faster than the current limit can act (OC3 running, OC1/OC2 on a "
                "ramp)",
                lambda p, c: {"load_torque_nm": _shock_load(p)},
                lambda p, c: {"load_torque_nm": 0.0},
                rank=3,
            ),
        ),
        Trip(
            "overvoltage",
            "the DC bus is above `supply.overvoltage_v` (by the ramp's phase)",
            PHASES,
            check=1,
            detect=_overvoltage,
            present=lambda m: m.motion.bench.supply > m.profile.supply.overvoltage_v,
            persists=lambda m: m.motion.bus > m.profile.supply.overvoltage_v,
            bench=Bench(
                "overvoltage",
                "v",
                "overvoltage",
                "supply switched high (OV1-3 by phase)",
                lambda p, c: {"supply_v": round(p.supply.overvoltage_v * 1.1, 1)},
                lambda p, c: {"supply_v": p.supply.voltage_v},
                rank=2,
            ),
        ),
        Trip(
            "undervoltage",
            "the DC bus is below `supply.undervoltage_v` while running (stopped, the drive is off); the step's "
            "bus watch trips it",
            present=lambda m: m.motion.bench.supply < m.profile.supply.undervoltage_v,
            persists=lambda m: not m.bus_ok,
            bench=Bench(
                "undervoltage",
                "u",
                "undervoltage",
                "supply switched low (UV while running, off while stopped)",
                lambda p, c: {"supply_v": round(p.supply.undervoltage_v * 0.5, 1)},
                lambda p, c: {"supply_v": p.supply.voltage_v},
                rank=1,
            ),
        ),
        Trip(
            "motor_overload",
            "the motor's I²t budget (`protection.motor_overload_curve`) is spent",
            check=5,
            detect=lambda p: lambda m, mo: mo.motor_i2t >= BUDGET,
            # past the rating within the limit (beyond it, a stall)
            present=lambda m: (
                m.load_current() <= m.profile.protection.current_limit_a and m.motion.motor_rate(m.load_current()) > 0.0
            ),
            persists=lambda m: m.motion.motor_i2t > m.profile.protection.overload_warning * BUDGET,
            foresee=lambda it, seg: seg.motor_rate > 0.0,
            trips_at=lambda it, seg, n: seg.motor_i2t(n) >= BUDGET,
            bench=Bench(
                "overload",
                "l",
                "overload",
                "load torque near the current limit (motor overload by its inverse-time curve)",
                *_load("overload"),
                rank=4,
            ),
        ),
        Trip(
            "drive_overload",
            "the drive's I²t budget (`protection.drive_overload_curve`) is spent",
            check=6,
            detect=lambda p: lambda m, mo: mo.drive_i2t >= BUDGET,
            present=lambda m: (
                m.load_current() <= m.profile.protection.current_limit_a and m.motion.drive_rate(m.load_current()) > 0.0
            ),
            persists=lambda m: m.motion.drive_i2t > m.profile.protection.overload_warning * BUDGET,
            foresee=lambda it, seg: seg.drive_rate > 0.0,
            trips_at=lambda it, seg, n: seg.drive_i2t(n) >= BUDGET,
        ),
        _latched("output_phase_loss", "output phase loss: only latched"),
        Trip(
            "overheat",
            "the module's temperature reaches `thermal.overheat_c`; it resets `thermal.overheat_reset_k` below",
            check=7,
            detect=_overheat,
            # the temperature the module heads for is past the trip level
            present=lambda m: (
                m.motion.bench.ambient + m.motion.loss * m.profile.thermal.resistance_k_per_w
                > m.profile.thermal.overheat_c
            ),
            persists=lambda m: m.motion.temp > m.profile.thermal.overheat_c - m.profile.thermal.overheat_reset_k,
            foresee=lambda it, seg: seg.temp_ss > it.profile.thermal.overheat_c,
            trips_at=lambda it, seg, n: seg.temp(n) >= it.profile.thermal.overheat_c,
            bench=Bench(
                "overheat",
                "o",
                "overheat",
                f"ambient at {HOT_AMBIENT:g} °C, the highest accepted (the trip time is the profile's)",
                lambda p, c: {"ambient_c": HOT_AMBIENT},
                lambda p, c: {"ambient_c": p.thermal.ambient_c},
                rank=6,
                eta=overheat_seconds,
                dashboard=f"ambient {HOT_AMBIENT:g} °C, the highest accepted: {{when}}; T/t advances virtual time",
            ),
        ),
        Trip(
            "external",
            "the EF input terminal is on",
            check=8,
            detect=_external,
            present=lambda m: bool(m.motion.cfg.inputs & Input.EF),
            persists=lambda m: bool(m.motion.cfg.inputs & Input.EF),
            bench=Bench(
                "external",
                "e",
                "external fault",
                "the EF input terminal",
                lambda p, c: {"terminal_inputs": _inputs(c) | Input.EF},
                lambda p, c: {"terminal_inputs": _inputs(c) & ~Input.EF},
                rank=8,
            ),
        ),
        Trip(
            "communication",
            "no request within the communication timeout (F08.02) with F08.03 = 0; 2 or 3 stop instead",
            check=9,
            detect=lambda p: lambda m, mo: mo.cfg.comm_action == COMM_TRIP and m.comm_expired(mo.k),
            present=lambda m: m.comm_expired(m.motion.k),
        ),
        _latched("current_detection", "current detection: only latched"),
        _latched("eeprom", "EEPROM: only latched"),
        Trip(
            "hall",
            "a bad Hall code (stuck at 0 or 7, out of sequence) while the bus is up",
            check=3,
            detect=lambda p: lambda m, mo: bool(m.hall.glitch),
            present=lambda m: m.hall.fault is not None,
            persists=lambda m: m.hall.fault is not None,
            bench=Bench(
                "hall",
                "h",
                "Hall sensor",
                "the Hall sensor stuck at 0 (the dashboard cycles: stuck 0, stuck 7, out of sequence, mended)",
                lambda p, c: {"hall_fault": "stuck0"},
                lambda p, c: {"hall_fault": None},
                rank=7,
                cycle=Cycle("hall_fault", (None, "stuck0", "stuck7", "sequence"), "mended"),
            ),
        ),
        Trip(
            "stall",
            "the rotor stays below `protection.stall_speed_rpm` for `protection.stall_time_s` while driven",
            check=4,
            detect=lambda p: lambda m, mo: mo.stall_steps >= m.stall_steps_limit,
            # the current limit cannot hold the load: a running rotor stalls
            present=lambda m: m.load_current() > m.profile.protection.current_limit_a,
            bench=Bench(
                "stall",
                "k",
                "locked rotor",
                "load torque past the current limit (stall while running)",
                *_load("stall"),
                rank=5,
            ),
        ),
    )
}


def docs_table() -> str:
    """The causes as docs/faults.md lists them (between its ``causes`` markers): one line a row, from the rows."""
    checked = sorted((t for t in TRIPS.values() if t.check is not None), key=lambda t: t.check or 0.0)
    order = {t.name: i for i, t in enumerate(checked, start=1)}
    lines = [
        "| cause | profile causes | step's order | bench's cause (dashboard key) | what trips it |",
        "|---|---|---|---|---|",
    ]
    for t in TRIPS.values():
        causes = ", ".join(f"`{c}`" for c in t.causes)
        bench = f"`{t.bench.name}` ({t.bench.key})" if t.bench is not None else f"none: latched as `{t.name}`"
        lines.append(f"| {t.name} | {causes} | {order.get(t.name, '-')} | {bench} | {t.doc} |")
    return "\n".join(lines) + "\n"


@functools.cache
def checked() -> tuple[Trip, ...]:
    """The rows the step tries, in their fixed order (``check``); kept until a row is registered or taken away."""
    rows = [t for t in TRIPS.values() if t.detect is not None and t.check is not None]
    return tuple(sorted(rows, key=lambda t: t.check or 0.0))


@functools.cache
def foreseen() -> tuple[Trip, ...]:
    """The rows a steady segment asks whether they can trip along it."""
    return tuple(t for t in TRIPS.values() if t.foresee is not None and t.trips_at is not None)


def _add_causes(trip: Trip) -> None:
    for phase, value in zip(trip.phases or (None,), trip.causes, strict=True):
        FaultCause._members[value] = FaultCause._make(value, trip, phase)


def levels() -> dict[str, Level]:
    """Every row's profile keys, by ``section.name``, in the rows' order."""
    return {level.key: level for t in TRIPS.values() for level in t.levels}


def _check_levels(trip: Trip) -> None:
    taken = levels()
    for level in trip.levels:
        if level.key in taken:
            raise ValueError(f"fault cause {trip.name}: profile key {level.key} is another row's")
        if level.kind not in (bool, int, float):
            raise ValueError(f"fault cause {trip.name}: profile key {level.key}: a bool, int or float default")
        if level.kind is not bool and (
            level.low is None or level.high is None or not level.low <= level.default <= level.high
        ):
            raise ValueError(f"fault cause {trip.name}: profile key {level.key}: its default outside its range")


def register(trip: Trip) -> Trip:
    """Add a cause row (front ends read the rows when asked; a program may register before or after importing)."""
    if trip.name in TRIPS or any(value in FaultCause._members for value in trip.causes):
        raise ValueError(f"fault cause {trip.name}: declared twice")
    _check_levels(trip)
    TRIPS[trip.name] = trip
    _add_causes(trip)
    checked.cache_clear()
    foreseen.cache_clear()
    return trip


def unregister(name: str) -> None:
    """Take a row away again (a test's throwaway row)."""
    trip = TRIPS.pop(name)
    for value in trip.causes:
        del FaultCause._members[value]
    checked.cache_clear()
    foreseen.cache_clear()


for _trip in TRIPS.values():
    _add_causes(_trip)
