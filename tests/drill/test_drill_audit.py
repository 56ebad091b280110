"""The audit of a drill's own frame log agrees with the drill: the exception-06 incident's ``retries`` check
requires the master to ask again after each 0x06 (a data frame error), and ``c20sim audit`` of that run's log
finds nothing to say of those repeats (no ``refused-repeat``)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from c20sim.cli import main
from tests.drill.conftest import RAW, drill

pytestmark = pytest.mark.serial  # the drill judges a master's real rhythm: .ci/run runs it alone

PLAN = """\
warmup = 2.0
[[drill]]
incident = "exception-06"
"""


def test_the_audit_of_a_drill_log_does_not_fault_the_retries_the_drill_requires(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    drilled = drill(tmp_path, f"{sys.executable} {RAW} careful --tcp {{tcp}}", plan=PLAN)
    assert drilled.failed() == {"1 exception-06": []}
    assert drilled.figure("1 exception-06", "retries") == "asked each of 3 failed requests again"
    refused = [
        json.loads(line)
        for line in drilled.log.read_text().splitlines()
        if '"dir": "tx"' in line and json.loads(line)["hex"][3:5] in ("83", "86")
    ]
    assert [r["hex"][6:8] for r in refused] == ["06", "06", "06"]  # the run's three 0x06, each asked again
    assert main(["audit", str(drilled.log), "--format", "json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert [f["rule"] for f in report["findings"] if f["rule"] == "refused-repeat"] == []
