"""A throwaway transport and a throwaway incident, each one row, played in a real ``c20sim drill`` against a
reference master.

A child interpreter registers the two rows (the RTU listener of tests/unit/test_rows_transports.py and the
slow-replies incident with its own check of tests/unit/test_rows_audit.py), then runs the command as ``c20sim
drill`` does: no other edit. The careful raw master (tests/drill/masters/raw_master.py) polls the drive over the
new transport through its ready-file key's placeholder (``{loop_tcp}``), and the run's verdicts are judged from
the wire: the throwaway incident passes with its own check, and ``crc`` (an RTU-only incident) is played over the
new transport because its line model is RTU.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.drill.conftest import RAW, Drilled

pytestmark = pytest.mark.serial  # the drill judges a master's real rhythm: .ci/run runs it alone

ROOT = Path(__file__).resolve().parents[2]

CHILD = r"""
import sys

from c20sim.drill import CHECKS, INCIDENTS
from c20sim.transport.rows import register
from tests.unit.test_rows_audit import CHECK, INCIDENT, THROWAWAY, THROWAWAY_CHECK
from tests.unit.test_rows_transports import LOOP

register(LOOP)  # the two rows: nothing else is edited
CHECKS[CHECK] = THROWAWAY_CHECK
INCIDENTS[INCIDENT] = THROWAWAY

from c20sim import cli

sys.exit(cli.main(sys.argv[1:]))
"""

PLAN = """\
warmup = 2.0
[[drill]]
incident = "throwaway-slow"
seconds = 1.0
[[drill]]
incident = "crc"
"""


def _child(*argv: str, timeout: float = 240.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", CHILD, *argv], capture_output=True, text=True, timeout=timeout, check=False, cwd=ROOT
    )


def test_the_throwaway_transport_is_a_drill_transport() -> None:
    done = _child("drill", "--help", timeout=60)
    assert done.returncode == 0, done.stderr
    assert "--transport {pty,tcp,modbus-tcp,loop-tcp}" in done.stdout
    done = _child("drill", "--list", timeout=60)
    assert done.returncode == 0, done.stderr
    assert "throwaway-slow" in done.stdout


def test_the_throwaway_incident_plays_over_the_throwaway_transport_against_a_real_master(tmp_path: Path) -> None:
    plan, log = tmp_path / "plan.toml", tmp_path / "frames.jsonl"
    plan.write_text(PLAN)
    master = f"{sys.executable} {RAW} careful --tcp {{loop_tcp}}"  # the new row's ready-file key
    argv = ["drill", "--transport", "loop-tcp", "--plan", str(plan), "--master", master, "--log", str(log)]
    done = _child(*argv, "--format", "json")
    assert done.returncode in (0, 1), done.stderr
    drilled = Drilled(done.returncode, json.loads(done.stdout), done.stderr, log, plan)
    assert drilled.failed() == {"1 throwaway-slow": [], "2 crc": []}
    assert drilled.code == 0
    slow = drilled.report["verdicts"][0]
    assert [c["check"] for c in slow["checks"]] == ["keeps-polling", "no-storm", "recovers", "throwaway-count"]
    count = slow["checks"][-1]
    assert count["figure"] == f"{count['value']} requests during the incident" and count["value"] >= 1
    assert drilled.figure("2 crc", "retries") == "asked each of 3 failed requests again"
    # the run's frame log judged again offline, the incident registered: the same report
    again = _child("drill", "--judge", str(log), "--plan", str(plan), "--format", "json", timeout=60)
    assert again.returncode == 0, again.stderr
    assert json.loads(again.stdout) == drilled.report


def test_without_the_rows_the_drill_has_neither(tmp_path: Path) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "c20sim", "drill", "--transport", "loop-tcp"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
        cwd=ROOT,
    )
    assert done.returncode == 2
    assert "argument --transport: invalid choice: 'loop-tcp'" in done.stderr
    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN)
    done = subprocess.run(
        [sys.executable, "-m", "c20sim", "drill", "--judge", str(tmp_path / "none.jsonl"), "--plan", str(plan)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
        cwd=ROOT,
    )
    assert done.returncode == 2
    assert "incident 'throwaway-slow' is unknown" in done.stderr
