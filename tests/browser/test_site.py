"""The site in headless Chromium (Debian's), served from 127.0.0.1: what a visitor's browser does with it.

The site is built by ``c20sim site build`` from the pyodide npm package ``tools/site-deps`` installs. The page
loads with no request leaving the loopback server; every frame of the sheet's command table typed into its
terminal gets the sheet's reply byte for byte; its keys, set speed and fault change the panel exactly as the
same operations change the model in CPython; its Web Serial transport (serial.js) serves a stand-in port of
Web Serial's shape, fed frames in chunks and at gaps.
"""

from __future__ import annotations

import asyncio
import json
import os
import shutil
import subprocess
import sys
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from c20sim.browser import site
from c20sim.browser.page import start
from tests.browser.chromium import CHROMIUM, PYODIDE, Browser, serve_site
from tests.tui.test_web import read_png
from tests.unit.test_golden import ECHO, STATELESS_ROWS

pytestmark = [
    pytest.mark.serial,  # the page's stand-in port is fed in chunks; a 20 ms stall in the page ends a frame
    pytest.mark.skipif(
        CHROMIUM is None,
        reason="Debian's chromium is not installed (apt-get install chromium); .ci/run must install it",
    ),
    pytest.mark.skipif(
        not (PYODIDE / "pyodide.asm.wasm").is_file(),
        reason="the pyodide npm package is not installed: run tools/site-deps (npm ci in tools/site); .ci/run must",
    ),
]


@pytest.fixture(scope="module")
def base(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    out = tmp_path_factory.mktemp("site")
    site.build(out, str(PYODIDE))
    with serve_site(out) as url:
        yield url


async def loaded(browser: Browser, base: str) -> None:
    await browser.goto(base)
    await browser.eval("window.c20.ready.then(() => true)", timeout=120)


def run(coroutine: Any) -> Any:
    return asyncio.run(coroutine)


async def type_frame(browser: Browser, frame: str) -> dict[str, str]:
    """Type ``frame`` into the terminal, press send, and read the exchange the page shows."""
    await browser.eval("(() => { const f = document.getElementById('frame'); f.value = ''; f.focus(); })()")
    await browser.type_text(frame)
    shown: dict[str, str] = await browser.eval(
        """new Promise((resolve) => {
            const box = document.getElementById('exchanges');
            const seen = new MutationObserver(() => {
                seen.disconnect();
                const x = box.firstElementChild;
                resolve({
                    typed: document.getElementById('frame').value,
                    request: x.querySelector('.request').textContent,
                    reply: x.querySelector('.reply').textContent,
                    words: x.querySelectorAll('.words')[1].textContent,
                });
            });
            seen.observe(box, {childList: true});
            document.getElementById('send').click();
        })"""
    )
    return shown


async def set_condition(browser: Browser, name: str, value: float) -> None:
    await browser.eval(
        f"(() => {{ const i = document.querySelector('#conditions-form input[name={name}]'); i.value = '{value}';"
        " i.dispatchEvent(new Event('change')); })()"
    )


async def click(browser: Browser, selector: str) -> None:
    await browser.eval(f"document.querySelector({json.dumps(selector)}).click()")


async def choose(browser: Browser, select: str, value: str) -> None:
    await browser.eval(
        f"(() => {{ const s = document.getElementById({json.dumps(select)}); s.value = {json.dumps(value)};"
        " s.dispatchEvent(new Event('change')); })()"
    )


async def panel(browser: Browser) -> dict[str, str]:
    shown: dict[str, str] = await browser.eval(
        "Object.fromEntries(['state', 'speed', 'setspeed', 'current', 'bus', 'fault', 'time']"
        ".map((id) => [id, document.getElementById(id).textContent]))"
    )
    shown["state_class"] = await browser.eval("document.getElementById('state').className")
    return shown


def test_the_page_loads_with_no_request_leaving_localhost(base: str) -> None:
    async def scenario() -> tuple[list[str], str, list[str]]:
        async with Browser() as browser:
            await loaded(browser, base)
            text = await browser.eval("document.getElementById('status').textContent")
            return browser.requests, text, browser.console

    requests, status, console = run(scenario())
    assert status.startswith("ready (")
    assert [r for r in requests if not r.startswith(base)] == []
    names = {r.removeprefix(base) for r in requests}
    assert {"", "app.js", "serial.js", "c20sim.zip", "pyodide/pyodide.asm.wasm", "pyodide/python_stdlib.zip"} <= names
    assert [c for c in console if c.startswith("exception")] == []


def test_every_frame_of_the_sheets_table_typed_into_the_terminal(base: str) -> None:
    async def scenario() -> list[tuple[str, dict[str, str]]]:
        async with Browser() as browser:
            await loaded(browser, base)
            shown = [(request, await type_frame(browser, request)) for _, request, _ in STATELESS_ROWS]
            # the rows that need a state, reached with the page's own controls
            shown.append(("01 06 20 0E 00 01 22 09", await type_frame(browser, "01 06 20 0E 00 01 22 09")))
            shown.append(("01 06 00 0A 09 C4 AE 0B", await type_frame(browser, "01 06 00 0A 09 C4 AE 0B")))
            shown.append(("01 03 00 0A 00 01 A4 08", await type_frame(browser, "01 03 00 0A 00 01 A4 08")))
            await set_condition(browser, "supply_v", 0)
            await click(browser, "[data-advance='1']")
            await click(browser, "[data-advance='1']")
            shown.append(("01 03 21 00 00 01 8E 36", await type_frame(browser, "01 03 21 00 00 01 8E 36")))
            await click(browser, "#restart")
            await type_frame(browser, "01 06 20 01 0B B8 D4 88")
            await type_frame(browser, "01 06 20 00 00 01 43 CA")
            await click(browser, "[data-advance='1']")
            await set_condition(browser, "supply_v", 15)
            await click(browser, "[data-advance='1']")
            shown.append(("01 03 21 02 00 01 2F F6", await type_frame(browser, "01 03 21 02 00 01 2F F6")))
            shown.append(("01 03 21 00 00 01 8E 36", await type_frame(browser, "01 03 21 00 00 01 8E 36")))
            # a speed reference above F00.03: the audit's finding on the page
            await type_frame(browser, "01 06 20 01 27 10 C9 F6")
            findings.extend(
                await browser.eval("[...document.querySelectorAll('#findings li')].map((li) => li.textContent)")
            )
            return shown

    findings: list[str] = []
    shown = run(scenario())
    expected = [request if response == ECHO else response for _, request, response in STATELESS_ROWS] + [
        "01 06 20 0E 00 01 22 09",
        "01 06 00 0A 09 C4 AE 0B",
        "01 03 02 09 C4 BF 87",
        "01 03 02 00 05 78 47",
        "01 03 02 00 0A 38 43",
        "01 03 02 00 04 B9 87",
    ]
    assert [s["typed"] for _, s in shown] == [request for request, _ in shown]
    assert [s["request"] for _, s in shown] == [request for request, _ in shown]
    assert [s["reply"] for _, s in shown] == expected
    words = {request: s["words"] for request, s in shown}
    assert words["01 03 00 32 00 01 25 C5"] == "exception 0x02 to read: illegal data address"
    assert words["01 06 00 00 00 05 49 C9"] == "exception 0x03 to write: illegal data value"
    assert findings == [
        "warning speed-above-max drive 1 2001H: speed reference 2001H = 10000 rpm above the maximum speed F00.03 = "
        "3000 rpm. Keep 2001H within F00.03 (3000 rpm): the drive limits it or refuses it (0x03). "
        "[sheet 2001H; profile F00.03]"
    ]


async def _model_panel() -> list[dict[str, Any]]:
    """The same operations on the same module in CPython: what the panel must show after each step."""
    page = start()
    out = []

    def shot() -> None:
        d = json.loads(page.state())["drive"]
        out.append(d)

    page.call("set_run_channel", "{}", '{"channel": "keypad"}')
    page.call("write_register", '{"register": "2001H"}', '{"value": 1500}')
    page.call("press_key", "{}", '{"key": "forward"}')
    page.advance(0.1, 2)
    shot()
    page.advance(1, 20)
    shot()
    page.call("fault", "{}", '{"cause": "undervoltage"}')
    page.advance(1, 20)
    shot()
    read = json.loads(await page.terminal("01 03 30 06 00 01 6B 0B"))
    out[-1]["read_speed"] = read["exchanges"][0]["reply"]
    page.close()
    return out


def expected_panel(d: dict[str, Any]) -> dict[str, str]:
    fault = f"0x{d['fault_code']:02X} {d['fault_name']}" if d["fault_code"] else "none"
    return {
        "state": d["state"],
        "speed": f"{d['speed_rpm']:.0f}",
        "setspeed": f"{d['set_speed_rpm']:.0f}",
        "current": f"{d['current_a']:.2f}",
        "bus": f"{d['bus_v']:.1f}",
        "fault": fault,
        "time": f"{d['t']:.2f}",
    }


def test_keys_set_speed_and_fault_change_the_panel_as_the_model_says(base: str, tmp_path: Path) -> None:
    async def scenario() -> list[dict[str, str]]:
        async with Browser() as browser:
            await loaded(browser, base)
            seen = [await panel(browser)]
            await choose(browser, "channel", "keypad")
            await browser.eval("document.getElementById('speed-input').value = '1500'")
            await click(browser, "#speed-form button[type=submit]")
            await click(browser, "[data-key='forward']")
            await click(browser, "[data-advance='0.1']")
            seen.append(await panel(browser))
            await click(browser, "[data-advance='1']")
            seen.append(await panel(browser))
            await choose(browser, "cause", "undervoltage")
            await click(browser, "#fault-form button[type=submit]")
            await click(browser, "[data-advance='1']")
            seen.append(await panel(browser))
            supply = await browser.eval("document.querySelector('#conditions-form input[name=supply_v]').value")
            seen[-1]["supply_input"] = supply
            read = await type_frame(browser, "01 03 30 06 00 01 6B 0B")  # the terminal and the frame log, shown
            seen[-1]["read_speed"] = read["reply"]
            await browser.screenshot(tmp_path / "page.png")
            return seen

    seen = run(scenario())
    model = run(_model_panel())
    assert seen[0]["state"] == "stopped" and seen[0]["speed"] == "0"
    for shown, d in zip(seen[1:], model, strict=True):
        assert {k: v for k, v in shown.items() if k in expected_panel(d)} == expected_panel(d)
    assert model[1]["state"] == "forward" and round(model[1]["speed_rpm"]) == 1500  # it ran, and the panel said so
    assert seen[2]["state_class"] == "value state running"
    assert model[2]["fault_code"] == 0x0A and seen[3]["state_class"] == "value state fault"
    # the cause brought about shows in the conditions: the supply sagged, as the model's conditions say
    assert float(seen[3]["supply_input"]) == round(model[2]["conditions"]["supply_v"], 4) < 48
    assert seen[3]["read_speed"] == model[2]["read_speed"]  # 3006H, read through the terminal, as in CPython
    # the screenshot shows the fault's red state badge and the plot's speed (blue) and current (orange) lines
    width, _height, pixels = read_png((tmp_path / "page.png").read_bytes())
    assert width == 1400
    red = sum(1 for r, g, b in pixels if r > 170 and g < 80 and b < 70)
    blue = sum(1 for r, g, b in pixels if b > 180 and r < 60 and 90 < g < 130)
    orange = sum(1 for r, g, b in pixels if r > 200 and 110 < g < 150 and b < 70)
    assert red > 200 and blue > 200 and orange > 100, (red, blue, orange)


STAND_IN = """
class StandInPort {
  // Web Serial's SerialPort as serial.js uses it: open(options), readable, writable, close().
  constructor() { this.opened = []; this.written = []; this.closes = 0; this.readable = null; this.writable = null; }
  async open(options) {
    this.opened.push(options);
    this.readable = new ReadableStream({ start: (c) => { this.ctrl = c; } });
    this.writable = new WritableStream({ write: (chunk) => {
      this.written.push({ t: performance.now(), hex: Array.from(chunk, (b) => b.toString(16).padStart(2, '0')).join(' ').toUpperCase() });
    } });
  }
  async close() { this.closes += 1; }
  push(hex) { this.ctrl.enqueue(Uint8Array.from(hex.split(' ').map((h) => parseInt(h, 16)))); this.pushed = performance.now(); }
}
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
async function settle() { for (let i = 0; i < 50; i++) await Promise.resolve(); }
async function until(test, ms = 20000) {
  const end = performance.now() + ms;
  while (!test()) { if (performance.now() > end) throw new Error('timed out'); await sleep(1); }
}
"""


def test_the_web_serial_transport_serves_a_stand_in_port(base: str) -> None:
    rows = [[request, request if response == ECHO else response] for _, request, response in STATELESS_ROWS]

    async def scenario() -> dict[str, Any]:
        async with Browser() as browser:
            await loaded(browser, base)
            answer: dict[str, Any] = await browser.eval(
                STAND_IN
                + f"""(async () => {{
  const rows = {json.dumps(rows)};
  const port = new StandInPort();
  const served = await c20.useSerial(port);
  const replies = [], latencies = [];
  try {{
  for (const [request] of rows) {{
    const bytes = request.split(' ');
    const before = port.written.length;
    // three reads, as a USB adapter's packets cut a frame; between them the reader takes each (microtasks: a
    // timer here would let other work of the page in, and a stall of 20 ms is silence that ends a frame)
    port.push(bytes.slice(0, 1).join(' ')); await settle();
    port.push(bytes.slice(1, 5).join(' ')); await settle();
    port.push(bytes.slice(5).join(' '));
    await until(() => port.written.length > before);
    replies.push(port.written[before].hex);
    latencies.push(port.written[before].t - port.pushed);
  }}
  // a frame broken by 60 ms of silence (more than the 20 ms that end a frame read without line timing)
  const before = port.written.length;
  port.push('01 06 21'); await sleep(60);
  port.push('00 00 01 8E 36'); await sleep(60);
  port.push('01 03 21 03 00 01 7E 36');
  await until(() => port.written.length > before);
  const afterGap = port.written.slice(before).map((w) => w.hex);
  // 2009H = 3 (W/R*: once the drive has stopped, ten seconds of model time on): the echo at 19200, then the
  // port opened again at 9600
  document.querySelector("[data-advance='10']").click();
  port.push('01 06 20 09 00 03 12 09');
  await until(() => port.opened.length === 2);
  const baudEcho = port.written[port.written.length - 1].hex;
  port.push('01 03 21 03 00 01 7E 36');
  await until(() => port.written.length === rows.length + 3);
  const after9600 = port.written[port.written.length - 1].hex;
  const frames = document.querySelectorAll('#frames tr').length;
  await served.close();
  return {{ replies, latencies, afterGap, baudEcho, opened: port.opened, after9600, closes: port.closes,
            stats: served.stats, frames }};
  }} catch (err) {{
    return {{ error: String(err), replies, log: JSON.parse(c20.page().frames(0, 100)).map((f) => `${{f.t}} ${{f.dir}} ${{f.hex}} ${{f.note}}`),
              written: port.written, stats: served.stats }};
  }}
}})()""",
                timeout=60,
            )
            return answer

    got = run(scenario())
    assert "error" not in got, json.dumps(got, indent=1)
    assert got["replies"] == [reply for _, reply in rows]
    assert got["afterGap"] == ["01 03 02 00 20 B9 9C"]  # the broken pieces got no answer, the next frame did
    assert got["baudEcho"] == "01 06 20 09 00 03 12 09"
    assert [o["baudRate"] for o in got["opened"]] == [19200, 9600]
    assert {(o["dataBits"], o["parity"], o["stopBits"]) for o in got["opened"]} == {(8, "none", 1)}
    assert got["after9600"] == "01 03 02 00 20 B9 9C"
    assert got["closes"] == 2  # once for the baud change, once at the end
    assert got["stats"]["replies"] == len(rows) + 3
    assert got["stats"]["chunks"] == 3 * len(rows) + 5  # each frame of the table in three reads
    assert got["frames"] >= 2 * len(rows)  # the page's frame log shows the serial port's frames
    assert all(0 <= latency < 1000 for latency in got["latencies"]), got["latencies"]


DROP = """(async () => {
  const data = new DataTransfer();
  data.items.add(new File([%s], %s, { type: 'application/toml' }));
  document.dispatchEvent(new DragEvent('drop', { dataTransfer: data, bubbles: true, cancelable: true }));
  await new Promise((r) => setTimeout(r, 0));
  for (let i = 0; i < 200; i++) { await new Promise((r) => setTimeout(r, 10)); if (document.getElementById('profile-note').textContent.includes(%s)) break; }
  return { note: document.getElementById('profile-note').textContent, cls: document.getElementById('profile-note').className,
           bus: document.getElementById('bus').textContent };
})()"""


def test_a_dropped_profile_and_the_real_time_clock(base: str) -> None:
    text = (Path(__file__).resolve().parents[2] / "profiles" / "c20-2200hv.toml").read_text()

    async def scenario() -> tuple[dict[str, str], dict[str, str], list[float]]:
        async with Browser() as browser:
            await loaded(browser, base)
            good = await browser.eval(DROP % (json.dumps(text), json.dumps("mine.toml"), json.dumps("mine.toml")))
            bad = await browser.eval(
                DROP % (json.dumps("[drive]\nnonsense = 1\n"), json.dumps("bad.toml"), json.dumps("bad.toml"))
            )
            await choose(browser, "clock", "realtime")
            times = []
            for _ in range(300):  # the panel's clock, refreshed ten times a second, until it has run half a second
                times.append(float(await browser.eval("document.getElementById('time').textContent")))
                if times[-1] >= 0.5:
                    break
                await asyncio.sleep(0.02)
            return good, bad, times

    good, bad, times = run(scenario())
    model = json.loads(start(text=text, filename="mine.toml").state())["drive"]
    assert good == {"note": "mine.toml (c20-2200hv)", "cls": "", "bus": f"{model['bus_v']:.1f}"}
    assert bad["note"] == (
        "bad.toml: drive: unknown key; allowed: name, description, software_version, protocol, motor, supply, "
        "protection, thermal, control, fault, parameter, behaviours"
    )
    assert bad["cls"] == "error" and bad["bus"] == good["bus"]  # the dropped drive stays
    assert times[-1] >= 0.5 and times == sorted(times)


RELAY_PORT = """(async () => {
  // a stand-in port whose bytes cross to the test (and from it to a pty): writes call the binding c20relay
  class RelayPort {
    async open(options) {
      this.options = options;
      this.readable = new ReadableStream({ start: (c) => { this.ctrl = c; } });
      this.writable = new WritableStream({ write: (chunk) => {
        window.c20relay(Array.from(chunk, (b) => b.toString(16).padStart(2, '0')).join(''));
      } });
    }
    async close() {}
    push(hex) { this.ctrl.enqueue(Uint8Array.from(hex.match(/../g).map((h) => parseInt(h, 16)))); }
  }
  window.relayPort = new RelayPort();
  await c20.useSerial(window.relayPort);
  return window.relayPort.options.baudRate;
})()"""


async def mbpoll(*argv: str) -> str:
    tool = shutil.which("mbpoll")
    assert tool is not None
    proc = await asyncio.create_subprocess_exec(
        tool, *argv, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT
    )
    out, _ = await asyncio.wait_for(proc.communicate(), 60)
    assert proc.returncode == 0, out.decode()
    return out.decode()


@pytest.mark.skipif(
    shutil.which("mbpoll") is None or shutil.which("socat") is None,
    reason="mbpoll or socat is not installed (apt-get install mbpoll socat); .ci/run installs them",
)
def test_mbpoll_on_a_serial_line_answered_by_the_page(base: str, tmp_path: Path) -> None:
    """An independent master (Debian's mbpoll) on one end of a socat pty pair, as on a second USB-RS485 adapter;
    the other end's bytes relayed to and from the page's Web Serial transport (a stand-in port, as no real
    adapter is here): the master's frames reach the page in whatever pieces the pty and the relay make."""
    drive_end, master_end = tmp_path / "drive", tmp_path / "master"
    socat = subprocess.Popen(
        ["socat", f"pty,raw,echo=0,link={drive_end}", f"pty,raw,echo=0,link={master_end}"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )

    async def scenario() -> tuple[int, list[str], dict[str, Any]]:
        async with Browser() as browser:
            await loaded(browser, base)
            calls = browser.listen("Runtime.bindingCalled")
            await browser.send("Runtime.addBinding", {"name": "c20relay"})
            baud = await browser.eval(RELAY_PORT)
            for _ in range(500):
                if drive_end.exists() and master_end.exists():
                    break
                await asyncio.sleep(0.01)
            fd = os.open(drive_end, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
            loop = asyncio.get_running_loop()
            inbound: asyncio.Queue[bytes] = asyncio.Queue()
            loop.add_reader(fd, lambda: inbound.put_nowait(os.read(fd, 4096)))

            async def to_page() -> None:
                while True:
                    data = await inbound.get()
                    await browser.eval(f"window.relayPort.push('{data.hex()}')")

            async def to_master() -> None:
                while True:
                    call = await calls.get()
                    os.write(fd, bytes.fromhex(call["payload"]))

            relays = [asyncio.create_task(to_page()), asyncio.create_task(to_master())]
            try:
                line = ["-m", "rtu", "-b", str(baud), "-P", "none", "-a", "1", "-0", "-o", "2"]
                outputs = [
                    await mbpoll(*line, "-r", str(0x2001), str(master_end), "1500"),
                    await mbpoll(*line, "-r", str(0x2000), str(master_end), "1"),
                    await mbpoll(*line, "-t", "4:hex", "-r", str(0x2103), "-c", "1", "-1", str(master_end)),
                ]
                await click(browser, "[data-advance='1']")
                outputs.append(await mbpoll(*line, "-t", "4", "-r", str(0x3006), "-c", "1", "-1", str(master_end)))
                shown = await panel(browser)
            finally:
                for task in relays:
                    task.cancel()
                loop.remove_reader(fd)
                os.close(fd)
            return baud, outputs, shown

    try:
        baud, outputs, shown = run(scenario())
    finally:
        socat.terminate()
        socat.wait(10)
    assert baud == 19200
    assert "Written 1 references." in outputs[0] and "Written 1 references." in outputs[1], outputs
    assert f"[{0x2103}]: \t0x0020" in outputs[2], outputs[2]
    assert f"[{0x3006}]: \t{shown['speed']}" in outputs[3], (outputs[3], shown)
    assert shown["state"] == "forward" and shown["speed"] == "1500"


def test_site_build_writes_the_site_and_says_how_to_serve_it(tmp_path: Path) -> None:
    out = tmp_path / "site"
    result = subprocess.run(
        [sys.executable, "-m", "c20sim", "site", "build", str(out), "--pyodide", str(PYODIDE)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    manifest = json.loads((out / "build.json").read_text())
    assert result.stdout == (
        f"c20sim site: {out}: {manifest['bytes'] / 1e6:.1f} MB (pyodide {manifest['pyodide']}); serve it as static "
        f"files, such as: python3 -m http.server -d {out} 8000\n"
    )
    assert manifest["pyodide"] == json.loads((PYODIDE / "package.json").read_text())["version"]
    assert set(manifest["files"]) == {
        "index.html",
        "app.js",
        "serial.js",
        "style.css",
        "c20sim.zip",
        *(f"pyodide/{name}" for name in site.PYODIDE_FILES),
    }
    assert manifest["bytes"] == sum(p.stat().st_size for p in out.rglob("*") if p.is_file() and p.name != "build.json")
    inside, _ = site.modules()
    with zipfile.ZipFile(out / "c20sim.zip") as zf:
        modules = {n for n in zf.namelist() if n.endswith(".py") and n.startswith("c20sim/")}
    assert len(modules) == len(inside)
    # built again over itself: the same files
    again = subprocess.run(
        [sys.executable, "-m", "c20sim", "site", "build", str(out), "--pyodide", str(PYODIDE)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert again.returncode == 0 and json.loads((out / "build.json").read_text())["files"] == manifest["files"]
