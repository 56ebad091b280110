"""What the browser page runs in Pyodide: one drive, its line, its audit, the terminal and the serial port.

The page is a front end like the dashboard: it holds a
:class:`~c20sim.core.simulator.Simulator` and asks for everything through the
rows of :data:`~c20sim.control.routes.TABLE` (:meth:`Page.call`, by the
operation's name), checked by :func:`~c20sim.control.routes.invoke` as the
HTTP API checks them. Frames reach the model as ``c20sim serve`` hands them
over: a :class:`~c20sim.transport.line.Line` with bus timing, and for the Web
Serial port an :class:`~c20sim.transport.endpoint.RtuEndpoint` with the
framer of a serial port without line timing (:func:`stream_framer`): a USB
adapter read through the browser delivers bytes in bursts, so a valid frame
completes on its length and a broken one after 20 ms of silence.

Nothing here imports the browser: bytes cross to JavaScript as hex text and
answers as JSON text, so the page's Python runs the same in CPython (its
tests) and in Pyodide. Each method that JavaScript calls returns a JSON
string; an error is ``{"error": "one line"}``, never a traceback.
"""

from __future__ import annotations

import asyncio
import json
import math
import re
import time
from collections.abc import Callable, Mapping
from typing import Any

from ..control import causes, liveaudit, ops
from ..control.routes import TABLE, invoke
from ..core.simulator import Simulator, make_clock
from ..drive.profile import DEFAULT_PROFILE, Profile, available_profiles, load_profile, parse_profile
from ..transport.endpoint import RtuEndpoint, stream_framer
from ..transport.line import Line
from ..wire.decode import decode_frame, describe
from ..wire.errors import C20SimError
from ..wire.protocol import MAX_ADU, FrameEvent, char_bits, crc16, decode_request, decode_response

__all__ = ["MAX_FRAMES", "SHEET_FRAMES", "Page", "SerialServe", "parse_hex", "start"]

#: Frames the page's log keeps (the newest): a few minutes of a busy master, and the page draws them all.
MAX_FRAMES = 500
#: Samples one :meth:`Page.advance` returns at most, for the plot.
MAX_SAMPLES = 200
#: The most bytes a user's TOML may have when dropped on the page (a shipped profile is a few dozen KiB).
MAX_PROFILE_BYTES = 256 * 1024
#: What the terminal waits for a reply at most (the line holds one for its turnaround and its line time).
REPLY_TIMEOUT = 2.0

#: The sheet's command table, corrected (docs/protocol.md, section 8): the terminal's list to pick from.
SHEET_FRAMES: tuple[tuple[str, str], ...] = (
    ("forward run (2000H = 1)", "01 06 20 00 00 01 43 CA"),
    ("reverse run (2000H = 2)", "01 06 20 00 00 02 03 CB"),
    ("stop (2000H = 5)", "01 06 20 00 00 05 42 09"),
    ("fault reset (2000H = 7)", "01 06 20 00 00 07 C3 C8"),
    ("set speed 3000 rpm (2001H)", "01 06 20 01 0B B8 D4 88"),
    ("write 200EH = 0", "01 06 20 0E 00 00 E3 C9"),
    ("enable function code writes (200EH = 1)", "01 06 20 0E 00 01 22 09"),
    ("read F00.10", "01 03 00 0A 00 01 A4 08"),
    ("write F00.10 = 25.00 Hz", "01 06 00 0A 09 C4 AE 0B"),
    ("read status word 1 (2100H)", "01 03 21 00 00 01 8E 36"),
    ("read status word 2 (2101H)", "01 03 21 01 00 01 DF F6"),
    ("read fault code (2102H)", "01 03 21 02 00 01 2F F6"),
    ("read F00.50 (absent)", "01 03 00 32 00 01 25 C5"),
    ("write F00.00 = 5", "01 06 00 00 00 05 49 C9"),
    ("read drive ID (2103H)", "01 03 21 03 00 01 7E 36"),
    ("read motor speed (3006H)", "01 03 30 06 00 01 6B 0B"),
    ("run at 3000 rpm in one frame (0x10)", "01 10 20 00 00 02 04 00 01 0B B8 3C EC"),
)

#: The serial formats the page offers: (parity, stop bits); the sheet's line is 8N1.
FORMATS: Mapping[str, tuple[str, int]] = {"8N1": ("N", 1), "8E1": ("E", 1), "8O1": ("O", 1), "8N2": ("N", 2)}

_HEX_JUNK = re.compile(r"0x|[\s,;:]+", re.IGNORECASE)


def parse_hex(text: str) -> bytes:
    """``"01 06 20 00 00 01 43 CA"``, ``"010620000001"`` or ``"0x01,0x06"`` -> bytes; C20SimError says what is
    wrong in one line."""
    digits = _HEX_JUNK.sub("", text)
    if not digits:
        raise C20SimError("no bytes: type a frame in hex, such as 01 03 21 00 00 01 8E 36")
    bad = re.search(r"[^0-9A-Fa-f]", digits)
    if bad:
        raise C20SimError(f"{bad.group(0)!r} is not a hex digit: type bytes such as 01 03 21 00 00 01 8E 36")
    if len(digits) % 2:
        raise C20SimError(f"an odd number of hex digits ({len(digits)}): each byte is two, such as 01 03")
    data = bytes.fromhex(digits)
    if len(data) > MAX_ADU:
        raise C20SimError(f"{len(data)} bytes: an RTU frame has at most {MAX_ADU}")
    return data


def _hex(data: bytes | None) -> str | None:
    return None if data is None else data.hex(" ").upper()


def _json(value: object) -> str:
    return json.dumps(value, allow_nan=False, default=str)


def _finite(value: object) -> object:
    """JSON has no NaN nor infinity: such a telemetry value is sent as null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite(v) for v in value]
    return value


def void(_: object) -> None:
    """What a JavaScript callback returns, dropped (the endpoint's callbacks return nothing)."""


def _error(exc: Exception) -> str:
    status = getattr(exc, "status", None)
    return _json({"error": str(exc), **({"status": status} if status is not None else {})})


class Page:
    """One drive at ``address`` of ``profile``, on a line with bus timing, with its live audit."""

    def __init__(
        self,
        profile: Profile,
        *,
        clock: str = "virtual",
        speed: float = 1.0,
        address: int = 1,
        source: str = "",
    ) -> None:
        self.profile = profile
        #: where the profile came from: a shipped profile's name, or the dropped file's name
        self.source = source or profile.name
        self.sim = Simulator(profile, [address], clock=make_clock(clock, speed), log_size=MAX_FRAMES)
        self.address = address
        self.line = Line(self.sim, bus_timing=True)
        self.audit = liveaudit.start(self.sim)
        self.serial: SerialServe | None = None

    # --- The route table's rows.

    def call(self, name: str, parameters: str = "{}", body: str = "{}") -> str:
        """The operation ``name`` of the route table with its path parameters and body (JSON text): its answer
        as the API would give it, or ``{"error": ...}``."""
        try:
            row = TABLE.named(name)
            params = dict(json.loads(parameters))
            if "address" in row.parameters:
                params.setdefault("address", self.address)
            return _json(_finite(invoke(self.sim, row, params, json.loads(body), row.path)))
        except (C20SimError, ValueError, TypeError) as exc:
            return _error(exc)

    # --- What the page shows.

    def info(self) -> str:
        """The profile, the line, the clock, and the vocabularies of the page's controls."""
        return _json(
            {
                "profile": self.profile.name,
                "source": self.source,
                "profiles": sorted(available_profiles()),
                "address": self.address,
                "baud": self.sim.bus.line_baud,
                "formats": list(FORMATS),
                "clock": "virtual" if self.sim.virtual else "realtime",
                "keys": list(ops.KEYS),
                "conditions": {
                    name: {"unit": c.unit, "low": c.low, "high": c.high, "help": c.help}
                    for name, c in ops.CONDITIONS.items()
                },
                "causes": causes.cause_names(self.profile),
                "sheet_frames": [{"operation": op, "request": frame} for op, frame in SHEET_FRAMES],
            }
        )

    def state(self) -> str:
        """The drive's state now (the ``drive`` row), the clock, the line's baud and the serial port's."""
        try:
            drive = invoke(self.sim, TABLE.named("drive"), {"address": self.address}, {})
            clock = invoke(self.sim, TABLE.named("clock"), {}, {})
        except C20SimError as exc:
            return _error(exc)
        return _json(
            _finite(
                {
                    "drive": drive,
                    "clock": clock,
                    "baud": self.sim.bus.line_baud,
                    "serial": None if self.serial is None else self.serial.state(),
                    "notices": list(self.sim.notices),
                }
            )
        )

    def advance(self, seconds: float, samples: int = 20) -> str:
        """Virtual clock: move time on by ``seconds`` in ``samples`` steps (the ``advance`` row each), and
        return the drive's telemetry after each: the plot's points."""
        try:
            steps = max(1, min(int(samples), MAX_SAMPLES))
            seconds = ops.number("seconds", seconds, 0, ops.MAX_ADVANCE)
            row = TABLE.named("advance")
            out = []
            for _ in range(steps):
                invoke(self.sim, row, {}, {"seconds": seconds / steps})
                out.append(self._sample())
        except C20SimError as exc:
            return _error(exc)
        return _json(_finite({"samples": out}))

    def sample(self) -> str:
        """One point of the plot now (the realtime clock's refresh)."""
        return _json(_finite(self._sample()))

    def _sample(self) -> dict[str, Any]:
        t = ops.telemetry(self.sim, self.address)
        return {"t": t.t, "speed_rpm": t.speed_rpm, "current_a": t.current_a, "bus_v": t.bus_v, "state": t.state}

    def frames(self, since: int = 0, last: int = 100) -> str:
        """The frame log after sequence number ``since``, the newest ``last`` of them."""
        return _json(ops.frames(self.sim, since=since, last=max(1, min(int(last), MAX_FRAMES))))

    def audit_report(self) -> str:
        """The live audit's report (the ``audit`` row), each finding with its line as ``c20sim audit`` words it."""
        try:
            report = invoke(self.sim, TABLE.named("audit"), {}, {})
        except C20SimError as exc:
            return _error(exc)
        for finding, line in zip(report["findings"], (f.line() for f in self.audit.findings()), strict=True):
            finding["line"] = line
        return _json(_finite(report))

    # --- The terminal: a master on the page.

    async def terminal(self, text: str, add_crc: bool = False) -> str:
        """Send the bytes typed (``add_crc``: with their CRC appended) as a master would: framed, then served by
        the line; the answer holds each frame found, its reply (or silence) and both in words."""
        try:
            data = parse_hex(text)
            if add_crc:
                data += crc16(data).to_bytes(2, "little")
                if len(data) > MAX_ADU:
                    raise C20SimError(f"{len(data)} bytes with the CRC: an RTU frame has at most {MAX_ADU}")
        except C20SimError as exc:
            return _error(exc)
        framer = stream_framer(self.sim.bus.line_baud)
        framer.feed(data, time.perf_counter())
        framer.flush()
        exchanges = []
        for event in framer.events():
            reply = await self._ask(event)
            exchanges.append(self._exchange(event, reply))
        return _json({"sent": _hex(data), "exchanges": exchanges})

    async def _ask(self, event: FrameEvent) -> bytes | None:
        loop = asyncio.get_running_loop()
        answer: asyncio.Future[bytes | None] = loop.create_future()

        def respond(reply: Any) -> None:
            if not answer.done():
                answer.set_result(None if reply is None else bytes(reply.data))

        self.line.submit(event, respond, self)
        try:
            return await asyncio.wait_for(answer, REPLY_TIMEOUT)
        except TimeoutError:
            self.line.cancel(self)
            return None

    def _exchange(self, event: FrameEvent, reply: bytes | None) -> dict[str, Any]:
        regs = self.profile.registers
        request_text = decode_frame(event.data, regs).text
        if event.note and event.note not in request_text:  # the framer's word (a gap), unless decode said it
            request_text = f"{request_text} ({event.note})"
        out: dict[str, Any] = {"request": _hex(event.data), "request_text": request_text, "reply": _hex(reply)}
        if reply is None:
            out["reply_text"] = "no reply (silence)"
            return out
        try:
            request = decode_request(event.data, check_crc=False)  # what it asked, to name a read's registers
        except ValueError:
            request = None
        try:
            out["reply_text"] = describe(decode_response(reply), regs, request)
        except ValueError:
            out["reply_text"] = decode_frame(reply, regs).text
        out["exception"] = bool(len(reply) > 1 and reply[1] & 0x80)
        return out

    # --- The serial port.

    async def open_serial(
        self,
        write: Callable[[str], object],
        reopen: Callable[[int], object],
        pause: Callable[[], object],
        resume: Callable[[], object],
        line_format: str = "8N1",
    ) -> SerialServe:
        """Serve the Web Serial port whose bytes :meth:`SerialServe.feed` gets: ``write(hex)`` puts a reply on
        it, ``reopen(baud)`` follows a 2009H change (after the acknowledging reply), ``pause()`` and
        ``resume()`` stop and restart its reading while a request is on the line (a coroutine: the endpoint
        takes the running loop)."""
        if self.serial is not None:
            self.serial.close()
        self.serial = SerialServe(self, write, reopen, pause, resume, line_format)
        return self.serial

    def close(self) -> None:
        if self.serial is not None:
            self.serial.close()
            self.serial = None
        self.line.close()
        self.audit.close()


class SerialServe:
    """The page's serial port, served as ``c20sim serve --serial`` serves one (without ``--line-timing``)."""

    def __init__(
        self,
        page: Page,
        write: Callable[[str], object],
        reopen: Callable[[int], object],
        pause: Callable[[], object],
        resume: Callable[[], object],
        line_format: str = "8N1",
    ) -> None:
        if line_format not in FORMATS:
            raise C20SimError(f"serial format {line_format!r}: choose one of {', '.join(FORMATS)}")
        parity, stopbits = FORMATS[line_format]
        self.page = page
        self.format = line_format
        self._write = write
        self._reopen = reopen
        bits = char_bits(8, parity, stopbits)
        page.sim.bus.char_bits = bits  # the line's character, as serve sets it from --parity and --stopbits
        self.baud = page.sim.bus.line_baud
        self.received = 0  #: bytes read from the port
        self.sent = 0  #: bytes of replies handed to the port
        self.endpoint = RtuEndpoint(
            page.line,
            stream_framer(self.baud, bits=bits),
            self._send,
            on_baud=self._baud,
            name="web serial",
            pause=lambda: void(pause()),
            resume=lambda: void(resume()),
        )

    @property
    def paused(self) -> bool:
        return self.endpoint.paused

    def feed(self, text: str) -> None:
        """Bytes read from the port now, as hex."""
        data = bytes.fromhex(text)
        self.received += len(data)
        self.endpoint.feed(data)

    def _send(self, data: bytes, baud: int) -> None:
        self.sent += len(data)
        self._write(data.hex())

    def _baud(self, baud: int) -> None:
        self.baud = baud
        self._reopen(baud)

    def state(self) -> dict[str, Any]:
        return {"baud": self.baud, "format": self.format, "received": self.received, "sent": self.sent}

    def close(self) -> None:
        self.endpoint.close()


def load(name: str = "", text: str = "", filename: str = "") -> tuple[Profile, str]:
    """A shipped profile by ``name``, or a user's TOML ``text`` (dropped on the page as ``filename``)."""
    if text:
        if len(text.encode()) > MAX_PROFILE_BYTES:
            raise C20SimError(f"{filename or 'the profile'}: more than {MAX_PROFILE_BYTES // 1024} KiB")
        return parse_profile(text, filename or "<dropped profile>"), filename or "dropped profile"
    chosen = name or DEFAULT_PROFILE
    return load_profile(chosen), chosen


def start(name: str = "", text: str = "", filename: str = "", clock: str = "virtual", speed: float = 1.0) -> Page:
    """The page's drive: raises C20SimError (ProfileError) in one line for a bad profile or clock."""
    profile, source = load(name, text, filename)
    return Page(profile, clock=clock, speed=speed, source=source)
