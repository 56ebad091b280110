"""Shared helpers for the unit tests (a drive on a bus, fed whole frames), and the suite's rule on skips.

A skipped test is a test that did not run: the run fails on a skip unless the
skip is on :data:`ALLOWED_SKIPS`, a short list with the reason each one is
allowed. Every run ends with the skips it had, allowed or not.
"""

from __future__ import annotations

import json
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from c20sim.core.bus import Bus, Reply
from c20sim.drive.profile import Profile, load_profile
from c20sim.wire.framing import RtuFramer


@pytest.fixture(scope="session")
def profile() -> Profile:
    return load_profile("c20-400hr")


class Line:
    """A master's view of a bus: send a frame, get the reply bytes (or None for silence)."""

    def __init__(self, bus: Bus) -> None:
        self.bus = bus
        self.framer = RtuFramer(bus.line_baud)
        self.t = 0.0
        self.replies: list[Reply] = []

    def send(self, frame: bytes | str, dt: float = 0.05) -> bytes | None:
        data = bytes.fromhex(frame) if isinstance(frame, str) else frame
        self.t += dt
        self.framer.feed(data, self.t)
        self.framer.tick(self.t + 1.0)
        answers = [r for e in self.framer.events() if (r := self.bus.handle(e)) is not None]
        assert len(answers) <= 1, answers
        self.replies += answers
        self.framer.set_baud(self.bus.line_baud)  # the master follows the line, as a transport does
        return answers[0].data if answers else None

    def hex(self, frame: bytes | str, dt: float = 0.05) -> str | None:
        reply = self.send(frame, dt)
        return reply.hex(" ").upper() if reply is not None else None


def wait_for_ready_file(path: Path, proc: subprocess.Popen[Any], timeout: float = 10.0) -> dict[str, str]:
    """The ready file of a ``c20sim serve`` subprocess, once written; fails early if the process exits."""
    deadline = time.monotonic() + timeout
    while not path.exists():
        if proc.poll() is not None:
            stderr = proc.stderr.read() if proc.stderr else ""
            text = stderr.decode() if isinstance(stderr, bytes) else stderr
            raise AssertionError(f"c20sim exited with {proc.returncode}: {text}")
        assert time.monotonic() < deadline, "no ready file in time"
        time.sleep(0.01)
    data: dict[str, str] = json.loads(path.read_text())
    return data


# --- Skips: listed with a reason, or the run fails.


@dataclass(frozen=True)
class AllowedSkip:
    """A skip the run may have: the test (a node id, or its prefix for every parameter), the skip's reason as the
    test words it (its start), and why the suite accepts it."""

    test: str
    reason: str
    why: str


#: How a test of the default ports (5020, 1502) starts its skip when a c20sim, or anything else, holds one.
DEFAULT_PORT_TAKEN = "a default port is taken on this machine"

#: The only skips that do not fail a run. Keep it short: a tool missing is not here (.ci/run installs them).
ALLOWED_SKIPS = (
    AllowedSkip(
        "tests/integration/test_frame_log.py::test_a_full_disk_keeps_whole_lines_and_logging_resumes",
        "cannot mount a tmpfs here",
        "a container without CAP_SYS_ADMIN refuses even root a tmpfs mount; a full disk cannot be made otherwise",
    ),
    # The two tests of the default ports themselves: every other test binds port 0, so the suite passes beside a
    # running c20sim (set-up command 1), and .ci/run says at its start which default port is held and by what.
    AllowedSkip(
        "tests/integration/test_modbus_tcp_first.py::test_the_default_endpoints_include_modbus_tcp_on_1502",
        DEFAULT_PORT_TAKEN,
        "it tests bare serve's default ports, which a c20sim the developer is running holds",
    ),
    AllowedSkip(
        "tests/integration/test_readme.py::test_the_tours_dashboard_lines",
        DEFAULT_PORT_TAKEN,
        "the tour's bare c20sim takes the default ports, which a c20sim the developer is running holds",
    ),
)

_skips: list[tuple[str, str]] = []


def _skip_reason(report: pytest.TestReport) -> str:
    longrepr = report.longrepr
    if isinstance(longrepr, tuple) and len(longrepr) == 3:
        reason = str(longrepr[2])
        return reason.removeprefix("Skipped: ")
    return str(longrepr)


def allowed(nodeid: str, reason: str) -> AllowedSkip | None:
    """The entry of :data:`ALLOWED_SKIPS` that allows this skip, if any."""
    for entry in ALLOWED_SKIPS:
        if (nodeid == entry.test or nodeid.startswith(entry.test + "[")) and reason.startswith(entry.reason):
            return entry
    return None


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    if report.skipped and not hasattr(report, "wasxfail"):
        _skips.append((report.nodeid, _skip_reason(report)))


def _unlisted() -> list[tuple[str, str]]:
    return [(nodeid, reason) for nodeid, reason in _skips if allowed(nodeid, reason) is None]


@pytest.hookimpl(trylast=True)
def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    if _unlisted() and exitstatus == pytest.ExitCode.OK:
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    unlisted = _unlisted()
    write = terminalreporter.write_line
    if not _skips:
        write("skips: none")
        return
    write(f"skips: {len(_skips)}, {len(unlisted)} of them not on the allowed list (tests/conftest.py ALLOWED_SKIPS)")
    for nodeid, reason in _skips:
        entry = allowed(nodeid, reason)
        if entry is not None:
            write(f"  allowed: {nodeid}: {reason} (allowed: {entry.why})")
        else:
            write(f"  NOT ALLOWED: {nodeid}: {reason}", red=True)
    if unlisted:
        write("the run fails: a skip not on the list is a test that did not run", red=True)
