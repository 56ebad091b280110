"""Running ``c20sim drill`` as a user does: the real command, a reference master it starts, a plan file."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

MASTERS = Path(__file__).parent / "masters"
RAW = MASTERS / "raw_master.py"
PYMODBUS = MASTERS / "pymodbus_master.py"
MBPOLL = MASTERS / "mbpoll_master.sh"

#: The slice every master meets in these tests: two reply faults, a trip, a power cycle, a dead link.
SMALL_PLAN = """\
warmup = 2.0
[[drill]]
incident = "crc"
[[drill]]
incident = "no-reply"
[[drill]]
incident = "trip"
[[drill]]
incident = "power-cycle"
[[drill]]
incident = "offline"
"""


@dataclass
class Drilled:
    code: int
    report: dict[str, Any]
    stderr: str
    log: Path
    plan: Path

    def failed(self) -> dict[str, list[str]]:
        """Each drill -> its failed checks (empty: passed)."""
        return {
            f"{v['index']} {v['incident']}": [c["check"] for c in v["checks"] if not c["passed"]]
            for v in self.report["verdicts"]
        }

    def figure(self, drill: str, check: str) -> str:
        for v in self.report["verdicts"]:
            if f"{v['index']} {v['incident']}" == drill:
                for c in v["checks"]:
                    if c["check"] == check:
                        return str(c["figure"])
        raise KeyError((drill, check))


def drill(tmp_path: Path, master: str, *args: str, plan: str = SMALL_PLAN, timeout: float = 240.0) -> Drilled:
    plan_path = tmp_path / "plan.toml"
    plan_path.write_text(plan)
    log = tmp_path / "frames.jsonl"
    command = [sys.executable, "-m", "c20sim", "drill", "--plan", str(plan_path), "--master", master]
    command += ["--log", str(log), "--format", "json", *args]
    done = subprocess.run(command, capture_output=True, text=True, timeout=timeout, check=False)
    if done.returncode not in (0, 1):
        pytest.fail(f"c20sim drill exit {done.returncode}: {done.stderr}")
    return Drilled(done.returncode, json.loads(done.stdout), done.stderr, log, plan_path)


def judge_again(drilled: Drilled) -> tuple[int, str]:
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "c20sim",
            "drill",
            "--judge",
            str(drilled.log),
            "--plan",
            str(drilled.plan),
            "--format",
            "json",
        ],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    return done.returncode, done.stdout
