"""``c20sim ctl`` for the service routes, against a served simulator in a subprocess."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.conftest import wait_for_ready_file


@pytest.fixture
def ready(tmp_path: Path) -> Iterator[Path]:
    path = tmp_path / "ready.json"
    options = ["--clock", "realtime", "--tcp", "127.0.0.1:0", "--control", "127.0.0.1:0", "--ready-file", str(path)]
    proc = subprocess.Popen(
        [sys.executable, "-m", "c20sim", "serve", *options], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        wait_for_ready_file(path, proc)
        yield path
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=10)
        assert proc.returncode == 0, err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def ctl(ready: Path, *args: str) -> tuple[int, Any, str]:
    done = subprocess.run(
        [sys.executable, "-m", "c20sim", "ctl", "--ready-file", str(ready), "--format", "json", *args],
        capture_output=True,
        text=True,
        timeout=30,
    )
    return done.returncode, json.loads(done.stdout) if done.returncode == 0 else None, done.stderr


def test_ctl_drives_the_clock_set_ups_and_generators(ready: Path, tmp_path: Path) -> None:
    code, health, _ = ctl(ready, "health")
    assert (code, health["status"], health["drives"]) == (0, "serving", [1])
    code, clock, _ = ctl(ready, "pause")
    assert (code, clock["paused"], clock["speed"]) == (0, True, 1.0)
    code, again, _ = ctl(ready, "clock")
    assert again["t"] == clock["t"]  # paused: the model's time stands still
    assert ctl(ready, "speed", "20")[1]["speed"] == 20.0
    assert ctl(ready, "resume")[1]["paused"] is False
    assert ctl(ready, "speed", "0") == (
        2,
        None,
        "c20sim: PUT /clock/speed: 400: speed: 0 is outside 0.001-1000\n",
    )
    code, state, _ = ctl(ready, "set", 'supply_v={"sine": 1, "period": 0.5}')
    assert code == 0 and state["generators"]["supply_v"]["kind"] == "sine"
    assert list(ctl(ready, "generators")[1]["generators"]) == ["supply_v"]
    assert ctl(ready, "generators", "--clear", "supply_v")[1] == {"generators": {}}
    code, reset, _ = ctl(ready, "reset")
    assert (code, reset["setup"], reset["drives"][0]["supply_v"]) == (0, "defaults", 48.0)
    code, _, err = ctl(ready, "reset", str(tmp_path / "missing.json"))
    assert code == 2 and "no such state file" in err and err.count("\n") == 1
