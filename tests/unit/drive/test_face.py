"""The register face: RAM registers, function codes and computed cells, and what a write does."""

from __future__ import annotations

import pytest

from c20sim.drive import face
from c20sim.drive.model import Drive
from c20sim.drive.profile import Profile
from c20sim.drive.terminals import Input, Output
from c20sim.wire.errors import ModbusError
from c20sim.wire.protocol import ExceptionCode
from c20sim.wire.registers import FIXED_REGISTERS, Command, Reg, RunChannel


def test_every_register_of_the_sheet_reads_through_its_storage_cell(profile: Profile) -> None:
    drive = Drive(profile)
    cells = {profile.registers.canonical(address) for address in FIXED_REGISTERS}
    values = {cell: face.read(drive, cell) for cell in cells}
    assert values[Reg.DRIVE_ID] == face.DRIVE_ID == 0x0020
    assert values[Reg.RESTORE_DEFAULTS] == 0  # 200FH has no cell: it reads 0
    assert values[Reg.SOFTWARE_VERSION] == profile.software_version
    assert set(face.READERS) <= cells
    with pytest.raises(KeyError):
        face.read(drive, 0x4000)


def test_ram_registers_read_back_what_was_written_until_a_power_cycle(profile: Profile) -> None:
    drive = Drive(profile)
    face.write(drive, Reg.SPEED_SETPOINT, 1234)
    face.write(drive, Reg.VIRTUAL_OUTPUTS, 0x0C)
    assert [face.read(drive, r) for r in (Reg.SPEED_SETPOINT, Reg.VIRTUAL_OUTPUTS)] == [1234, 0x0C]
    assert face.read(drive, Reg.OUTPUT_TERMINALS) == 0x0C
    drive.power_cycle()
    assert [face.read(drive, r) for r in face.RAM_REGISTERS] == [0] * len(face.RAM_REGISTERS)


def test_a_run_command_is_refused_unless_the_run_channel_is_communication(profile: Profile) -> None:
    drive = Drive(profile)
    face.check_write(drive, Reg.COMMAND, Command.FORWARD)
    face.write(drive, profile.registers.canonical(Reg.RUN_CHANNEL), RunChannel.KEYPAD)
    with pytest.raises(ModbusError) as refused:
        face.check_write(drive, Reg.COMMAND, Command.FORWARD)
    assert refused.value.code is ExceptionCode.OPERATION_FAILED
    assert str(refused.value).endswith("run commands come from the keypad (F00.01 = 0)")
    face.check_write(drive, Reg.COMMAND, Command.STOP)  # stop and reset are taken from anywhere
    face.check_write(drive, Reg.COMMAND, Command.RESET)


def test_a_command_write_moves_the_state_and_the_status_words_follow(profile: Profile) -> None:
    drive = Drive(profile)
    assert (face.read(drive, Reg.STATUS1), face.read(drive, Reg.STATUS2)) == (3, 0x41)  # stopped; comm, bus
    face.write(drive, Reg.SPEED_SETPOINT, 1500)
    face.write(drive, Reg.COMMAND, Command.REVERSE)
    drive.advance_to(2.0)
    assert face.read(drive, Reg.STATUS1) == 2
    assert face.read(drive, Reg.OUTPUT_TERMINALS) == Output.RUN
    assert face.read(drive, Reg.SET_FREQUENCY) == face.read(drive, Reg.OUTPUT_FREQUENCY) == 10000  # 100.00 Hz
    face.write(drive, Reg.COMMAND, Command.STOP)
    drive.advance_to(2.01)
    assert face.read(drive, Reg.STATUS1) == 2  # decelerating reads the direction of rotation
    drive.motion.motor_i2t = 0.81  # past the 80 % pre-warning
    assert face.read(drive, Reg.STATUS2) == 0x41 | face.STATUS2_OVERLOAD


def test_the_fault_reported_is_the_latched_one_and_undervoltage_while_off(profile: Profile) -> None:
    drive = Drive(profile)
    drive.force_fault(0x15)
    assert face.read(drive, Reg.FAULT_CODE) == face.read(drive, Reg.CURRENT_FAULT) == 0x15
    assert face.read(drive, Reg.OUTPUT_TERMINALS) == Output.FAULT
    drive.set_supply_voltage(0.0)
    drive.power_cycle()
    assert (face.read(drive, Reg.STATUS1), face.read(drive, Reg.FAULT_CODE)) == (5, 0x0A)
    assert face.read(drive, Reg.STATUS2) & face.STATUS2_BUS == 0


def test_the_output_values_are_zero_while_the_output_stage_is_off(profile: Profile) -> None:
    drive = Drive(profile)
    drive.set_active_load(0.5)  # a hoist's weight turns the rotor with the output off
    drive.advance_to(1.0)
    assert drive.motion.speed > 100.0
    outputs = (Reg.OUTPUT_FREQUENCY, Reg.OUTPUT_VOLTAGE, Reg.OUTPUT_CURRENT, Reg.OUTPUT_POWER)
    assert [face.read(drive, r) for r in outputs] == [0, 0, 0, 0]
    assert face.read(drive, Reg.MOTOR_SPEED) > 100  # the Halls see it turn


def test_writes_reach_the_virtual_inputs_the_parameters_and_restore_defaults(profile: Profile) -> None:
    drive = Drive(profile)
    face.write(drive, Reg.VIRTUAL_INPUTS, Input.EF)
    drive.advance_to(0.01)
    assert face.read(drive, Reg.INPUT_TERMINALS) == Input.EF
    assert face.read(drive, Reg.FAULT_CODE) == 0x11  # the external fault input trips
    accel = profile.registers.canonical(Reg.ACCEL_TIME)
    face.write(drive, accel, 20)
    assert (face.read(drive, accel), drive.motion.cfg.up) == (20, 1.5)
    face.write(drive, Reg.RESTORE_DEFAULTS, 1)
    assert (face.read(drive, accel), drive.motion.cfg.up) == (profile.defaults[accel], 6.0)
