"""One drive's Modbus face: a request in, a response or an exception reply out.

The slave owns the access rules of the register map and applies them in this
order, which the sheet's examples fix where it matters (F00.00 = 5 is refused
with 0x03 even while function codes are locked):

    0x02 unknown address -> 0x07 read-only -> 0x03 value out of range
    -> 0x04 function code while 200EH = 0 -> 0x05 password not given
    -> 0x08 W/R* register while running -> the drive's own refusals

A 0x10 write is checked whole against the state before the frame, then
applied whole: all or nothing. The drive behind it is any
:class:`~c20sim.drive.base.DrivePort`.
"""

from __future__ import annotations

from .drive.base import DrivePort
from .errors import ModbusError
from .profile import Profile
from .protocol import (
    MAX_WRITE_REGISTERS,
    ExceptionCode,
    ExceptionResponse,
    ReadRequest,
    ReadResponse,
    Request,
    Response,
    UnsupportedRequest,
    WriteMultipleRequest,
    WriteMultipleResponse,
    WriteSingleRequest,
    WriteSingleResponse,
)
from .registers import BAUD_RATES, Access, Reg, RegisterSpec, is_fcode

__all__ = ["Slave"]


class Slave:
    """Answers requests for one drive, by the sheet's rules."""

    def __init__(self, profile: Profile, drive: DrivePort) -> None:
        self.profile = profile
        self.drive = drive
        self.registers = profile.registers
        self._password = profile.protocol.password
        self._password_address = profile.password_address if self._password else None
        self._unlocked = not self._password
        self._address_cell = self.registers.canonical(Reg.ADDRESS)
        self._baud_cell = self.registers.canonical(Reg.BAUD)

    def attach(self, drive: DrivePort) -> None:
        """Answer for ``drive`` from now on (a reset to a set-up): as a drive switched on, the password locks."""
        self.drive = drive
        self._unlocked = not self._password

    @property
    def address(self) -> int:
        """The station address the drive answers to now (2008H)."""
        return self.drive.read(self._address_cell)

    @property
    def baud(self) -> int:
        """The line speed the drive listens at now (2009H)."""
        code = self.drive.read(self._baud_cell)
        return BAUD_RATES[code] if 0 <= code < len(BAUD_RATES) else BAUD_RATES[4]

    @property
    def unlocked(self) -> bool:
        """True when no password is set, or the right one has been written."""
        return self._unlocked

    def handle(self, request: Request, t: float, *, communicated: bool = True) -> Response:
        """Serve ``request`` at time ``t``; refusals come back as exception replies.

        ``communicated=False`` applies the same rules without feeding the communication timeout:
        an edit from the bench, not a master's frame.
        """
        self.drive.advance_to(t)
        try:
            response = self._serve(request)
        except ModbusError as exc:
            response = ExceptionResponse(request.slave, request.function, exc.code)
        if communicated:
            self.drive.communicated(t)
        return response

    def frame_error(self, slave: int, function: int) -> ExceptionResponse:
        """The reply to a frame with a bad CRC or length (exception 0x06)."""
        return ExceptionResponse(slave, function & 0x7F, ExceptionCode.FRAME_ERROR)

    # -- requests

    def _serve(self, request: Request) -> Response:
        match request:
            case ReadRequest(slave, start, count):
                return ReadResponse(slave, self._read(start, count))
            case WriteSingleRequest(slave, register, value):
                self._write({register: value})
                return WriteSingleResponse(slave, register, value)
            case WriteMultipleRequest(slave, start, values, count, byte_count):
                if not 1 <= count <= MAX_WRITE_REGISTERS or byte_count != 2 * count or len(values) != count:
                    raise ModbusError(ExceptionCode.ILLEGAL_VALUE, f"count {count}, byte count {byte_count}")
                if start + count > 0x10000:
                    raise ModbusError(ExceptionCode.ILLEGAL_ADDRESS, "write past FFFFH")
                self._write({start + i: v for i, v in enumerate(values)})
                return WriteMultipleResponse(slave, start, count)
            case UnsupportedRequest(_, function, _):
                raise ModbusError(ExceptionCode.ILLEGAL_FUNCTION, f"function 0x{function:02X}")
        raise AssertionError(f"unhandled request {request!r}")  # pragma: no cover

    def _read(self, start: int, count: int) -> tuple[int, ...]:
        if not 1 <= count <= self.profile.protocol.max_read_registers:
            raise ModbusError(
                ExceptionCode.ILLEGAL_VALUE,
                f"count {count}; this drive reads 1 to {self.profile.protocol.max_read_registers}",
            )
        values = []
        for address in range(start, start + count):
            if address == self._password_address:
                values.append(0)  # the password is write-only
                continue
            spec = self.registers.get(address)
            if spec is None:
                raise ModbusError(ExceptionCode.ILLEGAL_ADDRESS, f"{address:04X}H is not in the map")
            values.append(self.drive.read(spec.storage) & 0xFFFF)
        return tuple(values)

    def _write(self, writes: dict[int, int]) -> None:
        for address in writes:
            if address != self._password_address and address not in self.registers:
                raise ModbusError(ExceptionCode.ILLEGAL_ADDRESS, f"{address:04X}H is not in the map")
        unlocked = self._unlocked
        if self._password_address in writes:
            if writes.pop(self._password_address) != self._password:
                self._unlocked = False  # a wrong password locks, as it is refused
                raise ModbusError(ExceptionCode.PASSWORD_ERROR, "wrong password")
            unlocked = True
        checked = [(self.registers[a], v) for a, v in writes.items()]
        for spec, value in checked:
            self._check(spec, value, unlocked)
        # All checked: now the unlock and the writes take effect together.
        self._unlocked = unlocked
        for spec, value in checked:
            self.drive.write(spec.storage, value)

    def _check(self, spec: RegisterSpec, value: int, unlocked: bool) -> None:
        if not spec.access.writable:
            raise ModbusError(ExceptionCode.READ_ONLY, f"{spec.label} is read-only")
        if not spec.accepts(value):
            raise ModbusError(
                ExceptionCode.ILLEGAL_VALUE, f"{spec.label} = {value}; allowed {spec.minimum} to {spec.maximum}"
            )
        if is_fcode(spec.address):
            if not self.drive.read(Reg.WRITE_ENABLE):
                raise ModbusError(ExceptionCode.OPERATION_FAILED, "function codes are locked (200EH = 0)")
            if not unlocked:
                raise ModbusError(ExceptionCode.PASSWORD_ERROR, "password not given")
        if spec.access is Access.RW_STOPPED and self.drive.running:
            raise ModbusError(ExceptionCode.NOT_WHILE_RUNNING, f"{spec.label} is W/R*: stop the drive first")
        self.drive.check_write(spec.storage, value)
