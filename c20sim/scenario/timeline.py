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

Within a step the actions run in the order of the step kinds' table
(:data:`c20sim.scenario.stepkinds.TABLE`): ``set``, ``link``, ``clear_link``,
``fault``, ``clear_fault``, ``power_cycle``, then the ``write``s, then
``keypad``, ``expect`` (polled for ``within`` seconds) and the audit's
findings; a ``drill`` is awaited last. Expected values are raw register
values, as a master reads them (3008H = 480 is 48.0 V). A step's keys are the
rows of :mod:`.stepkinds` and :mod:`.stepchecks`; the format's reference is
docs/scenario-format.md. Loading raises :class:`ScenarioError` naming the
file, the step and the key, like a profile.

:func:`run` plays a scenario in virtual time, instantly, and returns a
:class:`Report`; :func:`play` follows a served simulator's clock.
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, TypeVar

from ..control import liveaudit, ops
from ..core.simulator import Simulator
from ..drive.files import MAX_DEPTH, FileReadError, read_text, toml_depth, too_deep
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
from .stepchecks import expectations
from .stepkinds import parse_step, table
from .steps import Expect, Outcome, ScenarioError, Step

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


@dataclass(frozen=True)
class Scenario:
    path: str
    name: str
    description: str = ""
    profile: str | None = None
    drives: tuple[int, ...] | None = None
    steps: tuple[Step, ...] = ()


#: Model seconds between two reads of a ``within`` step's registers.
POLL = 0.01
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
        step = parse_step(raw, index, path)
        if steps and step.at < steps[-1].at:
            raise ScenarioError(
                path, f"{step.label}, key 'at'", f"time runs backwards: step {index - 1} is at {steps[-1].at:g} s"
            )
        if drives is not None and step.drive is not None and step.drive not in drives:
            raise ScenarioError(path, f"{step.label}, key 'drive'", f"{step.drive} is not in drives {list(drives)}")
        steps.append(step)
    return Scenario(path, name, description, profile, drives, tuple(steps))


# --- Playing a scenario.


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
    """Raise ScenarioError if a step names a drive, register or cause the simulator lacks (each step kind's
    ``against``)."""
    for step in scenario.steps:
        for kind in table():
            if kind.against is not None and kind.key in step.given:
                problem = kind.against(step, sim)
                if problem is not None:
                    raise ScenarioError(scenario.path, f"{step.label}, key {kind.key!r}", problem)


def _drive_of(step: Step, sim: Simulator) -> int:
    return step.drive if step.drive is not None else next(iter(sim.drives))


def _acts(step: Step, sim: Simulator, address: int, t: float, *, after_writes: bool) -> list[Outcome]:
    """The acts of the step's kinds (:mod:`.stepkinds`), in the table's order: those before the writes, or those
    after them (the checks); an act two kinds share runs once."""
    out: list[Outcome] = []
    done: list[object] = []
    for kind in table():
        if kind.act is None or kind.after_writes != after_writes or kind.key not in step.given or kind.act in done:
            continue
        done.append(kind.act)
        out += [o if o.key else dataclasses.replace(o, key=kind.key) for o in kind.act(step, sim, address, t)]
    return out


def _settled(step: Step, outcomes: list[Outcome]) -> bool:
    """True unless the step waits (``within``) and its expectations do not all hold yet."""
    return step.within is None or all(o.ok for o in outcomes if o.key == "expect")


def _poll_times(step: Step, start: float) -> list[float]:
    """The model times a ``within`` step reads its registers again, every POLL s up to ``start + within``."""
    assert step.within is not None
    count = math.ceil(step.within / POLL - 1e-9)
    return [min(start + POLL * i, start + step.within) for i in range(1, count + 1)]


def _recheck(step: Step, sim: Simulator, outcomes: list[Outcome], start: float) -> list[Outcome]:
    """The step's outcomes with its expectations read again at the simulator's time, each in its place."""
    address = _drive_of(step, sim)
    fresh = iter(expectations(step, sim, address, sim.now(), since=start))
    return [dataclasses.replace(next(fresh), key="expect") if o.key == "expect" else o for o in outcomes]


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
    _acts(step, sim, address, t, after_writes=False)
    out = []
    for register, reg, value in step.write:
        request = WriteSingleRequest(address, reg, value)
        reply = sim.handle(FrameEvent(FrameKind.FRAME, encode(request), sim.now()))
        out.append(_written(sim, step, t, register, request, reply))
    if step.expect_silence and not step.write:
        poll = ReadRequest(address, Reg.STATUS1, 1)
        reply = sim.handle(FrameEvent(FrameKind.FRAME, encode(poll), sim.now()))
        out.append(_answered(sim, step, t, "read 2100H", poll, reply))
    return out + _acts(step, sim, address, t, after_writes=True)


async def apply_step_on_line(step: Step, sim: Simulator, line: Line) -> list[Outcome]:
    """Apply ``step`` on a served simulator: each write is a frame submitted to ``line``, stamped with the
    loop's time like a port's, served in its turn (after a reply the line holds) and awaited."""
    address = _drive_of(step, sim)
    t = sim.now()
    _acts(step, sim, address, t, after_writes=False)
    out = []
    for register, reg, value in step.write:
        request = WriteSingleRequest(address, reg, value)
        reply = await _submit(line, encode(request))
        out.append(_written(sim, step, t, register, request, reply))
    if step.expect_silence and not step.write:
        poll = ReadRequest(address, Reg.STATUS1, 1)
        reply = await _submit(line, encode(poll))
        out.append(_answered(sim, step, t, "read 2100H", poll, reply))
    return out + _acts(step, sim, address, t, after_writes=True)


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


def _served_only(scenario: Scenario) -> None:
    """Refuse a step whose kinds play only on a served simulator (a drill needs a real master)."""
    for step in scenario.steps:
        for kind in table():
            if kind.served is not None and kind.key in step.given:
                raise ScenarioError(scenario.path, step.label, f"{kind.key}: {kind.served_only}")


async def _served(step: Step, sim: Simulator) -> list[Outcome]:
    """The step's kinds that play on a served simulator, awaited in the table's order."""
    return [await kind.served(step, sim) for kind in table() if kind.served is not None and kind.key in step.given]


def run(scenario: Scenario, sim: Simulator) -> Report:
    """Play ``scenario`` on a simulator with a virtual clock, instantly."""
    if not sim.virtual:
        raise ScenarioError(scenario.path, "", "run needs a virtual clock; use play() to follow a realtime one")
    _served_only(scenario)
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
        _served_only(scenario)
    outcomes: list[Outcome] = []
    start = sim.now()
    for step in scenario.steps:
        while (wait := sim.wall_seconds_to(start + step.at)) > 0:
            await asyncio.sleep(min(0.5, wait))
        try:
            results = apply_step(step, sim) if line is None else await apply_step_on_line(step, sim, line)
            results += await _served(step, sim)
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
