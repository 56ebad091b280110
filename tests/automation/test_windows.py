"""Where there are no ptys and no loop signal handlers (Windows): import, serve over TCP, the fixture.

Tested here by poisoning ``termios``, ``tty`` and ``pty`` (and uvloop) in a subprocess's sitecustomize, and
making the event loop's ``add_signal_handler`` raise NotImplementedError as Windows' loops do.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from pymodbus import FramerType
from pymodbus.client import ModbusTcpClient

from tests.conftest import wait_for_ready_file

SITECUSTOMIZE = """
import sys
for _name in ("termios", "tty", "pty", "uvloop"):
    sys.modules[_name] = None  # import raises ImportError, as on Windows

import asyncio.unix_events


def _no_signals(self, sig, callback, *args):
    raise NotImplementedError  # what Windows' event loops do


asyncio.unix_events._UnixSelectorEventLoop.add_signal_handler = _no_signals
"""

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def windowsish(tmp_path: Path) -> dict[str, str]:
    """An environment whose Python has no termios, tty, pty or uvloop, and no loop signal handlers."""
    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(SITECUSTOMIZE)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(site), str(REPO)])
    return env


@pytest.fixture
def started() -> Iterator[list[subprocess.Popen[str]]]:
    procs: list[subprocess.Popen[str]] = []
    yield procs
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
        proc.wait()


IMPORTS = "import c20sim, c20sim.testing, c20sim.pytest_plugin, c20sim.cli, c20sim.control, c20sim.scenario.timeline"
LOADED = "import sys; print(sorted(m for m in ('termios', 'tty', 'pty') if sys.modules.get(m) is not None))"


def test_importing_the_package_and_its_plugin_never_imports_termios() -> None:
    # Here, on POSIX, where termios exists: importing the package still does not load it.
    done = subprocess.run(
        [sys.executable, "-c", f"{IMPORTS}; {LOADED}"], capture_output=True, text=True, timeout=60, cwd=REPO
    )
    assert (done.returncode, done.stdout.strip(), done.stderr) == (0, "[]", "")


def test_importing_works_where_termios_tty_and_pty_are_missing(windowsish: dict[str, str]) -> None:
    check = "import sys; assert sys.modules['termios'] is None and sys.modules['tty'] is None"
    done = subprocess.run(
        [sys.executable, "-c", f"{check}; {IMPORTS}; print('imported')"],
        capture_output=True,
        text=True,
        timeout=60,
        env=windowsish,
    )
    assert (done.returncode, done.stdout.strip(), done.stderr) == (0, "imported", "")


def test_serve_over_tcp_and_stop_on_sigint_without_ptys_or_loop_signals(
    tmp_path: Path, windowsish: dict[str, str], started: list[subprocess.Popen[str]]
) -> None:
    ready = tmp_path / "ready.json"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "c20sim",
            "serve",
            "--tcp",
            "127.0.0.1:0",
            "--modbus-tcp",
            "127.0.0.1:0",
            "--ready-file",
            str(ready),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=windowsish,
    )
    started.append(proc)
    info = wait_for_ready_file(ready, proc)
    assert set(info) == {"tcp", "modbus_tcp"}
    host, port = info["tcp"].rsplit(":", 1)
    rtu = ModbusTcpClient(host, port=int(port), framer=FramerType.RTU, timeout=2, retries=0)
    assert rtu.connect()
    assert rtu.read_holding_registers(0x2101, count=1, device_id=1).registers == [0x41]
    rtu.close()
    host, port = info["modbus_tcp"].rsplit(":", 1)
    mbap = ModbusTcpClient(host, port=int(port), timeout=2, retries=0)
    assert mbap.connect()
    assert mbap.read_holding_registers(0x2103, count=1, device_id=1).registers == [0x20]
    mbap.close()
    proc.send_signal(signal.SIGINT)  # handled by signal.signal, as on Windows' Ctrl+C
    out, err = proc.communicate(timeout=20)
    assert (proc.returncode, err) == (0, "")
    assert out.startswith("c20sim ready: c20-400hr, drives 1, realtime clock; tcp 127.0.0.1:")


def test_pty_says_in_one_line_that_it_needs_posix_and_names_the_alternatives(windowsish: dict[str, str]) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "c20sim", "serve", "--pty", "--tcp", "127.0.0.1:0"],
        capture_output=True,
        text=True,
        timeout=60,
        env=windowsish,
    )
    assert done.returncode == 2
    assert done.stdout == ""
    assert done.stderr == (
        "c20sim: --pty needs a POSIX system (Linux, macOS, BSD); on Windows use a com0com pair with --serial COMn, "
        "or --tcp HOST:PORT (RTU over TCP) or --modbus-tcp HOST:PORT\n"
    )


FIXTURE_TEST = """
import socket
import sys


def test_the_fixture_over_tcp(c20sim):
    assert sys.modules["termios"] is None and sys.modules["tty"] is None
    with socket.create_connection((c20sim.host, c20sim.port), timeout=5) as s:
        s.sendall(bytes.fromhex("01 03 21 01 00 01 DF F6"))  # read 2101H, status word 2
        reply = b""
        while len(reply) < 7:
            chunk = s.recv(64)
            assert chunk, "connection closed"
            reply += chunk
    assert reply.hex(" ") == "01 03 02 00 41 78 74"
    c20sim.advance(1.0)
    assert c20sim.now() == 1.0
"""


def test_the_pytest_fixture_over_tcp_without_ptys(tmp_path: Path, windowsish: dict[str, str]) -> None:
    tests = tmp_path / "suite"
    tests.mkdir()
    (tests / "test_on_windows.py").write_text(FIXTURE_TEST)
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(tests)],
        capture_output=True,
        text=True,
        timeout=120,
        env=windowsish,
        cwd=tests,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert "1 passed" in done.stdout
