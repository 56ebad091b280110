"""The built-in standard plan against the careful raw master over RTU over TCP: every drill the transport carries
passes, the JUnit, Markdown and plot reports are written, and the command the run names for judging its frame log
again gives the same report."""

from __future__ import annotations

import shlex
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from c20sim.drill import INCIDENTS
from tests.drill.conftest import RAW

pytestmark = pytest.mark.serial  # the drill judges a master's real rhythm: .ci/run runs it alone


def test_the_careful_master_passes_the_standard_plan(tmp_path: Path) -> None:
    junit, report = tmp_path / "drill.xml", tmp_path / "drill.md"
    done = subprocess.run(
        [
            sys.executable, "-m", "c20sim", "drill",
            "--master", f"{sys.executable} {RAW} careful --tcp {{tcp}}",
            "--junit", str(junit), "--report", str(report), "--log", str(tmp_path / "frames.jsonl"),
        ],
        capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    played = [name for name, incident in INCIDENTS.items() if "tcp" in incident.transports]
    lines = done.stdout.splitlines()
    assert done.returncode == 0, done.stdout + done.stderr
    assert [line.split(":")[0] for line in lines[1:-1]] == [f"pass {i} {name}" for i, name in enumerate(played, 1)]
    assert lines[-1].startswith(f"{len(played)} of {len(played)} drills passed")
    suite = ET.parse(junit).getroot().find("testsuite")
    assert suite is not None and suite.get("tests") == str(len(played)) and suite.get("failures") == "0"
    assert [case.get("name") for case in suite.iter("testcase")] == [f"{i} {n}" for i, n in enumerate(played, 1)]
    text = report.read_text()
    assert "![timeline](drill.png)" in text and "| 1 | crc | pass |" in text
    assert (tmp_path / "drill.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # no plan file was given: the command to judge the log again names the standard plan's transport, no plan
    hint = done.stderr.splitlines()[-1]
    log = tmp_path / "frames.jsonl"
    assert hint == f"drill: frame log {log}; judged again by: c20sim drill --judge {log} --transport tcp"
    again = shlex.split(hint.split("judged again by: ", 1)[1])
    assert again[:2] == ["c20sim", "drill"]
    judged = subprocess.run(
        [sys.executable, "-m", "c20sim", *again[1:]], capture_output=True, text=True, timeout=60, check=False
    )
    assert (judged.returncode, judged.stdout) == (0, done.stdout)
