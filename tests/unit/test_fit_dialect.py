"""The dialect probe and what fit learns from it, in virtual time (c20sim in this process): each quirk from
drives whose dialects differ, a probe that changes nothing on the drive, "not probed" where the capture did not
probe, and a quirk that grows by one row of :data:`c20sim.traffic.dialect.QUIRKS`."""

from __future__ import annotations

import dataclasses
import io
import itertools
import tomllib
from pathlib import Path

import pytest

from c20sim.core.bus import Direction
from c20sim.core.clock import VirtualClock
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import Profile, load_profile, parse_profile
from c20sim.traffic import dialect
from c20sim.traffic.capture import load_frame_log
from c20sim.traffic.dialect import Frame, Learned, Prober, Quirk, probe
from c20sim.traffic.fit import fit, load_capture
from c20sim.traffic.fitreport import summary, write_profile, write_report
from c20sim.traffic.master import Master
from c20sim.traffic.masterlinks import SimulatedLink, SimulatedTime
from c20sim.traffic.programme import simulated_capture
from c20sim.traffic.replay import replay
from c20sim.wire.errors import C20SimError
from c20sim.wire.protocol import ReadRequest, ReadResponse, WriteSingleRequest

SHIPPED = load_profile()


def _profile(**protocol: object) -> Profile:
    """The shipped profile with [protocol] keys changed, as a file (fit writes the fitted one beside its base)."""
    text = Path(SHIPPED.path).read_text()
    for key, value in protocol.items():
        old = f"{key} = {str(getattr(SHIPPED.protocol, key)).lower()}"
        assert old in text, old
        text = text.replace(old, f"{key} = {str(value).lower()}", 1)
    return parse_profile(text, SHIPPED.path)


def _probed(tmp_path: Path, truth: Profile, *, gate: int = 0, rtu: bool = True) -> Path:
    """A probe-only capture of a drive served from ``truth`` (its 200EH set to ``gate`` first, by its user)."""
    sim = Simulator(truth, [1], clock=VirtualClock())
    if gate:
        sim.slaves[1].handle(WriteSingleRequest(1, 0x200E, gate), sim.now())
    out = tmp_path / "dialect.jsonl"
    with out.open("w") as log:
        master = Master(SimulatedLink(sim), truth.registers, 1, clock=SimulatedTime(sim), log=log)
        master.header("pty" if rtu else "modbus-tcp", 19200, "8N1")
        probe(Prober(master.probe, 1, SHIPPED, rtu=rtu))
    return out


def _fit(path: Path) -> tuple[dict[str, object], list[str], Profile]:
    result = fit(load_capture(str(path), SHIPPED), SHIPPED)
    fitted = write_profile(result, path.with_suffix(".toml"), path.name)
    return tomllib.loads(path.with_suffix(".toml").read_text())["protocol"], summary(result), fitted


def _replays(path: Path, profile: Profile) -> int:
    """Replies that differ when the capture is replayed against ``profile``."""
    sim = Simulator(profile, [1], clock=VirtualClock())
    return len(replay(load_frame_log(str(path)), sim).differences)


@pytest.mark.parametrize(
    "changes",
    [
        {"reply_to_bad_crc": False, "max_read_registers": 8, "byte_count_exception": 3, "ram_only_alias": False},
        {"max_read_registers": 2},
        {"max_read_registers": 125, "byte_count_exception": 3},
        {"max_read_registers": 17, "reply_to_bad_crc": False},
    ],
)
def test_each_quirk_is_learned_exactly_and_replay_matches(tmp_path: Path, changes: dict[str, object]) -> None:
    truth = _profile(**changes)
    path = _probed(tmp_path, truth)
    protocol, words, fitted = _fit(path)
    for key in ("reply_to_bad_crc", "max_read_registers", "byte_count_exception", "ram_only_alias"):
        assert protocol[key] == getattr(truth.protocol, key), (key, words)
    assert _replays(path, fitted) == 0
    assert _replays(path, SHIPPED) > 0  # the probe tells these dialects from the shipped one


def test_the_report_says_per_quirk_value_base_written_and_frames(tmp_path: Path) -> None:
    path = _probed(tmp_path, _profile(max_read_registers=8, reply_to_bad_crc=False))
    _, words, _ = _fit(path)
    rows = {line.split()[1]: line for line in words if line.startswith("  dialect ")}
    assert list(rows) == [q.name for q in dialect.QUIRKS]
    assert rows["max_read_registers"] == (
        "  dialect max_read_registers    8            (base 1) written; a read of 8 answered, of 9 refused with "
        "0x03; lines 4-16 (7 requests)"
    )
    assert rows["reply_to_bad_crc"] == (
        "  dialect reply_to_bad_crc      false        (base true) written; silence to a bad CRC; silence to a bad "
        "length; lines 2-3"
    )
    # 200EH = 0 (as shipped): the RAM-only write answers 0x04, which does not tell whether a password is set
    assert rows["password"].startswith(
        "  dialect password              not learned  (base 0) not written: exception 0x04"
    )
    assert rows["write_enable"].startswith(
        "  dialect write_enable          present      (base -) not written: the profile"
    )
    text = path.with_suffix(".toml").read_text()
    assert 'max_read_registers = 8  # source = "capture": dialect.jsonl lines 4-16 (7 requests): a read of 8' in text


def test_password_with_the_gate_open(tmp_path: Path) -> None:
    """200EH = 1: the RAM-only write of the held value is taken where no password is set (password 0 learned),
    refused with 0x05 where one is (its value cannot be read: not learned, the base's kept)."""
    protocol, _, _ = _fit(_probed(tmp_path, SHIPPED, gate=1))
    assert protocol["password"] == 0
    locked = tmp_path / "locked"
    locked.mkdir()
    protocol, words, _ = _fit(_probed(locked, _profile(password=1234), gate=1))
    assert protocol["password"] == 0  # the base's
    assert any(
        "password              not learned  (base 0) not written: exception 0x05: a password" in w for w in words
    )


def test_the_probe_changes_nothing_on_the_drive(tmp_path: Path) -> None:
    """Every register reads the same after the probe; nothing is written to EEPROM (the state file, where every
    EEPROM write is saved, is as before); the one write the drive takes is the RAM-only write of the value the
    code held (the gate open, so that it is taken). Judged from outside the drive, so that it holds on the
    compiled core too."""
    state = tmp_path / "state.json"
    sim = Simulator(SHIPPED, [1], clock=VirtualClock(), state=state)
    slave = sim.slaves[1]
    slave.handle(WriteSingleRequest(1, 0x200E, 1), sim.now())

    def snapshot() -> dict[int, int]:
        out = {}
        for spec in SHIPPED.registers.specs():
            reply = slave.handle(ReadRequest(1, spec.address, 1), sim.now(), communicated=False)
            assert isinstance(reply, ReadResponse), spec.label
            out[spec.address] = reply.values[0]
        return out

    before = snapshot()
    saved = state.read_bytes() if state.exists() else None
    sim.bus.records.clear()
    master = Master(SimulatedLink(sim), SHIPPED.registers, 1, clock=SimulatedTime(sim), log=io.StringIO())
    probe(Prober(master.probe, 1, SHIPPED, rtu=True))
    records = list(sim.bus.records)
    taken = [
        (int.from_bytes(request.data[2:4], "big"), int.from_bytes(request.data[4:6], "big"))
        for request, reply in itertools.pairwise(records)
        if request.direction is Direction.RX
        and reply.direction is Direction.TX
        and request.data[1] in (0x06, 0x10)
        and not reply.data[1] & 0x80
    ]
    assert taken == [(0x800A, before[0x000A])]
    assert (state.read_bytes() if state.exists() else None) == saved
    assert snapshot() == before


def test_a_capture_without_the_probe_keeps_every_quirk_and_says_not_probed(tmp_path: Path) -> None:
    sim = Simulator(SHIPPED, [1], clock=VirtualClock())
    path = tmp_path / "plain.jsonl"
    with path.open("w") as log:
        simulated_capture(sim, log, speeds=(1500,), hold=2.0)
    protocol, words, _ = _fit(path)
    rows = [w for w in words if w.startswith("  dialect ")]
    assert len(rows) == len(dialect.QUIRKS)
    assert all("not learned" in row and "not written: not probed" in row for row in rows), rows
    assert "capture" not in "".join(
        line for line in path.with_suffix(".toml").read_text().splitlines() if "source =" in line
    )
    for key in ("reply_to_bad_crc", "max_read_registers", "byte_count_exception", "ram_only_alias", "password"):
        assert protocol[key] == getattr(SHIPPED.protocol, key)


def test_modbus_tcp_sends_no_bad_frame(tmp_path: Path) -> None:
    path = _probed(tmp_path, _profile(reply_to_bad_crc=False), rtu=False)
    assert not any(r.note == "dialect reply_to_bad_crc" for r in load_frame_log(str(path)))
    protocol, words, _ = _fit(path)
    assert protocol["reply_to_bad_crc"] is True  # the base's
    assert any(
        w == "  dialect reply_to_bad_crc      not learned  (base true) not written: not probed: over Modbus TCP the "
        "gateway makes the CRC and the length: a bad frame cannot be sent"
        for w in words
    )


def test_with_the_programme_the_dialect_and_the_physics_are_learned(tmp_path: Path) -> None:
    """exercise --dialect: the probe, then the programme, in one capture; replay against the fitted profile differs
    in no probe frame's reply (a physical read may differ by its last digit: the physics is fitted, not exact)."""
    truth = _profile(max_read_registers=4, byte_count_exception=3)
    sim = Simulator(truth, [1], clock=VirtualClock())
    path = tmp_path / "both.jsonl"
    with path.open("w") as log:
        simulated_capture(sim, log, speeds=(900, 1800), hold=3.0, dialect=SHIPPED)
    protocol, words, fitted = _fit(path)
    assert (protocol["max_read_registers"], protocol["byte_count_exception"]) == (4, 3)
    assert any(w.startswith("  motor.kt_nm_per_a") and "+-" in w for w in words), words
    sim = Simulator(fitted, [1], clock=VirtualClock())
    differences = replay(load_frame_log(str(path)), sim).differences
    assert not [d for d in differences if d.exchange.record.note.startswith("dialect ")]


def test_a_quirk_grows_by_one_row(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A throwaway row reaches the probe (its frame in the capture, noted), fit's report and the fitted profile's
    [protocol] table with its source, with no other edit."""

    def send(p: Prober) -> None:
        p.read("throwaway", 0x2103)

    def learned(frames: object, base: Profile) -> Learned:
        assert isinstance(frames, list) and all(isinstance(f, Frame) for f in frames)
        return Learned(150.0, f"{len(frames)} frame(s) of the throwaway row")

    row = Quirk("throwaway", "broadcast_delay_ms", send, learned, "a test's row")
    monkeypatch.setattr(dialect, "QUIRKS", (*dialect.QUIRKS, row))
    path = _probed(tmp_path, SHIPPED)
    assert [r.note for r in load_frame_log(str(path))][-2:] == ["dialect throwaway", ""]
    protocol, words, fitted = _fit(path)
    assert protocol["broadcast_delay_ms"] == 150.0
    assert fitted.protocol == dataclasses.replace(fitted.protocol, broadcast_delay_ms=150.0)
    assert any(w.startswith("  dialect throwaway") and "1 frame(s) of the throwaway row" in w for w in words)
    assert (
        'broadcast_delay_ms = 150.0  # source = "capture": dialect.jsonl line ' in path.with_suffix(".toml").read_text()
    )


def test_a_drive_that_goes_silent_ends_the_probe_in_one_line(tmp_path: Path) -> None:
    """After 20 exchanges the link carries nothing: three requests a drive answers go unanswered, and the probe
    ends saying so (not a timeout for each of its hundred requests); the frames so far are in the capture."""
    sim = Simulator(SHIPPED, [1], clock=VirtualClock())
    link = SimulatedLink(sim)
    real = link.exchange
    count = [0]

    def exchange(frame: bytes, timeout: float) -> bytes:
        count[0] += 1
        if count[0] > 20:
            sim.advance(timeout)
            return b""
        return real(frame, timeout)

    link.exchange = exchange  # type: ignore[method-assign]
    log = io.StringIO()
    master = Master(link, SHIPPED.registers, 1, clock=SimulatedTime(sim), log=log)
    with pytest.raises(C20SimError) as caught:
        probe(Prober(master.probe, 1, SHIPPED, rtu=True))
    assert str(caught.value) == (
        "the drive stopped answering during the dialect probe (registers): 3 requests in a row got no reply; "
        "the capture so far is kept"
    )
    assert count[0] == 23
    assert len(log.getvalue().splitlines()) == 23 + 20  # each request, and the 20 replies that came


def test_a_function_code_the_drive_lacks_is_dropped(tmp_path: Path) -> None:
    """The drive has no F00.03 (maximum speed): fit drops its [[parameter]] row, says so in its place, keeps the
    rest; replay against the fitted profile then matches every reply."""
    text = Path(SHIPPED.path).read_text()
    start = text.index('[[parameter]]\ncode = "F00.03"')
    end = text.index("[[parameter]]", start + 1)
    truth = parse_profile(text[:start] + text[end:], SHIPPED.path)
    assert 0x0003 not in truth.registers
    path = _probed(tmp_path, truth)
    _, words, fitted = _fit(path)
    assert 0x0003 not in fitted.registers and 0x000A in fitted.registers
    assert len(fitted.registers.parameters()) == len(SHIPPED.registers.parameters()) - 1
    row = next(w for w in words if w.startswith("  dialect registers"))
    assert "(base -) written; answer: 0000H-0002H, 000AH-000DH," in row
    assert "; the base has 0003H, which did not answer;" in row
    written = path.with_suffix(".toml").read_text()
    assert '# [[parameter]] F00.03 dropped: source = "capture": dialect.jsonl lines' in written
    assert 'code = "F00.03"' not in written and 'code = "F00.10"' in written
    assert _replays(path, fitted) == 0


@pytest.mark.parametrize(
    ("replies", "value", "why"),
    [
        ([b"\x01\x03\x04", b"\x01\x83\x03"], 2, "a read of 2 answered, of 3 refused with 0x03"),
        ([b"\x01\x83\x03"], 1, "a read of 2 refused with 0x03: one register a read"),
        ([b"\x01\x03\x04", b"\x01\x83\x01"], None, "exception 0x01 to a read of 3: it does not tell"),
        ([b"\x01\x03\x04", b""], None, "silence to a read of 3: it does not tell"),
        ([b"\x01\x03\x04", b"\x01\x83\x02", b"\x01\x83\x03"], None, "reads of 3 answered, of 5 refused"),
    ],
)
def test_the_read_limit_from_its_frames(replies: list[bytes], value: int | None, why: str) -> None:
    """What the read-limit row learns from the replies to reads of 2, 3, 5 registers (hand-made frames: a
    refusal other than 0x03, or silence, tells nothing; a gap between the counts answered and refused is named)."""
    counts = (2, 3, 5)
    frames = [
        Frame(4 + 2 * i, bytes((1, 3, 0x30, 0, 0, counts[i], 0, 0)), reply + b"\x00\x00" if reply else b"")
        for i, reply in enumerate(replies)
    ]
    learned = dialect._limit_learn(frames, SHIPPED)
    assert learned.value == value
    assert learned.why.startswith(why), learned.why


def test_an_answer_delay_hides_the_turnaround(tmp_path: Path) -> None:
    """F08.04 = 10 ms on the drive (its turnaround 2 ms): every reply comes 10 ms after its request, and a
    turnaround fitted from that would be the delay. The probe reads F08.04: fit writes it as the fitted profile's
    default, and does not write the 10 ms as the turnaround (the base's kept, the report says why)."""
    text = Path(SHIPPED.path).read_text()
    old = 'name = "answer delay"\ndefault = 0 '
    assert old in text
    truth = parse_profile(text.replace(old, 'name = "answer delay"\ndefault = 10 ', 1), SHIPPED.path)
    path = _probed(tmp_path, truth)
    capture = load_capture(str(path), SHIPPED)
    result = fit(capture, SHIPPED)
    assert result.turnaround is not None and result.turnaround.value == pytest.approx(10.0, abs=0.2)
    assert not result.turnaround.identified
    words = summary(result)
    assert any(
        w.startswith(f"  {'protocol.turnaround_ms':<34} not identifiable from this capture: 10 ms")
        and "its answer delay (10 ms, read from F08.04)" in w
        and w.endswith("; kept 2")
        for w in words
    ), words
    row = next(w for w in words if w.startswith("  dialect answer_delay"))
    assert row.startswith("  dialect answer_delay          10           (base -) written; F08.04 reads 10 ms; line ")
    fitted = write_profile(result, tmp_path / "fitted.toml", path.name)
    assert fitted.protocol.turnaround_ms == 2.0
    assert fitted.default(0x0804) == 10
    assert 'default = 10  # source = "capture": dialect.jsonl line ' in (tmp_path / "fitted.toml").read_text()
    assert _replays(path, fitted) == 0


def test_no_answer_delay_leaves_the_turnaround_fitted(tmp_path: Path) -> None:
    truth = _profile(turnaround_ms=3.5)
    result = fit(load_capture(str(_probed(tmp_path, truth)), SHIPPED), SHIPPED)
    assert result.turnaround is not None and result.turnaround.identified
    assert result.turnaround.value == pytest.approx(3.5, abs=0.2)
    fitted = write_profile(result, tmp_path / "fitted.toml", "dialect.jsonl")
    assert fitted.protocol.turnaround_ms == pytest.approx(3.5, abs=0.2) and fitted.default(0x0804) == 0


def test_the_report_file_has_the_dialect_table(tmp_path: Path) -> None:
    path = _probed(tmp_path, _profile(max_read_registers=8))
    result = fit(load_capture(str(path), SHIPPED), SHIPPED)
    written = write_report(result, tmp_path / "report", None)
    text = written[0].read_text()
    table = text[text.index("## The dialect") :].splitlines()[2:]
    rows = [line for line in table if line.startswith("| ") and not line.startswith("| quirk")][: len(dialect.QUIRKS)]
    assert [row.split(" | ")[0][2:] for row in rows] == [q.name for q in dialect.QUIRKS]
    assert rows[1] == (
        "| max_read_registers | the most one 0x03 may read | 8 | 1 | yes | a read of 8 answered, of 9 refused with "
        "0x03; lines 6-18 (7 requests) |"
    )
