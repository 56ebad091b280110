"""The raw-socket reference masters earn exactly their verdicts, through the real command, over RTU over TCP;
and the live report is the one ``--judge`` gives on the run's frame log."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import pytest

from tests.drill.conftest import RAW, drill, judge_again

pytestmark = pytest.mark.serial  # the drill judges a master's real rhythm: .ci/run runs it alone


def _master(style: str, where: str = "--tcp {tcp}") -> str:
    return f"{sys.executable} {RAW} {style} {where}"


def test_the_careful_master_passes_every_drill_and_the_judge_agrees_offline(tmp_path: Path) -> None:
    drilled = drill(tmp_path, _master("careful"))
    assert drilled.failed() == {"1 crc": [], "2 no-reply": [], "3 trip": [], "4 power-cycle": [], "5 offline": []}
    assert drilled.code == 0
    learned = drilled.report["learned"]
    assert abs(learned["poll_period_s"] - 0.1) < 0.01 and abs(learned["timeout_s"] - 0.25) < 0.02
    assert drilled.figure("1 crc", "retries") == "asked each of 3 failed requests again"
    # the hold is the marks' own (2 s asked; a loaded machine applies the release a little later)
    assert re.fullmatch(
        r"1 fault resets while the cause was present \(2\.\d s\)", drilled.figure("3 trip", "resets-once")
    )
    code, again = judge_again(drilled)
    assert code == 0 and json.loads(again) == drilled.report


def test_the_naive_master_fails_the_retries_the_trip_and_the_power_cycle(tmp_path: Path) -> None:
    drilled = drill(tmp_path, _master("naive"))
    assert drilled.failed() == {
        "1 crc": ["retries"],
        "2 no-reply": ["retries"],
        "3 trip": ["notices", "no-run-into-fault"],
        "4 power-cycle": ["restores-ram"],
        "5 offline": [],
    }
    assert drilled.code == 1
    assert re.fullmatch(
        r"3 of 3 failed requests not asked again; after frame \d+ it moved on to another request \d+ ms later "
        r"without asking again",
        drilled.figure("1 crc", "retries"),
    )
    assert drilled.figure("3 trip", "notices") == "never read 2100H or 2102H after the trip"
    assert re.fullmatch(
        r"\d+ run commands sent into the fault \(refused 0x01\), the first 0\.\d\d s after the incident began",
        drilled.figure("3 trip", "no-run-into-fault"),
    )
    assert re.fullmatch(
        r"a run command 0\.\d\d s after power-up, before any write of 2001H \(its RAM value was lost\)",
        drilled.figure("4 power-cycle", "restores-ram"),
    )
    code, again = judge_again(drilled)
    assert code == 1 and json.loads(again) == drilled.report


def test_the_stormy_master_fails_the_storms_and_the_dead_link(tmp_path: Path) -> None:
    drilled = drill(tmp_path, _master("stormy"))
    failed = drilled.failed()
    assert "no-storm" in failed["2 no-reply"]
    assert failed["3 trip"] == []
    assert "backs-off" in failed["4 power-cycle"] and "backs-off" in failed["5 offline"]
    assert re.fullmatch(
        r"a retry \d+\.\d ms after the request it repeats, sooner than the line can answer \(13\.5 ms\)",
        drilled.figure("2 no-reply", "no-storm"),
    )
    rate = re.fullmatch(
        r"(\d+\.\d) requests/s while the drive was silent, (\d+) % of its usual \d+\.\d/s",
        drilled.figure("5 offline", "backs-off"),
    )
    assert rate is not None and int(rate.group(2)) > 200
    # it retries at once, far sooner than its own poll period, without end: retries, not polls
    bounded = re.fullmatch(
        r"at most (\d+) retries of one request in a row \(limit 3\)", drilled.figure("5 offline", "bounded")
    )
    assert bounded is not None and int(bounded.group(1)) > 20
    assert "bounded" in failed["5 offline"]
    assert drilled.code == 1
