"""Device faults as causes: what a bench does to a drive to make it trip, with levels from its profile.

A real drive trips on what happens to it: a sagging supply, a jammed load, a
hot cabinet, a broken Hall sensor. :data:`CAUSES` names each such cause and
the conditions (:data:`~c20sim.control.ops.CONDITIONS`) that bring it about,
worked out from the profile's own trip levels: it is built from the rows of
the drive's causes (:data:`c20sim.drive.trips.TRIPS`) that say how a bench
brings them about (their ``bench``), so ``trip("undervoltage")``
means the same on every profile and in every front end (scenario
``fault = { cause = "undervoltage" }``, ``POST .../fault {"cause": ...}``,
pytest ``.trip("undervoltage")``, ``c20sim ctl fault --cause``, the
dashboard's fault keys). The drive then trips by its own physics, when and
how its model says: the cause is set, never the fault code.

The profile's faults that the model has no physical cause for (a power stage,
the EEPROM, ...) are causes too, by their profile name (``eeprom``): those
are latched, and stay until released.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass

from ..core.simulator import Simulator
from ..drive.model import Drive
from ..drive.profile import FaultCause, Profile
from ..drive.statemachine import State
from ..drive.trips import HOT_AMBIENT, TRIPS, Cycle, overheat_seconds
from . import ops

__all__ = [
    "CAUSES",
    "HOT_AMBIENT",
    "JSON",
    "TOML",
    "Cause",
    "FaultRequest",
    "Notation",
    "active",
    "cause_names",
    "clear_all",
    "every_name",
    "fault",
    "overheat_seconds",
    "physical",
    "read_fault",
    "release",
    "request",
    "reset_refusal",
    "trip",
]

Conditions = Mapping[str, object]


@dataclass(frozen=True)
class Cause:
    """A physical cause of device faults: the conditions that bring it about and those that end it."""

    name: str
    #: its key on the dashboard's fault panel
    key: str
    label: str
    #: what it does, in words, for help texts
    how: str
    #: the profile's faults it can trip
    faults: tuple[FaultCause, ...]
    #: (profile, conditions now) -> the conditions that bring it about
    on: Callable[[Profile, Conditions], dict[str, object]]
    #: (profile, conditions now) -> the conditions that end it
    off: Callable[[Profile, Conditions], dict[str, object]]
    #: (profile, the module's temperature or None) -> seconds to the trip (inf: never); None: the step's to find
    eta: Callable[[Profile, float | None], float] | None = None
    #: its words on the dashboard where it has an ``eta``: "{when}" stands for "trips in about N s"
    dashboard: str = ""
    #: the dashboard's switch steps one condition through values instead of on and off
    cycle: Cycle | None = None

    def present(self, drive: Drive) -> bool:
        """Whether it is there now, whoever set the conditions: the drive's protection decides, per fault."""
        return any(drive.cause_present(fault) for fault in self.faults)


def _from_rows() -> dict[str, Cause]:
    """The bench's causes of the rows of :data:`~c20sim.drive.trips.TRIPS`, in their ``rank``."""
    rows = sorted((t for t in TRIPS.values() if t.bench is not None), key=lambda t: t.bench.rank if t.bench else 0)
    out: dict[str, Cause] = {}
    for row in rows:
        b = row.bench
        assert b is not None
        faults = tuple(FaultCause(c) for c in row.causes)
        out[b.name] = Cause(b.name, b.key, b.label, b.how, faults, b.on, b.off, b.eta, b.dashboard, b.cycle)
    return out


class _Live(Mapping[str, Cause]):
    """The bench's causes as the rows are now: built again when a row was registered or taken away since."""

    def __init__(self) -> None:
        self._key: tuple[int, ...] = ()
        self._now: dict[str, Cause] = {}

    def now(self) -> dict[str, Cause]:
        key = tuple(id(t) for t in TRIPS.values())
        if key != self._key:
            self._now, self._key = _from_rows(), key
        return self._now

    def __getitem__(self, name: str) -> Cause:
        return self.now()[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self.now())

    def __len__(self) -> int:
        return len(self.now())


#: Every physical cause, by the name all front ends use: one per row of the drive's causes with a ``bench``,
#: read from the rows at each use (a row registered after this module was imported is in it).
CAUSES: Mapping[str, Cause] = _Live()


def physical() -> frozenset[FaultCause]:
    """The profile's fault causes that a physical cause (:data:`CAUSES`) brings about, as the rows are now."""
    return frozenset(f for cause in CAUSES.values() for f in cause.faults)


def every_name() -> tuple[str, ...]:
    """Every cause any profile's drive may be given: the physical ones, then every cause with no physical one
    (a profile has those it maps to a code: :func:`cause_names`)."""
    bodily = physical()
    return (*CAUSES, *(f.value for f in FaultCause if f not in bodily))


def latched(profile: Profile) -> dict[str, int]:
    """The profile's faults with no physical cause: name -> wire code (they are latched, not caused)."""
    bodily = physical()
    return {
        spec.cause.value: spec.code
        for spec in profile.faults.values()
        if spec.cause is not None and spec.cause not in bodily
    }


def cause_names(profile: Profile) -> list[str]:
    """Every cause a drive of ``profile`` can be given: the physical ones, then the latched faults."""
    return [*CAUSES, *latched(profile)]


def _check(sim: Simulator, cause: object) -> str:
    if not isinstance(cause, str) or cause not in cause_names(sim.profile):
        if isinstance(cause, str):
            raise ops.unknown("cause", cause, cause_names(sim.profile))
        raise ops.ControlError(f"cause: expected a name such as 'undervoltage', got {cause!r}")
    return cause


def trip(sim: Simulator, address: int, cause: object) -> str:
    """Bring ``cause`` about on the drive at ``address`` now; returns what was done, in words."""
    name = _check(sim, cause)
    if name in CAUSES:
        now = ops.conditions(sim, address)
        change = CAUSES[name].on(sim.profile, now)
        ops.set_conditions(sim, address, change)
        return f"drive {address}: {name}: {_words(change)}"
    code = latched(sim.profile)[name]
    ops.inject_fault(sim, address, code, True)
    return f"drive {address}: {name} (0x{code:02X}) latched"


def release(sim: Simulator, address: int, cause: object) -> str:
    """End ``cause`` on the drive at ``address`` (the fault stays until reset); returns what was done."""
    name = _check(sim, cause)
    if name in CAUSES:
        now = ops.conditions(sim, address)
        change = CAUSES[name].off(sim.profile, now)
        ops.set_conditions(sim, address, change)
        return f"drive {address}: {name} gone: {_words(change)} (reset to clear the fault)"
    ops.clear_fault(sim, address, reset=False)
    return f"drive {address}: {name} released (reset to clear the fault)"


# --- The one fault request: every front end hands the user's value to read_fault, then fault().


@dataclass(frozen=True)
class FaultRequest:
    """A device fault as a user asks for it: by its ``cause`` (brought about, the drive trips by its model), or
    latched by ``code`` (``persistent``: resets fail until it is cleared)."""

    cause: str | None = None
    code: int | None = None
    persistent: bool = False


@dataclass(frozen=True)
class Notation:
    """How a front end writes a fault request, for the examples in its errors."""

    word: str  #: what the front end calls a key of the request
    cause: str  #: the request by cause
    code: str  #: the request by code
    strict: bool  #: a cause with other keys: unknown ``word`` (JSON bodies) or "give a cause alone" (TOML)


JSON = Notation("field", '{"cause": "undervoltage"}', '{"code": 16}', strict=True)
TOML = Notation("key", '{ cause = "undervoltage" }', "{ code = 16, persistent = true }", strict=False)


def read_fault(value: object, notation: Notation = JSON, names: list[str] | None = None) -> FaultRequest:
    """The fault request in ``value``: ``{cause}``, ``{code, persistent}`` or a bare code; ControlError says what
    is wrong, in ``notation``. A cause is checked against ``names`` where given (a profile's :func:`cause_names`)."""
    if isinstance(value, Mapping):
        if "cause" in value:
            extra = [k for k in value if k != "cause"]
            if extra:
                if notation.strict:
                    raise ops.unknown(notation.word, str(extra[0]), ["cause"])
                raise ops.ControlError(f"give a cause alone, such as {notation.cause}")
            cause = value["cause"]
            if not isinstance(cause, str):
                raise ops.ControlError(f"cause: expected a name such as 'undervoltage', got {cause!r}")
            if names is not None and cause not in names:
                raise ops.unknown("cause", cause, names)
            return FaultRequest(cause=cause)
        extra = [k for k in value if k not in ("code", "persistent")]
        if extra:
            if notation.strict:
                raise ops.unknown(notation.word, str(extra[0]), ["code", "persistent", "cause"])
            raise ops.ControlError(f"unknown key {sorted(extra)[0]!r}; give {notation.cause} or {notation.code}")
        if "code" not in value:
            listed = f"; causes: {', '.join(names)}" if names is not None else ""
            raise ops.ControlError(
                f"give the fault by cause, such as {notation.cause}, or by code, such as {notation.code}{listed}"
            )
        code, persistent = ops.check_fault(value["code"], value.get("persistent", False))
        return FaultRequest(code=code, persistent=persistent)
    code, persistent = ops.check_fault(value, False)
    return FaultRequest(code=code, persistent=persistent)


def request(sim: Simulator, address: int, value: object, notation: Notation = JSON) -> str:
    """Read the fault request ``value`` as the user gave it and do it (see :func:`read_fault`, :func:`fault`)."""
    ops.drive(sim, address)
    return fault(sim, address, read_fault(value, notation, names=cause_names(sim.profile)))


def fault(sim: Simulator, address: int, request: FaultRequest) -> str:
    """Do ``request`` on the drive at ``address`` now; returns what was done, in words ("" for a code)."""
    if request.cause is not None:
        return trip(sim, address, request.cause)
    assert request.code is not None
    ops.inject_fault(sim, address, request.code, request.persistent)
    return ""


def active(sim: Simulator, address: int) -> dict[str, bool]:
    """Every cause of the profile and whether it is there now, whoever brought it about."""
    held = ops.held_fault(sim, address)  # the drive brought to now
    found = ops.drive(sim, address)
    out = {name: cause.present(found) for name, cause in CAUSES.items()}
    out.update({name: held == code for name, code in latched(sim.profile).items()})
    return out


def reset_refusal(sim: Simulator, address: int) -> str | None:
    """Why the drive refuses a fault reset now, in words; None when it has no fault or would take a reset.

    The drive's own reset guard decides: a cause still present, a fault latched as persistent, or a cause that
    has ended but that the fault outlasts (the bus not yet back above its recover level, the module still
    hot). The API's answer to a refused reset carries it (``refused``); ctl prints it.
    """
    found = ops.drive(sim, address)
    sim.sync()
    machine = found.machine
    if found.state is not State.FAULT or not machine.cause_persists():
        return None
    cause = machine.cause
    if cause is None:
        name = next((n for n, code in latched(sim.profile).items() if code == machine.fault), None)
        what = f"its cause, {name}," if name else f"fault {machine.fault}"
        return f"{what} was latched to hold until released; release it (ctl clear) and reset"
    name = next((c.name for c in CAUSES.values() if cause in c.faults), cause.value)
    if found.cause_present(cause):
        return f"its cause, {name}, is still present; end it (ctl clear --cause {name})"
    return (
        f"its cause, {name}, has ended, but the drive has not recovered from it yet; let time pass "
        "(ctl advance 1 on a virtual clock) and reset again (ctl key reset)"
    )


def clear_all(sim: Simulator, address: int) -> None:
    """End every cause at once (the nominal supply, no load, the profile's ambient, ...); faults stay until reset."""
    now = ops.conditions(sim, address)
    change: dict[str, object] = {}
    for cause in CAUSES.values():
        change.update(cause.off(sim.profile, {**now, **change}))
    ops.set_conditions(sim, address, change)
    ops.clear_fault(sim, address, reset=False)


def _words(change: Mapping[str, object]) -> str:
    def said(value: object) -> str:
        if isinstance(value, float):
            return f"{value:g}"
        return "none" if value is None else str(value)  # a mended Hall sensor: hall_fault none

    return ", ".join(f"{key} {said(value)}" for key, value in change.items())
