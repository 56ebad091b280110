"""Checking a profile's TOML: the checker of keys, numbers and curves, the fault table and the function codes.

Every error is a :class:`~c20sim.wire.errors.ProfileError` naming the file, the key and the allowed range, with
a "did you mean" for a misspelt key. The keys a cause row declares (:class:`~c20sim.drive.trips.Level`) are
checked from the row: their section's allowed keys, their range and unit in the error, their default. :func:`c20sim.drive.profile.parse_profile` calls these.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
from collections.abc import Mapping
from typing import Any

from ..wire.errors import ProfileError
from ..wire.registers import FIXED_REGISTERS, Access, RegisterSpec, format_fcode, is_fcode, parse_fcode
from .profiletypes import REQUIRED_MIRRORS, FaultCause, FaultSpec
from .trips import Level, levels


def _did_you_mean(word: str, choices: Any) -> str:
    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


class _Checker:
    def __init__(self, path: str) -> None:
        self.path = path

    def fail(self, key: str, message: str) -> ProfileError:
        return ProfileError(self.path, key, message)

    def table(self, data: Mapping[str, Any], key: str) -> Mapping[str, Any]:
        value = data.get(key)
        if not isinstance(value, dict):
            raise self.fail(key, "missing table" if value is None else f"must be a table, not {type(value).__name__}")
        return value

    def unknown_keys(self, data: Mapping[str, Any], allowed: Any, prefix: str) -> None:
        for key in data:
            if key not in allowed:
                raise self.fail(
                    f"{prefix}{key}", f"unknown key{_did_you_mean(key, allowed)}; allowed: {', '.join(allowed)}"
                )

    def number(
        self, value: Any, key: str, kind: type, minimum: float | None, maximum: float | None, unit: str = ""
    ) -> Any:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(key, f"must be a number, not {value!r}")
        if kind is int and not isinstance(value, int):
            raise self.fail(key, f"must be a whole number, not {value!r}")
        if not math.isfinite(value):
            bounds = f"; allowed {minimum:g} to {maximum:g}" if minimum is not None and maximum is not None else ""
            raise self.fail(key, f"must be a finite number, not {value}{bounds}{' ' + unit if unit and bounds else ''}")
        if (minimum is not None and value < minimum) or (maximum is not None and value > maximum):
            raise self.fail(
                key, f"{value} is out of range; allowed {minimum:g} to {maximum:g}{' ' + unit if unit else ''}"
            )
        return kind(value)

    def curve(self, value: Any, key: str) -> tuple[tuple[float, float], ...]:
        """An inverse-time curve: [[multiple, seconds], ...], multiples above 1 rising, times falling."""
        shape = "[[multiple of rated current, seconds], ...]"
        if not isinstance(value, list) or not value:
            raise self.fail(key, f"must be a non-empty array {shape}")
        points: list[tuple[float, float]] = []
        for i, pair in enumerate(value):
            if not isinstance(pair, list) or len(pair) != 2:
                raise self.fail(f"{key}[{i}]", f"must be a pair [multiple, seconds], not {pair!r}")
            multiple = self.number(pair[0], f"{key}[{i}][0]", float, 1.01, 20.0, "x rated")
            seconds = self.number(pair[1], f"{key}[{i}][1]", float, 0.01, 36000.0, "s")
            if multiple != multiple or seconds != seconds:  # NaN passes every comparison
                raise self.fail(f"{key}[{i}]", "must be finite numbers, not nan")
            if points and (multiple <= points[-1][0] or seconds >= points[-1][1]):
                raise self.fail(f"{key}[{i}]", "multiples must rise and times fall from one point to the next")
            points.append((multiple, seconds))
        return tuple(points)

    def level(self, table: Mapping[str, Any], level: Level) -> bool | int | float:
        """A cause row's key in ``table`` (its section), checked against the row's range; its default if absent."""
        if level.name not in table:
            return level.default
        value = table[level.name]
        if level.kind is bool:
            if not isinstance(value, bool):
                raise self.fail(level.key, f"must be true or false, not {value!r}")
            return value
        number: int | float = self.number(value, level.key, level.kind, level.low, level.high, level.unit)
        return number

    def section(self, data: Mapping[str, Any], name: str, cls: type) -> Any:
        table = self.table(data, name) if name in data or _required(cls) else {}
        fields = {f.name: f for f in dataclasses.fields(cls)}
        self.unknown_keys(table, [*fields, *(lv.name for lv in section_levels(name))], f"{name}.")
        values: dict[str, Any] = {}
        for fname, f in fields.items():
            key = f"{name}.{fname}"
            if fname not in table:
                if f.default is dataclasses.MISSING:
                    raise self.fail(key, f"missing; {_describe_field(f)}")
                continue
            value = table[fname]
            if f.type == "tuple[tuple[float, float], ...]":
                values[fname] = self.curve(value, key)
                continue
            kind = (
                bool
                if f.type in ("bool", bool)
                else int
                if f.type in ("int", int)
                else float
                if f.type in ("float", float)
                else str
            )
            if kind is bool:
                if not isinstance(value, bool):
                    raise self.fail(key, f"must be true or false, not {value!r}")
            elif kind is str:
                if not isinstance(value, str):
                    raise self.fail(key, f"must be a string, not {value!r}")
            else:
                meta = f.metadata
                value = self.number(value, key, kind, meta.get("min"), meta.get("max"), meta.get("unit", ""))
                if "choices" in meta and value not in meta["choices"]:
                    raise self.fail(key, f"{value} is not allowed; allowed: {', '.join(map(str, meta['choices']))}")
            values[fname] = value
        return cls(**values)


def section_levels(section: str) -> list[Level]:
    """The cause rows' keys in ``section``, as the rows are now."""
    return [level for level in levels().values() if level.section == section]


def own_sections() -> list[str]:
    """The tables only cause rows declare (none of the profile's own sections), in the rows' order."""
    return list(dict.fromkeys(lv.section for lv in levels().values() if lv.section not in _TOP_KEYS))


def parse_levels(check: _Checker, data: Mapping[str, Any]) -> dict[str, bool | int | float]:
    """Every cause row's key: the profile's value, checked against the row's range, or the row's default. A table
    only rows declare is checked here for unknown keys (the profile's own sections are, by ``section``)."""
    out: dict[str, bool | int | float] = {}
    for section in own_sections():
        table = check.table(data, section) if section in data else {}
        check.unknown_keys(table, [lv.name for lv in section_levels(section)], f"{section}.")
    for level in levels().values():
        table = data.get(level.section, {})
        out[level.key] = check.level(table if isinstance(table, dict) else {}, level)
    return out


def _required(cls: type) -> bool:
    return any(f.default is dataclasses.MISSING for f in dataclasses.fields(cls))


def _describe_field(f: dataclasses.Field[Any]) -> str:
    meta = f.metadata
    parts = []
    if "min" in meta:
        parts.append(f"allowed {meta['min']:g} to {meta['max']:g}{' ' + meta['unit'] if meta.get('unit') else ''}")
    if meta.get("doc"):
        parts.append(meta["doc"])
    return "; ".join(parts) or "required"


_TOP_KEYS = (
    "name",
    "description",
    "software_version",
    "protocol",
    "motor",
    "supply",
    "protection",
    "thermal",
    "control",
    "fault",
    "parameter",
    "behaviours",
)
_FAULT_KEYS = ("code", "name", "meaning", "cause", "source")
_PARAM_KEYS = (
    "code",
    "name",
    "default",
    "min",
    "max",
    "unit",
    "scale",
    "access",
    "mirror",
    "signed",
    "values",
    "source",
)
_SOURCES = ("sheet", "notes", "field", "assumed")


def _parse_faults(check: _Checker, raw: Any) -> dict[int, FaultSpec]:
    if not isinstance(raw, list) or not raw:
        raise check.fail("fault", "missing; an array of [[fault]] tables with code, name, meaning")
    faults: dict[int, FaultSpec] = {}
    causes: dict[FaultCause, int] = {}
    cause_names = [c.value for c in FaultCause]
    for i, entry in enumerate(raw):
        where = f"fault[{i}]"
        if not isinstance(entry, dict):
            raise check.fail(where, "must be a table")
        check.unknown_keys(entry, _FAULT_KEYS, f"{where}.")
        code = check.number(entry.get("code"), f"{where}.code", int, 1, 255)
        if code in faults:
            raise check.fail(f"{where}.code", f"code {code} is listed twice")
        fname = entry.get("name")
        if not isinstance(fname, str) or not fname:
            raise check.fail(f"{where}.name", "missing; a short name such as 'UV'")
        cause: FaultCause | None = None
        if "cause" in entry:
            text = entry["cause"]
            if text not in cause_names:
                raise check.fail(
                    f"{where}.cause",
                    f"unknown cause {text!r}{_did_you_mean(str(text), cause_names)}; allowed: {', '.join(cause_names)}",
                )
            cause = FaultCause(text)
            if cause in causes:
                raise check.fail(f"{where}.cause", f"cause {text!r} already has code {causes[cause]}")
            causes[cause] = code
        source = entry.get("source", "assumed")
        if source not in _SOURCES:
            raise check.fail(
                f"{where}.source", f"must be one of {', '.join(_SOURCES)}{_did_you_mean(str(source), _SOURCES)}"
            )
        faults[code] = FaultSpec(code, fname, str(entry.get("meaning", "")), cause, source)
    return faults


def _parse_parameters(check: _Checker, raw: Any) -> tuple[list[RegisterSpec], dict[int, int], dict[int, int]]:
    if not isinstance(raw, list) or not raw:
        raise check.fail("parameter", "missing; an array of [[parameter]] tables (the function-code table)")
    specs: list[RegisterSpec] = []
    defaults: dict[int, int] = {}
    mirrors: dict[int, int] = {}
    accesses = [a.value for a in Access]
    for i, entry in enumerate(raw):
        if not isinstance(entry, dict):
            raise check.fail(f"parameter[{i}]", "must be a table")
        code_text = entry.get("code")
        where = f"parameter[{i}]" if not isinstance(code_text, str) else f"parameter {code_text}"
        check.unknown_keys(entry, _PARAM_KEYS, f"{where}: ")
        try:
            address = parse_fcode(str(code_text))
        except ValueError as exc:
            raise check.fail(f"{where}.code", str(exc)) from None
        if address in defaults:
            raise check.fail(f"{where}.code", f"{format_fcode(address)} is listed twice")
        pname = entry.get("name")
        if not isinstance(pname, str) or not pname:
            raise check.fail(f"{where}.name", "missing; what the parameter is")
        signed = entry.get("signed", False)
        if not isinstance(signed, bool):
            raise check.fail(f"{where}.signed", "must be true or false")
        low, high = (-32768, 32767) if signed else (0, 65535)
        minimum = check.number(entry.get("min", low), f"{where}.min", int, low, high)
        maximum = check.number(entry.get("max", high), f"{where}.max", int, minimum, high)
        if "default" not in entry:
            raise check.fail(f"{where}.default", f"missing; allowed {minimum} to {maximum}")
        default = check.number(entry["default"], f"{where}.default", int, minimum, maximum)
        scale = check.number(entry.get("scale", 1), f"{where}.scale", float, 1e-6, 1e6)
        unit = entry.get("unit", "")
        if not isinstance(unit, str):
            raise check.fail(f"{where}.unit", "must be a string")
        access_text = entry.get("access", "W/R")
        if access_text not in accesses:
            raise check.fail(f"{where}.access", f"must be one of {', '.join(accesses)}, not {access_text!r}")
        values_raw = entry.get("values", {})
        if not isinstance(values_raw, dict) or not all(
            k.isdigit() and isinstance(v, str) for k, v in values_raw.items()
        ):
            raise check.fail(f"{where}.values", 'must be a table of "number" = "meaning"')
        source = entry.get("source", "assumed")
        if source not in _SOURCES:
            raise check.fail(
                f"{where}.source", f"must be one of {', '.join(_SOURCES)}{_did_you_mean(str(source), _SOURCES)}"
            )
        if "mirror" in entry:
            register = _parse_mirror(check, where, entry["mirror"], access_text, minimum, maximum, mirrors)
            mirrors[register] = address
        specs.append(
            RegisterSpec(
                address,
                pname,
                Access(access_text),
                minimum,
                maximum,
                unit,
                scale,
                signed,
                {int(k): v for k, v in values_raw.items()},
                source=source,
            )
        )
        defaults[address] = default & 0xFFFF
    assert all(is_fcode(s.address) for s in specs)
    return specs, defaults, mirrors


def _parse_register(text: Any) -> int | None:
    if not isinstance(text, str):
        return None
    body = text.strip().upper().removesuffix("H").removeprefix("0X")
    try:
        return int(body, 16)
    except ValueError:
        return None


def _parse_mirror(
    check: _Checker, where: str, mirror_text: Any, access_text: str, minimum: int, maximum: int, mirrors: dict[int, int]
) -> int:
    """The 20xxH register a function code mirrors: one of REQUIRED_MIRRORS, not mirrored twice, as W/R* as it
    and within its range in the sheet."""
    register = _parse_register(mirror_text)
    if register is None or register not in REQUIRED_MIRRORS:
        allowed = ", ".join(f"{r:04X}H" for r in REQUIRED_MIRRORS)
        raise check.fail(f"{where}.mirror", f"{mirror_text!r} cannot mirror a function code; allowed: {allowed}")
    if register in mirrors:
        raise check.fail(f"{where}.mirror", f"{register:04X}H already mirrors {format_fcode(mirrors[register])}")
    fixed = FIXED_REGISTERS[register]
    if fixed.access is Access.RW_STOPPED and access_text != Access.RW_STOPPED.value:
        raise check.fail(f"{where}.access", f"must be W/R* like the register it mirrors, {register:04X}H")
    if minimum < fixed.minimum or maximum > fixed.maximum:
        raise check.fail(
            f"{where}.max" if maximum > fixed.maximum else f"{where}.min",
            f"{minimum}-{maximum} goes beyond {register:04X}H's range in the sheet, {fixed.minimum}-{fixed.maximum}",
        )
    return register
