"""The dialect a capture shows (:mod:`c20sim.traffic.dialect`), as ``fit`` reports and writes it.

Per quirk: the value learned, the base profile's, whether it is written into the fitted profile and why not when
not, and the capture's lines that showed it. A quirk with a key in the profile's [protocol] table is written with
a comment ``# source = "capture": lines ...`` (the [protocol] table has no ``source`` key, as [[parameter]] and
[[fault]] rows do); a quirk the format cannot express is reported only.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from ..drive.profile import Profile
from ..wire.registers import format_fcode
from .dialect import Frame, Learned, Quirk, learn

__all__ = [
    "QuirkResult",
    "drop_parameters",
    "learn_dialect",
    "lines_words",
    "quirk_changes",
    "quirk_lines",
    "quirk_table",
    "quirk_values",
]


@dataclass(frozen=True)
class QuirkResult:
    quirk: Quirk
    learned: Learned
    base: object | None  #: the base profile's value; None where the format has no key
    lines: tuple[int, ...]  #: of the capture: the requests that showed it

    @property
    def written(self) -> bool:
        """Its key's value is written, or the rows of the function codes that did not answer are dropped."""
        learned = self.learned
        return (self.quirk.key is not None and learned.value is not None) or bool(learned.absent or learned.defaults)

    @property
    def why_not(self) -> str:
        """Why it is not written ("" when it is)."""
        if self.written:
            return ""
        if self.learned.value is None:
            return self.learned.why
        return "the profile format has no key for it"


def learn_dialect(probes: Sequence[tuple[str, Frame]], base: Profile, *, modbus_tcp: bool = False) -> list[QuirkResult]:
    """Each quirk of :data:`~c20sim.traffic.dialect.QUIRKS`, learned from the capture's probe frames."""
    out = []
    for quirk, learned, lines in learn(probes, base, modbus_tcp=modbus_tcp):
        value = getattr(base.protocol, quirk.key) if quirk.key is not None else None
        out.append(QuirkResult(quirk, learned, value, tuple(lines)))
    return out


def quirk_values(results: Sequence[QuirkResult]) -> dict[str, float]:
    """The learned values to put in the fitted profile, as ``protocol.KEY``."""
    values: dict[str, float] = {}
    for r in results:
        if r.written and r.quirk.key is not None and isinstance(r.learned.value, int | float):
            values[f"protocol.{r.quirk.key}"] = r.learned.value
    return values


def lines_words(lines: Sequence[int]) -> str:
    """Log lines as runs: ``lines 3, 5-9``."""
    runs: list[str] = []
    start = previous = None
    for line in sorted(lines):
        if previous is not None and line == previous + 1:
            previous = line
            continue
        if start is not None:
            runs.append(f"{start}-{previous}" if previous != start else f"{start}")
        start = previous = line
    if start is not None:
        runs.append(f"{start}-{previous}" if previous != start else f"{start}")
    if len(runs) > 6:  # a long probe (every register, one request each): its span
        return f"lines {min(lines)}-{max(lines)} ({len(lines)} requests)"
    return ("line " if len(lines) == 1 else "lines ") + ", ".join(runs) if runs else "no frames"


def drop_parameters(text: str, results: Sequence[QuirkResult], log_name: str) -> str:
    """``text`` (a profile) without the [[parameter]] rows of the function codes the drive answered 0x02 to (a
    comment in each one's place says so), and with the defaults of those whose value was read (the answer delay)."""
    gone = {format_fcode(a): r for r in results for a in r.learned.absent}
    defaults = {format_fcode(a): (raw, r) for r in results for a, raw in r.learned.defaults}
    out: list[str] = []
    block: list[str] = []

    def close() -> None:
        code = next(
            (line.split("=", 1)[1].split("#")[0].strip().strip('"') for line in block if line.startswith("code")), ""
        )
        if block and code in gone:
            r = gone[code]
            out.append(
                f'# [[parameter]] {code} dropped: source = "capture": {log_name} {lines_words(r.lines)}: it '
                "answered 0x02"
            )
        elif block and code in defaults:
            raw, r = defaults[code]
            source = f'# source = "capture": {log_name} {lines_words(r.lines)}: {r.learned.why}'
            out.extend(f"default = {raw}  {source}" if line.startswith("default") else line for line in block)
        else:
            out.extend(block)
        block.clear()

    for line in text.splitlines():
        if block and (not line.strip() or line.startswith(("[", "#"))):
            close()  # a row is its header and its keys: a blank line, a comment or a table ends it
        (block if line.startswith("[[parameter]]") or block else out).append(line)
    close()
    return "\n".join(out) + "\n"


def _toml(value: object) -> str:
    return ("true" if value else "false") if isinstance(value, bool) else str(value)


def quirk_changes(results: Sequence[QuirkResult], log_name: str) -> dict[tuple[str, str], str]:
    """The fitted profile's [protocol] lines for the learned quirks: ``value  # source = "capture": ...``."""
    changes: dict[tuple[str, str], str] = {}
    for r in results:
        if r.written and r.quirk.key is not None:
            changes[("protocol", r.quirk.key)] = (
                f'{_toml(r.learned.value)}  # source = "capture": {log_name} {lines_words(r.lines)}: {r.learned.why} '
                f"(was {_toml(r.base)})"
            )
    return changes


def quirk_lines(results: Sequence[QuirkResult]) -> list[str]:
    """The report's lines: per quirk, the value learned, the base's, written or why not, the frames."""
    out = []
    for r in results:
        learned = "not learned" if r.learned.value is None else _toml(r.learned.value)
        base = _toml(r.base) if r.quirk.key is not None else "-"
        written = "written" if r.written else f"not written: {r.why_not}"
        why = f"; {r.learned.why}" if r.learned.why != r.why_not else ""
        shown = f"{why}; {lines_words(r.lines)}" if r.lines else why
        out.append(f"  dialect {r.quirk.name:<21} {learned:<12} (base {base}) {written}{shown}")
    return out


def quirk_table(results: Sequence[QuirkResult]) -> list[str]:
    """The report's table of the dialect (Markdown): each quirk, what it is, learned, base, written, the frames."""
    out = [
        "| quirk | what | learned | base | written | shown by |",
        "|---|---|---|---|---|---|",
    ]
    for r in results:
        learned = "not learned" if r.learned.value is None else _toml(r.learned.value)
        base = _toml(r.base) if r.quirk.key is not None else "-"
        written = "yes" if r.written else f"no: {r.why_not}"
        shown = f"{r.learned.why}; {lines_words(r.lines)}" if r.lines else "-"
        cells = (r.quirk.name, r.quirk.doc, learned, base, written, shown)
        out.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    return out
