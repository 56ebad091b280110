"""The page's Python in CPython: the same module the site runs in Pyodide (c20sim.browser.page), its terminal
against the sheet's command table, its operations through the route table, its serial endpoint fed bytes in
chunks and at gaps; and ``c20sim site build``'s zip, imported alone by an interpreter that has nothing else."""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
import zipfile
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

from c20sim.browser import site
from c20sim.browser.page import SHEET_FRAMES, Page, SerialServe, parse_hex, start
from c20sim.wire.errors import C20SimError
from tests.unit.test_golden import ECHO, STATELESS_ROWS

# its serial endpoint is fed in chunks ms apart, and a 20 ms stall ends a frame: .ci/run runs it alone
pytestmark = pytest.mark.serial

ROOT = Path(__file__).resolve().parents[2]


def answer(text: str) -> dict[str, Any]:
    data: dict[str, Any] = json.loads(text)
    return data


@pytest.fixture
async def page() -> AsyncIterator[Page]:
    found = start()
    yield found
    found.close()


async def reply(page: Page, frame: str) -> str | None:
    exchanges = answer(await page.terminal(frame))["exchanges"]
    assert len(exchanges) == 1, exchanges
    result: str | None = exchanges[0]["reply"]
    return result


@pytest.mark.parametrize(
    ("operation", "request_hex", "response_hex"), STATELESS_ROWS, ids=[r[0] for r in STATELESS_ROWS]
)
async def test_the_terminal_answers_each_row_of_the_sheets_table(
    page: Page, operation: str, request_hex: str, response_hex: str
) -> None:
    assert await reply(page, request_hex) == (request_hex if response_hex == ECHO else response_hex)


async def test_the_stateful_rows_reached_through_the_pages_operations(page: Page) -> None:
    # write F00.10 after 200EH = 1
    assert await reply(page, "01 06 00 0A 09 C4 AE 0B") == "01 86 04 43 A3"
    assert await reply(page, "01 06 20 0E 00 01 22 09") == "01 06 20 0E 00 01 22 09"
    assert await reply(page, "01 06 00 0A 09 C4 AE 0B") == "01 06 00 0A 09 C4 AE 0B"
    # the supply off, the bus bled down: status word 1 reads 5
    assert "error" not in answer(page.call("set_conditions", "{}", '{"supply_v": 0}'))
    assert len(answer(page.advance(2.0, 10))["samples"]) == 10
    assert await reply(page, "01 03 21 00 00 01 8E 36") == "01 03 02 00 05 78 47"


async def test_an_undervoltage_trip_reads_as_the_sheet_says(page: Page) -> None:
    assert await reply(page, "01 06 20 01 0B B8 D4 88") == "01 06 20 01 0B B8 D4 88"
    assert await reply(page, "01 06 20 00 00 01 43 CA") == "01 06 20 00 00 01 43 CA"
    page.advance(1.0)
    page.call("set_conditions", "{}", '{"supply_v": 15}')
    page.advance(1.0)
    assert await reply(page, "01 03 21 02 00 01 2F F6") == "01 03 02 00 0A 38 43"
    assert await reply(page, "01 03 21 00 00 01 8E 36") == "01 03 02 00 04 B9 87"
    state = answer(page.state())["drive"]
    assert (state["fault_code"], state["fault_name"]) == (0x0A, "UV: bus undervoltage")


async def test_the_terminal_says_what_each_frame_means(page: Page) -> None:
    read = answer(await page.terminal("01 03 00 32 00 01 25 C5"))["exchanges"][0]
    assert read["reply"] == "01 83 02 C0 F1"
    assert read["exception"] is True
    assert read["reply_text"] == "exception 0x02 to read: illegal data address"
    assert read["request_text"].startswith("slave 1: read F00.50")
    crc = answer(await page.terminal("01 03 21 03 00 01", add_crc=True))["exchanges"][0]
    assert (crc["request"], crc["reply"]) == ("01 03 21 03 00 01 7E 36", "01 03 02 00 20 B9 9C")
    assert crc["reply_text"].startswith("2103H")
    bad = answer(await page.terminal("01 06 20 0E 00 01 E3 C9"))["exchanges"][0]
    assert (
        bad["request_text"]
        == "slave 1: write 200EH = 0001: function codes writable; bad CRC: got E3 C9, expected 22 09"
    )
    assert (bad["reply"], bad["reply_text"]) == ("01 86 06 C2 62", "exception 0x06 to write: data frame error")
    two = answer(await page.terminal("01 03 21 03 00 01 7E 36 01 03 21 01 00 01 DF F6"))["exchanges"]
    assert [x["reply"] for x in two] == ["01 03 02 00 20 B9 9C", "01 03 02 00 41 78 74"]


@pytest.mark.parametrize(
    ("text", "error"),
    [
        ("", "no bytes: type a frame in hex"),
        ("01 0G", "'G' is not a hex digit"),
        ("01 0", "an odd number of hex digits (3)"),
        ("00" * 257, "257 bytes: an RTU frame has at most 256"),
    ],
)
def test_a_bad_frame_typed_is_one_line(text: str, error: str) -> None:
    with pytest.raises(C20SimError) as caught:
        parse_hex(text)
    assert str(caught.value).startswith(error)


async def test_a_bad_frame_typed_comes_back_as_an_error(page: Page) -> None:
    assert answer(await page.terminal("zz")) == {
        "error": "'z' is not a hex digit: type bytes such as 01 03 21 00 00 01 8E 36"
    }


def test_the_pick_list_is_the_sheets_frames() -> None:
    frames = {frame for _, frame in SHEET_FRAMES}
    assert {row[1] for row in STATELESS_ROWS} <= frames


async def test_operations_are_the_route_tables_rows(page: Page) -> None:
    assert "unknown operation 'nope'" in answer(page.call("nope"))["error"]
    assert answer(page.call("press_key", "{}", '{"key": "sideways"}'))["error"].startswith("unknown key 'sideways'")
    refused = answer(page.call("write_register", '{"register": "2103H"}', '{"value": 1}'))
    assert "error" in refused and refused["status"] == 409
    assert answer(page.call("write_register", '{"register": "2001H"}', '{"value": 1500}'))["value"] == 1500
    refused_key = answer(page.call("press_key", "{}", '{"key": "forward"}'))
    assert refused_key["accepted"] is False  # the profile's run channel is communication: the keypad cannot run
    assert answer(page.call("set_run_channel", "{}", '{"channel": "keypad"}'))["channel"] == 0
    assert answer(page.call("press_key", "{}", '{"key": "forward"}'))["accepted"] is True
    page.advance(2.0)
    state = answer(page.state())["drive"]
    assert state["state"] == "forward" and round(state["speed_rpm"]) == 1500
    assert answer(page.call("fault", "{}", '{"cause": "undervoltage"}'))["note"]
    page.advance(2.0)
    assert answer(page.state())["drive"]["fault_code"] == 0x0A


def test_a_users_profile_is_checked_in_one_line() -> None:
    with pytest.raises(C20SimError) as caught:
        start(text="[drive]\nnonsense = 1\n", filename="mine.toml")
    assert str(caught.value).startswith("mine.toml:")
    assert "\n" not in str(caught.value)
    text = (ROOT / "profiles" / "c20-2200hv.toml").read_text()
    chosen = start(text=text, filename="copy.toml")
    assert answer(chosen.info())["source"] == "copy.toml"
    assert answer(chosen.info())["profile"] == "c20-2200hv"
    with pytest.raises(C20SimError, match="unknown clock 'sundial'"):
        start(clock="sundial")


class Port:
    """The JavaScript side of a Web Serial port, as serial.js is to SerialServe: what was written, reopened."""

    def __init__(self) -> None:
        self.written: list[bytes] = []
        self.reopened: list[int] = []
        self.pauses = 0
        self.replied = asyncio.Event()

    def write(self, text: str) -> None:
        self.written.append(bytes.fromhex(text))
        self.replied.set()

    def reopen(self, baud: int) -> None:
        self.reopened.append(baud)

    def pause(self) -> None:
        self.pauses += 1

    def resume(self) -> None:
        pass

    async def next_reply(self, timeout: float = 2.0) -> bytes:
        await asyncio.wait_for(self.replied.wait(), timeout)
        self.replied.clear()
        return self.written[-1]


async def serial(page: Page) -> tuple[SerialServe, Port]:
    port = Port()
    served = await page.open_serial(port.write, port.reopen, port.pause, port.resume)
    return served, port


async def test_the_serial_endpoint_answers_a_frame_fed_in_chunks(page: Page) -> None:
    served, port = await serial(page)
    for _operation, request, response in STATELESS_ROWS:
        data = bytes.fromhex(request)
        for chunk in (data[:1], data[1:5], data[5:]):  # as USB reads cut it
            served.feed(chunk.hex())
            await asyncio.sleep(0.002)
        expected = data if response == ECHO else bytes.fromhex(response)
        assert await port.next_reply() == expected
    assert served.state()["received"] == sum(len(bytes.fromhex(r[1])) for r in STATELESS_ROWS)
    # a master that waits for each reply is never paused: the endpoint reads on until a second request is framed
    # while one is on the line (serve's endpoint, so that an early retry is seen when it came), then pauses
    assert port.pauses == 0


async def test_a_gap_inside_a_frame_breaks_it_as_serve_does(page: Page) -> None:
    served, port = await serial(page)
    served.feed("010621")  # then 60 ms of silence: more than the 20 ms that end a frame without line timing
    await asyncio.sleep(0.06)
    served.feed("0000018E36")
    await asyncio.sleep(0.06)
    served.feed("0103210300017E36")
    assert await port.next_reply() == bytes.fromhex("01 03 02 00 20 B9 9C")
    frames = answer(page.frames())
    notes = [f for f in frames if f["dir"] == "rx"]
    assert [f["hex"] for f in notes] == ["01 06 21", "00 00 01 8E 36", "01 03 21 03 00 01 7E 36"]
    assert port.written == [bytes.fromhex("01 03 02 00 20 B9 9C")]  # the two broken pieces got no answer


async def test_a_baud_change_reopens_the_port_after_its_reply(page: Page) -> None:
    served, port = await serial(page)
    served.feed("010620090003" + "1209")  # 2009H = 3: 9600 baud
    assert await port.next_reply() == bytes.fromhex("01 06 20 09 00 03 12 09")
    for _ in range(100):
        if port.reopened:
            break
        await asyncio.sleep(0.01)
    assert port.reopened == [9600]
    assert served.state()["baud"] == 9600
    assert answer(page.state())["baud"] == 9600


async def test_a_serial_format_not_offered_is_refused(page: Page) -> None:
    port = Port()
    with pytest.raises(C20SimError, match="serial format '7E1': choose one of 8N1, 8E1, 8O1, 8N2"):
        await page.open_serial(port.write, port.reopen, port.pause, port.resume, "7E1")


# --- The zip the site ships.


def test_the_zip_holds_the_pure_core_and_no_io_front_end(tmp_path: Path) -> None:
    inside, outside = site.modules()
    assert outside == ["mypy_extensions"]
    for layer in ("wire", "drive", "core", "audit"):
        assert f"c20sim.{layer}" in inside
    assert {"c20sim.control.routes", "c20sim.control.ops", "c20sim.transport.endpoint", "c20sim.transport.line"} <= set(
        inside
    )
    forbidden = [m for m in inside if m.split(".")[1:2] in (["tui"], ["serve"], ["cli"], ["traffic"], ["scenario"])]
    assert forbidden == []
    assert not [m for m in inside if m in ("c20sim.control.http", "c20sim.transport.serial", "c20sim.transport.pty")]


def test_the_zip_alone_runs_the_page(tmp_path: Path) -> None:
    out = tmp_path / "c20sim.zip"
    inside, outside = site.modules()
    names = site._zip(out, inside, outside)
    assert "c20sim/profiles/c20-400hr.toml" in names
    with zipfile.ZipFile(out) as zf:
        assert not [n for n in zf.namelist() if n.endswith((".so", ".pyc"))]
    unpacked = tmp_path / "unpacked"  # as the page unpacks it (pyodide.unpackArchive)
    with zipfile.ZipFile(out) as zf:
        zf.extractall(unpacked)
    # -I -S: no site-packages, no user site: the standard library and the zip's files only, as in Pyodide
    script = (
        "import sys, asyncio, json; sys.path.insert(0, sys.argv[1]);"
        "from c20sim.browser.page import start\n"
        "async def main():\n"
        "    p = start(); a = json.loads(await p.terminal('01 03 21 03 00 01 7E 36')); print(a['exchanges'][0]['reply'])\n"
        "    print(sorted(m for m in sys.modules if m.split('.')[0] in ('aiohttp', 'textual', 'serial', 'pymodbus')))\n"
        "asyncio.run(main())"
    )
    result = subprocess.run(
        [sys.executable, "-I", "-S", "-c", script, str(unpacked)], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines() == ["01 03 02 00 20 B9 9C", "[]"]


def test_site_build_without_pyodide_is_one_line(tmp_path: Path) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "c20sim", "site", "build", str(tmp_path / "out"), "--pyodide", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2
    assert result.stderr.startswith(f"c20sim: --pyodide {tmp_path}: not the pyodide npm package (missing pyodide.mjs")
    assert len(result.stderr.splitlines()) == 1


async def test_the_audits_findings_come_with_their_line(page: Page) -> None:
    assert answer(page.audit_report())["findings"] == []
    await page.terminal("01 06 20 01 27 10 C9 F6")  # 2001H = 10000 rpm, above F00.03
    [finding] = answer(page.audit_report())["findings"]
    assert finding["rule"] == "speed-above-max"
    assert finding["line"] == (
        "warning speed-above-max drive 1 2001H: speed reference 2001H = 10000 rpm above the maximum speed F00.03 = "
        "3000 rpm. Keep 2001H within F00.03 (3000 rpm): the drive limits it or refuses it (0x03). "
        "[sheet 2001H; profile F00.03]"
    )
