"""The drill's reports: text, JSON, JUnit XML and Markdown, from a :class:`~c20sim.drill.judge.Judgement`.

Pure: strings and bytes out, no I/O (``c20sim drill`` writes them).
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

from .judge import Judgement
from .plan import Plan

__all__ = ["json_report", "junit_xml", "markdown", "text_report"]


def text_report(judgement: Judgement, early: str = "") -> str:
    lines = []
    if judgement.learned is not None:
        learned = judgement.learned
        how = "given" if learned.given else "learned"
        lines.append(
            f"master: poll period {learned.period * 1000:.0f} ms, timeout {learned.timeout * 1000:.0f} ms ({how}), "
            f"{learned.rate:.1f} requests/s"
        )
    if judgement.problem:
        lines.append(f"FAIL no drill judged: {judgement.problem}")
    lines += [v.line() for v in judgement.verdicts]
    passed = sum(v.passed for v in judgement.verdicts)
    lines.append(
        f"{passed} of {len(judgement.verdicts)} drills passed, {judgement.requests} requests"
        + (f"; {early}" if early else "")
    )
    return "\n".join(lines) + "\n"


def json_report(judgement: Judgement, early: str = "") -> str:
    return (
        json.dumps(
            {
                "passed": judgement.passed,
                "learned": judgement.learned.as_dict() if judgement.learned else None,
                "problem": judgement.problem or None,
                "ended_early": early or None,
                "requests": judgement.requests,
                "verdicts": [v.as_dict() for v in judgement.verdicts],
            },
            indent=2,
        )
        + "\n"
    )


def junit_xml(judgement: Judgement, suite: str = "c20sim drill") -> bytes:
    """JUnit XML: one test case per drill."""
    verdicts = judgement.verdicts
    failures = sum(not v.passed for v in verdicts) + (1 if judgement.problem else 0)
    root = ET.Element("testsuites", tests=str(len(verdicts)), failures=str(failures), errors="0")
    node = ET.SubElement(root, "testsuite", name=suite, tests=str(len(verdicts)), failures=str(failures))
    node.set("errors", "0")
    node.set("skipped", "0")
    if judgement.problem:
        case = ET.SubElement(node, "testcase", name="warm-up", classname="drill")
        ET.SubElement(case, "failure", message=judgement.problem, type="warm-up")
    for v in verdicts:
        case = ET.SubElement(node, "testcase", name=v.label, classname=f"drill.{v.incident}")
        if not v.passed:
            failure = ET.SubElement(case, "failure", message=v.figure, type="drill")
            failure.text = "\n".join(
                f"{c.check}: {'pass' if c.passed else 'FAIL'}: {c.figure} [{c.source}]" for c in v.checks
            )
        else:
            ET.SubElement(case, "system-out").text = "\n".join(f"{c.check}: {c.figure}" for c in v.checks)
    ET.indent(root)
    text: bytes = ET.tostring(root, encoding="utf-8", xml_declaration=True)
    return text + b"\n"


def markdown(judgement: Judgement, plan: Plan, plot: str | None = None, early: str = "") -> str:
    """The Markdown report: the master's rhythm, a table of the drills, each drill's checks, the plot if drawn."""
    out = ["# c20sim drill report", ""]
    if judgement.learned is not None:
        lv = judgement.learned
        out.append(
            f"The master polls every {lv.period * 1000:.0f} ms ({lv.rate:.1f} requests/s) and times out after "
            f"{lv.timeout * 1000:.0f} ms ({'given' if lv.given else 'learned in the warm-up'}). Plan: {plan.name}, "
            f"seed {plan.seed}."
        )
        out.append("")
    if judgement.problem:
        out += [f"**No drill judged:** {judgement.problem}", ""]
    if early:
        out += [f"**The run ended early:** {early}", ""]
    if plot:
        out += [f"![timeline]({plot})", ""]
    out += ["| # | incident | verdict | figure |", "|---|---|---|---|"]
    for v in judgement.verdicts:
        out.append(
            f"| {v.index} | {v.incident} | {'pass' if v.passed else '**FAIL**'} | {v.figure.replace('|', '/')} |"
        )
    out.append("")
    for v in judgement.verdicts:
        out += [f"## {v.label}: {'pass' if v.passed else 'FAIL'}", "", f"Source: {v.source}.", ""]
        for c in v.checks:
            frames = ", ".join(str(f.seq) for f in c.frames)
            out.append(
                f"- {c.check}: {'pass' if c.passed else '**FAIL**'}: {c.figure}"
                + (f" (frames {frames})" if frames else "")
                + f" [{c.source}]"
            )
        out.append("")
    return "\n".join(out)
