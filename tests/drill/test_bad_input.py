"""Bad input to ``c20sim drill``: one line on stderr, exit 2, and the master process always stopped."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest


def _run(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "c20sim", "drill", *args], capture_output=True, text=True, timeout=timeout, check=False
    )


def _one_line(done: subprocess.CompletedProcess[str]) -> str:
    lines = [line for line in done.stderr.splitlines() if not line.startswith("drill: ")]
    assert len(lines) == 1, done.stderr
    assert "Traceback" not in done.stderr
    return lines[0]


def _gone(pid: int) -> bool:
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        time.sleep(0.05)
    return False


def test_an_unknown_incident_is_one_line_and_exit_2(tmp_path: Path) -> None:
    plan = tmp_path / "plan.toml"
    plan.write_text('[[drill]]\nincident = "crc"\n[[drill]]\nincident = "powercycle"\n')
    done = _run("--plan", str(plan), "--master", "true")
    assert done.returncode == 2
    assert _one_line(done) == (
        f"c20sim: {plan}: drill 2: incident 'powercycle' is unknown; did you mean 'power-cycle'? the incidents are "
        "crc, no-reply, truncated, extra-bytes, wrong-address, wrong-function, split, wrong-transaction, "
        "exception-06, late, echo, bursts, slow, noise, offline, trip, comm-watchdog, power-cycle, undervoltage-dip, "
        "auto-reset, fault-record"
    )


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('[[drill]]\nincident = "crc"\nreplies = 500\n', "drill 1: replies: 500 is outside 1-100"),
        ("[[drill]\n", "not TOML: "),
        ('[[drill]]\nincident = "crc"\n', "drill 1: crc cannot be played over modbus-tcp (only pty, tcp)"),
    ],
)
def test_a_plan_with_an_error_is_one_line_and_exit_2(tmp_path: Path, text: str, message: str) -> None:
    plan = tmp_path / "plan.toml"
    plan.write_text(text)
    done = _run("--plan", str(plan), "--master", "true", "--transport", "modbus-tcp")
    assert done.returncode == 2
    assert message in _one_line(done)


def test_a_placeholder_for_an_endpoint_not_served_is_one_line(tmp_path: Path) -> None:
    done = _run("--master", "true {pty}", "--plan", str(_plan(tmp_path)))
    assert done.returncode == 2
    assert (
        _one_line(done)
        == "c20sim: --master: placeholder {pty} is not served here; use {tcp}, {tcp_port}, {host}, {port}"
    )


def _plan(tmp_path: Path) -> Path:
    plan = tmp_path / "plan.toml"
    plan.write_text('warmup = 1.0\n[[drill]]\nincident = "offline"\n')
    return plan


def test_a_master_that_exits_at_once_is_one_line_and_exit_2(tmp_path: Path) -> None:
    master = f"{sys.executable} -c \"import sys; print('cannot open {{tcp}}: refused'); sys.exit(3)\""
    done = _run("--master", master, "--plan", str(_plan(tmp_path)))
    assert done.returncode == 2
    assert _one_line(done).startswith(
        "c20sim: --master: exited at once (code 3) before sending anything: cannot open 127.0.0.1:"
    )


def test_a_master_that_never_sends_is_stopped_one_line_and_exit_2(tmp_path: Path) -> None:
    pid_file = tmp_path / "pid"
    master = (
        f"{sys.executable} -c \"import os, time; open('{pid_file}', 'w').write(str(os.getpid())); time.sleep(120)\""
    )
    # 5 s: time for the master's interpreter to start and write its pid on a loaded machine
    done = _run("--master", master, "--plan", str(_plan(tmp_path)), "--wait", "5")
    assert done.returncode == 2
    assert _one_line(done).startswith("c20sim: the master sent nothing in 5 s on tcp 127.0.0.1:")
    assert pid_file.exists(), "the master never started"
    assert _gone(int(pid_file.read_text()))


def test_a_master_command_that_cannot_start_is_one_line(tmp_path: Path) -> None:
    done = _run("--master", "/nonexistent/master {tcp}", "--plan", str(_plan(tmp_path)))
    assert done.returncode == 2
    assert _one_line(done) == "c20sim: --master '/nonexistent/master': cannot start: No such file or directory"


def test_judge_needs_a_drill_log(tmp_path: Path) -> None:
    log = tmp_path / "frames.jsonl"
    log.write_text('{"t": 1.0, "dir": "rx", "hex": "01 03 21 00 00 01 8E 36"}\n')
    done = _run("--judge", str(log), "--plan", str(_plan(tmp_path)))
    assert done.returncode == 2
    assert _one_line(done) == f"c20sim: {log}: no drill marks; give the frame log a c20sim drill run wrote (--log)"


def test_no_master_at_all_is_one_line_after_the_wait(tmp_path: Path) -> None:
    done = _run("--plan", str(_plan(tmp_path)), "--wait", "1")
    assert done.returncode == 2
    assert _one_line(done).startswith("c20sim: the master sent nothing in 1 s on tcp 127.0.0.1:")
    assert "drill: waiting for a master on tcp 127.0.0.1:" in done.stderr
