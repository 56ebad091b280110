"""The drill over the control API of a real ``c20sim serve``: POST /drill starts it on the master polling the
serve, GET /drill reports, DELETE /drill stops; ``c20sim ctl`` has the three actions."""

from __future__ import annotations

import json
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.conftest import wait_for_ready_file
from tests.drill.conftest import RAW

pytestmark = pytest.mark.serial  # the drill judges a master's real rhythm: .ci/run runs it alone


def _call(url: str, method: str = "GET", body: object = None) -> tuple[int, dict[str, Any]]:
    data = None if body is None else json.dumps(body).encode()
    request = urllib.request.Request(url, data=data, method=method, headers={"Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(request, timeout=30) as answer:
            return answer.status, json.loads(answer.read())
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read())


@pytest.fixture
def serve(tmp_path: Path) -> Iterator[Any]:
    started: list[subprocess.Popen[bytes]] = []

    def start(*options: str) -> dict[str, str]:
        ready = tmp_path / f"ready{len(started)}.json"
        command = [sys.executable, "-m", "c20sim", "serve", "--tcp", "127.0.0.1:0", "--control", "127.0.0.1:0"]
        proc = subprocess.Popen([*command, "--ready-file", str(ready), *options], stderr=subprocess.PIPE)
        started.append(proc)
        return wait_for_ready_file(ready, proc)

    def master(tcp: str, style: str) -> None:
        started.append(subprocess.Popen([sys.executable, str(RAW), style, "--tcp", tcp]))

    start.master = master  # type: ignore[attr-defined]
    yield start
    for proc in reversed(started):
        proc.terminate()
        proc.wait(10)


def _until_done(url: str, limit: float = 120.0) -> dict[str, Any]:
    deadline = time.monotonic() + limit
    while True:
        status, state = _call(url)
        assert status == 200
        if state["state"] in ("done", "failed"):
            return state
        assert time.monotonic() < deadline, state
        time.sleep(0.2)


def test_a_drill_over_the_api_judges_the_master_polling_the_serve(serve: Any) -> None:
    ready = serve()
    serve.master(ready["tcp"], "naive")
    url = f"{ready['control']}/drill"
    assert _call(url)[1]["state"] == "idle"
    status, state = _call(url, "POST", {"plan": ["no-reply", {"incident": "trip", "hold": 1.0}], "warmup": 1.5})
    assert status == 200 and state["state"] == "running"
    assert _call(url, "POST", {"plan": ["crc"]})[0] == 409  # one at a time
    done = _until_done(url)
    assert done["state"] == "done", done
    report = done["report"]
    failed = {v["incident"]: [c["check"] for c in v["checks"] if not c["passed"]] for v in report["verdicts"]}
    assert failed == {"no-reply": ["retries"], "trip": ["notices", "no-run-into-fault"]}
    assert report["text"].splitlines()[-1].startswith("0 of 2 drills passed")


def test_a_bad_plan_fails_in_one_line_and_the_virtual_clock_is_refused(serve: Any) -> None:
    ready = serve()
    url = f"{ready['control']}/drill"
    assert _call(url, "POST", {"plan": ["crcc"]})[0] == 200
    failed = _until_done(url)
    assert failed["state"] == "failed"
    assert failed["error"].startswith("POST /drill: drill 1: incident 'crcc' is unknown; did you mean 'crc'?")
    virtual = serve("--clock", "virtual")
    status, answer = _call(f"{virtual['control']}/drill", "POST", {"plan": ["crc"]})
    assert status == 409 and "realtime clock" in json.dumps(answer)


def test_ctl_starts_and_stops_a_drill(serve: Any, tmp_path: Path) -> None:
    ready = serve()
    ready_file = next(tmp_path.glob("ready0.json"))
    ctl = [sys.executable, "-m", "c20sim", "ctl", "--ready-file", str(ready_file), "--format", "json"]
    started = subprocess.run([*ctl, "start-drill", "--wait", "30"], capture_output=True, text=True, check=False)
    assert started.returncode == 0, started.stderr
    assert json.loads(started.stdout)["state"] == "running"
    stopped = subprocess.run([*ctl, "stop-drill"], capture_output=True, text=True, check=False)
    assert stopped.returncode == 0, stopped.stderr
    assert json.loads(stopped.stdout)["progress"] == "stopping"
    state = _until_done(f"{ready['control']}/drill")
    assert state["state"] == "done" and state["progress"] == "stopped"
    assert _call(f"{ready['control']}/link")[1]["active"] == []
