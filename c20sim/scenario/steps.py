"""A scenario's steps: the keys a ``[[step]]`` table may hold, each checked once at load, and what a step is.

The format's reference is docs/scenario-format.md; :mod:`c20sim.scenario.timeline` loads and plays a scenario.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, TypeVar

from ..audit import RULES
from ..control import causes, ops
from ..drill import read_plan
from ..drive.profile import FaultCause
from ..wire.errors import C20SimError
from ..wire.protocol import (
    ExceptionCode,
)

T = TypeVar("T")

__all__ = ["CAUSE_NAMES", "MAX_WITHIN", "STEP_KEYS", "Expect", "Outcome", "ScenarioError", "Step", "parse_step"]


class ScenarioError(C20SimError):
    """A scenario that cannot be loaded or played: names the file, the step and the key."""

    def __init__(self, path: str, where: str, message: str) -> None:
        self.path = path
        self.where = where
        self.message = message
        super().__init__(f"{path}: {where}: {message}" if where else f"{path}: {message}")


@dataclass(frozen=True)
class Expect:
    """A register must read ``value`` (raw) within ``tolerance``."""

    register: str  #: as written in the file
    address: int
    value: int
    tolerance: int = 0


@dataclass(frozen=True)
class Step:
    """What happens at time ``at`` (seconds from the start), to ``drive`` (None: the first drive)."""

    index: int  #: 1-based, in file order
    at: float
    drive: int | None = None
    note: str = ""
    set: Mapping[str, object] = field(default_factory=dict)
    link: Mapping[str, object] = field(default_factory=dict)
    clear_link: bool = False
    fault: causes.FaultRequest | None = None  #: a fault by its cause, or latched by code
    clear_fault: bool = False
    release: str | None = None  #: a fault's cause to end, before clear_fault's reset
    power_cycle: bool = False
    write: tuple[tuple[str, int, int], ...] = ()  #: (register as written, address, value)
    keypad: str | int | None = None
    expect: tuple[Expect, ...] = ()
    expect_exception: int | None = None  #: every write of the step must be refused with this code
    expect_silence: bool = False  #: no write (or a read of 2100H, with none) may be answered
    within: float | None = None  #: poll ``expect`` in model time for up to this long
    expect_findings: tuple[str, ...] = ()  #: the audit's rules that must have found something by now
    forbid_findings: tuple[str, ...] = ()  #: rules that must have found nothing ("any": no finding at all)
    #: a drill (docs/drill.md) on the master polling the served drive: its incidents, as a plan's [[drill]] tables
    drill: tuple[Mapping[str, object], ...] = ()

    @property
    def audited(self) -> bool:
        """The step reads the audit (docs/audit.md)."""
        return bool(self.expect_findings or self.forbid_findings)

    @property
    def cause(self) -> str | None:
        """The fault's cause this step brings about, if it asks for one by cause."""
        return self.fault.cause if self.fault is not None else None

    @property
    def label(self) -> str:
        return f"step {self.index} (at {self.at:g} s)"


STEP_KEYS = (
    "at",
    "drive",
    "note",
    "set",
    "link",
    "clear_link",
    "fault",
    "clear_fault",
    "power_cycle",
    "write",
    "keypad",
    "expect",
    "expect_exception",
    "expect_silence",
    "within",
    "expect_findings",
    "forbid_findings",
    "drill",
)

#: The longest ``within`` (model seconds).
MAX_WITHIN = 3600.0


def parse_step(raw: object, index: int, path: str) -> Step:
    if not isinstance(raw, dict):
        raise ScenarioError(path, f"step {index}", "expected a table ([[step]])")
    at = raw.get("at")
    if isinstance(at, bool) or not isinstance(at, int | float) or not math.isfinite(at) or at < 0:
        raise ScenarioError(path, f"step {index}, key 'at'", "give the step's time in seconds from the start, >= 0")
    label = f"step {index} (at {at:g} s)"

    def fail(key: str, message: str) -> ScenarioError:
        return ScenarioError(path, f"{label}, key {key!r}", message)

    for key in raw:
        if key not in STEP_KEYS:
            raise fail(key, str(ops.unknown("key", key, STEP_KEYS)))

    def table(key: str) -> dict[str, Any]:
        value = raw.get(key, {})
        if not isinstance(value, dict):
            raise fail(key, "expected a table, such as { supply_v = 24 }")
        return value

    def flag(key: str) -> bool:
        value = raw.get(key, False)
        if not isinstance(value, bool):
            raise fail(key, "expected true or false")
        return value

    def checked(key: str, fn: Callable[[], T]) -> T:
        """Check with control's own checker: one vocabulary, and its message, for the API and the scenarios."""
        try:
            return fn()
        except ops.ControlError as exc:
            raise fail(key, str(exc)) from None

    drive = raw.get("drive")
    if drive is not None and (isinstance(drive, bool) or not isinstance(drive, int) or not 1 <= drive <= 247):
        raise fail("drive", "expected a drive address 1-247")
    note = raw.get("note", "")
    if not isinstance(note, str):
        raise fail("note", "expected a string")

    conditions = table("set")
    if conditions:
        checked("set", lambda: ops.check_conditions(conditions))
    link = table("link")
    if link:
        checked("link", lambda: ops.check_link_faults(link))

    fault_value = raw.get("fault")
    fault: causes.FaultRequest | None = None
    if fault_value is not None:
        fault = checked("fault", lambda: causes.read_fault(fault_value, causes.TOML, names=list(CAUSE_NAMES)))

    clear_value = raw.get("clear_fault", False)
    release: str | None = None
    if isinstance(clear_value, dict):
        if set(clear_value) != {"cause"}:
            raise fail("clear_fault", 'give true, or a cause to end, such as { cause = "undervoltage" }')
        release = _cause(clear_value["cause"], "clear_fault", fail)
        clear_value = True
    elif not isinstance(clear_value, bool):
        raise fail("clear_fault", 'expected true or false, or { cause = "undervoltage" }')

    def unquoted(key: str, register: str, value: object) -> None:
        """TOML reads ``F00.10 = 5000`` unquoted as the table F00 = { 10 = 5000 }: say to quote it."""
        if isinstance(value, dict) and register.upper().startswith("F") and all(k.isdigit() for k in value):
            first = sorted(value)[0]
            raise fail(key, f'{register}: unknown key {first!r}; quote a function code, as "{register}.{first}" = N')

    writes: list[tuple[str, int, int]] = []
    for register, value in table("write").items():
        unquoted("write", register, value)
        address = checked("write", functools.partial(ops.register_address, register))
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 0xFFFF:
            raise fail("write", f"{register}: expected a raw value 0-65535, got {value!r}")
        writes.append((register, address, value))

    keypad = raw.get("keypad")
    if keypad is not None:
        checked("keypad", lambda: ops.key_command(keypad))

    expects: list[Expect] = []
    for register, given in table("expect").items():
        value = given
        unquoted("expect", register, given)
        address = checked("expect", functools.partial(ops.register_address, register))
        tolerance: object = 0
        if isinstance(given, dict):
            extra = set(given) - {"value", "tolerance"}
            if extra:
                hint = (
                    f'; quote a function code, as "{register}.{sorted(extra)[0]}" = N'
                    if register.upper().startswith("F")
                    else "; give { value = N, tolerance = N }"
                )
                raise fail("expect", f"{register}: unknown key {sorted(extra)[0]!r}{hint}")
            value, tolerance = given.get("value"), given.get("tolerance", 0)
        if isinstance(value, bool) or not isinstance(value, int):
            raise fail("expect", f"{register}: expected a raw register value (an integer), got {value!r}")
        if isinstance(tolerance, bool) or not isinstance(tolerance, int) or tolerance < 0:
            raise fail("expect", f"{register}: tolerance must be a whole number >= 0, got {tolerance!r}")
        expects.append(Expect(register, address, value, tolerance))

    expect_exception = raw.get("expect_exception")
    if expect_exception is not None:
        codes = [int(c) for c in ExceptionCode]
        if isinstance(expect_exception, bool) or expect_exception not in codes:
            raise fail("expect_exception", f"expected an exception code {codes[0]}-{codes[-1]}, such as 8")
        if not writes:
            raise fail("expect_exception", "the step has no write to be refused; give write = { ... } too")
    expect_silence = flag("expect_silence")
    if expect_silence and expect_exception is not None:
        raise fail("expect_silence", "a write cannot be both refused and unanswered; give one of the two")
    within = raw.get("within")
    if within is not None:
        if (
            isinstance(within, bool)
            or not isinstance(within, int | float)
            or not math.isfinite(within)
            or not 0 < within <= MAX_WITHIN
        ):
            raise fail("within", f"expected seconds of model time, > 0 and <= {MAX_WITHIN:g}, such as 2.0")
        if not expects:
            raise fail("within", "nothing to wait for; give expect = { ... } too")
        within = float(within)

    findings: dict[str, tuple[str, ...]] = {}
    for key, allowed in (("expect_findings", tuple(RULES)), ("forbid_findings", ("any", *RULES))):
        given = raw.get(key, [])
        if not isinstance(given, list) or not all(isinstance(x, str) for x in given):
            raise fail(key, 'expected a list of the audit\'s rules, such as ["eeprom-wear"]')
        for name in given:
            if name not in allowed:
                raise fail(key, str(ops.unknown("rule", name, allowed)))
        findings[key] = tuple(given)
    both = set(findings["expect_findings"]) & set(findings["forbid_findings"])
    if both:
        raise fail("forbid_findings", f"{sorted(both)[0]} is expected and forbidden at once; give one of the two")

    drill: tuple[Mapping[str, object], ...] = ()
    if "drill" in raw:
        given = raw["drill"]
        items = [given] if isinstance(given, (str, dict)) else given
        if not isinstance(items, list) or not items:
            raise fail("drill", 'expected an incident or a list of them, such as ["crc", { incident = "trip" }]')
        drill = tuple({"incident": x} if isinstance(x, str) else dict(x) for x in items)
        try:
            read_plan({"drill": list(drill)}, "drill")
        except C20SimError as exc:
            raise fail("drill", str(exc).removeprefix("drill: ")) from None

    return Step(
        index=index,
        at=float(at),
        drive=drive,
        note=note,
        set=conditions,
        link=link,
        clear_link=flag("clear_link"),
        fault=fault,
        clear_fault=clear_value,
        release=release,
        power_cycle=flag("power_cycle"),
        write=tuple(writes),
        keypad=keypad,
        expect=tuple(expects),
        expect_exception=expect_exception,
        expect_silence=expect_silence,
        within=within,
        expect_findings=findings["expect_findings"],
        forbid_findings=findings["forbid_findings"],
        drill=drill,
    )


#: Every cause a scenario may name; whether the profile has a latched one is checked against the simulator.
CAUSE_NAMES = (*causes.CAUSES, *(f.value for f in FaultCause if f not in causes.PHYSICAL))


def _cause(value: object, key: str, fail: Callable[[str, str], ScenarioError]) -> str:
    if not isinstance(value, str) or value not in CAUSE_NAMES:
        message = str(ops.unknown("cause", value, CAUSE_NAMES)) if isinstance(value, str) else "expected a cause's name"
        raise fail(key, message)
    return value


@dataclass(frozen=True)
class Outcome:
    """One expectation or action of one step, and whether it held."""

    step: Step
    t: float
    ok: bool
    text: str
