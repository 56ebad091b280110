"""``c20sim web``: the dashboard in a browser. The page's WebSocket is read as a browser would read it (aiohttp's
client), and, where Debian's chromium is installed, headless Chromium takes a screenshot of the running drive."""

from __future__ import annotations

import asyncio
import base64
import json
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import aiohttp
import pytest
from pymodbus import FramerType
from pymodbus.client import ModbusTcpClient

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


class Web:
    def __init__(self, proc: subprocess.Popen[str], page: str, control: str) -> None:
        self.proc, self.page, self.control = proc, page, control

    @property
    def base(self) -> str:
        return self.page.split("?")[0].rstrip("/")


def start_web(*options: str) -> Iterator[Web]:
    argv = [sys.executable, "-m", "c20sim", "web", "--tcp", "127.0.0.1:0", "--clock", "virtual", *options]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()  # the ready line, or nothing if it failed
        found = re.match(r"c20sim web ready: (\S+) \(attached to (\S+)\)", line)
        assert found, f"no ready line: {line!r}; stderr: {proc.stderr.read() if proc.stderr else ''}"
        yield Web(proc, found.group(1).replace("0.0.0.0", "127.0.0.1"), found.group(2))
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


@pytest.fixture
def web() -> Iterator[Web]:
    yield from start_web("--web", "127.0.0.1:0")


def get_json(url: str) -> dict[str, Any]:
    """A blocking GET (the test's loop is not needed for it)."""
    with urllib.request.urlopen(url, timeout=5) as response:
        data: dict[str, Any] = json.loads(response.read())
    return data


def tcp_port(control: str) -> int:
    """The RTU-over-TCP port of the serve the page is attached to, as its control API says."""
    return int(get_json(f"{control}/")["endpoints"]["tcp"].rsplit(":", 1)[1])


async def screen_until(ws: aiohttp.ClientWebSocketResponse, text: str, timeout: float = 20.0) -> str:
    """What the page's terminal received until ``text`` is in it (the app's output, as xterm.js gets it)."""
    received = ""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while text not in received:
        left = deadline - loop.time()
        assert left > 0, f"{text!r} never came to the page; the last of it: {received[-400:]!r}"
        message = await ws.receive(timeout=left)
        assert message.type in (aiohttp.WSMsgType.BINARY, aiohttp.WSMsgType.TEXT), message
        received += message.data.decode(errors="replace") if isinstance(message.data, bytes) else message.data
    return received


async def test_the_page_runs_a_dashboard_attached_to_the_serve(web: Web) -> None:
    async with aiohttp.ClientSession() as session:
        async with session.get(web.page) as response:
            assert response.status == 200
            assert "/ws" in await response.text()
        async with session.ws_connect(f"{web.base}/ws?width=100&height=30") as ws:
            await screen_until(ws, "STOPPED")
            port = tcp_port(web.control)
            client = ModbusTcpClient("127.0.0.1", port=port, framer=FramerType.RTU, timeout=2, retries=0)
            assert client.connect()
            try:
                assert not client.write_register(0x2001, 1500, device_id=1).isError()
                assert not client.write_register(0x2000, 1, device_id=1).isError()
                await ws.send_str(json.dumps(["stdin", "t"]))  # a key from the browser: +1 s of virtual time
                await screen_until(ws, "FORWARD RUNNING")
                # only the browser's key moves the virtual clock: the motor at speed is the key taken
                deadline = asyncio.get_running_loop().time() + 20
                while client.read_holding_registers(0x3006, count=1, device_id=1).registers != [1500]:
                    assert asyncio.get_running_loop().time() < deadline, "the key from the browser was not taken"
                    await asyncio.sleep(0.05)
            finally:
                client.close()
    web.proc.send_signal(signal.SIGTERM)
    assert web.proc.wait(20) == 0
    with socket.socket() as probe:  # the serve it started is stopped with it
        assert probe.connect_ex(("127.0.0.1", port)) != 0


async def test_beyond_loopback_the_page_needs_its_token() -> None:
    for web in start_web("--web", "0.0.0.0:0"):
        token = web.page.split("?token=")[1]
        assert len(token) >= 32
        jar = aiohttp.CookieJar(unsafe=True)  # cookies for an IP address, as a browser keeps them
        async with aiohttp.ClientSession(cookie_jar=jar) as session:
            async with session.get(web.base + "/") as response:
                assert response.status == 401
            async with session.get(web.base + "/?token=wrong") as response:
                assert response.status == 401
            async with session.get(web.page) as response:
                assert response.status == 200
            async with session.ws_connect(f"{web.base}/ws?width=100&height=30") as ws:  # the cookie carries it
                await screen_until(ws, "STOPPED")


def test_a_busy_web_port_is_one_line_and_exit_2() -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        result = subprocess.run(
            [sys.executable, "-m", "c20sim", "web", "--tcp", "127.0.0.1:0", "--web", f"127.0.0.1:{port}"],
            capture_output=True,
            text=True,
            timeout=60,
        )
    assert result.returncode == 2, result.stderr
    assert result.stderr.startswith(f"c20sim: --web 127.0.0.1:{port}: cannot listen"), result.stderr
    assert "Traceback" not in result.stderr


@pytest.mark.skipif(
    CHROMIUM is None, reason="Debian's chromium is not installed (apt-get install chromium); .ci/run must install it"
)
def test_chromium_screenshot_shows_the_running_drive(web: Web, tmp_path: Path) -> None:
    port = tcp_port(web.control)
    client = ModbusTcpClient("127.0.0.1", port=port, framer=FramerType.RTU, timeout=2, retries=0)
    assert client.connect()
    try:
        assert not client.write_register(0x2001, 1500, device_id=1).isError()
        assert not client.write_register(0x2000, 1, device_id=1).isError()
    finally:
        client.close()
    request = urllib.request.Request(
        f"{web.control}/time/advance", data=b'{"seconds": 2}', headers={"Content-Type": "application/json"}
    )
    with urllib.request.urlopen(request, timeout=5):
        pass
    assert CHROMIUM is not None
    # The page is an app: it draws once its WebSocket is up. Chromium's DevTools protocol (on aiohttp's own
    # WebSocket client) takes screenshots until one shows the drive running, or the deadline passes.
    shot = tmp_path / "dashboard.png"
    green = asyncio.run(screenshot_until_green(web.page, tmp_path, shot))
    assert green > 1000, f"only {green} green pixels: the screenshot does not show a running drive ({shot})"


def green_pixels(png: bytes) -> int:
    width, height, pixels = read_png(png)
    assert width == 1280 and height > 600, (width, height)  # the window less the headless browser's own bars
    # the drive's state is drawn as " FORWARD RUNNING " in black on green (a stopped drive is white on blue)
    return sum(1 for r, g, b in pixels if g > 120 and g > r + 50 and g > b + 50)


async def screenshot_until_green(page: str, tmp_path: Path, shot: Path, timeout: float = 60.0) -> int:
    """Open ``page`` in headless Chromium, and screenshot it until thousands of green pixels (the running drive's
    state) show or ``timeout`` passes; the last screenshot is written to ``shot``; returns its green pixels."""
    assert CHROMIUM is not None
    profile = tmp_path / "chromium"
    browser = subprocess.Popen(
        [
            CHROMIUM,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--hide-scrollbars",
            "--window-size=1280,800",
            f"--user-data-dir={profile}",
            "--remote-debugging-port=0",
            "about:blank",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + timeout
        active = profile / "DevToolsActivePort"
        while not active.exists() or len(active.read_text().splitlines()) < 2:
            assert time.monotonic() < deadline, "Chromium never opened its DevTools port"
            await asyncio.sleep(0.1)
        port = active.read_text().splitlines()[0]
        async with aiohttp.ClientSession() as session:
            async with session.put(f"http://127.0.0.1:{port}/json/new?{page}") as answer:
                target = await answer.json(content_type=None)
            async with session.ws_connect(target["webSocketDebuggerUrl"], max_msg_size=0) as ws:
                green, n = 0, 0
                while True:
                    n += 1
                    await ws.send_json({"id": n, "method": "Page.captureScreenshot", "params": {"format": "png"}})
                    while True:
                        message = await ws.receive_json(timeout=max(1.0, deadline - time.monotonic()))
                        if message.get("id") == n:
                            break
                    png = base64.b64decode(message["result"]["data"])
                    green = green_pixels(png)
                    if green > 1000 or time.monotonic() > deadline:
                        shot.write_bytes(png)
                        return green
                    await asyncio.sleep(0.5)
    finally:
        browser.terminate()
        try:
            browser.wait(10)
        except subprocess.TimeoutExpired:
            browser.kill()
            browser.wait()


def read_png(data: bytes) -> tuple[int, int, list[tuple[int, int, int]]]:
    """Width, height and RGB pixels of an 8-bit RGB or RGBA, non-interlaced PNG (what Chromium writes)."""
    import struct
    import zlib

    assert data[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG"
    pos, idat = 8, b""
    width = height = channels = 0
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        kind, body = data[pos + 4 : pos + 8], data[pos + 8 : pos + 8 + length]
        pos += 12 + length
        if kind == b"IHDR":
            width, height, depth, colour = struct.unpack(">IIBB", body[:10])
            assert depth == 8 and colour in (2, 6), f"PNG depth {depth}, colour type {colour}"
            channels = 3 if colour == 2 else 4
        elif kind == b"IDAT":
            idat += body
    raw = zlib.decompress(idat)
    stride = width * channels
    previous = bytearray(stride)
    pixels = []
    for row in range(height):
        kind, line = raw[row * (stride + 1)], bytearray(raw[row * (stride + 1) + 1 : (row + 1) * (stride + 1)])
        for i in range(stride):
            left = line[i - channels] if i >= channels else 0
            up, corner = previous[i], previous[i - channels] if i >= channels else 0
            if kind == 1:
                line[i] = (line[i] + left) & 0xFF
            elif kind == 2:
                line[i] = (line[i] + up) & 0xFF
            elif kind == 3:
                line[i] = (line[i] + (left + up) // 2) & 0xFF
            elif kind == 4:
                p = left + up - corner
                pa, pb, pc = abs(p - left), abs(p - up), abs(p - corner)
                line[i] = (line[i] + (left if pa <= pb and pa <= pc else up if pb <= pc else corner)) & 0xFF
        pixels += [(line[i], line[i + 1], line[i + 2]) for i in range(0, stride, channels)]
        previous = line
    return width, height, pixels


def test_the_page_says_that_its_dashboard_is_starting(web: Web) -> None:
    """The first paint, before the dashboard process's first byte: what it is and that a screenshot at load
    shows only it (a plain headless screenshot does)."""
    from c20sim.tui.web import SPLASH

    with urllib.request.urlopen(web.page, timeout=20) as response:
        page = response.read().decode()
    assert f"<div>{SPLASH}</div>" in page
    assert SPLASH == (
        "c20sim: the dashboard of this page is starting (a second or two). A screenshot taken as the page loads shows "
        "only this: take it once the dashboard shows (docs/dashboard.md)."
    )
