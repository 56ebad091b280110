"""The drill's pure parts: the link-fault rows it added, the plan's checks, and the judge on frame streams made
here (each check passing and failing with its figure)."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from c20sim.core.bus import Bus
from c20sim.drill import INCIDENTS, Mark, judge, learn, read_plan, standard_plan
from c20sim.drill.checks import CHECKS
from c20sim.drill.checks import CHECKS as _CHECKERS  # one table now: a check is one row
from c20sim.drill.incidents import Learned
from c20sim.drive.profile import Profile
from c20sim.wire.errors import C20SimError
from c20sim.wire.protocol import ExceptionCode, ReadRequest, ReadResponse, crc16, encode
from tests.conftest import Line
from tests.unit.test_bus import make_slave, read, write


def _with_crc(body: bytes) -> bytes:
    return body + crc16(body).to_bytes(2, "little")


# -- the link-fault rows


def test_reply_faults_for_the_next_n_replies_switch_themselves_off(profile: Profile) -> None:
    line = Line(Bus([make_slave(profile, 1)], seed=1))
    good = encode(ReadResponse(1, (0,)))
    bad = good[:-2] + bytes((good[-2] ^ 0xFF, good[-1] ^ 0xFF))
    line.bus.link.corrupt_crc = True
    line.bus.link.replies = 2
    assert [line.send(read(1, 0x2001)) for _ in range(3)] == [bad, bad, good]
    assert line.bus.link.active == []


def test_a_forced_exception_for_the_next_n_replies(profile: Profile) -> None:
    line = Line(Bus([make_slave(profile, 1)], seed=1))
    line.bus.link.forced_exception = ExceptionCode(6)
    line.bus.link.replies = 1
    assert line.hex(read(1, 0x2001)) == "01 83 06 " + _with_crc(b"\x01\x83\x06")[-2:].hex(" ").upper()
    assert line.hex(read(1, 0x2001)) == encode(ReadResponse(1, (0,))).hex(" ").upper()


def test_a_forced_exception_with_another_reply_fault_counts_each_reply_once(profile: Profile) -> None:
    """The next 4 replies forced to 0x06 and delayed: 4 exceptions, then the drive's own replies (each reply was
    counted twice, so the fault ended after 2)."""
    line = Line(Bus([make_slave(profile, 1)], seed=1))
    line.bus.link.forced_exception = ExceptionCode(6)
    line.bus.link.delay = 0.001
    line.bus.link.replies = 4
    codes = [line.send(read(1, 0x2001), dt=0.1) for _ in range(6)]
    assert [reply[1] if reply else None for reply in codes] == [0x83, 0x83, 0x83, 0x83, 0x03, 0x03]


def test_wrong_function_answers_the_code_xor_7_with_a_good_crc(profile: Profile) -> None:
    line = Line(Bus([make_slave(profile, 1)], seed=1))
    line.bus.link.wrong_function = True
    reply = line.send(read(1, 0x2001))
    assert reply == _with_crc(b"\x01\x04\x02\x00\x00")
    assert line.send(write(1, 0x2001, 100)) == _with_crc(b"\x01\x01" + struct.pack(">HH", 0x2001, 100))


def test_echo_puts_the_request_before_the_reply(profile: Profile) -> None:
    line = Line(Bus([make_slave(profile, 1)], seed=1))
    line.bus.link.echo = True
    request = read(1, 0x2001)
    assert line.send(request) == request + encode(ReadResponse(1, (0,)))


def test_bursts_hold_a_reply_to_the_next_boundary(profile: Profile) -> None:
    line = Line(Bus([make_slave(profile, 1)], seed=1))
    line.bus.link.burst = 0.016
    line.send(read(1, 0x2001), dt=0.1)  # the request's last byte at 0.1 s; due 0.102 s; the burst at 0.112 s
    assert line.replies[-1].delay == pytest.approx(0.012, abs=1e-9)


def test_noise_flips_one_bit_of_a_reply_and_hits_requests_as_crc_errors(profile: Profile) -> None:
    line = Line(Bus([make_slave(profile, 1)], seed=3))
    line.bus.link.noise_percent = 100.0
    replies = [line.send(read(1, 0x2001)) for _ in range(50)]
    # every request is hit past its address (a CRC error at the drive: exception 0x06), and every reply too: one
    # flipped bit, which CRC-16 always catches
    assert line.bus.counters_of(1).crc_errors == 50
    assert all(reply is not None and len(reply) == 5 and crc16(reply) != 0 for reply in replies)


# -- plans


def test_an_unknown_incident_names_the_place_and_a_close_one() -> None:
    with pytest.raises(
        C20SimError, match=r"^p.toml: drill 2: incident 'crcc' is unknown; did you mean 'crc'\? the incidents are crc, "
    ):
        read_plan({"drill": [{"incident": "offline"}, {"incident": "crcc"}]}, "p.toml")


@pytest.mark.parametrize(
    ("doc", "message"),
    [
        ({"drill": [{"incident": "crc", "replies": 0}]}, "p.toml: drill 1: replies: 0 is outside 1-100"),
        (
            {"drill": [{"incident": "crc", "replies": 1.5}]},
            "p.toml: drill 1: replies: expected a whole number from 1 to 100, got 1.5",
        ),
        (
            {"drill": [{"incident": "crc", "repiles": 2}]},
            "p.toml: drill 1: 'repiles' is not a parameter of crc; did you mean 'replies'? it takes replies",
        ),
        (
            {"drill": [{"incident": "trip", "cause": "rain"}]},
            "p.toml: drill 1: cause 'rain': give one of external, undervoltage",
        ),
        ({"drill": []}, 'p.toml: no drill; give at least one [[drill]] with incident = "..."'),
        ({"warmpu": 1, "drill": [{"incident": "crc"}]}, "p.toml: 'warmpu' is not a plan key; did you mean 'warmup'?"),
        ({"warmup": 0.1, "drill": [{"incident": "crc"}]}, "p.toml: warmup: 0.1 is outside 0.5-600"),
    ],
)
def test_a_plan_with_an_error_is_one_line(doc: dict[str, object], message: str) -> None:
    with pytest.raises(C20SimError) as caught:
        read_plan(doc, "p.toml")
    assert str(caught.value).startswith(message)
    assert "\n" not in str(caught.value)


def test_the_standard_plan_plays_every_incident_and_only_what_a_transport_carries() -> None:
    assert [d.name for d in standard_plan().drills] == list(INCIDENTS)
    over_mbap = [d.name for d in standard_plan(transport="modbus-tcp").drills]
    assert "crc" not in over_mbap and "echo" not in over_mbap and "wrong-address" in over_mbap
    assert [d.index for d in standard_plan(transport="modbus-tcp").drills] == list(range(1, len(over_mbap) + 1))


def test_every_incident_names_known_checks_and_a_source() -> None:
    assert set(CHECKS) == set(_CHECKERS)
    for incident in INCIDENTS.values():
        assert set(incident.checks) <= set(CHECKS), incident.name
        assert incident.does and incident.robust and incident.watch


def test_every_incident_and_check_has_a_row_in_the_docs() -> None:
    """docs/drill.md's tables: a row for each incident of the table and each check (`` | `name` | ``)."""
    text = (Path(__file__).resolve().parents[2] / "docs" / "drill.md").read_text()
    missing = [name for name in [*INCIDENTS, *CHECKS] if f"| `{name}` |" not in text]
    assert missing == [], "docs/drill.md has no row for " + ", ".join(missing)


# -- the judge, on streams made here

STATUS = _with_crc(b"\x01\x03\x21\x00\x00\x01")
SPEED = _with_crc(b"\x01\x03\x30\x06\x00\x01")
STATUS_OK = _with_crc(b"\x01\x03\x02\x00\x01")
SPEED_OK = _with_crc(b"\x01\x03\x02\x05\xdc")


class Stream:
    """A master's frames, made by hand: 2100H and 3006H every 100 ms, each answered 15 ms later."""

    def __init__(self) -> None:
        self.frames: list[tuple[float, str, bytes]] = []
        self.marks: list[Mark] = []
        self.t = 0.0

    def ask(self, request: bytes, reply: bytes | None, after: float = 0.015) -> None:
        self.frames.append((self.t, "rx", request))
        self.frames.append((self.t + after, "tx", b"" if reply is None else reply))
        self.t += after + 0.001

    def cycle(self, n: int = 1) -> None:
        for _ in range(n):
            start = self.t
            self.ask(STATUS, STATUS_OK)
            self.ask(SPEED, SPEED_OK)
            self.t = start + 0.1

    def mark(self, event: str, index: int = 0, incident: str = "") -> None:
        self.marks.append(Mark(self.t, event, index, incident))

    def warm(self) -> None:
        self.mark("warmup")
        self.cycle(20)
        self.mark("probe")
        start = self.t
        self.ask(STATUS, None, 0.002)
        self.t = start + 0.25  # its timeout, then the retry
        self.ask(STATUS, STATUS_OK)
        self.mark("learned")
        self.t = start + 0.3


def test_the_rhythm_and_timeout_are_learned_from_the_warm_up() -> None:
    s = Stream()
    s.warm()
    learned = learn(s.frames, s.marks)
    assert (learned.period, learned.timeout, learned.given) == (0.1, 0.25, False)
    assert learned.rate == pytest.approx(20.0)


def _crc_plan() -> object:
    return read_plan({"drill": [{"incident": "crc"}]}, "p.toml")


def test_a_master_that_retries_each_broken_reply_passes() -> None:
    s = Stream()
    s.warm()
    s.mark("start", 1, "crc")
    broken = STATUS_OK[:-1] + bytes((STATUS_OK[-1] ^ 0xFF,))
    for _ in range(3):
        start = s.t
        s.ask(STATUS, broken)
        s.t = start + 0.25
    s.ask(STATUS, STATUS_OK)
    s.mark("end", 1, "crc")
    s.ask(SPEED, SPEED_OK)
    s.t += 0.1
    s.cycle(10)
    result = judge(s.frames, _crc_plan(), s.marks)  # type: ignore[arg-type]
    (verdict,) = result.verdicts
    assert verdict.passed, verdict.line()
    assert [c.figure for c in verdict.checks] == [
        "asked each of 3 failed requests again",
        "8.9 requests/s, 0.4x its usual",
        "at most 3 retries of one request in a row (limit 3)",
        "a good reply 0.02 s after the incident (limit 0.75 s)",
    ]


def test_a_master_that_takes_a_broken_reply_and_moves_on_fails_retries() -> None:
    s = Stream()
    s.warm()
    s.mark("start", 1, "crc")
    broken = STATUS_OK[:-1] + bytes((STATUS_OK[-1] ^ 0xFF,))
    s.ask(STATUS, broken)
    s.t += 0.01
    s.mark("end", 1, "crc")
    s.ask(SPEED, SPEED_OK)
    s.cycle(10)
    (verdict,) = judge(s.frames, _crc_plan(), s.marks).verdicts  # type: ignore[arg-type]
    assert not verdict.passed
    retries = verdict.checks[0]
    assert retries.check == "retries" and not retries.passed
    assert (
        retries.figure
        == "1 of 1 failed requests not asked again; after frame 85 it moved on to another request 26 ms later without asking again"
    )
    assert [f.seq for f in retries.frames] == [85, 87]


def test_a_retry_sooner_than_the_line_can_answer_is_a_storm() -> None:
    s = Stream()
    s.warm()
    s.mark("start", 1, "no-reply")
    for _ in range(3):
        s.ask(STATUS, None, 0.002)
        s.t += 0.002  # 5 ms after the last: a read at 19200 baud takes 13.5 ms on the line
    s.ask(STATUS, STATUS_OK)
    s.mark("end", 1, "no-reply")
    s.cycle(10)
    plan = read_plan({"drill": [{"incident": "no-reply"}]}, "p.toml")
    (verdict,) = judge(s.frames, plan, s.marks).verdicts
    storm = next(c for c in verdict.checks if c.check == "no-storm")
    assert not storm.passed
    assert storm.figure == "a retry 5.0 ms after the request it repeats, sooner than the line can answer (13.5 ms)"


def test_without_a_warm_up_nothing_is_judged_and_it_says_why() -> None:
    s = Stream()
    s.cycle(5)
    result = judge(s.frames, _crc_plan(), [])  # type: ignore[arg-type]
    assert not result.passed and result.verdicts == ()
    assert result.problem == "no warm-up in the marks: the frame log was not written by c20sim drill"


def test_a_drill_the_run_never_reached_fails_as_not_played() -> None:
    s = Stream()
    s.warm()
    s.cycle(3)
    (verdict,) = judge(s.frames, _crc_plan(), s.marks).verdicts  # type: ignore[arg-type]
    assert not verdict.passed and verdict.figure == "recovers: not played: the run ended before it"


def test_the_same_frames_and_marks_give_the_same_verdicts() -> None:
    s = Stream()
    s.warm()
    s.mark("start", 1, "crc")
    s.ask(STATUS, None, 0.002)
    s.t += 0.25
    s.ask(STATUS, STATUS_OK)
    s.mark("end", 1, "crc")
    s.cycle(10)
    first = judge(s.frames, _crc_plan(), s.marks)  # type: ignore[arg-type]
    again = judge(list(s.frames), _crc_plan(), list(s.marks))  # type: ignore[arg-type]
    assert first == again


def test_a_request_frame_is_read_by_register() -> None:
    assert encode(ReadRequest(1, 0x2100, 1)) == STATUS


def test_the_same_seed_gives_the_same_noise(profile: Profile) -> None:
    def replies(seed: int) -> list[bytes | None]:
        line = Line(Bus([make_slave(profile, 1)], seed=seed))
        line.bus.link.noise_percent = 30.0
        return [line.send(read(1, 0x2001)) for _ in range(100)]

    assert replies(5) == replies(5)
    assert replies(5) != replies(6)


# -- the drive's checks, on streams made here

RUN = _with_crc(b"\x01\x06\x20\x00\x00\x01")
RUN_REFUSED = _with_crc(b"\x01\x86\x01")
RESET = _with_crc(b"\x01\x06\x20\x00\x00\x07")
SETPOINT = _with_crc(b"\x01\x06\x20\x01\x05\xdc")


def test_a_run_command_before_2001h_after_power_up_fails_restores_ram() -> None:
    s = Stream()
    s.warm()
    s.mark("start", 1, "power-cycle")
    s.t += 1.0
    s.mark("end", 1, "power-cycle")
    s.t += 0.01
    s.ask(RUN, RUN)
    s.ask(SETPOINT, SETPOINT)
    s.cycle(10)
    plan = read_plan({"drill": [{"incident": "power-cycle"}]}, "p.toml")
    (verdict,) = judge(s.frames, plan, s.marks).verdicts
    ram = next(c for c in verdict.checks if c.check == "restores-ram")
    assert not ram.passed
    assert ram.figure == "a run command 0.01 s after power-up, before any write of 2001H (its RAM value was lost)"
    backs = next(c for c in verdict.checks if c.check == "backs-off")
    assert backs.passed and backs.figure == "0.0 requests/s while the drive was silent, 0 % of its usual 20.0/s"


def test_two_resets_while_the_cause_is_present_and_a_run_into_the_fault() -> None:
    s = Stream()
    s.warm()
    s.mark("start", 1, "trip")
    s.ask(STATUS, _with_crc(b"\x01\x03\x02\x00\x04"))
    s.ask(RESET, RESET)
    s.ask(RUN, RUN_REFUSED)
    s.ask(RESET, RESET)
    s.t += 1.0
    s.mark("end", 1, "trip")
    s.cycle(10)
    plan = read_plan({"drill": [{"incident": "trip"}]}, "p.toml")
    (verdict,) = judge(s.frames, plan, s.marks).verdicts
    figures = {c.check: (c.passed, c.figure) for c in verdict.checks}
    assert figures["notices"] == (True, "read 2100H 0.02 s after the trip (limit 0.55 s)")
    assert figures["resets-once"] == (False, "2 fault resets while the cause was present (1.1 s)")
    assert figures["no-run-into-fault"] == (
        False,
        "1 run commands sent into the fault (refused 0x01), the first 0.03 s after the incident began",
    )


def test_a_new_request_before_its_own_transaction_id_fails_waits_own_id() -> None:
    s = Stream()
    s.warm()  # learned timeout 0.25 s: the right reply comes 125 ms after the wrong-id one
    s.mark("start", 1, "wrong-transaction")
    s.ask(STATUS, STATUS_OK)  # the reply under another id (the line's frame is good)
    s.mark("end", 1, "wrong-transaction")
    s.ask(SPEED, SPEED_OK)  # 1 ms later: moved on before its own id came
    s.cycle(10)
    plan = read_plan({"drill": [{"incident": "wrong-transaction", "replies": 1}]}, "p.toml")
    (verdict,) = judge(s.frames, plan, s.marks).verdicts
    own = verdict.checks[0]
    assert (own.check, own.passed) == ("waits-own-id", False)
    assert own.figure == (
        "1 of 1 took the reply under another id: frame 87, a new request 1 ms after it, before its own came (125 ms)"
    )


def test_takes_replies_says_when_it_cannot_tell() -> None:
    s = Stream()
    s.mark("warmup")
    for _ in range(20):  # one request polled: asked again after each good reply
        start = s.t
        s.ask(STATUS, STATUS_OK)
        s.t = start + 0.1
    s.mark("probe")
    start = s.t
    s.ask(STATUS, None, 0.002)
    s.t = start + 0.25
    s.ask(STATUS, STATUS_OK)
    s.mark("learned")
    s.mark("start", 1, "late")
    s.ask(STATUS, STATUS_OK, 0.125)
    s.mark("end", 1, "late")
    s.ask(STATUS, STATUS_OK)
    plan = read_plan({"drill": [{"incident": "late"}]}, "p.toml")
    (verdict,) = judge(s.frames, plan, s.marks).verdicts
    takes = verdict.checks[0]
    assert takes.passed and takes.figure == "cannot tell: the master asks the same request in a row when all is well"


def _one_request_warm_up(s: Stream, timeout: float) -> None:
    """A master that polls 2100H alone every 100 ms; the probe's unanswered request asked again after ``timeout``."""
    s.mark("warmup")
    for _ in range(20):
        start = s.t
        s.ask(STATUS, STATUS_OK)
        s.t = start + 0.1
    s.mark("probe")
    start = s.t
    s.ask(STATUS, None, 0.002)
    s.t = start + timeout
    s.ask(STATUS, STATUS_OK)
    s.mark("learned")
    s.t = start + timeout + 0.1


def _offline(s: Stream, gaps: list[float]) -> dict[str, tuple[bool, str]]:
    """The drive silent while the master asks 2100H at ``gaps`` apart, then answers again; the offline verdict."""
    s.mark("start", 1, "offline")
    for gap in gaps:
        start = s.t
        s.ask(STATUS, None, 0.002)
        s.t = start + gap
    s.mark("end", 1, "offline")
    for _ in range(10):
        start = s.t
        s.ask(STATUS, STATUS_OK)
        s.t = start + 0.1
    return _played("offline", s, seconds=sum(gaps))


@pytest.mark.parametrize(
    ("timeout", "gap"),
    [
        (0.35, 0.35),  # mbpoll in a shell loop: one try, its 250 ms timeout, then the loop's 100 ms sleep
        (0.1, 0.1),  # a master on a fixed 100 ms schedule whose timeout ends before its next poll
    ],
)
def test_a_poller_repeating_one_request_through_an_outage_is_bounded(timeout: float, gap: float) -> None:
    s = Stream()
    _one_request_warm_up(s, timeout)
    checks = _offline(s, [gap] * 9)
    # 9 failed requests, each asked again (the last by the first poll after the outage): all polls, as before the
    # outage
    assert checks["bounded"] == (
        True,
        "at most 0 retries of one request in a row (limit 3); 9 repeats of a failed request 75 ms or more after it "
        "are polls at its own period (100 ms), not retries",
    )


def test_a_one_request_master_retrying_8_times_at_10_ms_fails_bounded() -> None:
    s = Stream()
    _one_request_warm_up(s, 0.01)
    checks = _offline(s, [0.01] * 8 + [0.1] + [0.01] * 8 + [0.1])
    passed, figure = checks["bounded"]
    assert not passed
    # each poll (100 ms on) starts a new run of retries: 8 in a row, never 17; the polls are the one in the outage
    # and the first after it
    assert figure == (
        "at most 8 retries of one request in a row (limit 3); 2 repeats of a failed request 75 ms or more after it "
        "are polls at its own period (100 ms), not retries"
    )


def test_a_master_polling_two_requests_retries_when_it_asks_one_again_however_late() -> None:
    """Its warm-up never asks one request twice in a row: a repeat 350 ms after a failure is a retry."""
    s = Stream()
    s.warm()
    checks = _offline(s, [0.35] * 5)
    assert checks["bounded"] == (False, "at most 5 retries of one request in a row (limit 3)")


# -- the drive's own behaviours: the automatic reset (F08.28/F08.29) and the fault record (F07.27-F07.48)

FAULTED = _with_crc(b"\x01\x03\x02\x00\x04")  # 2100H = 4
RECORD = _with_crc(b"\x01\x03\x07\x1b\x00\x01")  # F07.27 (071BH)
RECORD_AT = _with_crc(b"\x01\x03\x07\x24\x00\x01")  # F07.36 (0724H): the current at the fault
RECORD_OK = _with_crc(b"\x01\x03\x02\x00\x02")


def _played(incident: str, s: Stream, **values: object) -> dict[str, tuple[bool, str]]:
    plan = read_plan({"drill": [{"incident": incident, **values}]}, "p.toml")
    (verdict,) = judge(s.frames, plan, s.marks).verdicts
    return {c.check: (c.passed, c.figure) for c in verdict.checks}


def _faulted_for(s: Stream, seconds: float) -> None:
    """The master polls 2100H (4: fault) and 3006H every 100 ms for ``seconds``."""
    until = s.t + seconds
    while s.t < until - 1e-9:
        start = s.t
        s.ask(STATUS, FAULTED)
        s.ask(SPEED, SPEED_OK)
        s.t = start + 0.1


def test_a_master_that_waits_for_the_drives_own_reset_and_runs_again_passes_auto_reset() -> None:
    s = Stream()
    s.warm()
    s.mark("start", 1, "auto-reset")
    _faulted_for(s, 1.0)  # the drive resets itself 1.0 s after the trip (F08.29 = 1 s)
    s.ask(STATUS, _with_crc(b"\x01\x03\x02\x00\x03"))  # stopped
    s.ask(RUN, RUN)
    s.t += 0.068
    s.cycle(9)
    s.mark("end", 1, "auto-reset")
    s.cycle(40)
    checks = _played("auto-reset", s)
    assert checks["waits-auto-reset"] == (True, "no reset of its own within F08.29 = 1 s")
    assert checks["resumes"] == (
        True,
        "a run command the drive took 1.02 s after the trip, 0.02 s after its automatic reset (limit 0.75 s)",
    )
    assert all(passed for passed, _ in checks.values()), checks


def test_a_reset_of_its_own_during_the_countdown_fails_waits_auto_reset() -> None:
    s = Stream()
    s.warm()
    s.mark("start", 1, "auto-reset")
    s.ask(STATUS, FAULTED)
    s.ask(RESET, RESET)  # at once: races the drive's own reset
    _faulted_for(s, 0.5)
    s.ask(RESET, RESET)
    s.t += 2.0
    s.mark("end", 1, "auto-reset")
    s.cycle(40)
    checks = _played("auto-reset", s, interval=2.0)
    assert checks["waits-auto-reset"] == (
        False,
        "2 fault resets of its own while the drive's automatic reset counted down, the first 0.02 s after the trip "
        "(F08.29 = 2 s)",
    )
    assert checks["resumes"] == (False, "no run command the drive took after the trip")


def test_a_run_command_long_after_the_drives_reset_fails_resumes() -> None:
    s = Stream()
    s.warm()
    s.mark("start", 1, "auto-reset")
    _faulted_for(s, 1.0)
    s.cycle(10)  # a second of polling a stopped drive (2100H reads 1 here: the master does not look)
    s.ask(RUN, RUN)
    s.mark("end", 1, "auto-reset")
    s.cycle(40)
    assert _played("auto-reset", s)["resumes"] == (
        False,
        "a run command the drive took 2.00 s after the trip, 1.00 s after its automatic reset (limit 0.75 s)",
    )


def test_a_record_read_before_the_reset_passes_reads_record() -> None:
    s = Stream()
    s.warm()
    s.mark("start", 1, "fault-record")
    s.ask(STATUS, FAULTED)
    s.ask(RECORD_AT, RECORD_OK)
    s.ask(RESET, RESET)
    s.t += 0.5
    s.mark("end", 1, "fault-record")
    s.cycle(40)
    checks = _played("fault-record", s)
    assert checks["reads-record"] == (True, "read the fault record 0.03 s after the trip, before its reset")
    assert all(passed for passed, _ in checks.values()), checks


@pytest.mark.parametrize(
    ("steps", "figure"),
    [
        ([(RESET, RESET), (RECORD, RECORD_OK)], "reset the fault 0.02 s after the trip, before it read the fault "
         "record (0.03 s)"),
        ([(RESET, RESET)], "reset the fault 0.02 s after the trip without reading the fault record (F07.27-F07.40)"),
        ([], "never read the fault record (F07.27-F07.40)"),
    ],
)  # fmt: skip
def test_a_reset_before_the_record_or_none_fails_reads_record(steps: list[tuple[bytes, bytes]], figure: str) -> None:
    s = Stream()
    s.warm()
    s.mark("start", 1, "fault-record")
    s.ask(STATUS, FAULTED)
    for request, reply in steps:
        s.ask(request, reply)
    s.t += 0.5
    s.mark("end", 1, "fault-record")
    s.cycle(40)
    assert _played("fault-record", s)["reads-record"] == (False, figure)


def test_a_record_read_before_the_trip_is_not_a_read_after_it() -> None:
    s = Stream()
    s.warm()
    s.ask(RECORD, RECORD_OK)  # the old record, in the warm-up's tail
    s.t += 0.1
    s.mark("start", 1, "fault-record")
    s.ask(STATUS, FAULTED)
    s.t += 0.5
    s.mark("end", 1, "fault-record")
    s.cycle(40)
    assert _played("fault-record", s)["reads-record"] == (False, "never read the fault record (F07.27-F07.40)")


def test_the_auto_reset_incident_sets_and_puts_back_f08_28_and_f08_29() -> None:
    plan = read_plan({"drill": [{"incident": "auto-reset", "interval": 2.5, "hold": 0.4}]}, "p.toml")
    (drill,) = plan.drills
    steps, length = drill.incident.steps(drill.values, Learned(0.1, 0.25))
    assert length == 3.5
    assert [(s.at, s.op, dict(s.args)) for s in steps] == [
        (0.0, "fcode", {"code": "F08.28", "value": 1}),
        (0.0, "fcode", {"code": "F08.29", "value": 25}),
        (0.0, "trip", {"cause": "external"}),
        (0.4, "release", {"cause": "external"}),
        (3.5, "fcode", {"code": "F08.28", "value": 0}),
        (3.5, "fcode", {"code": "F08.29", "value": 10}),
    ]
    with pytest.raises(C20SimError, match=r"p.toml: drill 1: interval: 0.1 is outside 0.2-30"):
        read_plan({"drill": [{"incident": "auto-reset", "interval": 0.1}]}, "p.toml")


# -- the command that judges a run's frame log again


def _drill_args(*argv: str) -> object:
    import argparse

    from c20sim.drillcli import add_drill_command

    parser = argparse.ArgumentParser()
    add_drill_command(parser.add_subparsers())
    return parser.parse_args(["drill", *argv])


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        # the standard plan is built in: no plan file, the transport's standard plan
        ((), "c20sim drill --judge {cwd}/frames.jsonl --transport tcp"),
        (("--transport", "pty", "--seed", "7"), "c20sim drill --judge {cwd}/frames.jsonl --transport pty --seed 7"),
        (
            ("--plan", "my plan.toml", "--transport", "pty"),
            "c20sim drill --judge {cwd}/frames.jsonl --plan '{cwd}/my plan.toml'",
        ),
        (
            ("--plan", "/p/plan.toml", "--profile", "mine.toml"),
            "c20sim drill --judge {cwd}/frames.jsonl --plan /p/plan.toml --profile {cwd}/mine.toml",
        ),
    ],
)
def test_the_judge_command_names_what_the_run_judged_by(
    argv: tuple[str, ...], expected: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from c20sim.drillcli import judge_command

    monkeypatch.chdir(tmp_path)  # relative paths are made absolute: the command works from anywhere
    command = judge_command(_drill_args(*argv), "frames.jsonl")  # type: ignore[arg-type]
    assert command == expected.format(cwd=tmp_path)
