"""Scenarios: the shipped examples pass, a wrong expectation fails readably, a bad file names its fault."""

from __future__ import annotations

import json
import queue
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest

from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile
from c20sim.scenario.timeline import ScenarioError, load_scenario, parse_scenario, run

SCENARIOS = Path(__file__).resolve().parents[2] / "scenarios"


def c20sim(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "c20sim", *args], capture_output=True, text=True, timeout=30, check=False
    )


def write(tmp_path: Path, text: str, name: str = "s.toml") -> Path:
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


@pytest.mark.parametrize("name", ["undervoltage", "overload", "comm_timeout"])
def test_shipped_examples_pass(name: str) -> None:
    scenario = load_scenario(SCENARIOS / f"{name}.toml")
    report = run(scenario, Simulator(load_profile(scenario.profile), scenario.drives or (1,)))
    assert report.failures == []
    assert len(report.outcomes) > 5


def test_undervoltage_report_from_the_command_line() -> None:
    result = c20sim("run-scenario", str(SCENARIOS / "undervoltage.toml"))
    assert result.returncode == 0, result.stdout + result.stderr
    lines = result.stdout.splitlines()
    assert lines[0] == f"scenario undervoltage trip and recovery ({SCENARIOS / 'undervoltage.toml'})"
    assert "  ok   step 4 (at 2.1 s): 2102H (fault code) = 10 (UV: bus undervoltage), expected 10" in lines
    assert lines[-1] == "passed: 21 check(s)"


def test_a_wrong_expectation_fails_with_a_readable_report(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        """
        name = "too fast"
        [[step]]
        at = 0
        write = { "2001H" = 1500, "2000H" = 1 }
        [[step]]
        at = 0.2
        note = "mid-ramp"
        expect = { motor_speed = { value = 1500, tolerance = 5 }, status1 = 1 }
        """,
    )
    result = c20sim("run-scenario", str(path))
    assert result.returncode == 1
    assert result.stdout == (
        f"scenario too fast ({path})\n"
        "  ok   step 1 (at 0 s): write 2001H = 1500: taken\n"
        "  ok   step 1 (at 0 s): write 2000H = 1: taken\n"
        "  FAIL step 2 (at 0.2 s) [mid-ramp]: 3006H (motor speed) = 1194 (1194 rpm), expected 1500 +/- 5 (1500 rpm)\n"
        "  ok   step 2 (at 0.2 s) [mid-ramp]: 2100H (status word 1) = 1 (forward running), expected 1\n"
        "FAILED: 1 of 4 check(s)\n"
    )


def test_a_refused_write_fails(tmp_path: Path) -> None:
    scenario = parse_scenario({"step": [{"at": 0, "write": {"F00.10": 2500}}]}, "locked.toml")
    report = run(scenario, Simulator(load_profile()))
    assert [(o.ok, o.text) for o in report.outcomes] == [
        (False, "write F00.10 = 2500: exception 0x04 to write: operation failed")
    ]


def test_registers_are_named_as_the_control_api_names_them() -> None:
    from c20sim import control

    sim = Simulator(load_profile())
    names = ["fault code", "fault-code", "FAULT_CODE", "2102H", "0x2102", "2102h", "status1"]
    scenario = parse_scenario({"step": [{"at": 0, "expect": dict.fromkeys(names, 0)}]}, "s.toml")
    assert [e.address for e in scenario.steps[0].expect] == [control.parse_register(sim, n) for n in names]
    assert [e.address for e in scenario.steps[0].expect] == [0x2102] * 6 + [0x2100]
    report = run(scenario, sim)
    assert [o.ok for o in report.outcomes] == [True] * 6 + [False]


def test_a_refused_keypad_press_fails() -> None:
    scenario = parse_scenario(
        {"step": [{"at": 0, "fault": {"code": 17, "persistent": True}, "keypad": "reset"}, {"at": 1, "keypad": 1}]},
        "stuck.toml",
    )
    report = run(scenario, Simulator(load_profile()))
    assert [(o.step.index, o.ok, o.text) for o in report.outcomes] == [
        (1, False, "keypad reset: refused by the drive"),
        (2, False, "keypad 1: refused by the drive"),
    ]
    assert not report.ok


@pytest.mark.parametrize(
    ("step", "message"),
    [
        (
            {"at": 1, "expct": {}},
            "s.toml: step 1 (at 1 s), key 'expct': unknown key 'expct'; did you mean 'expect'? (known: at, drive, "
            "note, set, link, clear_link, fault, clear_fault, power_cycle, write, keypad, expect, expect_exception, "
            "expect_silence, within, expect_findings, forbid_findings, drill)",
        ),
        (
            {"at": 1, "set": {"supply": 3}},
            "s.toml: step 1 (at 1 s), key 'set': unknown condition 'supply'; did you mean 'supply_v'? (known: "
            "supply_v, load_torque_nm, active_load_nm, load_inertia_kg_m2, ambient_c, hall_fault, ai1_v, ai2_v, ai3_v, dial_switches, terminal_inputs)",
        ),
        (
            {"at": 1, "set": {"supply_v": "low"}},
            "s.toml: step 1 (at 1 s), key 'set': supply_v: expected a number, got \"low\"",
        ),
        (
            {"at": 1, "expect": {"2100": "four"}},
            "s.toml: step 1 (at 1 s), key 'expect': 2100: expected a raw register value (an integer), got 'four'",
        ),
        (
            {"at": 1, "expect": {"statu1": 4}},
            "s.toml: step 1 (at 1 s), key 'expect': unknown register 'statu1'; did you mean 'status1'? (give a name "
            "such as speed or status, an address such as 3006H, 0x3006 or 12294, or a function code such as F00.10)",
        ),
        (
            {"at": 1, "link": {"offline": "yes"}},
            "s.toml: step 1 (at 1 s), key 'link': offline: expected true or false, got \"yes\"",
        ),
        (
            {"at": 1, "keypad": "run"},
            "s.toml: step 1 (at 1 s), key 'keypad': unknown key 'run' (known: forward, reverse, jog_forward, "
            "jog_reverse, stop, free_stop, reset, jog_stop)",
        ),
        (
            {"at": 1, "fault": 0},
            "s.toml: step 1 (at 1 s), key 'fault': code: 0 is outside 1-255",
        ),
        (
            {"at": 1, "write": {"sped": 5}},
            "s.toml: step 1 (at 1 s), key 'write': unknown register 'sped'; did you mean 'speed'? (give a name such "
            "as speed or status, an address such as 3006H, 0x3006 or 12294, or a function code such as F00.10)",
        ),
        (
            {"at": 1, "write": {"F00": {"10": 5000}}},  # TOML read F00.10 = 5000 unquoted as a table
            "s.toml: step 1 (at 1 s), key 'write': F00: unknown key '10'; quote a function code, as \"F00.10\" = N",
        ),
        (
            {"at": 1, "expect": {"F00": {"10": 5000}}},  # TOML read F00.10 = 5000 unquoted as a table
            "s.toml: step 1 (at 1 s), key 'expect': F00: unknown key '10'; quote a function code, as \"F00.10\" = N",
        ),
        ({"at": 1, "keypad": 9}, "s.toml: step 1 (at 1 s), key 'keypad': key: 9 is outside 1-8"),
        (
            {"at": 1, "fault": {"code": 16, "persistent": "yes"}},
            "s.toml: step 1 (at 1 s), key 'fault': persistent: expected true or false, got \"yes\"",
        ),
        (
            {"at": 1, "write": {"F99.99": 1}},
            "s.toml: step 1 (at 1 s), key 'write': register 'F99.99': 'F99.99': group must be 00-31 and number 00-255",
        ),
        ({"at": -1}, "s.toml: step 1, key 'at': give the step's time in seconds from the start, >= 0"),
        ({"at": float("nan")}, "s.toml: step 1, key 'at': give the step's time in seconds from the start, >= 0"),
        ({"at": float("inf")}, "s.toml: step 1, key 'at': give the step's time in seconds from the start, >= 0"),
        (
            {"at": 1, "set": {"supply_v": float("nan")}},
            "s.toml: step 1 (at 1 s), key 'set': supply_v: expected a finite number, got nan",
        ),
    ],
)
def test_bad_step_names_file_step_and_key(step: dict[str, object], message: str) -> None:
    with pytest.raises(ScenarioError) as caught:
        parse_scenario({"step": [step]}, "s.toml")
    assert str(caught.value) == message


def test_bad_files(tmp_path: Path) -> None:
    with pytest.raises(
        ScenarioError, match=r"s\.toml: step 2 \(at 1 s\), key 'at': time runs backwards: step 1 is at 2 s$"
    ):
        parse_scenario({"step": [{"at": 2}, {"at": 1}]}, "s.toml")
    with pytest.raises(
        ScenarioError,
        match=r"^s\.toml: key 'steps': unknown key 'steps'; did you mean 'step'\? "
        r"\(known: name, description, profile, drives, step\)$",
    ):
        parse_scenario({"steps": []}, "s.toml")
    path = write(tmp_path, '[[step]]\nat = 0\nexpect = { "F09.99" = 1 }\n')
    result = c20sim("run-scenario", str(path))
    assert (result.returncode, result.stdout) == (2, "")
    assert result.stderr == (
        f"c20sim: {path}: step 1 (at 0 s), key 'expect': register 'F09.99': the profile c20-400hr has no register F09.99\n"
    )
    path = write(tmp_path, "[[step]]\nat = 0\n[[step]]\nat = inf\nexpect = { status1 = 1 }\n")
    result = c20sim("run-scenario", str(path))
    assert (result.returncode, result.stdout) == (2, "")
    assert result.stderr == (
        f"c20sim: {path}: step 2, key 'at': give the step's time in seconds from the start, >= 0\n"
    )
    result = c20sim("run-scenario", str(tmp_path / "absent.toml"))
    assert result.stderr == f"c20sim: {tmp_path / 'absent.toml'}: cannot read: No such file or directory\n"


def read_lines(proc: subprocess.Popen[str], count: int, timeout: float = 20.0) -> list[str]:
    """The next ``count`` lines of the process's stdout, or a failure saying what came before the deadline."""
    assert proc.stdout is not None
    stream = proc.stdout
    lines: queue.Queue[str | None] = queue.Queue()

    def reader() -> None:
        for line in iter(stream.readline, ""):
            lines.put(line)
        lines.put(None)  # end of the stream

    threading.Thread(target=reader, daemon=True).start()
    got: list[str] = []
    deadline = time.monotonic() + timeout
    while len(got) < count:
        try:
            line = lines.get(timeout=max(0.0, deadline - time.monotonic()))
        except queue.Empty:
            line = None
        if line is None:
            state = "still running" if proc.poll() is None else f"exited with {proc.returncode}"
            raise AssertionError(f"{len(got)} of {count} lines in {timeout:g} s; the process is {state}; got {got}")
        got.append(line)
    return got


def test_read_lines_fails_at_its_deadline() -> None:
    code = "import sys, time; print('one', flush=True); time.sleep(30)"
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        started = time.monotonic()
        with pytest.raises(
            AssertionError, match=r"^1 of 2 lines in 1 s; the process is still running; got \['one\\n'\]$"
        ):
            read_lines(proc, 2, timeout=1.0)
        assert time.monotonic() - started < 10
    finally:
        proc.kill()
        proc.wait()


def test_serve_plays_a_scenario_in_virtual_time(tmp_path: Path) -> None:
    ready = tmp_path / "ready.json"
    scenario = str(SCENARIOS / "comm_timeout.toml")
    options = ["--clock", "virtual", "--tcp", "127.0.0.1:0", "--control", "127.0.0.1:0", "--ready-file", str(ready)]
    proc = subprocess.Popen(
        [sys.executable, "-m", "c20sim", "serve", *options, "--scenario", scenario, "--then", "serve"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        lines = read_lines(proc, 13)  # the ready line, 11 checks, the verdict
        assert lines[0].startswith("c20sim ready: c20-400hr, drives 1, virtual clock; tcp 127.0.0.1:")
        assert lines[-1] == "scenario communication timeout: passed\n"
        assert (
            "scenario communication timeout: ok   step 4 (at 2.5 s): 2102H (fault code) = 18 (CE: RS485 communication fault (timeout)), expected 18\n"
            in lines
        )
        from c20sim.control.ctl import call

        state = call(json.loads(ready.read_text())["control"], "GET", "/drives/1")
        assert (state["t"], state["fault_code"]) == (2.5, 0x12)  # the scenario drove the clock
        assert proc.poll() is None  # --then serve: still serving after the verdict
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=10)
    assert proc.returncode == 0


async def test_play_follows_a_realtime_clock() -> None:
    from c20sim.core.clock import RealtimeClock
    from c20sim.scenario.timeline import play

    sim = Simulator(load_profile(), (1,), clock=RealtimeClock(speed=20))
    scenario = parse_scenario(
        {"step": [{"at": 0, "write": {"2000H": 1}}, {"at": 1.0, "expect": {"status1": 1, "motor_speed": 0}}]}, "rt"
    )
    report = await play(scenario, sim)  # 1 s of model time is 50 ms of wall time at speed 20
    assert [(o.step.index, o.ok) for o in report.outcomes] == [(1, True), (2, True), (2, True)]
    assert report.outcomes[-1].t >= 1.0


async def test_a_served_scenario_writes_on_the_line_in_its_turn() -> None:
    import asyncio

    from c20sim.core.bus import Reply
    from c20sim.scenario.timeline import play
    from c20sim.transport.line import Line
    from c20sim.wire.protocol import FrameEvent, FrameKind, ReadRequest, encode

    sim = Simulator(load_profile(), (1,))
    line = Line(sim)
    sim.link_faults(1).delay = 0.05  # every reply holds the line for 50 ms
    loop = asyncio.get_running_loop()
    served_when_answered: list[int] = []

    def master(reply: Reply | None) -> None:
        assert reply is not None
        served_when_answered.append(len(sim.bus.records))

    sent = loop.time()
    line.submit(FrameEvent(FrameKind.FRAME, encode(ReadRequest(1, 0x2103, 1)), sent), master)
    assert line.busy
    scenario = parse_scenario({"step": [{"at": 0, "write": {"2001H": 1500}, "expect": {"2001H": 1500}}]}, "s.toml")
    report = await play(scenario, sim, line=line)
    assert [(o.ok, o.text) for o in report.outcomes] == [
        (True, "write 2001H = 1500: taken"),
        (True, "2001H (communication speed setting) = 1500 (1500 rpm), expected 1500"),
    ]
    assert [(r.direction, r.data[1]) for r in sim.bus.records] == [("rx", 3), ("tx", 3), ("rx", 6), ("tx", 6)]
    # the write waited for the master's reply to leave the line: it was not served before then
    assert served_when_answered == [2]
    # and it is stamped as a port stamps a frame, with the loop's time; model_t is the drive's
    write_rx = sim.bus.records[2]
    assert sent <= write_rx.t <= loop.time()
    assert write_rx.model_t == 0.0


async def test_serve_warns_of_the_scenario_settings_it_does_not_take(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from c20sim.serve import ServeOptions, Server

    path = write(tmp_path, 'profile = "c20-2200hv"\ndrives = [1, 2]\n[[step]]\nat = 0\nexpect = { status1 = 3 }\n')
    server = Server(Simulator(load_profile(), (1,)), ServeOptions(tcp="127.0.0.1:0", scenario=str(path)))
    await server.start()
    assert server.scenario_task is not None
    report = await server.scenario_task
    await server.aclose()
    assert report.ok
    assert capsys.readouterr().err == (
        f"c20sim: warning: {path}: the scenario names profile c20-2200hv, but c20-400hr is served; "
        "serve takes the profile from --profile\n"
        f"c20sim: warning: {path}: the scenario names drives 1,2, but 1 are served; serve takes the drives from --drives\n"
    )


async def test_closing_the_server_waits_for_the_scenario_to_stop(tmp_path: Path) -> None:
    from c20sim.core.clock import RealtimeClock
    from c20sim.serve import ServeOptions, Server

    path = write(tmp_path, "[[step]]\nat = 3600\nexpect = { status1 = 3 }\n")
    sim = Simulator(load_profile(), (1,), clock=RealtimeClock())
    server = Server(sim, ServeOptions(tcp="127.0.0.1:0", scenario=str(path)))
    await server.start()
    task = server.scenario_task
    assert task is not None and not task.done()
    await server.aclose()
    assert task.cancelled()


def test_a_fault_by_cause_trips_by_the_drives_physics() -> None:
    scenario = parse_scenario(
        {
            "step": [
                {"at": 0, "write": {"2001H": 1500, "2000H": 1}},
                {"at": 2, "fault": {"cause": "undervoltage"}, "expect": {"fault_code": 0}},
                {"at": 2.5, "expect": {"fault_code": 0x0A, "status1": 4}},
                {"at": 3, "clear_fault": {"cause": "undervoltage"}},
                {"at": 4, "keypad": "reset", "expect": {"fault_code": 0}},
                {"at": 5, "fault": {"cause": "eeprom"}, "expect": {"fault_code": 0x15}},
            ]
        },
        "cause.toml",
    )
    assert (scenario.steps[1].cause, scenario.steps[3].release) == ("undervoltage", "undervoltage")
    report = run(scenario, Simulator(load_profile()))
    assert report.ok, report.render()
    assert len(report.outcomes) == 8


@pytest.mark.parametrize(
    ("fault", "message"),
    [
        (
            {"cause": "undervolt"},
            "c.toml: step 1 (at 0 s), key 'fault': unknown cause 'undervolt'; did you mean 'undervoltage'?",
        ),
        ({"cause": "overheat", "code": 16}, "c.toml: step 1 (at 0 s), key 'fault': give a cause alone"),
    ],
)
def test_a_bad_cause_names_the_key(fault: dict[str, object], message: str) -> None:
    with pytest.raises(ScenarioError) as caught:
        parse_scenario({"step": [{"at": 0, "fault": fault}]}, "c.toml")
    assert str(caught.value).startswith(message)


@pytest.mark.parametrize(("body", "code"), [("status1 = 1", 1), ("status1 = 3", 0)])
def test_serve_ends_with_its_scenario_and_its_exit_code(tmp_path: Path, body: str, code: int) -> None:
    """A CI job's ``serve --scenario`` ends when the scenario does, on its own: 1 failed, 0 passed; the ready file
    goes with it."""
    path = write(tmp_path, f"[[step]]\nat = 0.5\nexpect = {{ {body} }}\n", "s.toml")
    ready = tmp_path / "ready.json"
    argv = ["serve", "--clock", "virtual", "--tcp", "127.0.0.1:0", "--ready-file", str(ready), "--scenario", str(path)]
    done = subprocess.run([sys.executable, "-m", "c20sim", *argv], capture_output=True, text=True, timeout=60)
    lines = done.stdout.splitlines()
    assert (done.returncode, done.stderr, len(lines)) == (code, "", 3)  # the ready line, the check, the verdict
    assert lines[-1] == ("scenario s: FAILED (1 of 1 checks)" if code else "scenario s: passed")
    assert not ready.exists()


def test_then_without_a_scenario_is_a_usage_error() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "c20sim", "serve", "--tcp", "127.0.0.1:0", "--then", "serve"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert (done.returncode, done.stdout) == (2, "")
    assert done.stderr == (
        "c20sim: --then: it says what follows a --scenario; give --scenario FILE too, or leave --then out\n"
    )


def test_serve_exits_1_when_its_scenario_failed(tmp_path: Path) -> None:
    """With --then serve, serve stays up after the verdict, and its exit code still says the scenario failed."""
    path = write(tmp_path, "[[step]]\nat = 0.5\nexpect = { status1 = 1 }\n", "fails.toml")
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "c20sim",
            "serve",
            "--clock",
            "virtual",
            "--tcp",
            "127.0.0.1:0",
            "--scenario",
            str(path),
            "--then",
            "serve",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        lines = read_lines(proc, 3)  # the ready line, the check, the verdict
        assert lines[-1] == "scenario fails: FAILED (1 of 1 checks)\n"
        assert proc.poll() is None
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=10)
    assert proc.returncode == 1
