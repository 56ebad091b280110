"""The container test's timings, printed at the end of the run (also under -q)."""

from __future__ import annotations

import pytest

#: seconds per step, filled by tests/deploy/test_container.py
TIMINGS: dict[str, float] = {}


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    if TIMINGS:
        terminalreporter.write_line(
            "container test timings: " + ", ".join(f"{step} {seconds:.1f} s" for step, seconds in TIMINGS.items())
        )
