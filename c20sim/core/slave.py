"""One drive's Modbus face: a request in, a response or an exception reply out.

The slave owns the access rules of the register map and applies them in this
order, which the sheet's examples fix where it matters (F00.00 = 5 is refused
with 0x03 even while function codes are locked):

    0x02 unknown address -> 0x07 read-only -> 0x03 value out of range
    -> 0x04 function code while 200EH = 0 -> 0x05 password not given
    -> 0x08 W/R* register while running -> a run command while faulted (the
    profile's code, 0x01 by default) -> a feature the model lacks (the profile's
    code) -> the drive's own refusals

A 0x10 whose byte count is not twice its register count is refused with the
profile's code, 0x06 by default (the sheet's "length of data frame is
incorrect"), 0x03 where the profile says so.

A 0x10 write is checked whole against the state before the frame, then
applied whole: all or nothing.

Where the profile says so (``protocol.ram_only_alias``), a function code's
address with bit 15 set (F00.10 at 800AH) is its RAM-only address, as in the
INVT family: a write there meets every rule a write to the code meets, then
changes the value in RAM only (not saved, lost at power-off); a read there
gets 0x02, as the address is write-only. The drive behind it is any
:class:`~c20sim.drive.base.DrivePort`.
"""

from __future__ import annotations

from ..drive.base import DrivePort
from ..drive.config import F_ANSWER_DELAY
from ..drive.profile import Profile
from ..wire.errors import ModbusError
from ..wire.protocol import (
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
from ..wire.registers import BAUD_RATES, Access, Reg, RegisterSpec, is_fcode, ram_alias_of

#: 2000H values that run or jog the motor (sheet: 1 forward, 2 reverse, 3 forward jog, 4 reverse jog).
RUN_COMMAND_VALUES = frozenset({1, 2, 3, 4})
#: 2100H status word 1: "0004h: drive in fault" (sheet).
STATUS_FAULT = 4
#: 2007H: "6: simple PLC setting" (sheet).
SPEED_SOURCE_PLC = 6
#: 2006H: inside the sheet's range "(0-4)" but not among the channels it names.
RUN_CHANNEL_UNNAMED = 4

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
        self._speed_source_cell = self.registers.canonical(Reg.SPEED_SOURCE)
        self._run_channel_cell = self.registers.canonical(Reg.RUN_CHANNEL)
        self._turnaround = profile.protocol.turnaround_ms / 1000.0
        #: the answer delay's function code (F08.04), if the profile has it, and its scale to seconds
        spec = self.registers.get(F_ANSWER_DELAY)
        self._answer_delay = (F_ANSWER_DELAY, spec.scale / 1000.0) if spec is not None else None

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
    def answer_delay(self) -> float:
        """Seconds from a request's end to its reply's start: the profile's turnaround (the drive's own processing
        time), or the answer delay F08.04 a master set, whichever is longer (INVT P14.03: "the reply waits at
        least this long"; assumed for the C20)."""
        if self._answer_delay is None:
            return self._turnaround
        cell, scale = self._answer_delay
        return max(self._turnaround, self.drive.read(cell) * scale)

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
        # by class, not a match: a match tries each case's class and reads its fields, on every request
        kind = request.__class__
        if kind is ReadRequest:
            assert isinstance(request, ReadRequest)
            return ReadResponse(request.slave, self._read(request.start, request.count))
        if kind is WriteSingleRequest:
            assert isinstance(request, WriteSingleRequest)
            self._write({request.register: request.value})
            return WriteSingleResponse(request.slave, request.register, request.value)
        if kind is WriteMultipleRequest:
            assert isinstance(request, WriteMultipleRequest)
            return self._write_multiple(request)
        if kind is UnsupportedRequest:
            raise ModbusError(ExceptionCode.ILLEGAL_FUNCTION, f"function 0x{request.function:02X}")
        raise AssertionError(f"unhandled request {request!r}")  # pragma: no cover

    def _write_multiple(self, request: WriteMultipleRequest) -> Response:
        slave, start, values, count, byte_count = (
            request.slave,
            request.start,
            request.values,
            request.count,
            request.byte_count,
        )
        if byte_count != 2 * count or len(values) != count:
            # Sheet, 0x06: "The length of data frame is incorrect". Modbus-standard stacks answer
            # 0x03 instead; the profile chooses (protocol.byte_count_exception, 6 by default).
            raise ModbusError(
                ExceptionCode(self.profile.protocol.byte_count_exception),
                f"byte count {byte_count}, {count} registers need {2 * count}",
            )
        if not 1 <= count <= MAX_WRITE_REGISTERS:
            raise ModbusError(ExceptionCode.ILLEGAL_VALUE, f"count {count}")
        if start + count > 0x10000:
            raise ModbusError(ExceptionCode.ILLEGAL_ADDRESS, "write past FFFFH")
        self._write({start + i: v for i, v in enumerate(values)})
        return WriteMultipleResponse(slave, start, count)

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
                base = self._ram_alias(address)
                if base is not None:
                    raise ModbusError(
                        ExceptionCode.ILLEGAL_ADDRESS, f"{address:04X}H is {base:04X}H's RAM-only address: write-only"
                    )
                raise ModbusError(ExceptionCode.ILLEGAL_ADDRESS, f"{address:04X}H is not in the map")
            values.append(self.drive.read(spec.storage) & 0xFFFF)
        return tuple(values)

    def _ram_alias(self, address: int) -> int | None:
        """The function code whose RAM-only address ``address`` is, where the profile has them, else None."""
        if not self.profile.protocol.ram_only_alias:
            return None
        base = ram_alias_of(address)
        return base if base is not None and base in self.registers and base != self._password_address else None

    def _write(self, writes: dict[int, int]) -> None:
        ram_only: set[int] = set()
        for address in list(writes):
            if address != self._password_address and address not in self.registers:
                base = self._ram_alias(address)
                if base is None:
                    raise ModbusError(ExceptionCode.ILLEGAL_ADDRESS, f"{address:04X}H is not in the map")
                writes[base] = writes.pop(address)
                ram_only.add(base)
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
            if spec.address in ram_only:
                self.drive.write_ram(spec.storage, value)
            else:
                self.drive.write(spec.storage, value)

    def panel_write(self, address: int, value: int) -> None:
        """A parameter set from the drive's own panel: every rule a master meets but the communication locks
        (200EH and the password), which guard the bus, not the keypad. Raises ModbusError with the code a
        master would get."""
        spec = self.registers.get(address)
        if spec is None:
            raise ModbusError(ExceptionCode.ILLEGAL_ADDRESS, f"{address:04X}H is not in the map")
        self._check(spec, value, unlocked=True, comm_locks=False)
        self.drive.write(spec.storage, value)

    def _check(self, spec: RegisterSpec, value: int, unlocked: bool, *, comm_locks: bool = True) -> None:
        if not spec.access.writable:
            raise ModbusError(ExceptionCode.READ_ONLY, f"{spec.label} is read-only")
        if not spec.accepts(value):
            raise ModbusError(
                ExceptionCode.ILLEGAL_VALUE, f"{spec.label} = {value}; allowed {spec.minimum} to {spec.maximum}"
            )
        if is_fcode(spec.address) and comm_locks:
            if not self.drive.read(Reg.WRITE_ENABLE):
                raise ModbusError(ExceptionCode.OPERATION_FAILED, "function codes are locked (200EH = 0)")
            if not unlocked:
                raise ModbusError(ExceptionCode.PASSWORD_ERROR, "password not given")
        if spec.access is Access.RW_STOPPED and self.drive.running:
            raise ModbusError(ExceptionCode.NOT_WHILE_RUNNING, f"{spec.label} is W/R*: stop the drive first")
        quirks = self.profile.protocol
        # Sheet, 0x01 "Illegal order": "The slave does not support this command or processes the request
        # in an error state". A run or jog command while faulted gets the profile's code (0x01 by
        # default; 0 = echoed and ignored, as the state table ignores it). Assumed: the sheet does not say.
        if (
            spec.storage == Reg.COMMAND
            and value in RUN_COMMAND_VALUES
            and quirks.run_while_faulted_exception
            and self.drive.read(Reg.STATUS1) == STATUS_FAULT
        ):
            raise ModbusError(ExceptionCode(quirks.run_while_faulted_exception), "the drive is faulted: reset it first")
        if spec.storage == self._speed_source_cell and value == SPEED_SOURCE_PLC and not quirks.simple_plc:
            # Sheet, 2007H: "6: simple PLC setting", with "model related" beside the dial switch settings.
            # This model has no PLC program (protocol.simple_plc = false): the profile's code refuses it.
            raise ModbusError(
                ExceptionCode(quirks.lacking_feature_exception), f"{spec.label} = 6: this model has no simple PLC"
            )
        if spec.storage == self._run_channel_cell and value == RUN_CHANNEL_UNNAMED:
            # Sheet, 2006H: "Operation instruction selection (0-4)", but it names 0-3 only: no model is known
            # to have a fifth channel, so the profile's code for a feature the model lacks refuses it (assumed).
            raise ModbusError(
                ExceptionCode(quirks.lacking_feature_exception), f"{spec.label} = 4: this model has no such channel"
            )
        self.drive.check_write(spec.storage, value)
