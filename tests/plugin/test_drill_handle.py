"""The pytest handle's drill: ``c20sim.drill(...)`` plays incidents on the fixture's drive against the test's own
master and judges them, as ``c20sim drill`` does."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable, Iterator

import pytest

from c20sim.drillrun import text_report
from c20sim.testing import C20Sim
from c20sim.wire.errors import C20SimError
from tests.drill.conftest import RAW

pytestmark = pytest.mark.serial  # the drill judges a master's real rhythm: .ci/run runs it alone


@pytest.fixture
def master(c20sim: C20Sim) -> Iterator[Callable[[str], None]]:
    started: list[subprocess.Popen[bytes]] = []

    def start(style: str) -> None:
        started.append(subprocess.Popen([sys.executable, str(RAW), style, "--tcp", f"{c20sim.host}:{c20sim.port}"]))

    yield start
    for process in started:
        process.terminate()
        process.wait(5)


@pytest.mark.c20sim(clock="realtime")
def test_a_careful_master_passes_the_handles_drill(c20sim: C20Sim, master: Callable[[str], None]) -> None:
    master("careful")
    judgement = c20sim.drill(["no-reply", {"incident": "trip", "hold": 1.0}], warmup=1.5)
    assert judgement.passed, text_report(judgement)
    assert [v.label for v in judgement.verdicts] == ["1 no-reply", "2 trip"]
    assert c20sim.link_faults()["active"] == []  # the plant is left healthy


@pytest.mark.c20sim(clock="realtime")
def test_a_naive_master_fails_the_trip_with_its_figures(c20sim: C20Sim, master: Callable[[str], None]) -> None:
    master("naive")
    judgement = c20sim.drill("trip", poll_period=0.1, timeout=0.25, warmup=1.0)
    (verdict,) = judgement.verdicts
    assert not verdict.passed
    assert [c.check for c in verdict.checks if not c.passed] == ["notices", "no-run-into-fault"]
    assert judgement.learned is not None and judgement.learned.given


def test_the_drill_needs_the_realtime_clock(c20sim: C20Sim) -> None:
    with pytest.raises(C20SimError, match=r"^a drill needs the realtime clock"):
        c20sim.drill("crc")


def test_an_unknown_incident_is_named(c20sim: C20Sim) -> None:
    with pytest.raises(C20SimError, match=r"^drill\(\.\.\.\): drill 1: incident 'crcc' is unknown; did you mean 'crc'"):
        c20sim.drill("crcc")
