"""The step kinds that check: what the registers must read, how the writes must be answered, what the audit
must have found. One :class:`~c20sim.scenario.steps.StepKind` row each, in the order they are read."""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from ..audit import RULES
from ..control import liveaudit, ops
from ..wire.protocol import ExceptionCode
from .steps import Expect, Outcome, Reading, Step, StepKind, missing_register

if TYPE_CHECKING:
    from ..core.simulator import Simulator

__all__ = ["CHECKS", "MAX_WITHIN", "expectations"]

#: The longest ``within`` (model seconds).
MAX_WITHIN = 3600.0


def _expect(value: object, reading: Reading) -> dict[str, object]:
    expects: list[Expect] = []
    for register, given in reading.table("expect", value).items():
        raw = given
        reading.unquoted("expect", register, given)
        address = reading.checked("expect", functools.partial(ops.register_address, register))
        tolerance: object = 0
        if isinstance(given, dict):
            extra = set(given) - {"value", "tolerance"}
            if extra:
                hint = (
                    f'; quote a function code, as "{register}.{sorted(extra)[0]}" = N'
                    if register.upper().startswith("F")
                    else "; give { value = N, tolerance = N }"
                )
                raise reading.fail("expect", f"{register}: unknown key {sorted(extra)[0]!r}{hint}")
            raw, tolerance = given.get("value"), given.get("tolerance", 0)
        if isinstance(raw, bool) or not isinstance(raw, int):
            raise reading.fail("expect", f"{register}: expected a raw register value (an integer), got {raw!r}")
        if isinstance(tolerance, bool) or not isinstance(tolerance, int) or tolerance < 0:
            raise reading.fail("expect", f"{register}: tolerance must be a whole number >= 0, got {tolerance!r}")
        expects.append(Expect(register, address, raw, tolerance))
    return {"expect": tuple(expects)}


def _expect_exception(value: object, reading: Reading) -> dict[str, object]:
    codes = [int(c) for c in ExceptionCode]
    if isinstance(value, bool) or value not in codes:
        raise reading.fail("expect_exception", f"expected an exception code {codes[0]}-{codes[-1]}, such as 8")
    if not reading.read.get("write"):
        raise reading.fail("expect_exception", "the step has no write to be refused; give write = { ... } too")
    return {"expect_exception": value}


def _expect_silence(value: object, reading: Reading) -> dict[str, object]:
    silence = reading.flag("expect_silence", value)
    if silence and reading.read.get("expect_exception") is not None:
        raise reading.fail("expect_silence", "a write cannot be both refused and unanswered; give one of the two")
    return {"expect_silence": silence}


def _within(value: object, reading: Reading) -> dict[str, object]:
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float)
        or not (math.isfinite(value) and 0 < value <= MAX_WITHIN)
    ):
        raise reading.fail("within", f"expected seconds of model time, > 0 and <= {MAX_WITHIN:g}, such as 2.0")
    if not reading.read.get("expect"):
        raise reading.fail("within", "nothing to wait for; give expect = { ... } too")
    return {"within": float(value)}


def _findings(key: str, allowed: Callable[[], tuple[str, ...]]) -> Any:
    """The parser of a findings key; ``allowed`` is asked at each read, so a rule added to RULES is taken."""

    def parse(value: object, reading: Reading) -> dict[str, object]:
        if not isinstance(value, list) or not all(isinstance(x, str) for x in value):
            raise reading.fail(key, 'expected a list of the audit\'s rules, such as ["eeprom-wear"]')
        for name in value:
            if name not in allowed():
                raise reading.fail(key, str(ops.unknown("rule", name, allowed())))
        both = set(value) & set(reading.read.get("expect_findings", ()))
        if key == "forbid_findings" and both:
            raise reading.fail(key, f"{sorted(both)[0]} is expected and forbidden at once; give one of the two")
        return {key: tuple(value)}

    return parse


def expectations(step: Step, sim: Simulator, address: int, t: float, since: float | None = None) -> list[Outcome]:
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


def _audited(step: Step, sim: Simulator, address: int, t: float) -> list[Outcome]:
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


def _rules(allowed: Callable[[], tuple[str, ...]], description: str) -> Any:
    return lambda: {
        "type": "array",
        "items": {"enum": list(allowed())},
        "uniqueItems": True,
        "description": description,
    }


_RAW_OR_TOLERANCE = {
    "oneOf": [
        {"type": "integer"},
        {
            "type": "object",
            "properties": {"value": {"type": "integer"}, "tolerance": {"type": "integer", "minimum": 0}},
            "required": ["value"],
            "additionalProperties": False,
        },
    ]
}

CHECKS = (
    StepKind(
        "expect",
        _expect,
        lambda: {
            "type": "object",
            "additionalProperties": _RAW_OR_TOLERANCE,
            "description": "raw values registers (speed, 3006H, motor_speed ...) must read, optionally within a "
            "tolerance",
        },
        "table `REGISTER = raw` or `REGISTER = { value = N, tolerance = N }`",
        "what registers must read",
        expectations,
        after_writes=True,
        against=lambda step, sim: missing_register(((e.register, e.address) for e in step.expect), sim),
    ),
    StepKind(
        "expect_exception",
        _expect_exception,
        lambda: {
            "type": "integer",
            "minimum": 1,
            "maximum": 8,
            "description": "every write of the step must be refused with this exception code",
        },
        "1-8",
        "every write of the step must be refused with this code (0x08 on a locked write, ...)",
    ),
    StepKind(
        "expect_silence",
        _expect_silence,
        lambda: {"type": "boolean", "description": "the step's writes (or a read of 2100H) must get no reply"},
        "boolean",
        "the step's writes (or, with none, a read of 2100H) must get no reply: the drive offline",
    ),
    StepKind(
        "within",
        _within,
        lambda: {
            "type": "number",
            "exclusiveMinimum": 0,
            "maximum": int(MAX_WITHIN),
            "description": "seconds of model time the expectations may take to hold (polled every 10 ms)",
        },
        "seconds, above 0 to 3600",
        "`expect` may take this long in model time to hold (read every 10 ms); a failure shows the last value seen",
    ),
    StepKind(
        "expect_findings",
        _findings("expect_findings", lambda: tuple(RULES)),
        _rules(lambda: tuple(RULES), "the audit's rules that must have found something by this step (docs/audit.md)"),
        "list of the audit's rules",
        'each must have found something by this step: `["eeprom-wear"]` ([audit.md](audit.md))',
        _audited,
        after_writes=True,
    ),
    StepKind(
        "forbid_findings",
        _findings("forbid_findings", lambda: ("any", *RULES)),
        _rules(lambda: ("any", *RULES), 'rules that must have found nothing by this step; "any": no finding at all'),
        'list of rules, or `["any"]`',
        'none of them may have found anything by this step; `"any"`: no finding at all',
        _audited,
        after_writes=True,
    ),
)
