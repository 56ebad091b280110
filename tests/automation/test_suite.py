"""run-scenario at scale: many files and globs in worker processes, one line each, exit codes, JUnit XML."""

from __future__ import annotations

import shutil
import subprocess
import sys
import textwrap
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from c20sim.scenario.suite import expand, junit_xml, run_file
from c20sim.wire.errors import C20SimError

SCENARIOS = Path(__file__).resolve().parents[2] / "scenarios"

FAILING = """
name = "too fast"
[[step]]
at = 0
write = { "2001H" = 1500, "2000H" = 1 }
[[step]]
at = 0.2
expect = { motor_speed = { value = 1500, tolerance = 5 } }
"""


def c20sim(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "c20sim", *args], capture_output=True, text=True, timeout=120, check=False, cwd=cwd
    )


@pytest.fixture
def suite(tmp_path: Path) -> Path:
    """A directory with the three shipped scenarios and one that fails."""
    for name in ("comm_timeout", "overload", "undervoltage"):
        shutil.copy(SCENARIOS / f"{name}.toml", tmp_path / f"{name}.toml")
    (tmp_path / "zz_fails.toml").write_text(textwrap.dedent(FAILING))
    return tmp_path


def test_many_files_print_one_line_each_and_fail_if_one_fails(suite: Path) -> None:
    result = c20sim("run-scenario", "*.toml", "--jobs", "2", "--junit", "report.xml", cwd=suite)
    assert result.returncode == 1, result.stderr
    assert result.stderr == ""
    assert result.stdout.splitlines() == [
        "PASS  communication timeout (comm_timeout.toml): 11 check(s)",
        "PASS  overload (overload.toml): 12 check(s)",
        "PASS  undervoltage trip and recovery (undervoltage.toml): 21 check(s)",
        "FAIL  too fast (zz_fails.toml): 1 of 3 check(s) failed; first: step 2 (at 0.2 s): "
        "3006H (motor speed) = 1194 (1194 rpm), expected 1500 +/- 5 (1500 rpm)",
        "4 scenario(s): 3 passed, 1 failed, 0 error(s)",
    ]
    root = ET.parse(suite / "report.xml").getroot()
    assert root.tag == "testsuites"
    (node,) = root.findall("testsuite")
    assert {k: node.get(k) for k in ("tests", "failures", "errors", "skipped")} == {
        "tests": "4",
        "failures": "1",
        "errors": "0",
        "skipped": "0",
    }
    cases = node.findall("testcase")
    assert [c.get("name") for c in cases] == [
        "communication timeout",
        "overload",
        "undervoltage trip and recovery",
        "too fast",
    ]
    assert [c.get("classname") for c in cases][-1] == "scenarios.zz_fails"
    assert [c.find("failure") is not None for c in cases] == [False, False, False, True]
    failure = cases[3].find("failure")
    assert failure is not None and failure.text is not None
    assert failure.get("message", "").startswith("step 2 (at 0.2 s): 3006H (motor speed) = 1194")
    assert failure.text.splitlines()[-1] == "FAILED: 1 of 3 check(s)"
    assert all(float(c.get("time", "-1")) >= 0 for c in cases)


def test_all_passing_exits_0_and_a_bad_file_exits_2_with_its_line(suite: Path) -> None:
    (suite / "zz_fails.toml").unlink()
    result = c20sim("run-scenario", str(suite), "-j", "2")
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stdout.splitlines()[-1] == "3 scenario(s): 3 passed, 0 failed, 0 error(s)"

    (suite / "bad.toml").write_text("[[step]]\nat = 1\nwrite = { nosuch = 1 }\n")
    result = c20sim("run-scenario", str(suite / "*.toml"), "--junit", str(suite / "r.xml"))
    assert result.returncode == 2
    lines = result.stdout.splitlines()
    assert lines[0].startswith(f"ERROR {suite / 'bad.toml'}: step 1 (at 1 s), key 'write': ")
    assert "'nosuch'" in lines[0]
    assert lines[-1] == "4 scenario(s): 3 passed, 0 failed, 1 error(s)"
    node = ET.parse(suite / "r.xml").getroot().find("testsuite")
    assert node is not None
    assert (node.get("tests"), node.get("failures"), node.get("errors")) == ("4", "0", "1")


def test_a_pattern_that_matches_nothing_is_one_line_and_exit_2(tmp_path: Path) -> None:
    result = c20sim("run-scenario", str(tmp_path / "*.toml"))
    assert result.returncode == 2
    assert result.stdout == ""
    assert result.stderr == f"c20sim: {tmp_path / '*.toml'}: no scenario file matches\n"
    result = c20sim("run-scenario", "--jobs", "0", str(SCENARIOS))
    assert result.returncode == 2
    assert "argument --jobs/-j: 0 is outside 1-64" in result.stderr


def test_expand_keeps_order_and_each_file_once(suite: Path) -> None:
    first = str(suite / "overload.toml")
    assert expand([first, str(suite / "*.toml")]) == [first] + [
        str(suite / f"{n}.toml") for n in ("comm_timeout", "undervoltage", "zz_fails")
    ]
    with pytest.raises(C20SimError, match="no scenario file matches"):
        expand([str(suite / "nothing*.toml")])


def test_parallel_results_equal_serial_ones(suite: Path) -> None:
    from c20sim.scenario.suite import run_files

    paths = expand([str(suite)]) * 3
    serial = [(r.path, r.status, r.report) for r in run_files(paths, jobs=1)]
    parallel = [(r.path, r.status, r.report) for r in run_files(paths, jobs=2)]
    assert parallel == serial
    assert [s for _, s, _ in serial] == ["passed", "passed", "passed", "failed"] * 3


def test_junit_escapes_what_xml_cannot_hold_raw(tmp_path: Path) -> None:
    path = tmp_path / "odd.toml"
    path.write_text('name = "a <b> & \\"c\\""\n[[step]]\nat = 0\nexpect = { status1 = 1 }\n')
    result = run_file(str(path))
    assert result.status == "failed"
    root = ET.fromstring(junit_xml([result]))
    case = root.find("testsuite/testcase")
    assert case is not None
    assert case.get("name") == 'a <b> & "c"'


def test_one_file_prints_its_full_report_and_still_writes_junit(tmp_path: Path) -> None:
    junit = tmp_path / "one.xml"
    result = c20sim("run-scenario", str(SCENARIOS / "overload.toml"), "--junit", str(junit))
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines()[-1] == "passed: 12 check(s)"
    node = ET.parse(junit).getroot().find("testsuite")
    assert node is not None and (node.get("tests"), node.get("failures"), node.get("errors")) == ("1", "0", "0")
    bad = tmp_path / "bad.toml"
    bad.write_text("[[step]]\nat = -1\n")
    result = c20sim("run-scenario", str(bad), "--junit", str(junit))
    assert (result.returncode, result.stdout) == (2, "")
    assert result.stderr == f"c20sim: {bad}: step 1, key 'at': give the step's time in seconds from the start, >= 0\n"
    node = ET.parse(junit).getroot().find("testsuite")
    assert node is not None and (node.get("tests"), node.get("errors")) == ("1", "1")
