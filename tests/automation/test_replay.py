"""replay: a frame log (as serve --log-frames writes it) played against another profile, in virtual time."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from c20sim import control
from c20sim.core.clock import VirtualClock
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import Profile, load_profile
from c20sim.traffic.capture import parse_log
from c20sim.traffic.replay import replay
from c20sim.wire.errors import C20SimError
from c20sim.wire.protocol import FrameEvent, FrameKind, ReadRequest, ReadResponse, WriteSingleRequest, encode

POLLED = (0x3006, 0x3007, 0x3008)  # speed, output power, DC bus voltage


def session(profile: str, *, offline_at: float | None = None) -> list[str]:
    """A master starts the motor at 1500 rpm and polls; the frame log as JSON lines, as serve writes it."""
    sim = Simulator(load_profile(profile))
    lines: list[str] = []
    sim.bus.subscribe(lambda record: lines.append(json.dumps(record.as_dict())))

    def send(t: float, frame: bytes, kind: FrameKind = FrameKind.FRAME) -> None:
        sim.run_until(t)
        if offline_at is not None and t >= offline_at:
            control.set_link_faults(sim, 1, {"offline": True})
        sim.handle(FrameEvent(kind, frame, sim.now()))

    send(0.0, encode(WriteSingleRequest(1, 0x2001, 1500)))
    send(0.5, encode(WriteSingleRequest(1, 0x2000, 1)))
    for i in range(4):
        for register in POLLED:
            send(2.0 + i, encode(ReadRequest(1, register, 1)))
    send(6.0, bytes.fromhex("01 03 21 00 00 01 8E 37"), FrameKind.CRC_ERROR)  # exception 0x06 from both profiles
    return lines


def no_load(profile: Profile) -> tuple[int, int]:
    """3007H and 3008H at 1500 rpm with no load: friction and viscous loss, the supply sagging by its resistance."""
    power = (profile.motor.friction_nm + profile.motor.viscous_nm_per_krpm * 1.5) * 1500 * 2 * math.pi / 60
    bus = profile.supply.voltage_v - power / profile.supply.voltage_v * profile.supply.source_resistance_ohm
    return round(power), round(bus * 10)


def test_the_same_profile_replays_to_the_same_replies() -> None:
    records = parse_log(session("c20-400hr"))
    result = replay(records, Simulator(load_profile("c20-400hr"), clock=VirtualClock()))
    assert (result.exchanges, result.differences, result.skipped) == (15, (), 0)


def test_another_profile_differs_exactly_where_the_profiles_do() -> None:
    records = parse_log(session("c20-400hr"))
    result = replay(records, Simulator(load_profile("c20-2200hv"), clock=VirtualClock()))
    small, large = no_load(load_profile("c20-400hr")), no_load(load_profile("c20-2200hv"))
    assert (small, large) == ((10, 480), (51, 3098))
    got = [
        (d.exchange.record.data[2:4].hex().upper(), d.exchange.reply[3:5], d.simulated[3:5]) for d in result.differences
    ]
    # speed (3006H) is the same ramp in both; power and bus voltage differ at every poll
    assert got == [
        (register, value[0].to_bytes(2, "big"), value[1].to_bytes(2, "big"))
        for _ in range(4)
        for register, value in (("3007", (small[0], large[0])), ("3008", (small[1], large[1])))
    ]
    first = result.differences[0]
    assert first.text == (
        f"line 7 (t {first.exchange.record.t:.6f} s): read 3007H (output power): "
        "recorded 3007H = 000A: 10 W [01 03 02 00 0A 38 43]; simulated 3007H = 0033: 51 W [01 03 02 00 33 F8 51]"
    )


def reply(value: int) -> str:
    return encode(ReadResponse(1, (value,))).hex(" ").upper()


def test_a_recorded_silence_is_a_difference_in_words() -> None:
    records = parse_log(session("c20-400hr", offline_at=5.0))
    result = replay(records, Simulator(load_profile("c20-400hr"), clock=VirtualClock()))
    assert [d.text.split(": ", 1)[1] for d in result.differences] == [
        f"read {r:04X}H ({n}): recorded no reply; simulated {r:04X}H = {v}"
        for r, n, v in (
            (0x3006, "motor speed", f"05DC: 1500 rpm [{reply(1500)}]"),
            (0x3007, "output power", f"000A: 10 W [{reply(10)}]"),
            (0x3008, "DC bus voltage", f"01E0: 48.0 V [{reply(480)}]"),
        )
    ] + [
        "a broken frame (slave 1: read 2100H (status word 1); bad CRC: got 8E 37, expected 8E 36): "
        "recorded no reply; simulated exception 0x06 to read: data frame error [01 83 06 C1 32]"
    ]


def write_log(tmp_path: Path, lines: list[str]) -> Path:
    path = tmp_path / "log.jsonl"
    path.write_text("\n".join(lines) + "\n")
    return path


def c20sim(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "c20sim", *args], capture_output=True, text=True, timeout=60, check=False
    )


def test_replay_from_the_command_line(tmp_path: Path) -> None:
    log = write_log(tmp_path, session("c20-400hr"))
    result = c20sim("replay", str(log), "--profile", "c20-2200hv")
    assert result.returncode == 1, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0] == f"replay {log} against c20-2200hv, drives 1: 15 frame(s) from the master"
    assert len(lines) == 10 and all(line.startswith("  DIFF line ") for line in lines[1:9])
    assert lines[-1] == "15 replayed: 8 replies differ"
    assert c20sim("replay", str(log)).returncode == 0


@pytest.mark.parametrize(
    ("lines", "message"),
    [
        (['{"t": 0, "dir": "tx", "hex": "01 03 02 00 03 F8 45"}'], "no frame from the master (dir rx) to replay"),
        (['{"t": 0, "dir": "rx", "hex": "01"}', "oops"], "line 2: not JSON; a frame log has one JSON object a line"),
    ],
)
def test_a_bad_log_is_one_line_and_exit_2(tmp_path: Path, lines: list[str], message: str) -> None:
    log = write_log(tmp_path, lines)
    result = c20sim("replay", str(log))
    assert (result.returncode, result.stdout, result.stderr) == (2, "", f"c20sim: {log}: {message}\n")


def test_replay_needs_a_virtual_clock() -> None:
    from c20sim.core.clock import RealtimeClock

    with pytest.raises(C20SimError, match="virtual clock"):
        replay([], Simulator(load_profile(), clock=RealtimeClock()))
