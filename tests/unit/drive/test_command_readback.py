"""What 2000H reads back, through the slave: the command in force, 0 once the drive has dropped it (assumed)."""

from __future__ import annotations

from c20sim.core.slave import Slave
from c20sim.drive.model import Drive
from c20sim.drive.profile import Profile
from c20sim.wire.protocol import (
    ExceptionCode,
    ExceptionResponse,
    ReadRequest,
    ReadResponse,
    WriteSingleRequest,
    WriteSingleResponse,
)
from c20sim.wire.registers import Command, Reg


class Master:
    """A master on one drive's slave, in virtual time: each request a little later than the one before."""

    def __init__(self, profile: Profile) -> None:
        self.drive = Drive(profile)
        self.slave = Slave(profile, self.drive)
        self.t = 0.0

    def write(self, register: int, value: int, after: float = 0.01) -> None:
        self.t += after
        response = self.slave.handle(WriteSingleRequest(1, register, value), self.t)
        assert response == WriteSingleResponse(1, register, value), response

    def read(self, register: int, after: float = 0.01) -> int:
        self.t += after
        response = self.slave.handle(ReadRequest(1, register, 1), self.t)
        assert isinstance(response, ReadResponse), response
        return response.values[0]

    def command_and_status(self, after: float = 0.01) -> tuple[int, int]:
        return self.read(Reg.COMMAND, after), self.read(Reg.STATUS1, 0.0)


def running(profile: Profile) -> Master:
    master = Master(profile)
    master.write(Reg.SPEED_SETPOINT, 1500)
    master.write(Reg.COMMAND, Command.FORWARD)
    assert master.command_and_status(2.0) == (1, 1)
    return master


def test_a_trip_drops_the_run_command_and_a_reset_written_reads_back(profile: Profile) -> None:
    master = running(profile)
    master.write(Reg.VIRTUAL_INPUTS, 0x008)  # EF: the external fault trips at the next step
    assert master.command_and_status() == (0, 4)
    master.write(Reg.VIRTUAL_INPUTS, 0)
    master.write(Reg.COMMAND, Command.RESET)
    assert master.command_and_status() == (7, 3)
    assert master.command_and_status(5.0) == (7, 3)  # stopped, and it stays so: no restart


def test_after_a_reset_from_the_keypad_2000h_reads_0_not_forward_run(profile: Profile) -> None:
    master = running(profile)
    master.write(Reg.VIRTUAL_INPUTS, 0x008)
    master.write(Reg.VIRTUAL_INPUTS, 0)
    assert master.command_and_status() == (0, 4)
    assert master.drive.keypad(Command.RESET)
    assert master.command_and_status(5.0) == (0, 3)


def test_a_reset_refused_while_the_cause_persists_still_reads_back_as_written(profile: Profile) -> None:
    master = running(profile)
    master.write(Reg.VIRTUAL_INPUTS, 0x008)
    master.write(Reg.COMMAND, Command.RESET)  # EF still set: echoed, refused by the drive
    assert master.command_and_status() == (7, 4)


def test_a_run_ended_other_than_by_2000h_reads_0_and_a_stop_written_reads_5(profile: Profile) -> None:
    keypad, written = running(profile), running(profile)
    assert keypad.drive.keypad(Command.STOP)
    written.write(Reg.COMMAND, Command.STOP)
    assert keypad.command_and_status(0.0) == (0, 1)  # ramping down, still turning forward
    assert written.command_and_status(0.0) == (5, 1)
    assert keypad.command_and_status(3.0) == (0, 3)
    assert written.command_and_status(3.0) == (5, 3)


def test_a_run_command_refused_while_faulted_leaves_2000h_at_0(profile: Profile) -> None:
    master = running(profile)
    master.drive.force_fault(0x15)
    master.t += 0.01
    refused = master.slave.handle(WriteSingleRequest(1, Reg.COMMAND, Command.FORWARD), master.t)
    assert refused == ExceptionResponse(1, 0x06, ExceptionCode.ILLEGAL_FUNCTION)
    assert master.command_and_status() == (0, 4)


def test_a_reversal_and_a_jog_keep_the_command_written(profile: Profile) -> None:
    master = running(profile)
    master.write(Reg.COMMAND, Command.REVERSE)
    assert master.command_and_status(3.0) == (2, 2)
    master.write(Reg.COMMAND, Command.STOP)
    master.write(Reg.COMMAND, Command.JOG_FORWARD, after=3.0)
    assert master.command_and_status(1.0) == (3, 1)
    master.write(Reg.COMMAND, Command.JOG_STOP)
    assert master.command_and_status(2.0) == (8, 3)
    master.drive.power_cycle()
    assert master.command_and_status() == (0, 3)
