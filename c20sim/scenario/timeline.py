"""Scenarios: a TOML timeline of conditions, faults, writes and expectations, checked once at load.

A scenario says what happens to a drive and when, and what the registers
must read then::

    name = "undervoltage trip"
    [[step]]
    at = 0.0
    write = { "2001H" = 1500, "2000H" = 1 }     # as a master: through the bus, access rules apply
    [[step]]
    at = 2.0
    set = { supply_v = 24 }                      # conditions, as the control API names them
    [[step]]
    at = 2.1
    expect = { status1 = 4, fault_code = 0x0A, bus_voltage = { value = 240, tolerance = 10 } }

A fault is given by its cause, as a bench brings it about
(``fault = { cause = "undervoltage" }``; the names are
:data:`c20sim.control.causes.CAUSES` and the profile's faults with no physical
cause), or latched by code (``fault = { code = 16, persistent = true }``);
``clear_fault = { cause = "undervoltage" }`` ends a cause and presses reset.

A step may expect the audit (docs/audit.md) to have found something by then
(``expect_findings = ["eeprom-wear"]``), or nothing of a rule
(``forbid_findings = ["line-demand"]``, ``["any"]``: nothing at all): the
frames the scenario's writes and every master sent are judged as a real line
would take them.

A step may play a drill (``drill = ["crc", { incident = "trip", hold = 1.0 }]``, docs/drill.md) on the
master polling a served drive (``serve --scenario FILE``, realtime clock); the step waits for it, and its
verdicts are the step's outcome. ``run-scenario`` (virtual time, no master) refuses such a scenario.

A step may expect its writes to be refused (``expect_exception = 8``: each
write answered with exception 0x08) or unanswered (``expect_silence = true``:
no reply, as from a drive that is offline; with no write in the step, a read
of 2100H is sent to check it). ``within = 2.0`` makes the step's ``expect``
an eventual state: the registers are read every :data:`POLL` seconds of
model time until they all match, or fail after 2 s with the last value seen;
time has then moved on, and a later step whose time has passed runs at once.

Within a step the actions run in a fixed order: ``set``, ``link``,
``clear_link``, ``fault``, ``clear_fault``, ``power_cycle``, ``write``,
``keypad``, then ``expect`` (polled for ``within`` seconds). Expected values
are raw register values, as a master reads them (3008H = 480 is 48.0 V).
The format's reference is docs/scenarios.md. Loading raises
:class:`ScenarioError` naming the file, the step and the key, like a profile.

:func:`run` plays a scenario in virtual time, instantly, and returns a
:class:`Report`; :func:`play` follows a served simulator's clock.
"""

from __future__ import annotations

import asyncio
import functools
import math
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, TypeVar

from ..audit import RULES
from ..control import causes, drills, liveaudit, ops
from ..core.simulator import Simulator
from ..drill import read_plan
from ..drive.files import MAX_DEPTH, FileReadError, read_text, toml_depth, too_deep
from ..drive.profile import FaultCause
from ..wire.errors import C20SimError
from ..wire.protocol import (
    ExceptionCode,
    FrameEvent,
    FrameKind,
    ReadRequest,
    Request,
    WriteSingleRequest,
    decode_response,
    encode,
)
from ..wire.registers import Reg
from ..wire.vocabulary import UnknownRegister, resolve_register

if TYPE_CHECKING:
    from ..core.bus import Reply
    from ..transport.line import Line

T = TypeVar("T")

__all__ = [
    "Expect",
    "Outcome",
    "Report",
    "Scenario",
    "ScenarioError",
    "Step",
    "apply_step",
    "apply_step_on_line",
    "load_scenario",
    "play",
    "run",
]


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


@dataclass(frozen=True)
class Scenario:
    path: str
    name: str
    description: str = ""
    profile: str | None = None
    drives: tuple[int, ...] | None = None
    steps: tuple[Step, ...] = ()


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

#: Model seconds between two reads of a ``within`` step's registers.
POLL = 0.01
#: The longest ``within`` (model seconds).
MAX_WITHIN = 3600.0
TOP_KEYS = ("name", "description", "profile", "drives", "step")


def load_scenario(path: str | Path) -> Scenario:
    """Read and check a scenario file; raises ScenarioError naming the file, step and key."""
    where = str(path)
    try:
        text = read_text(path, "scenario", named="TOML scenario")
        if toml_depth(text) > MAX_DEPTH:
            raise too_deep(where, "scenario")
        data = tomllib.loads(text)
    except FileReadError as exc:
        raise ScenarioError(where, "", exc.reason) from None
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(where, "", f"not valid TOML: {exc}") from None
    return parse_scenario(data, where)


def parse_scenario(data: Mapping[str, Any], path: str = "<scenario>") -> Scenario:
    for key in data:
        if key not in TOP_KEYS:
            raise ScenarioError(path, f"key {key!r}", str(ops.unknown("key", key, TOP_KEYS)))
    name = data.get("name", Path(path).stem)
    if not isinstance(name, str):
        raise ScenarioError(path, "key 'name'", "expected a string")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise ScenarioError(path, "key 'description'", "expected a string")
    profile = data.get("profile")
    if profile is not None and not isinstance(profile, str):
        raise ScenarioError(path, "key 'profile'", "expected a profile name or path")
    drives = data.get("drives")
    if drives is not None:
        if (
            not isinstance(drives, list)
            or not drives
            or not all(isinstance(d, int) and not isinstance(d, bool) and 1 <= d <= 247 for d in drives)
        ):
            raise ScenarioError(path, "key 'drives'", "expected a list of addresses 1-247, such as [1, 2]")
        drives = tuple(drives)
    raw_steps = data.get("step", [])
    if not isinstance(raw_steps, list) or not raw_steps:
        raise ScenarioError(path, "", "no steps; give [[step]] tables, each with at = seconds")
    steps: list[Step] = []
    for index, raw in enumerate(raw_steps, start=1):
        step = _parse_step(raw, index, path)
        if steps and step.at < steps[-1].at:
            raise ScenarioError(
                path, f"{step.label}, key 'at'", f"time runs backwards: step {index - 1} is at {steps[-1].at:g} s"
            )
        if drives is not None and step.drive is not None and step.drive not in drives:
            raise ScenarioError(path, f"{step.label}, key 'drive'", f"{step.drive} is not in drives {list(drives)}")
        steps.append(step)
    return Scenario(path, name, description, profile, drives, tuple(steps))


def _parse_step(raw: object, index: int, path: str) -> Step:
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


# --- Playing a scenario.


@dataclass(frozen=True)
class Outcome:
    """One expectation or action of one step, and whether it held."""

    step: Step
    t: float
    ok: bool
    text: str


@dataclass(frozen=True)
class Report:
    scenario: Scenario
    outcomes: tuple[Outcome, ...]

    @property
    def ok(self) -> bool:
        return all(o.ok for o in self.outcomes)

    @property
    def failures(self) -> list[Outcome]:
        return [o for o in self.outcomes if not o.ok]

    def render(self) -> str:
        """The report as a reader wants it: every check, then the verdict."""
        lines = [f"scenario {self.scenario.name} ({self.scenario.path})"]
        for o in self.outcomes:
            note = f" [{o.step.note}]" if o.step.note else ""
            lines.append(f"  {'ok  ' if o.ok else 'FAIL'} {o.step.label}{note}: {o.text}")
        checks = len(self.outcomes)
        if self.ok:
            lines.append(f"passed: {checks} check(s)")
        else:
            lines.append(f"FAILED: {len(self.failures)} of {checks} check(s)")
        return "\n".join(lines) + "\n"


def check(scenario: Scenario, sim: Simulator) -> None:
    """Raise ScenarioError if a step names a drive or register the simulator lacks."""
    registers = sim.profile.registers
    names = causes.cause_names(sim.profile)
    for step in scenario.steps:
        cause = step.fault.cause if step.fault is not None else None
        for key, name in (("fault", cause), ("clear_fault", step.release)):
            if name is not None and name not in names:
                raise ScenarioError(
                    scenario.path, f"{step.label}, key {key!r}", f"the profile {sim.profile.name} has no cause {name!r}"
                )
        if step.drive is not None and step.drive not in sim.drives:
            raise ScenarioError(
                scenario.path,
                f"{step.label}, key 'drive'",
                f"no drive at address {step.drive}; drives: {', '.join(map(str, sim.drives))}",
            )
        for key, items in (
            ("write", [w[:2] for w in step.write]),
            ("expect", [(e.register, e.address) for e in step.expect]),
        ):
            for register, address in items:
                if address not in registers:
                    try:  # the vocabulary's own words, with its did-you-mean (2100 is decimal: 2100H?)
                        resolve_register(register, registers, f"the profile {sim.profile.name}")
                    except UnknownRegister as exc:
                        raise ScenarioError(scenario.path, f"{step.label}, key {key!r}", str(exc)) from None


def _drive_of(step: Step, sim: Simulator) -> int:
    return step.drive if step.drive is not None else next(iter(sim.drives))


def _act(step: Step, sim: Simulator, address: int) -> None:
    """The step's actions before its writes: conditions, link and device faults, power."""
    if step.set:
        ops.set_conditions(sim, address, step.set)
    if step.link:
        ops.set_link_faults(sim, address, step.link)
    if step.clear_link:
        ops.clear_link_faults(sim, address)
    if step.fault is not None:
        causes.fault(sim, address, step.fault)
    if step.release is not None:
        causes.release(sim, address, step.release)
    if step.clear_fault:
        ops.clear_fault(sim, address, True)
    if step.power_cycle:
        ops.power_cycle(sim, address)


def _after_writes(step: Step, sim: Simulator, address: int, t: float) -> list[Outcome]:
    """The keypad press and the expectations, after the writes were answered."""
    out: list[Outcome] = []
    if step.keypad is not None:
        taken = ops.press_key(sim, address, step.keypad)
        out.append(Outcome(step, t, taken, f"keypad {step.keypad}: {'taken' if taken else 'refused by the drive'}"))
    return out + _expectations(step, sim, address, t) + _audited(step, sim, t)


def _audited(step: Step, sim: Simulator, t: float) -> list[Outcome]:
    """``expect_findings`` and ``forbid_findings``: what the live audit found by now (any drive, or the line)."""
    if not step.audited:
        return []
    audit = liveaudit.of(sim)
    if audit is None:
        return [Outcome(step, t, False, "audit: off (serve --no-audit); no finding can be checked")]
    found = audit.findings()
    out: list[Outcome] = []
    for rule in step.expect_findings:
        hits = [f for f in found if f.rule == rule]
        if hits:
            out.append(Outcome(step, t, True, f"audit: {rule} found: {hits[0].where}: {hits[0].figure}"))
        else:
            seen = ", ".join(sorted({f.rule for f in found})) or "none"
            out.append(Outcome(step, t, False, f"audit: no {rule} finding, expected one (findings: {seen})"))
    for rule in step.forbid_findings:
        hits = [f for f in found if rule in ("any", f.rule)]
        if hits:
            what = "; ".join(f"{f.rule} {f.where}: {f.figure}" for f in hits[:3])
            out.append(Outcome(step, t, False, f"audit: {what}, forbidden"))
        else:
            out.append(Outcome(step, t, True, f"audit: no {'finding' if rule == 'any' else rule + ' finding'}"))
    return out


def _expectations(step: Step, sim: Simulator, address: int, t: float, since: float | None = None) -> list[Outcome]:
    """The step's expectations read now; ``since``: the time a ``within`` step began to wait."""
    out: list[Outcome] = []
    for expect in step.expect:
        info = ops.read_register(sim, address, expect.address)
        ok = abs(info["raw"] - expect.value) <= expect.tolerance
        within = f" +/- {expect.tolerance}" if expect.tolerance else ""
        spec = sim.profile.registers[expect.address]
        wanted = spec.describe(expect.value & 0xFFFF)
        text = f"{info['register']} ({info['name']}) = {info['raw']} ({info['text']})"
        text += f", expected {expect.value}{within} ({wanted})" if not ok else f", expected {expect.value}{within}"
        if since is not None and step.within is not None:
            text += f" (after {t - since:.3g} s)" if ok else f" (still after {step.within:g} s)"
        out.append(Outcome(step, t, ok, text))
    return out


def _settled(step: Step, outcomes: list[Outcome]) -> bool:
    """True unless the step waits (``within``) and its expectations, the last outcomes, do not all hold yet."""
    return step.within is None or all(o.ok for o in outcomes[len(outcomes) - len(step.expect) :])


def _poll_times(step: Step, start: float) -> list[float]:
    """The model times a ``within`` step reads its registers again, every POLL s up to ``start + within``."""
    assert step.within is not None
    count = math.ceil(step.within / POLL - 1e-9)
    return [min(start + POLL * i, start + step.within) for i in range(1, count + 1)]


def _recheck(step: Step, sim: Simulator, outcomes: list[Outcome], start: float) -> list[Outcome]:
    """The step's outcomes with its expectations read again at the simulator's time."""
    address = _drive_of(step, sim)
    fresh = _expectations(step, sim, address, sim.now(), since=start)
    return outcomes[: len(outcomes) - len(step.expect)] + fresh


def _written(
    sim: Simulator, step: Step, t: float, register: str, request: WriteSingleRequest, reply: Reply | None
) -> Outcome:
    """The outcome of a master's write, from the reply the bus gave it."""
    return _answered(sim, step, t, f"write {register} = {request.value}", request, reply)


def _answered(sim: Simulator, step: Step, t: float, label: str, request: Request, reply: Reply | None) -> Outcome:
    """A master's request and its reply, judged by what the step expects: taken, refused, or silence."""
    from ..wire.decode import describe

    wanted = step.expect_exception
    wanted_text = f"exception 0x{wanted:02X} ({ExceptionCode(wanted).meaning})" if wanted is not None else ""
    if reply is None:
        if step.expect_silence:
            return Outcome(step, t, True, f"{label}: no reply, as expected")
        return Outcome(step, t, False, f"{label}: no reply" + (f", expected {wanted_text}" if wanted else ""))
    try:
        response = decode_response(reply.data)
    except ValueError:
        return Outcome(step, t, False, f"{label}: a broken reply {reply.data.hex(' ').upper()}")
    said = describe(response, sim.profile.registers, request)
    if step.expect_silence:
        return Outcome(step, t, False, f"{label}: answered ({said}), expected no reply")
    if response.function & 0x80:
        if wanted is not None and reply.data[2] == wanted:
            return Outcome(step, t, True, f"{label}: refused with {wanted_text}, as expected")
        return Outcome(step, t, False, f"{label}: {said}" + (f", expected {wanted_text}" if wanted else ""))
    if wanted is not None:
        return Outcome(step, t, False, f"{label}: taken, expected {wanted_text}")
    return Outcome(step, t, True, f"{label}: taken")


def apply_step(step: Step, sim: Simulator) -> list[Outcome]:
    """Apply ``step`` at the simulator's time, with no line: the outcomes of its writes and expectations.

    A write is a master's frame handed to the bus (frame log, link faults, access rules),
    stamped with the model's time: with no endpoint there is no other line time, so the
    frame log's times are the model's (``t`` equals ``model_t``).
    """
    address = _drive_of(step, sim)
    t = sim.now()
    _act(step, sim, address)
    out = []
    for register, reg, value in step.write:
        request = WriteSingleRequest(address, reg, value)
        reply = sim.handle(FrameEvent(FrameKind.FRAME, encode(request), sim.now()))
        out.append(_written(sim, step, t, register, request, reply))
    if step.expect_silence and not step.write:
        poll = ReadRequest(address, Reg.STATUS1, 1)
        reply = sim.handle(FrameEvent(FrameKind.FRAME, encode(poll), sim.now()))
        out.append(_answered(sim, step, t, "read 2100H", poll, reply))
    return out + _after_writes(step, sim, address, t)


async def apply_step_on_line(step: Step, sim: Simulator, line: Line) -> list[Outcome]:
    """Apply ``step`` on a served simulator: each write is a frame submitted to ``line``, stamped with the
    loop's time like a port's, served in its turn (after a reply the line holds) and awaited."""
    address = _drive_of(step, sim)
    t = sim.now()
    _act(step, sim, address)
    out = []
    for register, reg, value in step.write:
        request = WriteSingleRequest(address, reg, value)
        reply = await _submit(line, encode(request))
        out.append(_written(sim, step, t, register, request, reply))
    if step.expect_silence and not step.write:
        poll = ReadRequest(address, Reg.STATUS1, 1)
        reply = await _submit(line, encode(poll))
        out.append(_answered(sim, step, t, "read 2100H", poll, reply))
    return out + _after_writes(step, sim, address, t)


#: The longest wait for the line's answer to a scenario's write: an injected delay and its jitter (60 s each).
LINE_TIMEOUT = 125.0


async def _submit(line: Line, frame: bytes) -> Reply | None:
    loop = asyncio.get_running_loop()
    answer: asyncio.Future[Reply | None] = loop.create_future()

    def respond(reply: Reply | None) -> None:
        if not answer.done():
            answer.set_result(reply)

    line.submit(FrameEvent(FrameKind.FRAME, frame, loop.time()), respond)
    try:
        return await asyncio.wait_for(answer, LINE_TIMEOUT)
    except TimeoutError:
        return None  # the line never answered (a bug it logged): the outcome says no reply


def _audit_for(scenario: Scenario, sim: Simulator) -> None:
    """A scenario that reads the audit has one: started now if the simulator audits nothing yet (a served one
    has it from the start, unless --no-audit)."""
    if any(step.audited for step in scenario.steps) and liveaudit.of(sim) is None:
        liveaudit.start(sim)


def _no_drill_here(scenario: Scenario) -> None:
    for step in scenario.steps:
        if step.drill:
            raise ScenarioError(
                scenario.path,
                step.label,
                "drill: a drill plays on a real master: serve --scenario FILE with the realtime clock, and a master "
                "polling the serve (docs/drill.md)",
            )


async def _drill_step(step: Step, sim: Simulator) -> Outcome:
    """Play the step's drill on the master polling the served drive; the outcome is its verdicts."""
    t = sim.now()
    service = drills.of(sim)
    service.start({"plan": [dict(item) for item in step.drill]})
    while (state := service.status())["state"] == "running":
        await asyncio.sleep(0.2)
    if state["state"] == "failed":
        return Outcome(step, t, False, f"drill: {state['error']}")
    report = state["report"]
    verdicts = report["verdicts"]
    failed = [v for v in verdicts if not v["passed"]]
    text = f"drill: {len(verdicts) - len(failed)} of {len(verdicts)} drills passed"
    if failed:
        first = failed[0]
        figures = "; ".join(c["figure"] for c in first["checks"] if not c["passed"])
        text += f"; {first['index']} {first['incident']}: {figures}"
    if report.get("problem"):
        text += f"; {report['problem']}"
    return Outcome(step, t, bool(report["passed"]) and not report.get("ended_early"), text)


def run(scenario: Scenario, sim: Simulator) -> Report:
    """Play ``scenario`` on a simulator with a virtual clock, instantly."""
    if not sim.virtual:
        raise ScenarioError(scenario.path, "", "run needs a virtual clock; use play() to follow a realtime one")
    _no_drill_here(scenario)
    check(scenario, sim)
    _audit_for(scenario, sim)
    outcomes: list[Outcome] = []
    start = sim.now()
    for step in scenario.steps:
        sim.run_until(start + step.at)
        try:
            results = apply_step(step, sim)
        except ops.ControlError as exc:
            raise ScenarioError(scenario.path, step.label, str(exc)) from None
        if not _settled(step, results):
            began = sim.now()
            for t in _poll_times(step, began):
                sim.run_until(t)
                results = _recheck(step, sim, results, began)
                if _settled(step, results):
                    break
        outcomes += results
    return Report(scenario, tuple(outcomes))


async def play(scenario: Scenario, sim: Simulator, *, line: Line | None = None, out: IO[str] | None = None) -> Report:
    """Play ``scenario`` on a served simulator: a virtual clock is advanced to each step, a realtime one
    is waited for. With the server's ``line``, writes are frames on it, served in turn with the
    ports' (without, they go to the bus directly); each outcome is printed to ``out``."""
    check(scenario, sim)
    _audit_for(scenario, sim)
    if sim.virtual:
        _no_drill_here(scenario)
    outcomes: list[Outcome] = []
    start = sim.now()
    for step in scenario.steps:
        while (wait := sim.wall_seconds_to(start + step.at)) > 0:
            await asyncio.sleep(min(0.5, wait))
        try:
            results = apply_step(step, sim) if line is None else await apply_step_on_line(step, sim, line)
            if step.drill:
                results.append(await _drill_step(step, sim))
        except ops.ControlError as exc:
            raise ScenarioError(scenario.path, step.label, str(exc)) from None
        if not _settled(step, results):
            began = sim.now()
            for t in _poll_times(step, began):
                while (wait := sim.wall_seconds_to(t)) > 0:
                    await asyncio.sleep(min(0.5, wait))
                results = _recheck(step, sim, results, began)
                if _settled(step, results):
                    break
        outcomes += results
        if out is not None:
            for o in results:
                print(
                    f"scenario {scenario.name}: {'ok  ' if o.ok else 'FAIL'} {step.label}: {o.text}",
                    file=out,
                    flush=True,
                )
        await asyncio.sleep(0)
    report = Report(scenario, tuple(outcomes))
    if out is not None:
        verdict = "passed" if report.ok else f"FAILED ({len(report.failures)} of {len(outcomes)} checks)"
        print(f"scenario {scenario.name}: {verdict}", file=out, flush=True)
    return report
