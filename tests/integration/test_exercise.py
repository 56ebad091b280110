"""``c20sim exercise``: the bench master against c20sim on a pty, RTU over TCP and Modbus TCP."""

from __future__ import annotations

import asyncio
import json
import signal
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from pymodbus import FramerType
from pymodbus.client import ModbusSerialClient

from c20sim.cli import main
from c20sim.traffic.capture import load_frame_log
from c20sim.traffic.programme import POLL
from c20sim.wire.protocol import ExceptionCode, WriteSingleRequest, decode_request, encode
from c20sim.wire.registers import Reg
from tests.conftest import wait_for_ready_file
from tests.integration.conftest import ServeFactory, c20sim_command


@pytest.fixture
def served(tmp_path: Path) -> Iterator[dict[str, str]]:
    """``c20sim serve`` in real time on a pty, RTU over TCP and Modbus TCP."""
    ready = tmp_path / "ready.json"
    args = ("--pty", "--tcp", "127.0.0.1:0", "--modbus-tcp", "127.0.0.1:0", "--ready-file", str(ready))
    proc = subprocess.Popen(c20sim_command("serve", *args), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        yield wait_for_ready_file(ready, proc)
    finally:
        proc.kill()
        proc.wait()


def exercise(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(c20sim_command("exercise", *args), capture_output=True, text=True, timeout=60, check=False)


def test_read_and_write_by_name_in_units_on_every_transport(served: dict[str, str]) -> None:
    ports = (served["pty"], f"tcp://{served['tcp']}", f"modbus-tcp://{served['modbus_tcp']}")
    for port in ports:
        result = exercise(port, "read", "bus", "status", "fault", "id")
        assert result.returncode == 0, result.stderr
        assert result.stdout.splitlines() == [
            "3008H DC bus voltage: 48.0 V",
            "2100H status word 1: stopped",
            "2102H fault code: no fault",
            "2103H drive ID: 0x0020",
        ]
    result = exercise(served["pty"], "write", "setpoint", "1234")
    assert result.stdout == "writing 2001H communication speed setting = 1234 rpm (raw 1234)\n"
    result = exercise(f"tcp://{served['tcp']}", "write", "accel", "2.5")
    assert result.stdout.startswith("writing a function code, kept in the drive's EEPROM: 2003H acceleration time")
    client = ModbusSerialClient(served["pty"], framer=FramerType.RTU, timeout=1, retries=0)
    assert client.connect()
    try:  # an independent master sees what was written
        assert client.read_holding_registers(0x2001, count=1, device_id=1).registers == [1234]
        assert client.read_holding_registers(0x2003, count=1, device_id=1).registers == [25]
    finally:
        client.close()


@pytest.mark.parametrize(
    ("words", "message"),
    [
        (
            ["read", "torque"],
            "c20sim: unknown register 'torque' (give a name such as speed or status, an address such as 3006H, "
            "0x3006 or 12294, or a function code such as F00.10)\n",
        ),
        (
            ["read", "sped"],
            "c20sim: unknown register 'sped'; did you mean 'speed'? (give a name such as speed or status, an address "
            "such as 3006H, 0x3006 or 12294, or a function code such as F00.10)\n",
        ),
        (["write", "setpoint", "fast"], "c20sim: 2001H communication speed setting: 'fast' is not a number"),
        (["write", "setpoint", "4000"], "c20sim: 2001H communication speed setting: 4000 is outside 0 rpm to 3000 rpm"),
        (["write", "speed", "10"], "c20sim: 3006H motor speed is read-only"),
        ([], "c20sim: give --out FILE for the capture, or an action"),
        (["--out", "x.jsonl", "--hold", "-1"], "c20sim: --hold -1: give seconds, from 0 to 86400 (a day)"),
        (["--out", "x.jsonl", "--rate", "0"], "c20sim: --rate 0: give reads a second, above 0 and at most 100"),
        (["read", "speed", "--timeout", "0"], "c20sim: --timeout 0: give seconds, above 0 and at most 60"),
    ],
)
def test_bad_words_are_one_line(served: dict[str, str], words: list[str], message: str) -> None:
    result = exercise(served["pty"], *words)
    assert result.returncode == 2
    assert result.stderr.startswith(message) and result.stderr.count("\n") == 1


@pytest.mark.parametrize("transport", ["pty", "tcp"])
def test_the_programme_makes_a_capture_fit_accepts(served: dict[str, str], tmp_path: Path, transport: str) -> None:
    out = tmp_path / "capture.jsonl"
    port = served["pty"] if transport == "pty" else f"tcp://{served['tcp']}"
    result = exercise(port, "--out", str(out), "--hold", "0.3", "--rate", "20", "--speeds", "1000,2000")
    assert result.returncode == 0, result.stderr
    assert "no function code" in result.stdout
    header, *records = load_frame_log(str(out))
    assert (header.kind, header.data) == ("link", b"")  # how the capture was carried: fit models the link by it
    assert header.note == ("link pty 19200 8N1" if transport == "pty" else "link tcp 19200 8N1")
    requests = [decode_request(r.data) for r in records if r.direction == "rx"]
    writes = [(r.register, r.value) for r in requests if r.function == 6]  # type: ignore[union-attr]
    assert writes == [(0x2001, 1000), (0x2000, 1), (0x2001, 2000), (0x2000, 5)]  # no function code written
    read = {r.start for r in requests if r.function == 3}  # type: ignore[union-attr]
    assert set(POLL) <= read
    # the link's timing reads: a one-register read and a read of 8, which c20sim refuses (it reads one at a time)
    blocks = [i for i, r in enumerate(requests) if r.function == 3 and r.count == 8]  # type: ignore[union-attr]
    assert len(blocks) == 10
    assert all(records[2 * i + 1].data[1:3] == bytes((0x83, 0x03)) for i in blocks)
    assert all(r.direction == "tx" for r in records[1::2]) and len(records) % 2 == 0  # every request answered
    times = [r.t for r in records]
    assert times == sorted(times)

    # it ran and stopped the drive: the last status word read stopped, after speeds near 2000 rpm were read
    def values(register: str) -> list[int]:
        return [
            int(records[i + 1].data[3:5].hex(), 16)
            for i, r in enumerate(records)
            if r.direction == "rx" and r.data[1:4] == bytes.fromhex("03" + register)
        ]

    assert max(values("3006")) > 1900 and values("2100")[-1] == 3
    # while a step ramps (1000 rpm in 0.17 s with serve's 0.5 s ramps), the current and the speed are read in turn
    reads = [(i, r.start) for i, r in enumerate(requests) if r.function == 3]  # type: ignore[union-attr]
    for step in (i for i, r in enumerate(requests) if r.function == 6 and r.register == 0x2001):  # type: ignore[union-attr]
        first_two = [start for i, start in reads if i > step][:2]
        assert sorted(first_two) == [0x3004, 0x3006], first_two
    fitted = subprocess.run(
        c20sim_command("fit", str(out), "--out", str(tmp_path / "mydrive.toml")),
        capture_output=True,
        text=True,
        check=False,
    )
    assert fitted.returncode == 0, fitted.stderr
    assert "motor.kt_nm_per_a" in fitted.stdout and (tmp_path / "mydrive.toml").exists()


def test_refuses_a_drive_that_is_not_stopped(served: dict[str, str], tmp_path: Path) -> None:
    assert exercise(served["pty"], "write", "setpoint", "500").returncode == 0
    assert exercise(served["pty"], "write", "command", "forward").returncode == 0
    out = tmp_path / "capture.jsonl"
    result = exercise(served["pty"], "--out", str(out))
    assert result.returncode == 2
    assert result.stderr == (
        "c20sim: the drive is not stopped (forward running, 2100H = 1); the programme starts only a stopped drive\n"
    )
    records = load_frame_log(str(out))
    assert all(decode_request(r.data).function == 3 for r in records if r.direction == "rx" and r.data)  # only read


async def _exercise_in_thread(served_port: str, out: Path, started: asyncio.Event) -> int:
    loop = asyncio.get_running_loop()

    def run() -> int:
        return main(["exercise", served_port, "--out", str(out), "--hold", "30", "--rate", "50", "--timeout", "0.2"])

    task = loop.run_in_executor(None, run)
    while not out.exists() or '"01 06 20 00 00 01' not in out.read_text():  # the run command went out
        await asyncio.sleep(0.01)
    started.set()
    return await task


async def test_silence_stops_the_drive_and_says_why(
    serve: ServeFactory, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    served = await serve()
    started = asyncio.Event()
    out = tmp_path / "capture.jsonl"
    task = asyncio.ensure_future(_exercise_in_thread(served.pty, out, started))
    await started.wait()
    served.sim.link_faults(1).drop_next = 3  # three requests in a row go unanswered
    assert await task == 2
    err = capsys.readouterr().err
    assert err.startswith("c20sim: no reply to read ") and err.count("\n") == 1
    assert err.endswith("within 0.2 s; the drive was told to stop (2000H = 5)\n")
    assert served.sim.drive(1).read(Reg.COMMAND) == 5
    last = [json.loads(line) for line in out.read_text().splitlines()][-2:]
    stop = encode(WriteSingleRequest(1, 0x2000, 5)).hex(" ").upper()
    assert [(r["dir"], r["hex"]) for r in last] == [("rx", stop), ("tx", stop)]  # the stop, answered


async def test_exceptions_stop_the_programme_in_one_line(
    serve: ServeFactory, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    served = await serve()
    started = asyncio.Event()
    task = asyncio.ensure_future(_exercise_in_thread(served.pty, tmp_path / "capture.jsonl", started))
    await started.wait()
    served.sim.link_faults(1).forced_exception = ExceptionCode.ILLEGAL_ADDRESS
    assert await task == 2
    err = capsys.readouterr().err
    assert err.startswith("c20sim: the drive answered exception 0x02 (illegal data address) to read ")
    # the stop was answered with the exception too: the user is told to stop it by hand
    assert err.endswith("stop it by hand\n") and err.count("\n") == 1


def test_ctrl_c_stops_the_drive_first(served: dict[str, str], tmp_path: Path) -> None:
    out = tmp_path / "capture.jsonl"
    args = ("--out", str(out), "--hold", "30", "--rate", "20")
    proc = subprocess.Popen(
        c20sim_command("exercise", served["pty"], *args), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    run = encode(WriteSingleRequest(1, 0x2000, 1)).hex(" ").upper()
    deadline = time.monotonic() + 20
    while not (out.exists() and run in out.read_text()):  # the drive was started
        assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read() if proc.stderr else ""
        time.sleep(0.02)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == 130
    assert err.startswith("\ninterrupted: the drive was told to stop (2000H = 5); ") and err.count("\n") == 2
    records = load_frame_log(str(out))
    stop = encode(WriteSingleRequest(1, 0x2000, 5))
    # the last request is the stop and the last frame its echo; between them may lie the late reply to the read
    # that Ctrl-C abandoned, logged as that and not taken for the stop's answer
    last = max(i for i, r in enumerate(records) if r.direction == "rx")
    after = records[last + 1 :]
    assert (records[last].data, after[-1].data, len(after) <= 2) == (stop, stop, True)
    assert [r.note for r in after[:-1]] in ([], ["a late reply to an earlier request: not this one's"])
    client = ModbusSerialClient(served["pty"], framer=FramerType.RTU, timeout=1, retries=0)
    assert client.connect()
    try:  # an independent master reads the command in force: stop
        assert client.read_holding_registers(0x2000, count=1, device_id=1).registers == [5]
    finally:
        client.close()


def test_the_load_change_is_asked_for_and_marked(served: dict[str, str], tmp_path: Path) -> None:
    out = tmp_path / "capture.jsonl"
    args = (served["pty"], "--out", str(out), "--hold", "0.3", "--rate", "20", "--speeds", "1500", "--load-change")
    result = subprocess.run(c20sim_command("exercise", *args), input="\n\n", capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert "apply the load now, then press Enter (Ctrl-C stops the drive)" in result.stdout
    assert "take the load off now, then press Enter" in result.stdout
    marks = [r for r in load_frame_log(str(out)) if r.kind == "mark"]
    assert [(m.note, m.data) for m in marks] == [("load-on", b""), ("load-off", b"")]
    # nobody answers (stdin closed): the drive is stopped, and the programme says why
    result = subprocess.run(c20sim_command("exercise", *args), input="", capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert result.stderr == (
        "c20sim: no answer to 'apply the load now' (stdin closed); the drive was told to stop (2000H = 5)\n"
    )


async def test_a_gateways_exception_is_named(serve: ServeFactory, capsys: pytest.CaptureFixture[str]) -> None:
    served = await serve()
    served.sim.link_faults(1).offline = True  # the drive behind the gateway says nothing: the gateway answers 0x0B
    port = f"modbus-tcp://127.0.0.1:{served.modbus_tcp_port}"
    loop = asyncio.get_running_loop()
    assert await loop.run_in_executor(None, main, ["exercise", port, "read", "bus", "--timeout", "3"]) == 2
    assert capsys.readouterr().err == (
        "c20sim: the drive answered exception 0x0B (gateway: the drive did not answer) to read 3008H (DC bus voltage)\n"
    )
