"""The audit's rules on the pure core: a master's frames to a real drive on a bus, in virtual time.

Each misbehaving master gets exactly its finding with its figure; a sane one gets none. The same frames
read back as a frame log (t, dir, hex) give the same findings: live and offline are one engine.
"""

from __future__ import annotations

import itertools

import pytest

from c20sim.audit import RULES, Auditor, Finding, Limits, Severity
from c20sim.core.bus import Bus
from c20sim.core.slave import Slave
from c20sim.drive.model import Drive
from c20sim.drive.profile import Profile
from c20sim.wire.protocol import (
    ExceptionCode,
    ExceptionResponse,
    ReadRequest,
    ReadResponse,
    WriteMultipleRequest,
    WriteSingleRequest,
    encode,
    transaction_time,
)
from c20sim.wire.registers import Reg, fcode_address
from tests.conftest import Line

READ_TX = transaction_time(8, 7, 19200, 10, 0.002)  # a one-register read at 19200 8N1, 2 ms turnaround
F00_03, F00_10, F00_11, F00_50, F08_02 = (fcode_address(g, n) for g, n in ((0, 3), (0, 10), (0, 11), (0, 50), (8, 2)))


class Master:
    """A master on a bus of one real drive (address 1), with the auditor fed by the bus, as serve feeds it."""

    def __init__(self, profile: Profile) -> None:
        self.bus = Bus([Slave(profile, Drive(profile))])
        self.line = Line(self.bus)
        self.auditor = Auditor(profile)
        self.log: list[tuple[float, str, bytes]] = []
        self.profile = profile

        def listen(record: object) -> None:
            t, direction, data = record.t, str(record.direction), record.data  # type: ignore[attr-defined]
            self.log.append((t, direction, data))
            self.auditor.feed(t, direction, data)

        self.bus.subscribe(listen)

    def read(self, register: int, dt: float, slave: int = 1) -> bytes | None:
        return self.line.send(encode(ReadRequest(slave, register, 1)), dt)

    def write(self, register: int, value: int, dt: float, slave: int = 1) -> bytes | None:
        return self.line.send(encode(WriteSingleRequest(slave, register, value)), dt)

    def findings(self) -> list[Finding]:
        """The live findings; checked to be those of the same frames read back offline."""
        live = self.auditor.findings()
        offline = Auditor(self.profile)
        for t, direction, data in self.log:
            offline.feed(round(t, 6), direction, bytes.fromhex(data.hex(" ")))
        assert [(f.key, f.severity, f.figure, f.count) for f in offline.findings()] == [
            (f.key, f.severity, f.figure, f.count) for f in live
        ]
        return live


@pytest.fixture
def master(profile: Profile) -> Master:
    return Master(profile)


def only(master: Master) -> Finding:
    found = master.findings()
    assert [f.rule for f in found] == [found[0].rule] if found else []
    assert len(found) == 1, [f.line() for f in found]
    return found[0]


def test_a_sane_poller_gets_no_finding(master: Master) -> None:
    for _ in range(40):
        master.read(Reg.STATUS1, 0.0625)
        master.read(Reg.MOTOR_SPEED, 0.0625)
    assert master.findings() == []
    demand = master.auditor.line_demand()
    assert demand.now == pytest.approx(16 * READ_TX * 100)  # 16 reads a second
    assert demand.transactions == 80


def test_a_poller_too_fast_for_the_line(master: Master) -> None:
    for _ in range(600):
        master.read(Reg.STATUS1, 1 / 256)  # each after its reply: no collision, but 256 a second
    finding = only(master)
    assert (finding.rule, finding.severity, finding.drive) == ("line-demand", Severity.ERROR, None)
    # the window's 256 reads need 3.445 s of line, and take from the first request to the end of the last
    expected = 256 * READ_TX * 100 / (255 / 256 + READ_TX)
    assert finding.value == pytest.approx(expected)
    assert finding.figure == "line demand 341 % of 19200 8N1: 256 transactions in 1.010 s need 3.445 s of line"
    assert master.auditor.line_demand().peak == pytest.approx(expected)


def test_a_line_kept_exactly_full_is_a_warning_and_one_asked_for_more_an_error(profile: Profile) -> None:
    """A master polling back to back on a real line keeps it exactly full: 100 %, a warning (no room for a retry),
    though a window of 1 s holds the requests of 75 reads of 13.46 ms. Asking each read 0.3 ms sooner than the
    line carries it is an error: 102 %."""
    full = Master(profile)
    for _ in range(300):
        full.read(Reg.STATUS1, READ_TX)
    finding = only(full)
    assert (finding.rule, finding.severity) == ("line-demand", Severity.WARNING)
    assert finding.value == pytest.approx(100.0)
    assert full.auditor.line_demand().mean == pytest.approx(100.0)

    faster = Master(profile)
    for _ in range(300):
        faster.read(Reg.STATUS1, READ_TX - 0.0003)
    demand = [f for f in faster.findings() if f.rule == "line-demand"]
    assert [f.severity for f in demand] == [Severity.ERROR]
    assert demand[0].value == pytest.approx(100 * READ_TX / (READ_TX - 0.0003), abs=0.1)


def test_a_demand_creeping_past_full_becomes_an_error(master: Master) -> None:
    """A master near a full line that then asks 0.4 % more: the finding turns to an error, though the peak grew
    by less than half a point at a time (it was judged afresh only on a half point's growth, and stayed a
    warning at 100.4 %)."""
    for _ in range(300):
        master.read(Reg.STATUS1, 1 / 74)  # 99.6 %: a warning
    assert [(f.rule, f.severity) for f in master.findings()] == [("line-demand", Severity.WARNING)]
    for _ in range(300):
        master.read(Reg.STATUS1, READ_TX / 1.004)  # 100.4 %
    finding = only(master)
    assert (finding.rule, finding.severity) == ("line-demand", Severity.ERROR)
    peak = master.auditor.line_demand().peak
    assert peak == pytest.approx(100.4, abs=0.05)
    assert 100.2 <= finding.value <= peak <= finding.value + 0.5  # the peak, to within half a point


def test_a_cyclic_function_code_writer_wears_the_eeprom(master: Master) -> None:
    assert master.write(Reg.WRITE_ENABLE, 1, 0.1) is not None
    for i in range(20):
        master.write(F00_10, 2000 + i, 0.125)
    master.write(Reg.WRITE_ENABLE, 0, 0.1)
    finding = only(master)
    assert (finding.rule, finding.severity, finding.drive, finding.subject) == (
        "eeprom-wear",
        Severity.ERROR,
        1,
        "F00.10",
    )
    assert finding.value == pytest.approx(28800.0)  # 19 writes in 2.375 s
    assert finding.figure == "F00.10 stored 28,800 times an hour (20 writes): rated 100,000 writes reached in 3.5 h"
    assert "800AH" in finding.advice
    assert "assumed" in finding.source


def test_a_cyclic_0x10_writer_wears_the_eeprom_of_every_register_it_carries(master: Master) -> None:
    """0x10 stores each of its registers as 0x06 would: 2001H (RAM) then 2002H and 2003H (EEPROM cells)."""
    for i in range(20):
        master.line.send(encode(WriteMultipleRequest(1, Reg.SPEED_SETPOINT, (1000 + i, 4, 30 + i % 2))), 0.125)
    found = master.findings()
    assert [(f.rule, f.severity, f.subject, f.figure) for f in found] == [
        (
            "eeprom-wear",
            Severity.ERROR,
            "2002H",
            "2002H stored 28,800 times an hour (the same value each time; 20 writes): rated 100,000 writes reached "
            "in 3.5 h",
        ),
        (
            "eeprom-wear",
            Severity.ERROR,
            "2003H",
            "2003H stored 28,800 times an hour (20 writes): rated 100,000 writes reached in 3.5 h",
        ),
    ]


def test_a_speed_above_the_maximum_inside_a_0x10_block_is_seen(master: Master) -> None:
    """2000H then 2001H in one 0x10: the speed reference is the block's second register."""
    master.line.send(encode(WriteMultipleRequest(1, Reg.COMMAND, (1, 3000 + 500))), 0.1)
    finding = only(master)
    assert (finding.rule, finding.subject) == ("speed-above-max", "2001H")


def test_writing_the_ram_only_address_is_no_wear(master: Master) -> None:
    for _ in range(20):
        master.write(0x800A, 2000, 0.125)  # refused by this model (0x02), never stored
    assert [f.rule for f in master.findings()] == ["refused-repeat"]


def test_a_slow_poller_near_the_watchdog(master: Master) -> None:
    master.write(Reg.WRITE_ENABLE, 1, 0.1)
    master.write(F08_02, 50, 0.1)  # 5.0 s
    master.write(Reg.WRITE_ENABLE, 0, 0.1)
    for _ in range(4):
        master.read(Reg.STATUS1, 4.5)
    finding = only(master)
    assert (finding.rule, finding.severity, finding.drive) == ("comm-watchdog", Severity.WARNING, 1)
    assert finding.value == pytest.approx(90.0)
    assert finding.figure == "longest silence 4.50 s is 90 % of the communication timeout F08.02 = 5 s"


def test_a_silence_past_the_timeout_is_an_error(profile: Profile) -> None:
    auditor = Auditor(profile, comm_timeout=2.0)
    request = encode(ReadRequest(1, Reg.STATUS1, 1))
    auditor.feed(1.0, "rx", request)
    auditor.feed(3.5, "rx", request)
    (finding,) = auditor.findings()
    assert (finding.rule, finding.severity, finding.value) == ("comm-watchdog", Severity.ERROR, 125.0)
    assert finding.figure.endswith(": the drive trips CE")


def test_an_early_retrier(master: Master) -> None:
    master.read(Reg.STATUS1, 0.1, slave=7)  # nobody at 7: silence
    master.read(Reg.STATUS1, 0.005, slave=7)  # retried after 5 ms: the reply needs 13.5 ms on the line
    master.read(Reg.STATUS1, 0.05, slave=7)  # after 50 ms: a fair timeout
    finding = only(master)
    assert (finding.rule, finding.severity, finding.drive, finding.count) == ("early-retry", Severity.ERROR, 7, 1)
    assert finding.figure == (
        "a retry 5.0 ms after the last, before its reply could have finished (13.5 ms on 19200 8N1)"
    )
    assert [f.seq for f in finding.frames] == [1, 2]


def test_a_request_before_the_reply_collides(profile: Profile) -> None:
    auditor = Auditor(profile)
    auditor.feed(1.0, "rx", encode(ReadRequest(1, Reg.STATUS1, 1)))
    auditor.feed(1.0002, "rx", encode(ReadRequest(1, Reg.STATUS2, 1)))  # pipelined: its reply comes after
    auditor.feed(1.002, "tx", bytes.fromhex("01 03 02 00 05 78 47"))
    (finding,) = auditor.findings()
    assert (finding.rule, finding.drive) == ("collision", 1)


def test_a_request_within_a_timer_tick_of_the_reply_is_a_sequential_master(profile: Profile) -> None:
    # the reply is recorded as due 2 ms after the request; the loop's millisecond timers may send it after 1.1 ms
    auditor = Auditor(profile)
    request = encode(ReadRequest(1, Reg.STATUS1, 1))
    auditor.feed(1.0, "rx", request)
    auditor.feed(1.002, "tx", encode(ReadResponse(1, (5,))))
    auditor.feed(1.0012, "rx", request)
    assert auditor.findings() == []


def test_one_that_ignores_0x08(master: Master) -> None:
    master.write(Reg.SPEED_SETPOINT, 1000, 0.1)
    master.write(Reg.COMMAND, 1, 0.1)
    for _ in range(4):
        assert master.write(Reg.BAUD, 3, 0.1) == encode(ExceptionResponse(1, 6, ExceptionCode.NOT_WHILE_RUNNING))
    master.write(Reg.COMMAND, 5, 0.1)
    finding = only(master)
    assert (finding.rule, finding.drive, finding.subject, finding.count) == ("refused-while-running", 1, "2009H", 2)
    assert finding.figure == "write of 2009H refused 0x08 (parameter cannot be changed while running) 4 times"


def test_one_that_talks_right_after_a_broadcast(master: Master) -> None:
    master.read(Reg.STATUS1, 0.1)
    master.write(Reg.SPEED_SETPOINT, 500, 0.2, slave=0)
    master.read(Reg.STATUS1, 0.01)
    finding = only(master)
    assert (finding.rule, finding.severity, finding.drive) == ("broadcast-turnaround", Severity.WARNING, None)
    assert finding.figure.startswith("a request 10.0 ms after a broadcast; the drive needs 100 ms")


def test_one_that_leaves_200eh_enabled(master: Master) -> None:
    master.write(Reg.WRITE_ENABLE, 1, 0.1)
    master.write(F00_11, 50, 0.1)
    for _ in range(12):
        master.read(Reg.STATUS1, 0.5)
    finding = only(master)
    assert (finding.rule, finding.drive, finding.subject) == ("write-enable-left-on", 1, "200EH")
    assert finding.figure == "200EH = 1 (function codes writable) left on 5.0 s after the last function-code write"


def test_200eh_written_back_to_0_is_clean(master: Master) -> None:
    master.write(Reg.WRITE_ENABLE, 1, 0.1)
    master.write(F00_11, 50, 0.1)
    master.write(Reg.WRITE_ENABLE, 0, 0.1)
    for _ in range(12):
        master.read(Reg.STATUS1, 0.5)
    assert master.findings() == []


@pytest.mark.parametrize(
    ("steps", "rule", "subject", "code"),
    [
        ([("read", F00_50)] * 3, "absent-register", "F00.50", 0x02),
        ([("write", F00_10, 100)] * 3, "fcode-locked", "F00.10", 0x04),
    ],
)
def test_repeated_refusals(master: Master, steps: list[tuple[object, ...]], rule: str, subject: str, code: int) -> None:
    for step in steps:
        if step[0] == "read":
            master.read(int(step[1]), 0.1)  # type: ignore[call-overload]
        else:
            master.write(int(step[1]), int(step[2]), 0.1)  # type: ignore[call-overload]
    finding = only(master)
    assert (finding.rule, finding.subject, finding.count) == (rule, subject, 1)
    assert f"refused 0x{code:02X}" in finding.figure and finding.figure.endswith("3 times")


def test_two_refusals_are_a_probe_not_a_finding(master: Master) -> None:
    master.read(F00_50, 0.1)
    master.read(F00_50, 0.1)
    assert master.findings() == []


def test_run_commands_on_the_wrong_channel(master: Master) -> None:
    master.write(Reg.WRITE_ENABLE, 1, 0.1)
    master.write(Reg.RUN_CHANNEL, 1, 0.1)  # terminals
    master.write(Reg.WRITE_ENABLE, 0, 0.1)
    for _ in range(3):
        assert master.write(Reg.COMMAND, 1, 0.1) == encode(ExceptionResponse(1, 6, ExceptionCode.OPERATION_FAILED))
    finding = only(master)
    assert (finding.rule, finding.subject) == ("run-channel", "2000H")


def test_a_reset_loop(master: Master) -> None:
    for _ in range(3):
        master.write(Reg.COMMAND, 7, 2.0)
    finding = only(master)
    assert (finding.rule, finding.subject) == ("reset-loop", "2000H")
    assert finding.figure == "fault reset 2000H = 7 sent 3 times in 4.0 s"


def test_a_speed_reference_above_the_maximum(master: Master) -> None:
    master.write(Reg.WRITE_ENABLE, 1, 0.1)
    master.write(F00_03, 2000, 0.1)
    master.write(Reg.WRITE_ENABLE, 0, 0.1)
    master.write(Reg.SPEED_SETPOINT, 2500, 0.1)
    finding = only(master)
    assert (finding.rule, finding.subject, finding.value) == ("speed-above-max", "2001H", 2500.0)
    assert finding.figure == "speed reference 2001H = 2500 rpm above the maximum speed F00.03 = 2000 rpm"


def test_ignore_silences_a_rule_and_an_unknown_rule_is_one_line(profile: Profile) -> None:
    auditor = Auditor(profile, comm_timeout=2.0, ignore=["comm-watchdog"])
    request = encode(ReadRequest(1, Reg.STATUS1, 1))
    auditor.feed(1.0, "rx", request)
    auditor.feed(3.5, "rx", request)
    assert auditor.findings() == []
    with pytest.raises(ValueError, match="unknown rule 'line-demnad'; the rules are line-demand, "):
        Auditor(profile, ignore=["line-demnad"])


def test_events_give_new_and_grown_findings_once(profile: Profile) -> None:
    auditor = Auditor(profile, limits=Limits(window=0.5))
    request = encode(ReadRequest(1, Reg.STATUS1, 1))
    reply = encode(ReadResponse(1, (5,)))
    for k in range(200):
        auditor.feed(k / 100, "rx", request)  # 100 a second: 135 %
        auditor.feed(k / 100 + 0.002, "tx", reply)
    events = auditor.events()
    assert [(e.rule, e.severity, e.count) for e in events] == [("line-demand", Severity.ERROR, 1)]  # new: once
    assert events[0] == auditor.findings()[0]
    assert auditor.events() == []  # asked again: nothing said twice
    for k in range(200, 400):  # the same demand two seconds more: not grown, so no event
        auditor.feed(k / 100, "rx", request)
        auditor.feed(k / 100 + 0.002, "tx", reply)
    assert auditor.events() == []
    for k in range(400):  # the master speeds up to 200 a second: the finding grows
        auditor.feed(4 + k / 200, "rx", request)
        auditor.feed(4 + k / 200 + 0.002, "tx", reply)
    grown = auditor.events()
    assert len(grown) >= 10
    assert [e.count for e in grown] == list(range(2, 2 + len(grown)))  # each growth said once, in order
    peaks = [events[0].value] + [e.value for e in grown]
    assert all(later > earlier + 0.5 for earlier, later in itertools.pairwise(peaks))  # each one grown
    assert grown[-1] == auditor.findings()[0] and len(auditor.findings()) == 1
    assert auditor.events() == []


def test_the_line_demand_now_falls_to_0_when_the_master_is_quiet(profile: Profile) -> None:
    auditor = Auditor(profile)
    request, reply = encode(ReadRequest(1, Reg.STATUS1, 1)), encode(ReadResponse(1, (5,)))
    for k in range(32):
        auditor.feed(k / 16, "rx", request)
        auditor.feed(k / 16 + 0.002, "tx", reply)
    expected = 16 * READ_TX * 100
    assert auditor.line_demand().now == pytest.approx(expected)
    assert auditor.line_demand(31 / 16 + 0.5).now == pytest.approx(8 * READ_TX * 100)  # half the window left
    quiet = auditor.line_demand(10.0)
    assert (quiet.now, quiet.peak, quiet.transactions) == (0.0, pytest.approx(expected), 32)


def test_the_window_is_bounded(profile: Profile) -> None:
    from c20sim.audit.engine import MAX_WINDOW

    auditor = Auditor(profile)
    request = encode(ReadRequest(1, Reg.STATUS1, 1))
    for k in range(MAX_WINDOW + 10):
        auditor.feed(k * 1e-6, "rx", request)
    assert len(auditor._window) <= MAX_WINDOW


def test_every_rule_has_a_section_in_the_docs() -> None:
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "docs" / "audit.md").read_text()
    assert [rule for rule in RULES if f"### `{rule}`" not in text] == []


# -- what a frame means is remembered by its bytes (a master polls the same few): never what the stream changed


def test_the_same_request_after_a_baud_change_costs_the_new_baud(profile: Profile) -> None:
    auditor = Auditor(profile)
    request = encode(ReadRequest(1, Reg.STATUS1, 1))
    auditor.feed(1.0, "rx", request)
    auditor.set_baud(9600)
    auditor.feed(2.0, "rx", request)
    demand = auditor.line_demand()
    assert (demand.baud, demand.transactions) == (9600, 2)
    assert demand.busy == READ_TX + transaction_time(8, 7, 9600, 10, 0.002)


def test_a_remembered_poll_is_judged_by_the_timeout_written_since(profile: Profile) -> None:
    auditor = Auditor(profile)  # F08.02 = 0 by default: no watchdog
    poll, answer = encode(ReadRequest(1, Reg.STATUS1, 1)), encode(ReadResponse(1, (5,)))
    write = encode(WriteSingleRequest(1, F08_02, 20))  # 2.0 s
    t = 0.0
    for gap in (3.0, 3.0, 0.5):
        t += gap
        auditor.feed(t, "rx", poll)
        auditor.feed(t + 0.002, "tx", answer)
    assert auditor.findings() == []
    auditor.feed(t + 0.1, "rx", write)
    auditor.feed(t + 0.102, "tx", write)  # the drive took it (0x06 echoes the request)
    auditor.feed(t + 2.0, "rx", poll)  # 1.9 s after the write: 95 % of the new timeout
    (finding,) = auditor.findings()
    assert (finding.rule, finding.severity, finding.drive) == ("comm-watchdog", Severity.WARNING, 1)
    assert finding.figure == "longest silence 1.90 s is 95 % of the communication timeout F08.02 = 2 s"


async def test_the_live_audit_judges_each_frame_at_the_baud_it_went_at(profile: Profile) -> None:
    """Frames queued on both sides of a 2009H write the line followed (no loop turn between them): those
    before it cost the old baud, those after the new one, as a frame at a time would."""
    from c20sim.control import liveaudit
    from c20sim.core.simulator import Simulator
    from c20sim.wire.protocol import FrameEvent, FrameKind

    sim = Simulator(profile, (1,), seed=1)
    audit = liveaudit.start(sim)
    try:
        poll = encode(ReadRequest(1, Reg.STATUS1, 1))
        frames = [poll, encode(WriteSingleRequest(1, Reg.BAUD, 5)), poll, poll]  # 5: 38400 baud
        for k, frame in enumerate(frames):
            assert sim.bus.handle(FrameEvent(FrameKind.FRAME, frame, 1.0 + k), sim.now()) is not None
        assert sim.bus.line_baud == 38400
        assert len(audit._queue) > 0  # not yet audited: the loop has not turned
        demand = audit.line_demand()
        assert (demand.baud, demand.transactions, audit.auditor.frames) == (38400, 4, 8)
        write = transaction_time(8, 8, 19200, 10, 0.002)
        fast = transaction_time(8, 7, 38400, 10, 0.002)
        assert demand.busy == READ_TX + write + fast + fast
    finally:
        audit.close()


def test_the_live_audit_runs_its_batches_on_whichever_loop_serves(profile: Profile) -> None:
    """A batch waits for the serving loop's next turn; a simulator served again on a new loop (the first one
    closed) schedules there, and with no loop running in the feeding thread a batch is audited at once."""
    import asyncio

    from c20sim.control import liveaudit
    from c20sim.core.simulator import Simulator
    from c20sim.wire.protocol import FrameEvent, FrameKind

    sim = Simulator(profile, (1,), seed=1)
    audit = liveaudit.start(sim)
    poll = encode(ReadRequest(1, Reg.STATUS1, 1))
    transactions = liveaudit.BATCH // 2
    t = 1.0

    def poll_a_batch() -> None:
        nonlocal t
        for _ in range(transactions):
            t += 0.05
            assert sim.bus.handle(FrameEvent(FrameKind.FRAME, poll, t), sim.now()) is not None

    async def served() -> tuple[int, int]:
        poll_a_batch()
        waiting = len(audit._queue)
        await asyncio.sleep(0)  # the loop's next turn: the batch is audited
        return waiting, len(audit._queue)

    def from_a_thread() -> int:
        poll_a_batch()
        return len(audit._queue)

    async def served_and_fed_from_a_thread() -> tuple[int, int]:
        first = await served()
        return first[1], await asyncio.to_thread(from_a_thread)

    try:
        assert asyncio.run(served()) == (liveaudit.BATCH, 0)
        assert asyncio.run(served()) == (liveaudit.BATCH, 0)  # the first loop is closed: this one audits
        poll_a_batch()
        assert len(audit._queue) == 0  # no loop: audited at once
        # a thread with no loop of its own audits at once, and hands nothing to another thread's loop
        assert asyncio.run(served_and_fed_from_a_thread()) == (0, 0)
        assert audit.auditor.frames == 5 * liveaudit.BATCH
    finally:
        audit.close()
