"""A fit in words and pictures, and the fitted profile written beside its base."""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from pathlib import Path

from ..drive.profile import Profile
from ..wire.errors import C20SimError
from ..wire.registers import Reg
from .fitcapture import Capture, _units
from .fitdialect import drop_parameters, quirk_changes, quirk_lines, quirk_table
from .fitmodel import COMPARED, FitResult

# --- The new profile.


def _format(value: float) -> str:
    return f"{value:.6g}" if "e" not in f"{value:.6g}" else f"{value:.4e}"


def write_profile(result: FitResult, out: Path, log_name: str) -> Profile:
    """The base profile's file with each fitted value replaced and its source said; loaded before it is kept."""
    base = result.base
    text = Path(base.path).read_text(encoding="utf-8")
    changes: dict[tuple[str, str], str] = {}
    for f in result.fitted:
        if f.identified:
            value = _format(f.value)
            changes[(f.parameter.section, f.parameter.key)] = (
                f"{value}  # fitted from {log_name}, +-{f.sigma:.2g} (was {_format(f.base)})"
            )
    if result.turnaround is not None and result.turnaround.identified:
        t = result.turnaround
        changes[("protocol", "turnaround_ms")] = (
            f"{t.value:.3g}  # fitted from {log_name}, +-{t.sigma:.2g} (was {_format(t.base)})"
        )
    changes |= quirk_changes(result.dialect, log_name)
    temps = result.capture.reads.get(Reg.TEMPERATURE)
    if temps:
        changes[("thermal", "ambient_c")] = (
            f"{_units(temps[0]):.4g}  # the drive's temperature when {log_name} began (was {_format(base.thermal.ambient_c)})"
        )
    lines = text.splitlines()
    section = ""
    done: set[tuple[str, str]] = set()
    out_lines: list[str] = []
    header = re.compile(r"^\s*\[([A-Za-z_]+)\]\s*(#.*)?$")
    for line in lines:
        match = header.match(line)
        if match or line.lstrip().startswith("[["):
            _add_missing(out_lines, section, changes, done)
            section = match.group(1) if match else "[[]]"  # an array of tables: nothing of ours in it
            out_lines.append(line)
            continue
        key = line.split("=", 1)[0].strip() if "=" in line and not line.lstrip().startswith("#") else ""
        if (section, key) in changes:
            out_lines.append(f"{key} = {changes[(section, key)]}")
            done.add((section, key))
        elif section == "" and key == "name":
            out_lines.append(f'name = "{out.stem}"')
        elif section == "" and key == "description":
            out_lines.append(f'description = "{base.name} fitted to {log_name} by c20sim fit"')
        else:
            out_lines.append(line)
    _add_missing(out_lines, section, changes, done)
    new_text = drop_parameters("\n".join(out_lines) + "\n", result.dialect, log_name)
    if missing := [f"{s}.{k}" for s, k in changes if (s, k) not in done]:
        raise C20SimError(f"{base.path}: no [{missing[0].split('.')[0]}] table to put {missing[0]} in")
    from ..drive.profile import parse_profile

    profile = parse_profile(new_text, str(out))  # c20sim's own loader: what is written loads
    try:
        out.write_text(new_text, encoding="utf-8")
    except OSError as exc:
        raise C20SimError(f"--out {out}: cannot write: {exc.strerror}") from None
    return profile


def _add_missing(
    lines: list[str], section: str, changes: dict[tuple[str, str], str], done: set[tuple[str, str]]
) -> None:
    for (s, key), value in changes.items():
        if s == section and (s, key) not in done:
            while lines and not lines[-1].strip():
                lines.pop()
            lines.append(f"{key} = {value}")
            lines.append("")
            done.add((s, key))


# --- In words.


def summary(result: FitResult) -> list[str]:
    """The fit in words: each parameter, its value and uncertainty or why it was not identified."""
    capture = result.capture
    reads = sum(len(r) for r in capture.reads.values())
    lines = [
        f"fit {capture.path} to {result.base.name}: drive {capture.address}, {capture.duration:.1f} s, "
        f"{reads} reads of physical quantities; {result.evaluations} model runs in {result.seconds:.1f} s",
        *link_words(capture),
    ]
    for f in result.fitted:
        p = f.parameter
        if f.identified:
            lines.append(f"  {p.name:<34} {_format(f.value):>10} {p.unit:<8} +-{f.sigma:.2g}  (base {_format(f.base)})")
        else:
            lines.append(f"  {p.name:<34} not identifiable from this capture: {f.why}; kept {_format(f.base)}")
    if result.turnaround is not None and not result.turnaround.identified:
        t = result.turnaround
        lines.append(
            f"  {'protocol.turnaround_ms':<34} not identifiable from this capture: {t.value:.3g} ms +-{t.sigma:.2g} "
            f"found, but {t.why}; kept {_format(t.base)}"
        )
    elif result.turnaround is not None:
        t = result.turnaround
        lines.append(
            f"  {'protocol.turnaround_ms':<34} {t.value:>10.3g} ms       +-{t.sigma:.2g}  (base {_format(t.base)})"
        )
    else:
        lines.append(
            f"  {'protocol.turnaround_ms':<34} not identifiable from this capture: fewer than 5 answered requests"
        )
    lines += quirk_lines(result.dialect)
    if result.load_nm is not None:
        lines.append(f"  the load applied by hand: {result.load_nm[0]:.3g} N m +-{result.load_nm[1]:.2g} (not written)")
    for address, (_, recorded, before) in result.before.items():
        after = result.after[address][2]
        name, unit, _ = COMPARED[address]
        lines.append(
            f"  {name:<16} rms difference {_rms(recorded, before):.3g} {unit} with the base profile, "
            f"{_rms(recorded, after):.3g} {unit} fitted"
        )
    if result.states_compared:
        lines.append(
            f"  status words and fault codes: {result.states_compared - result.states_differ} of "
            f"{result.states_compared} reads agree with the fitted model"
        )
    lines += [f"  note: {n}" for n in result.notes]
    return lines


def link_words(capture: Capture) -> list[str]:
    """How the capture was carried, and what that link adds to each transaction's time, in words."""
    link, baud, bits = capture.link, capture.baud, capture.bits
    lines = [f"  link: {link.name}, {baud} baud, {bits}-bit characters ({link.why_words(capture.link_why)})"]
    if capture.timings:
        read = link.fixed(8, 7, baud, bits) * 1000
        lines.append(f"  a one-register read's time on it, besides the turnaround: {read:.3f} ms ({link.words})")
    if capture.turnaround is not None and capture.turnaround[2]:
        late, count = capture.turnaround[2], len(capture.timings)
        lines.append(f"  {late} of {count} transactions came over 1 ms later (a queue, a timer, the machine's load)")
    return lines


def _rms(a: Sequence[float], b: Sequence[float]) -> float:
    return math.sqrt(sum((x - y) ** 2 for x, y in zip(a, b, strict=True)) / max(1, len(a)))


def write_report(result: FitResult, directory: Path, profile_path: Path | None) -> list[Path]:
    """``report.md`` in words and, with matplotlib, a residual plot per quantity (PNG and SVG)."""
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise C20SimError(f"--report {directory}: cannot create: {exc.strerror}") from None
    written: list[Path] = []
    pictures: list[str] = []
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        pass  # the words still go out; the report says how to get the pictures
    else:
        for address, (t, recorded, before) in result.before.items():
            after = result.after[address][2]
            name, unit, _ = COMPARED[address]
            fig, (top, bottom) = plt.subplots(2, 1, figsize=(10, 6), sharex=True, height_ratios=(2, 1))
            top.plot(t, recorded, ".", markersize=2, color="black", label="recorded")
            top.plot(t, before, "-", linewidth=0.8, color="tab:red", label=f"model, {result.base.name}")
            top.plot(t, after, "-", linewidth=0.8, color="tab:blue", label="model, fitted")
            top.set_ylabel(f"{name} ({unit})")
            top.legend(loc="best", fontsize=8)
            top.set_title(f"{name} ({address:04X}H): {Path(result.capture.path).name}")
            bottom.plot(t, [b - r for b, r in zip(before, recorded, strict=True)], ".", markersize=2, color="tab:red")
            bottom.plot(t, [a - r for a, r in zip(after, recorded, strict=True)], ".", markersize=2, color="tab:blue")
            bottom.axhline(0.0, color="grey", linewidth=0.5)
            bottom.set_ylabel(f"model - recorded ({unit})")
            bottom.set_xlabel("time in the capture (s)")
            fig.tight_layout()
            stem = name.replace(" ", "-")
            for suffix in (".png", ".svg"):
                path = directory / f"{stem}{suffix}"
                fig.savefig(path, dpi=100)
                written.append(path)
            plt.close(fig)
            pictures.append(f"![{name}]({stem}.png)")
    lines = ["# c20sim fit report", "", "```", *summary(result), "```", ""]
    lines += ["## The dialect", "", *quirk_table(result.dialect), ""]
    if profile_path is not None:
        lines += [
            f"The fitted profile: `{profile_path}`. Compare it with the capture: "
            f"`c20sim replay {result.capture.path} --profile {profile_path}`.",
            "",
        ]
    lines += [
        "Each plot: the recorded reads (black), the model with the base profile (red) and fitted (blue); below, "
        "the model minus the recording. What remains after the fit is read noise, the registers' resolution, "
        "the timing of the reads, and what the model does not describe.",
        "",
    ]
    lines += pictures if pictures else ["(no plots: they need matplotlib: pip install 'c20sim[plots]')"]
    report = directory / "report.md"
    report.write_text("\n".join(lines) + "\n", encoding="utf-8")
    written.insert(0, report)
    return written
