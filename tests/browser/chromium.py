"""Headless Chromium (Debian's) driven over its DevTools protocol, and the site served from loopback.

No driver library: the protocol is JSON over a WebSocket, spoken with aiohttp's client (a dependency of
c20sim). :class:`Browser` starts ``chromium --headless`` on a fresh profile with every background service
off, opens one page, records every request the page makes (``Network.requestWillBeSent``), and evaluates
JavaScript in it. :func:`serve_site` serves a built site on 127.0.0.1, port 0, from a thread. The tests and
``bench/bench_browser.py`` share both.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import functools
import http.server
import json
import shutil
import subprocess
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import aiohttp

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
ROOT = Path(__file__).resolve().parents[2]
PYODIDE = ROOT / "tools" / "site" / "node_modules" / "pyodide"

#: Chromium's switches: headless, no sandbox (root in a container), and nothing that calls home.
FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-default-apps",
    "--disable-extensions",
    "--hide-scrollbars",
    "--window-size=1400,1300",
)


class _Handler(http.server.SimpleHTTPRequestHandler):
    extensions_map = {  # noqa: RUF012 (the base class's own attribute, replaced)
        **http.server.SimpleHTTPRequestHandler.extensions_map,
        ".wasm": "application/wasm",
        ".mjs": "text/javascript",
        ".js": "text/javascript",
        ".json": "application/json",
        ".zip": "application/zip",
    }

    def log_message(self, format: str, *args: Any) -> None:
        pass


@contextlib.contextmanager
def serve_site(site: Path) -> Iterator[str]:
    """Serve ``site`` as static files on 127.0.0.1 (port 0); yields its base URL."""
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(_Handler, directory=str(site)))
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/"
    finally:
        server.shutdown()
        server.server_close()
        thread.join(10)


class Browser:
    """One headless Chromium with one page; use as ``async with Browser() as b``."""

    def __init__(self, timeout: float = 60.0) -> None:
        assert CHROMIUM is not None
        self.timeout = timeout
        self.requests: list[str] = []  #: every URL the page asked for, in order
        self.console: list[str] = []  #: the page's console messages and uncaught exceptions
        self._dir = tempfile.TemporaryDirectory(prefix="c20sim-chromium-", ignore_cleanup_errors=True)
        self._proc: subprocess.Popen[bytes] | None = None
        self._session: aiohttp.ClientSession | None = None
        self._ws: aiohttp.ClientWebSocketResponse | None = None
        self._id = 0
        self._pending: dict[int, asyncio.Future[dict[str, Any]]] = {}
        self._events: dict[str, list[asyncio.Future[dict[str, Any]]]] = {}
        self._reader: asyncio.Task[None] | None = None
        self._queues: dict[str, asyncio.Queue[dict[str, Any]]] = {}

    async def __aenter__(self) -> Browser:
        assert CHROMIUM is not None
        profile = Path(self._dir.name)
        self._proc = subprocess.Popen(
            [CHROMIUM, *FLAGS, f"--user-data-dir={profile}", "--remote-debugging-port=0", "about:blank"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        active = profile / "DevToolsActivePort"
        deadline = time.monotonic() + self.timeout
        while not active.exists() or len(active.read_text().splitlines()) < 2:
            if self._proc.poll() is not None:
                raise AssertionError(f"chromium exited with {self._proc.returncode} before its DevTools port opened")
            assert time.monotonic() < deadline, "Chromium never opened its DevTools port"
            await asyncio.sleep(0.05)
        port = active.read_text().splitlines()[0]
        self._session = aiohttp.ClientSession()
        async with self._session.put(f"http://127.0.0.1:{port}/json/new?about:blank") as answer:
            target = await answer.json(content_type=None)
        self._ws = await self._session.ws_connect(target["webSocketDebuggerUrl"], max_msg_size=0)
        self._reader = asyncio.create_task(self._read())
        await self.send("Network.enable")
        await self.send("Runtime.enable")
        await self.send("Page.enable")
        return self

    async def __aexit__(self, *exc: object) -> None:
        if self._reader is not None:
            self._reader.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._reader
        if self._ws is not None:
            await self._ws.close()
        if self._session is not None:
            await self._session.close()
        if self._proc is not None:
            self._proc.terminate()
            try:
                self._proc.wait(10)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        # chromium's helper processes may still be writing the profile as the main one exits: try again a while
        deadline = time.monotonic() + 10
        while True:
            try:
                shutil.rmtree(self._dir.name)
                break
            except FileNotFoundError:
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                await asyncio.sleep(0.1)

    async def _read(self) -> None:
        assert self._ws is not None
        async for message in self._ws:
            data = json.loads(message.data)
            if "id" in data:
                future = self._pending.pop(data["id"], None)
                if future is not None and not future.done():
                    future.set_result(data)
                continue
            method = data.get("method", "")
            params = data.get("params", {})
            if method == "Network.requestWillBeSent":
                self.requests.append(params["request"]["url"])
            elif method == "Runtime.consoleAPICalled":
                self.console.append(" ".join(str(a.get("value", a.get("description", ""))) for a in params["args"]))
            elif method == "Runtime.exceptionThrown":
                details = params["exceptionDetails"]
                self.console.append(f"exception: {details.get('exception', {}).get('description', details['text'])}")
            queue = self._queues.get(method)
            if queue is not None:
                queue.put_nowait(params)
            for waiter in self._events.pop(method, []):
                if not waiter.done():
                    waiter.set_result(params)

    async def send(self, method: str, params: dict[str, Any] | None = None) -> dict[str, Any]:
        assert self._ws is not None
        self._id += 1
        future: asyncio.Future[dict[str, Any]] = asyncio.get_running_loop().create_future()
        self._pending[self._id] = future
        await self._ws.send_json({"id": self._id, "method": method, "params": params or {}})
        answer = await asyncio.wait_for(future, self.timeout)
        if "error" in answer:
            raise AssertionError(f"{method}: {answer['error']}")
        result: dict[str, Any] = answer.get("result", {})
        return result

    def listen(self, method: str) -> asyncio.Queue[dict[str, Any]]:
        """Every event ``method`` from now on, in order (a binding's calls: ``Runtime.bindingCalled``)."""
        return self._queues.setdefault(method, asyncio.Queue())

    async def goto(self, url: str) -> None:
        """Open ``url`` and wait for its load event."""
        loaded: asyncio.Future[dict[str, Any]] = asyncio.get_running_loop().create_future()
        self._events.setdefault("Page.loadEventFired", []).append(loaded)
        await self.send("Page.navigate", {"url": url})
        await asyncio.wait_for(loaded, self.timeout)

    async def eval(self, expression: str, timeout: float | None = None) -> Any:
        """The value of ``expression`` (awaited if a promise), as JSON; a thrown error fails with its text."""
        result = await asyncio.wait_for(
            self.send(
                "Runtime.evaluate",
                {"expression": expression, "awaitPromise": True, "returnByValue": True, "userGesture": True},
            ),
            timeout or self.timeout,
        )
        if "exceptionDetails" in result:
            details = result["exceptionDetails"]
            raise AssertionError(
                f"{expression[:80]!r} threw: {details.get('exception', {}).get('description', details['text'])}"
            )
        return result["result"].get("value")

    async def type_text(self, text: str) -> None:
        """Type ``text`` into the focused element, as a keyboard would insert it."""
        await self.send("Input.insertText", {"text": text})

    async def screenshot(self, path: Path) -> bytes:
        shot = await self.send("Page.captureScreenshot", {"format": "png", "captureBeyondViewport": True})
        png = base64.b64decode(shot["data"])
        path.write_bytes(png)
        return png
