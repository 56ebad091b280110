"""The control API's token from a file or the environment, where the process list does not show it.

``--control-token TOKEN`` is readable by every local user in ``ps``; serve says
so. ``--control-token-file PATH`` and ``C20SIM_CONTROL_TOKEN`` keep it off the
command line. Through the real process: the token is asked for, and is not in
``/proc/PID/cmdline``.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.conftest import wait_for_ready_file

TOKEN = "a-token-of-my-own-0123456789"
WARNING = (
    "c20sim: warning: --control-token: every user of this machine can read the token in the process list; "
    "give it in a file (--control-token-file PATH) or in the environment ($C20SIM_CONTROL_TOKEN)"
)


def status(url: str, token: str | None) -> int:
    request = urllib.request.Request(f"{url}/time")
    if token is not None:
        request.add_header("Authorization", f"Bearer {token}")
    try:
        with urllib.request.urlopen(request, timeout=5) as response:
            return int(response.status)
    except urllib.error.HTTPError as exc:
        return int(exc.code)


#: the control API and a wire endpoint on port 0: with no endpoint, serve takes the default ports, which a running
#: c20sim may hold
ENDPOINTS = ("--tcp", "127.0.0.1:0", "--control", "127.0.0.1:0")


def serve(tmp_path: Path, options: list[str], env: dict[str, str]) -> Iterator[tuple[str, list[str]]]:
    """A serve with a control API and the token from ``options`` or ``env``: its URL and its command line."""
    ready = tmp_path / "ready.json"
    argv = [sys.executable, "-m", "c20sim", "serve", "--clock", "virtual", *ENDPOINTS]
    argv += ["--ready-file", str(ready), *options]
    environ = {k: v for k, v in os.environ.items() if k != "C20SIM_CONTROL_TOKEN"} | env
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=environ)
    try:
        info = wait_for_ready_file(ready, proc)
        assert info["token"] == TOKEN
        cmdline = Path(f"/proc/{proc.pid}/cmdline").read_bytes().split(b"\0")
        yield info["control"], [part.decode() for part in cmdline]
        proc.send_signal(signal.SIGTERM)
        _out, err = proc.communicate(timeout=10)
        assert proc.returncode == 0, err
        assert "Traceback" not in err, err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.parametrize("source", ["file", "environment"])
def test_a_token_from_a_file_or_the_environment_is_asked_for_and_not_shown(tmp_path: Path, source: str) -> None:
    (tmp_path / "token").write_text(f"{TOKEN}\n")
    if source == "file":
        options, env = ["--control-token-file", str(tmp_path / "token")], {}
    else:
        options, env = [], {"C20SIM_CONTROL_TOKEN": TOKEN}
    for url, cmdline in serve(tmp_path, options, env):
        assert TOKEN not in " ".join(cmdline), cmdline
        assert (status(url, None), status(url, "wrong"), status(url, TOKEN)) == (401, 401, 200)


def test_the_token_on_the_command_line_works_and_is_warned_about(tmp_path: Path) -> None:
    ready = tmp_path / "ready.json"
    argv = [sys.executable, "-m", "c20sim", "serve", "--clock", "virtual", *ENDPOINTS]
    argv += ["--ready-file", str(ready), "--control-token", TOKEN]
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        info = wait_for_ready_file(ready, proc)
        assert status(info["control"], TOKEN) == 200
        proc.send_signal(signal.SIGTERM)
        _out, err = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert err.splitlines() == [WARNING], err


@pytest.mark.parametrize(
    ("make", "options", "expected"),
    [
        ("fifo", ["--control-token-file", "tok"], "c20sim: --control-token-file tok: is a FIFO (named pipe), "),
        ("empty", ["--control-token-file", "tok"], "c20sim: --control-token-file tok: empty; put the token in it"),
        ("two words", ["--control-token-file", "tok"], "c20sim: --control-token-file tok: the token is one line"),
        ("", ["--control-token-file", "tok"], "c20sim: --control-token-file tok: cannot read: No such file"),
        ("file", ["--control-token-file", "tok", "--control-token", "x"], "c20sim: give --control-token or "),
    ],
)
def test_a_bad_token_file_is_one_line_and_exit_2(tmp_path: Path, make: str, options: list[str], expected: str) -> None:
    tok = tmp_path / "tok"
    if make == "fifo":
        os.mkfifo(tok)
    elif make == "empty":
        tok.write_text("\n")
    elif make:
        tok.write_text(f"{make}\n")
    argv = [sys.executable, "-m", "c20sim", "serve", "--tcp", "127.0.0.1:0", "--control", "127.0.0.1:0", *options]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=30, check=False, cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    assert len(done.stderr.splitlines()) == 1 and done.stderr.startswith(expected), done.stderr
    assert done.stdout == ""
