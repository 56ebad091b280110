"""The sniffer's framing: each direction cut by the protocol, broken bytes ended by silence, one JSON line each."""

from __future__ import annotations

import asyncio
import io
import json

from c20sim.drive.profile import load_profile
from c20sim.traffic.record import Recorder


async def wait_for_lines(out: io.StringIO, count: int, deadline: float = 5.0) -> list[dict[str, object]]:
    loop = asyncio.get_running_loop()
    end = loop.time() + deadline
    while len(out.getvalue().splitlines()) < count:
        assert loop.time() < end, f"only {out.getvalue().splitlines()} in time"
        await asyncio.sleep(0.005)
    return [json.loads(line) for line in out.getvalue().splitlines()]


async def test_frames_split_across_chunks_and_noise_ended_by_silence() -> None:
    out = io.StringIO()
    recorder = Recorder(out, load_profile().registers, 19200)
    recorder.start()
    recorder.heard("rx", bytes.fromhex("01 03 21 00"))
    recorder.heard("rx", bytes.fromhex("00 01 8E 36"))  # the rest of the request: complete on its length
    recorder.heard("tx", bytes.fromhex("01 03 02 00 03 F8 45"))
    recorder.heard("rx", bytes.fromhex("FF 00"))  # bytes that start no frame: ended by silence
    records = await wait_for_lines(out, 3)
    assert [(r["dir"], r["hex"], r["kind"], r["text"]) for r in records] == [
        ("rx", "01 03 21 00 00 01 8E 36", "request", "read 2100H (status word 1)"),
        ("tx", "01 03 02 00 03 F8 45", "reply", "2100H = 0003: stopped"),
        ("rx", "FF 00", "noise", "2 byte(s): too short for a frame (address, function, CRC)"),
    ]
    assert all(r["model_t"] is None and isinstance(r["t"], float) for r in records)
    assert recorder.records == 3


async def test_the_log_stops_at_max_records() -> None:
    out = io.StringIO()
    recorder = Recorder(out, load_profile().registers, 19200, max_records=1)
    recorder.start()
    recorder.heard("rx", bytes.fromhex("01 03 21 00 00 01 8E 36"))
    recorder.heard("tx", bytes.fromhex("01 03 02 00 03 F8 45"))
    recorder.flush()
    assert (recorder.records, recorder.full, len(out.getvalue().splitlines())) == (1, True, 1)
