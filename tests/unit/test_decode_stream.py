"""decode over a stream: frames cut by the protocol (request, then its reply), hex dumps, JSONL frame logs."""

from __future__ import annotations

import io
import itertools
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from c20sim.cli import main
from c20sim.drive.profile import load_profile
from c20sim.traffic.capture import parse_dump, parse_log
from c20sim.wire.decode import split_frames
from c20sim.wire.errors import C20SimError
from c20sim.wire.protocol import (
    ExceptionCode,
    ExceptionResponse,
    ReadRequest,
    ReadResponse,
    WriteMultipleRequest,
    WriteMultipleResponse,
    WriteSingleRequest,
    WriteSingleResponse,
    encode,
)

REGISTERS = load_profile().registers
READ = "01 03 21 00 00 01 8E 36"
READ_REPLY = "01 03 02 00 03 F8 45"
WRITE = "01 06 20 00 00 01 43 CA"


def pieces(text: str) -> list[tuple[int, str, str]]:
    return [(p.offset, p.kind, p.text) for p in split_frames(bytes.fromhex(text), REGISTERS)]


def test_a_request_and_its_reply() -> None:
    assert pieces(f"{READ} {READ_REPLY}") == [
        (0, "request", "slave 1: read 2100H (status word 1)"),
        (8, "reply", "slave 1: 2100H = 0003: stopped"),
    ]


def test_an_echo_is_the_reply_to_the_same_bytes_before_it() -> None:
    assert [k for _, k, _ in pieces(f"{WRITE} {WRITE} {WRITE} {WRITE}")] == ["request", "reply"] * 2


def test_noise_is_gathered_until_a_frame_starts() -> None:
    assert pieces(f"FF 00 {READ} {READ_REPLY} AA BB CC 01 83 02 C0 F1") == [
        (0, "noise", "2 byte(s) that start no frame"),
        (2, "request", "slave 1: read 2100H (status word 1)"),
        (10, "reply", "slave 1: 2100H = 0003: stopped"),
        (17, "noise", "3 byte(s) that start no frame"),
        (20, "exception", "slave 1: exception 0x02 to read: illegal data address"),
    ]


def test_a_request_with_no_reply_is_followed_by_the_next_request() -> None:
    broadcast = "00 06 20 01 0B B8 D5 59"
    assert [k for _, k, _ in pieces(f"{READ} {broadcast} {READ} {READ_REPLY}")] == [
        "request",
        "request",
        "request",
        "reply",
    ]


def test_a_capture_starting_with_a_reply_and_an_unknown_function() -> None:
    assert pieces(f"{READ_REPLY} 01 04 00 00 00 01 31 CA 01 84 01 82 C0") == [
        (0, "reply", "slave 1: read reply: 0003"),
        (7, "request", "slave 1: function 0x04, which the C20 does not support"),
        (15, "exception", "slave 1: exception 0x01 to function 0x04: illegal function"),
    ]


requests = st.one_of(
    st.builds(ReadRequest, st.integers(1, 247), st.integers(0, 0xFFFF), st.integers(1, 8)),
    st.builds(WriteSingleRequest, st.integers(1, 247), st.integers(0, 0xFFFF), st.integers(0, 0xFFFF)),
    st.builds(
        WriteMultipleRequest,
        st.integers(1, 247),
        st.integers(0, 0xFF00),
        st.lists(st.integers(0, 0xFFFF), min_size=1, max_size=8).map(tuple),
    ),
)


def reply_to(request: ReadRequest | WriteSingleRequest | WriteMultipleRequest, refused: int | None) -> bytes:
    if refused is not None:
        return encode(ExceptionResponse(request.slave, request.function, ExceptionCode(refused)))
    match request:
        case ReadRequest(slave, start, count):
            return encode(ReadResponse(slave, tuple((start + i) & 0xFFFF for i in range(count))))
        case WriteSingleRequest(slave, register, value):
            return encode(WriteSingleResponse(slave, register, value))
        case WriteMultipleRequest(slave, start, values):
            return encode(WriteMultipleResponse(slave, start, len(values)))
    raise AssertionError(request)


@given(st.lists(st.tuples(requests, st.one_of(st.none(), st.integers(1, 8)), st.booleans()), min_size=1, max_size=20))
def test_any_session_is_cut_back_into_its_frames(
    session: list[tuple[ReadRequest | WriteSingleRequest | WriteMultipleRequest, int | None, bool]],
) -> None:
    stream = b""
    expected: list[tuple[str, bytes]] = []
    for (request, _, answered), (following, _, _) in itertools.pairwise(session):
        # the one reading the protocol cannot tell apart: an unanswered 0x06 request sent again is an echo
        assume(answered or not isinstance(request, WriteSingleRequest) or following != request)
    for request, refused, answered in session:
        stream += encode(request)
        expected.append(("request", encode(request)))
        if answered:
            stream += reply_to(request, refused)
            expected.append(("exception" if refused else "reply", reply_to(request, refused)))
    assert [(p.kind, p.data) for p in split_frames(stream)] == expected


HEXDUMP = """\
00000000  01 03 21 00 00 01 8e 36  01 03 02 00 03 f8 45 01  |..!....6......E.|
00000010  06 20 00 00 01 43 ca 01  06 20 00 00 01 43 ca     |. ...C... ...C.|
0000001f
"""
XXD = """\
00000000: 0103 2100 0001 8e36 0103 0200 03f8 4501  ..!....6......E.
00000010: 0620 0000 0143 ca01 0620 0000 0143 ca    . ...C... ...C.
"""
STREAM = bytes.fromhex(f"{READ} {READ_REPLY} {WRITE} {WRITE}")


@pytest.mark.parametrize("text", [HEXDUMP, XXD, f"# a capture\n{READ}\n{READ_REPLY}\n{WRITE}{WRITE}\n".lower()])
def test_dumps_are_read_without_offsets_or_text(text: str) -> None:
    assert parse_dump(text) == STREAM


def test_a_bad_dump_line_is_named() -> None:
    with pytest.raises(C20SimError, match=r"^line 2: not hex bytes: 'zz'$"):
        parse_dump("01 02\nzz\n")


def run(capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, stdin: str, *argv: str) -> tuple[int, str]:
    monkeypatch.setattr(sys, "stdin", io.StringIO(stdin))
    code = main(["decode", *argv])
    out, err = capsys.readouterr()
    return code, out + err


def test_decode_reads_a_dump_on_stdin(capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    assert run(capsys, monkeypatch, HEXDUMP) == (
        0,
        "01 03 21 00 00 01 8E 36\n"
        "  request: slave 1: read 2100H (status word 1)\n"
        "01 03 02 00 03 F8 45\n"
        "  reply: slave 1: 2100H = 0003: stopped\n"
        "01 06 20 00 00 01 43 CA\n"
        "  request: slave 1: write 2000H = 0001: forward run\n"
        "01 06 20 00 00 01 43 CA\n"
        "  reply: slave 1: write 2000H = 0001: forward run\n",
    )


def test_decode_of_a_pair_in_arguments_exits_1_on_noise(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["decode", READ, READ_REPLY]) == 0
    assert capsys.readouterr().out.splitlines()[3] == "  reply: slave 1: 2100H = 0003: stopped"
    assert main(["decode", READ, "FF"]) == 1
    assert capsys.readouterr().out.splitlines()[2:] == ["FF", "  noise: 1 byte(s) that start no frame"]


def record(t: float, direction: str, hex_: str, **extra: str) -> str:
    return json.dumps({"t": t, "dir": direction, "hex": hex_, **extra})


def test_decode_reads_a_frame_log(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    log = "\n".join(
        [
            record(0.5, "rx", READ),
            record(0.502, "tx", "01 03 02 00 03 F8 45"),
            record(1.0, "rx", "01 03 21 00 00 01 8E 37", kind="crc_error"),
            record(1.5, "tx", "", kind="dropped", note="drop_next"),
        ]
    )
    expected = (
        "    0.500000 rx 01 03 21 00 00 01 8E 36\n"
        "  request: slave 1: read 2100H (status word 1)\n"
        "    0.502000 tx 01 03 02 00 03 F8 45\n"
        "  reply: slave 1: 2100H = 0003: stopped\n"
        "    1.000000 rx 01 03 21 00 00 01 8E 37\n"
        "  broken: slave 1: read 2100H (status word 1); bad CRC: got 8E 37, expected 8E 36\n"
        "    1.500000 tx\n"
        "  dropped: no bytes on the wire (drop_next)\n"
    )
    assert run(capsys, monkeypatch, log + "\n") == (1, expected)
    (tmp_path / "log.jsonl").write_text(log)
    assert run(capsys, monkeypatch, "", "--file", str(tmp_path / "log.jsonl")) == (1, expected)


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("[1]", "line 2: expected a JSON object with t, dir and hex"),
        (
            '{"t": 1, "dir": "up", "hex": ""}',
            'line 2: key \'dir\': expected "rx" (master to drive) or "tx" (drive to master)',
        ),
        (
            '{"t": -1, "dir": "rx", "hex": ""}',
            "line 2: key 't': expected the frame's time in seconds, a finite number >= 0",
        ),
        ('{"t": 1, "dir": "rx", "hex": "0g"}', "line 2: key 'hex': not hex bytes: '0g'"),
        ("{not json", "line 2: not JSON; a frame log has one JSON object a line"),
        (
            '{"t": 1, "dir": "rx", "hex": "", "modbus_tcp": {"transaction": 70000, "unit": 1}}',
            'line 2: key \'modbus_tcp\': expected {"transaction": 0-65535, "unit": 0-255}',
        ),
        (
            '{"t": 1, "dir": "rx", "hex": "", "modbus_tcp": 5}',
            'line 2: key \'modbus_tcp\': expected {"transaction": 0-65535, "unit": 0-255}',
        ),
        (
            '{"t": 1, "dir": "rx", "hex": "", "modbus_tcp": {"transaction": 1, "unit": 1}, "rtu": 3}',
            "line 2: key 'rtu': expected the RTU frame on the line in hex, or null for the gateway's own answer",
        ),
        (
            '{"t": 1, "dir": "rx", "hex": "", "modbus_tcp": {"transaction": 1, "unit": 1}, "rtu": "zz"}',
            "line 2: key 'rtu': not hex bytes: 'zz'",
        ),
    ],
)
def test_a_bad_log_line_is_named(line: str, message: str) -> None:
    with pytest.raises(C20SimError) as caught:
        parse_log([record(0, "rx", READ), line], "cap.jsonl")
    assert str(caught.value) == f"cap.jsonl: {message}"


def test_decode_with_no_input_on_a_terminal_says_what_to_give() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "c20sim", "decode", "--file", "/nonexistent/cap"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert (result.returncode, result.stdout) == (2, "")
    assert result.stderr == "c20sim: /nonexistent/cap: cannot read: No such file or directory\n"


def test_a_closed_pipe_ends_decode_quietly(tmp_path: Path) -> None:
    log = tmp_path / "big.jsonl"
    log.write_text("".join(record(i * 0.01, "rx", READ) + "\n" for i in range(200)))
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader has gone, as after `| head -1`
    try:
        result = subprocess.run(
            [sys.executable, "-m", "c20sim", "decode", "--file", str(log)],
            stdout=write_end,
            stderr=subprocess.PIPE,
            timeout=30,
            check=False,
        )
    finally:
        os.close(write_end)
    assert (result.returncode, result.stderr) == (0, b"")


def test_a_different_0x06_after_an_unanswered_one_is_the_next_request_not_its_echo() -> None:
    """Found by the property test above: two unanswered writes of one register with different values. A 0x06
    reply echoes its request byte for byte, so the second frame cannot be the first one's reply."""
    first, second = encode(WriteSingleRequest(1, 0, 0)), encode(WriteSingleRequest(1, 0, 1))
    stream = encode(ReadRequest(1, 0, 1)) + first + second
    assert [(p.kind, p.data) for p in split_frames(stream)] == [
        ("request", encode(ReadRequest(1, 0, 1))),
        ("request", first),
        ("request", second),
    ]
    echo = split_frames(first + first)
    assert [(p.kind, p.request) for p in echo] == [("request", None), ("reply", WriteSingleRequest(1, 0, 0))]


def test_a_modbus_tcp_record_without_rtu_is_read_as_the_line_frame_of_its_mbap_bytes() -> None:
    """A log made by another tool may carry the MBAP frame and its header only: the RTU frame is derived from it."""
    line = '{"t": 1, "dir": "rx", "hex": "00 07 00 00 00 06 01 03 21 00 00 01", "modbus_tcp": {"transaction": 7, "unit": 1}}'
    [found] = parse_log([line], "cap.jsonl")
    assert (found.mbap, found.line_data) == ((7, 1), bytes.fromhex("01 03 21 00 00 01 8E 36"))
