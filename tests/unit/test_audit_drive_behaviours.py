"""The audit's rules on the drive's own behaviours (automatic fault reset F08.28/F08.29, the fault record
F07.27-F07.48), on frames between a master and a real drive on a bus, in virtual time.

A master that does it gets exactly one finding, with its figure; one that does not gets none. The same frames
read back offline give the same findings (``Master.findings`` checks it).
"""

from __future__ import annotations

import pytest

from c20sim.audit import Auditor, Severity
from c20sim.drive.model import Drive
from c20sim.drive.profile import Profile
from c20sim.wire.protocol import ReadRequest, ReadResponse, WriteSingleRequest, encode
from c20sim.wire.registers import Reg, fcode_address
from tests.unit.test_audit import Master

F07_27, F07_33, F07_36 = fcode_address(7, 27), fcode_address(7, 33), fcode_address(7, 36)
F08_28, F08_29 = fcode_address(8, 28), fcode_address(8, 29)
FAULT = 0x02


def _drive(master: Master) -> Drive:
    drive = master.bus.slaves[0].drive
    assert isinstance(drive, Drive)
    return drive


def _auto_reset(master: Master, trials: int, tenths: int) -> None:
    """The master sets the drive's automatic reset over the wire: 200EH = 1, F08.28, F08.29, 200EH = 0."""
    for register, value in ((Reg.WRITE_ENABLE, 1), (F08_28, trials), (F08_29, tenths), (Reg.WRITE_ENABLE, 0)):
        assert master.write(register, value, 0.05) is not None
    assert master.line.replies[-1].data[1] == 0x06  # taken, not refused


def _trip(master: Master) -> None:
    _drive(master).force_fault(FAULT, persistent=True)  # held: the drive's own reset cannot clear it


def _rules(master: Master) -> list[tuple[str, Severity, str, str, int]]:
    return [(f.rule, f.severity, f.subject, f.figure, f.count) for f in master.findings()]


@pytest.fixture
def master(profile: Profile) -> Master:
    return Master(profile)


def test_a_reset_inside_the_automatic_reset_interval_races_the_drive(master: Master) -> None:
    _auto_reset(master, 3, 50)  # three trials, 5.0 s apart
    _trip(master)
    assert master.read(Reg.FAULT_CODE, 0.1) is not None  # 2102H = 2: the master sees the fault
    master.read(F07_27, 0.1)  # and reads the record: no fault-record-unread
    master.write(Reg.COMMAND, 7, 0.4)  # 0.5 s after it saw the fault
    assert _rules(master) == [
        (
            "auto-reset-race",
            Severity.WARNING,
            "2000H",
            "fault reset 2000H = 7 sent 0.50 s after the master saw fault 0x02, within the automatic reset interval "
            "F08.29 = 5 s (F08.28 = 3)",
            1,
        )
    ]
    finding = master.findings()[0]
    seen_t = next(t for t, way, data in master.log if way == "tx" and data == encode(ReadResponse(1, (FAULT,))))
    reset_t = master.log[-2][0]
    assert master.log[-2][2] == encode(WriteSingleRequest(1, Reg.COMMAND, 7))
    assert (finding.frames[0].t, finding.frames[1].t, finding.value) == (seen_t, reset_t, reset_t - seen_t)
    assert "INVT GD20 P08.28/P08.29" in finding.source and "F08.28 = 0 as the profile ships it" in finding.source


def test_a_second_early_reset_counts_on_the_same_finding(master: Master) -> None:
    _auto_reset(master, 3, 50)
    _trip(master)
    master.read(Reg.FAULT_CODE, 0.1)
    master.read(F07_27, 0.1)
    master.write(Reg.COMMAND, 7, 0.4)
    master.write(Reg.COMMAND, 7, 1.0)  # the fault is held: still in the interval, 1.5 s after
    (finding,) = master.findings()
    assert (finding.rule, finding.count) == ("auto-reset-race", 2)
    assert finding.figure.startswith("fault reset 2000H = 7 sent 0.50 s after")  # the first one's figure


def test_the_settings_a_master_read_back_count_too(master: Master) -> None:
    drive = _drive(master)
    drive.write(F08_28, 2)  # set at the keypad: the master learns it by reading it
    drive.write(F08_29, 30)
    assert master.read(F08_28, 0.1) == encode(ReadResponse(1, (2,)))
    master.read(F08_29, 0.1)
    _trip(master)
    master.read(Reg.STATUS1, 0.1)  # 2100H = 4 only
    master.read(F07_33, 0.1)
    master.write(Reg.COMMAND, 7, 1.0)
    assert [(f.rule, f.figure) for f in master.findings()] == [
        (
            "auto-reset-race",
            "fault reset 2000H = 7 sent 1.10 s after the master saw the fault (2100H = 4), within the automatic "
            "reset interval F08.29 = 3 s (F08.28 = 2)",
        )
    ]


def test_a_master_that_waits_out_the_interval_gets_none(master: Master) -> None:
    _auto_reset(master, 1, 10)  # one trial, 1.0 s after the trip
    _trip(master)
    master.read(Reg.FAULT_CODE, 0.1)
    master.read(F07_27, 0.1)
    for _ in range(10):
        master.read(Reg.FAULT_CODE, 0.1)  # the held fault outlives the drive's one trial
    master.write(Reg.COMMAND, 7, 0.1)  # 1.2 s after it saw the fault
    assert _rules(master) == []


def test_no_automatic_reset_no_race(master: Master) -> None:
    _trip(master)  # F08.28 = 0 as shipped
    master.read(Reg.FAULT_CODE, 0.1)
    master.read(F07_27, 0.1)
    master.write(Reg.COMMAND, 7, 0.1)
    assert _rules(master) == []


def test_a_reset_without_a_read_of_the_record(master: Master) -> None:
    _trip(master)
    master.read(Reg.FAULT_CODE, 0.1)
    master.write(Reg.COMMAND, 7, 0.3)
    assert _rules(master) == [
        (
            "fault-record-unread",
            Severity.WARNING,
            "F07.27",
            "fault 0x02 seen, reset 2000H = 7 sent 0.30 s later without a read of the fault record "
            "(F07.27-F07.40, 071BH-0728H)",
            1,
        )
    ]


def test_a_record_read_before_the_fault_is_not_a_read_after_it(master: Master) -> None:
    master.read(F07_36, 0.1)  # the old record, before the trip
    _trip(master)
    master.read(Reg.STATUS1, 0.1)
    master.write(Reg.COMMAND, 7, 0.2)
    assert [f.rule for f in master.findings()] == ["fault-record-unread"]
    assert master.findings()[0].figure.startswith("a fault (2100H = 4) seen, reset 2000H = 7 sent 0.20 s later")


@pytest.mark.parametrize("cell", [F07_27, F07_33, F07_36])
def test_a_read_of_the_record_after_the_fault_is_enough(master: Master, cell: int) -> None:
    _trip(master)
    master.read(Reg.FAULT_CODE, 0.1)
    master.read(cell, 0.1)
    master.write(Reg.COMMAND, 7, 0.1)
    assert _rules(master) == []


def test_the_next_fault_asks_for_the_record_again(master: Master) -> None:
    drive = _drive(master)
    _trip(master)
    master.read(Reg.FAULT_CODE, 0.1)
    master.read(F07_27, 0.1)
    drive.release_fault()
    master.write(Reg.COMMAND, 7, 0.1)
    assert master.read(Reg.FAULT_CODE, 0.1) == encode(ReadResponse(1, (0,)))  # out of the fault: forgotten
    _trip(master)
    master.read(Reg.FAULT_CODE, 0.1)
    master.write(Reg.COMMAND, 7, 0.1)
    assert [(f.rule, f.count) for f in master.findings()] == [("fault-record-unread", 1)]


def test_a_blind_reset_is_neither(master: Master) -> None:
    _auto_reset(master, 3, 50)
    _trip(master)
    master.write(Reg.COMMAND, 7, 0.1)  # a fault the master never saw: reset-loop's to judge, not these
    assert _rules(master) == []


def test_a_profile_without_the_record_is_not_judged_on_it(profile: Profile) -> None:
    from dataclasses import replace

    defaults = {a: v for a, v in profile.defaults.items() if a != F07_27}
    bare = replace(profile, defaults=defaults)
    auditor = Auditor(bare)
    frames = [
        (0.0, "rx", encode(ReadRequest(1, Reg.FAULT_CODE, 1))),
        (0.01, "tx", encode(ReadResponse(1, (FAULT,)))),
        (0.1, "rx", encode(WriteSingleRequest(1, Reg.COMMAND, 7))),
        (0.11, "tx", encode(WriteSingleRequest(1, Reg.COMMAND, 7))),
    ]
    auditor.feed_all(frames)
    assert auditor.findings() == []
    full = Auditor(profile)
    full.feed_all(frames)
    assert [f.rule for f in full.findings()] == ["fault-record-unread"]


# -- the answer delay (F08.04): a master that gives up sooner than the delay the drive answers after

F08_04 = fcode_address(8, 4)
READ_STATUS = encode(ReadRequest(1, Reg.STATUS1, 1))
STATUS_RUNNING = encode(ReadResponse(1, (1,)))


def _set_delay(ms: int) -> list[tuple[float, str, bytes]]:
    """A master's frames that set F08.04 to ``ms`` (200EH = 1, F08.04, 200EH = 0), each echoed (taken)."""
    frames: list[tuple[float, str, bytes]] = []
    for i, (register, value) in enumerate(((Reg.WRITE_ENABLE, 1), (F08_04, ms), (Reg.WRITE_ENABLE, 0))):
        write = encode(WriteSingleRequest(1, register, value))
        frames += [(0.1 * i, "rx", write), (0.1 * i + 0.012, "tx", write)]
    return frames


def test_a_timeout_shorter_than_the_answer_delay_it_set(profile: Profile) -> None:
    auditor = Auditor(profile)
    frames = _set_delay(100)  # the drive answers 100 ms after a request
    # a read at 1.0 s; the master gives up after 50 ms and asks again; the drive's reply comes after both
    frames += [(1.0, "rx", READ_STATUS), (1.05, "rx", READ_STATUS), (1.109, "tx", STATUS_RUNNING)]
    auditor.feed_all(frames)
    delayed = [f for f in auditor.findings() if f.rule == "answer-delay-timeout"]
    assert [(f.severity, f.drive, f.subject, f.figure, f.value, f.count) for f in delayed] == [
        (
            Severity.ERROR,
            1,
            "F08.04",
            "a request 50.0 ms after an unanswered one, whose reply could not have finished before 111.5 ms: the "
            "answer delay F08.04 = 100 ms is longer than the master waits",
            pytest.approx(0.05),
            1,
        )
    ]
    assert [(r.seq, r.t) for r in delayed[0].frames] == [(7, 1.0), (8, 1.05)]


def test_a_master_that_waits_out_the_answer_delay_gets_none(master: Master) -> None:
    for register, value in ((Reg.WRITE_ENABLE, 1), (F08_04, 100), (Reg.WRITE_ENABLE, 0)):
        master.write(register, value, 0.1)
    assert master.read(Reg.STATUS1, 0.1) is not None
    assert master.line.replies[-1].delay == pytest.approx(0.1)  # the real drive answers after its delay
    for _ in range(5):
        master.read(Reg.STATUS1, 0.2)  # 200 ms apart: each reply in before the next request
    assert [f.rule for f in master.findings()] == []


def test_an_unanswered_request_without_an_answer_delay_is_not_judged_here(profile: Profile) -> None:
    auditor = Auditor(profile)
    auditor.feed_all([(1.0, "rx", READ_STATUS), (1.05, "rx", READ_STATUS), (1.06, "tx", STATUS_RUNNING)])
    assert [f.rule for f in auditor.findings()] == []  # F08.04 = 0: the drive answers after its turnaround


def test_the_answer_delay_a_master_read_back_counts(profile: Profile) -> None:
    auditor = Auditor(profile)
    read_delay = encode(ReadRequest(1, F08_04, 1))
    frames = [(0.0, "rx", read_delay), (0.012, "tx", encode(ReadResponse(1, (200,))))]  # set at the keypad
    frames += [(1.0, "rx", READ_STATUS), (1.15, "rx", READ_STATUS), (1.209, "tx", STATUS_RUNNING)]
    auditor.feed_all(frames)
    (finding,) = auditor.findings()
    assert finding.rule == "answer-delay-timeout"
    assert finding.figure.startswith(
        "a request 150.0 ms after an unanswered one, whose reply could not have finished "
        "before 211.5 ms: the answer delay F08.04 = 200 ms"
    )


def test_a_throwaway_rule_hears_the_reads_of_the_registers_it_watches_only(
    profile: Profile, monkeypatch: pytest.MonkeyPatch
) -> None:
    from c20sim.audit import rules
    from c20sim.audit.window import Window

    heard: list[tuple[int, int, tuple[int, ...], int, float]] = []

    class Throwaway(rules.Rule):
        id = "throwaway-read"

        def watches(self, register: int, count: int) -> bool:
            return register <= Reg.FAULT_CODE < register + count

        def read(self, audit: Window, slave: int, register: int, values: tuple[int, ...], seq: int, t: float) -> None:
            heard.append((slave, register, values, seq, t))

    monkeypatch.setitem(rules.RULES, Throwaway.id, Throwaway)
    auditor = Auditor(profile)
    auditor.feed_all(
        [
            (0.0, "rx", encode(ReadRequest(1, Reg.STATUS1, 1))),
            (0.01, "tx", encode(ReadResponse(1, (4,)))),
            (0.1, "rx", encode(ReadRequest(1, Reg.FAULT_CODE, 1))),
            (0.11, "tx", encode(ReadResponse(1, (FAULT,)))),
            (0.2, "rx", encode(ReadRequest(1, Reg.FAULT_CODE, 1))),
            (0.21, "tx", bytes.fromhex("01 83 02 C0 F1")),  # an exception: no values, not heard
        ]
    )
    assert heard == [(1, Reg.FAULT_CODE, (FAULT,), 4, 0.11)]
