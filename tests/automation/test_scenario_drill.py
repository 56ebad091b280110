"""A scenario's drill step: under ``serve --scenario`` (realtime) it plays the drill on the master polling the serve
and its verdicts are the step's outcome; ``run-scenario`` (virtual time) refuses it at once."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from c20sim.scenario.timeline import ScenarioError, load_scenario
from tests.drill.conftest import RAW

pytestmark = pytest.mark.serial  # the drill judges a master's real rhythm: .ci/run runs it alone

SCENARIO = """\
name = "drill step"
[[step]]
at = 0.0
drill = ["no-reply", { incident = "trip", hold = 1.0 }]
"""


def test_a_drill_step_is_checked_at_load(tmp_path: Path) -> None:
    path = tmp_path / "s.toml"
    path.write_text(SCENARIO.replace('"no-reply"', '"no-replyy"'))
    with pytest.raises(
        ScenarioError,
        match=r"s.toml: step 1 \(at 0 s\), key 'drill': drill 1: incident 'no-replyy' is unknown; did you mean 'no-reply'",
    ):
        load_scenario(path)


def test_run_scenario_refuses_a_drill_step(tmp_path: Path) -> None:
    path = tmp_path / "s.toml"
    path.write_text(SCENARIO)
    done = subprocess.run(
        [sys.executable, "-m", "c20sim", "run-scenario", str(path)], capture_output=True, text=True, check=False
    )
    assert done.returncode != 0
    assert "a drill plays on a real master: serve --scenario FILE with the realtime clock" in done.stdout + done.stderr


def test_serve_scenario_plays_the_drill_on_the_master(tmp_path: Path) -> None:
    path = tmp_path / "s.toml"
    path.write_text(SCENARIO.replace("at = 0.0", "at = 0.5"))
    ready = tmp_path / "ready.json"
    serve = subprocess.Popen(
        [sys.executable, "-m", "c20sim", "serve", "--tcp", "127.0.0.1:0", "--ready-file", str(ready), "--scenario", str(path)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    from tests.conftest import wait_for_ready_file

    tcp = wait_for_ready_file(ready, serve)["tcp"]
    master = subprocess.Popen([sys.executable, str(RAW), "naive", "--tcp", tcp])
    try:
        out, err = serve.communicate(timeout=120)
    finally:
        master.terminate()
        master.wait(5)
    assert serve.returncode == 1, err
    lines = [line for line in (out + err).splitlines() if line.startswith("scenario drill step:")]
    assert any(
        "FAIL step 1 (at 0.5 s): drill: 0 of 2 drills passed; 1 no-reply: 3 of 3 failed requests not asked again"
        in line
        for line in lines
    ), lines
