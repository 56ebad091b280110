"""A real serial port, such as a USB-RS485 adapter, through pyserial.

The port is opened exclusively, so a second simulator (or a terminal program)
cannot share it by mistake. A baud change through 2009H is applied to the
port after its reply has left the wire, as the drive does.

A port that goes away (a USB adapter unplugged) is reported in one line and
tried again every :data:`REOPEN_EVERY` seconds; when it is back (the bench
is replugged) it is served again, with a line saying so.

With ``line_timing`` the port is a :class:`~c20sim.transport.timed.TimedEndpoint`:
strict framing with the character time of the port's own format (10 bits for
8N1, 11 for 8E1, 8O1 and 8N2), and replies written whole at their start time
(the UART paces the bytes). Arrival times are only as fine as the adapter
delivers bytes: see docs/line-timing.md for USB adapters.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging

import serial

from ..wire.errors import C20SimError
from ..wire.protocol import char_bits
from .device import open_serial
from .endpoint import RtuEndpoint, stream_framer
from .line import Line
from .timed import TimedEndpoint

log = logging.getLogger(__name__)

__all__ = ["SerialPort"]

#: Seconds between attempts to open a port that went away.
REOPEN_EVERY = 1.0


class SerialPort:
    """A serial device in front of a simulator's bus."""

    def __init__(
        self,
        line: Line,
        device: str,
        *,
        parity: str = "N",
        stopbits: int = 1,
        line_timing: bool = False,
    ) -> None:
        self.line = line
        self.device = device
        self.baud = line.sim.bus.line_baud  # the drive's own setting (F08.01), as --baud set it
        self.parity = parity
        self.stopbits = stopbits
        self.line_timing = line_timing
        self._port: serial.Serial | None = None
        self._endpoint: RtuEndpoint | TimedEndpoint | None = None
        self._baud_change: asyncio.Task[None] | None = None
        self._reopen: asyncio.TimerHandle | None = None

    @property
    def name(self) -> str:
        return self.device

    @property
    def is_open(self) -> bool:
        return self._port is not None

    async def start(self) -> None:
        try:
            self._open()
        except serial.SerialException as exc:
            raise C20SimError(_explain(self.device, exc)) from None

    def _open(self) -> None:
        """Open the port and serve it; raises SerialException."""
        self._port = open_serial(self.device, self.baud, self.parity, self.stopbits)
        framer = stream_framer(self.baud, line_timing=self.line_timing, bits=char_bits(8, self.parity, self.stopbits))
        if self.line_timing:
            port = self._port
            self._endpoint = TimedEndpoint(
                self.line,
                port.fileno(),
                framer,
                pace=False,
                name=f"serial {self.device}",
                write=lambda data: port.write(data) or 0,
                on_baud=self._set_baud_now,
            )
            return
        self._endpoint = RtuEndpoint(
            self.line,
            framer,
            self._send,
            on_baud=self._set_baud,
            name=f"serial {self.device}",
            pause=self._pause,
            resume=self._resume,
        )
        asyncio.get_running_loop().add_reader(self._port.fileno(), self._readable)

    def _pause(self) -> None:
        """Backpressure: leave the master's bytes in the port while its request is on the line."""
        if self._port is not None:
            asyncio.get_running_loop().remove_reader(self._port.fileno())

    def _resume(self) -> None:
        if self._port is not None:
            asyncio.get_running_loop().add_reader(self._port.fileno(), self._readable)

    def _readable(self) -> None:
        assert self._port is not None and isinstance(self._endpoint, RtuEndpoint)
        try:
            data = self._port.read(4096)
        except serial.SerialException as exc:
            # The adapter was unplugged or the line hung up: the fd stays readable forever, so stop watching it.
            log.error("serial port %s lost (%s); serving it again when it is back", self.device, exc)
            self._drop()
            self._reopen = asyncio.get_running_loop().call_later(REOPEN_EVERY, self._try_reopen)
            return
        if data:
            self._endpoint.feed(data)

    def _send(self, data: bytes, baud: int) -> None:
        assert self._port is not None
        self._port.write(data)

    def _set_baud(self, baud: int) -> None:
        self._baud_change = asyncio.get_running_loop().create_task(self._change_baud(baud))

    def _set_baud_now(self, baud: int) -> None:
        """On the line-timed writer thread, after the acknowledging reply was written: it leaves first."""
        port = self._port
        if port is not None and port.is_open:
            port.flush()
            port.baudrate = baud
            self.baud = baud

    async def _change_baud(self, baud: int) -> None:
        port = self._port
        if port is None:
            return
        await asyncio.to_thread(port.flush)  # the acknowledging reply leaves the wire at the old baud first
        if port.is_open:
            port.baudrate = baud
            self.baud = baud

    def _try_reopen(self) -> None:
        self._reopen = None
        try:
            self._open()
        except (serial.SerialException, OSError):
            self._port = None
            self._reopen = asyncio.get_running_loop().call_later(REOPEN_EVERY, self._try_reopen)
            return
        log.warning("serial port %s is back; serving it again", self.device)

    def close(self) -> None:
        if self._reopen is not None:
            self._reopen.cancel()
            self._reopen = None
        self._drop()

    def _drop(self) -> None:
        if self._baud_change is not None:
            self._baud_change.cancel()
        if self._endpoint is not None:
            self._endpoint.close()
        if self._port is not None:
            with contextlib.suppress(RuntimeError, ValueError):
                asyncio.get_running_loop().remove_reader(self._port.fileno())
            self._port.close()
            self._port = None


def _explain(device: str, exc: serial.SerialException) -> str:
    code = exc.errno if isinstance(exc.errno, int) else getattr(exc.__context__, "errno", None)
    text = str(exc)
    if code == errno.ENOENT or "No such file" in text:
        return f"--serial {device}: no such device; check the adapter is plugged in (ls /dev/ttyUSB* /dev/ttyACM*)"
    if code == errno.EACCES or "Permission denied" in text:
        return f"--serial {device}: permission denied; add yourself to the dialout group or run with access to the port"
    if code in (errno.EBUSY, errno.EAGAIN, errno.EWOULDBLOCK) or "lock" in text.lower() or "busy" in text.lower():
        return f"--serial {device}: the port is busy (another program has it open); close that program or choose another port"
    return f"--serial {device}: cannot open: {text}"
