"""Files that are too big, endless, blocking or nested too deeply: one line naming the file, exit 2, at once.

Each used to grow the process to gigabytes (a link to /dev/zero), hang before
ready with no word (a FIFO as --state), or end in a RecursionError traceback
(TOML nested 100,000 deep). Every command that opens a file is tried, through
the real process; a FIFO with no writer would block one that opened it for
reading without O_NONBLOCK, so the test's timeout is the check that none does.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from c20sim.drive.files import LIMITS, MAX_DEPTH
from tests.integration.conftest import c20sim_run, one_line


@pytest.fixture
def hostile(tmp_path: Path) -> Path:
    os.mkfifo(tmp_path / "fifo")
    (tmp_path / "zero").symlink_to("/dev/zero")
    with open(tmp_path / "sparse", "wb") as f:  # 3 GiB that cost no disk: as truncate -s 3G makes
        f.truncate(3 * 1024**3)
    (tmp_path / "deep.toml").write_text("x = " + "[" * 100_000 + "]" * 100_000 + "\n")
    (tmp_path / "inline.toml").write_text("x = " + "{a = " * 5_000 + "1" + "}" * 5_000 + "\n")
    (tmp_path / "dotted.toml").write_text(".".join(["a"] * 100_000) + " = 1\n")
    (tmp_path / "deep.jsonl").write_text('{"t": 0, "dir": "rx", "hex": "01", "x": ' + "[" * 100_000 + "\n")
    return tmp_path


SERVE = ("serve", "--tcp", "127.0.0.1:0")

# (arguments, the line's start): {f} is the hostile file's name
CASES = {
    "profile": ((*SERVE, "--profile", "{f}"), "c20sim: {f}: "),
    "state": ((*SERVE, "--state", "{f}"), "c20sim: {f}: "),
    "serve-scenario": ((*SERVE, "--scenario", "{f}"), "c20sim: {f}: "),
    "profiles-show": (("profiles", "show", "{f}"), "c20sim: {f}: "),
    "replay": (("replay", "{f}"), "c20sim: {f}: "),
    "decode": (("decode", "--file", "{f}"), "c20sim: {f}: "),
    "ctl": (("ctl", "--ready-file", "{f}", "time"), "c20sim: --ready-file {f}: "),
    "mcp": (("mcp", "--attach", "{f}"), "c20sim: --attach {f}: "),
}


@pytest.mark.parametrize("file", ["fifo", "zero"])
@pytest.mark.parametrize("case", sorted(CASES))
def test_a_fifo_or_a_device_is_refused_in_one_line(hostile: Path, case: str, file: str) -> None:
    args, start = CASES[case]
    line = one_line(c20sim_run(*(a.format(f=file) for a in args), cwd=hostile))
    assert line.startswith(start.format(f=file)), line
    kind = "a FIFO (named pipe)" if file == "fifo" else "a character device"
    assert f"is {kind}, not a regular file" in line, line


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_huge_sparse_file_is_refused_by_its_size(hostile: Path, case: str) -> None:
    args, start = CASES[case]
    line = one_line(c20sim_run(*(a.format(f="sparse") for a in args), cwd=hostile))
    assert line.startswith(start.format(f="sparse")), line
    assert "bigger than" in line or "more than 64 MiB" in line, line


def test_run_scenario_names_the_file_and_goes_on(hostile: Path) -> None:
    done = c20sim_run("run-scenario", "fifo", "zero", "sparse", "deep.toml", cwd=hostile)
    assert done.returncode != 0
    assert "Traceback" not in done.stdout + done.stderr
    out = done.stdout + done.stderr
    for needle in ("is a FIFO", "is a character device", "bigger than", f"nested deeper than {MAX_DEPTH} levels"):
        assert needle in out, out


@pytest.mark.parametrize("file", ["deep.toml", "inline.toml", "dotted.toml"])
@pytest.mark.parametrize("case", ["profile", "profiles-show", "serve-scenario"])
def test_deep_toml_is_one_line(hostile: Path, case: str, file: str) -> None:
    args, start = CASES[case]
    line = one_line(c20sim_run(*(a.format(f=file) for a in args), cwd=hostile))
    assert line.startswith(start.format(f=file)), line
    assert f"nested deeper than {MAX_DEPTH} levels" in line, line


@pytest.mark.parametrize("case", ["replay", "decode"])
def test_deep_jsonl_is_one_line(hostile: Path, case: str) -> None:
    args, _start = CASES[case]
    line = one_line(c20sim_run(*(a.format(f="deep.jsonl") for a in args), cwd=hostile))
    assert line.startswith("c20sim: deep.jsonl: line 1: nested deeper than"), line


def test_a_file_just_over_its_bound_is_refused(tmp_path: Path) -> None:
    (tmp_path / "big.toml").write_text("#" * LIMITS["profile"] + "\n")
    line = one_line(c20sim_run("profiles", "show", "big.toml", cwd=tmp_path))
    assert line == "c20sim: big.toml: bigger than 1 MiB, too big for a profile; is it the right file?"
