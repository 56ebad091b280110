"""Shared helpers for the unit tests: a drive on a bus, fed whole frames."""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest

from c20sim.core.bus import Bus, Reply
from c20sim.drive.profile import Profile, load_profile
from c20sim.wire.protocol import RtuFramer


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
