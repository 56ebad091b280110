"""Telemetry reads the drive as the register face does, and changes nothing."""

from __future__ import annotations

from dataclasses import asdict

from c20sim.drive.model import Drive
from c20sim.drive.profile import Profile
from c20sim.drive.telemetry import snapshot
from c20sim.wire.registers import Command, Reg


def test_telemetry_agrees_with_the_registers(profile: Profile) -> None:
    drive = Drive(profile)
    drive.set_load_torque(1.6)  # about 13 A of 10 A rated: the overload budget fills
    drive.write(Reg.SPEED_SETPOINT, 3000)
    drive.write(Reg.COMMAND, Command.FORWARD)
    drive.advance_to(5.0)
    tel = snapshot(drive)
    assert (tel.t, tel.state, tel.status, tel.speed_rpm, tel.set_speed_rpm) == (5.0, "forward", 1, 3000.0, 3000.0)
    assert tel.status == drive.read(Reg.STATUS1)
    assert tel.fault_code == drive.read(Reg.FAULT_CODE) == 0 and tel.fault_name == ""
    assert tel.hall == drive.read(Reg.HALL)
    assert (tel.input_terminals, tel.output_terminals) == (
        drive.read(Reg.INPUT_TERMINALS),
        drive.read(Reg.OUTPUT_TERMINALS),
    )
    assert round(tel.current_a * 100) == drive.read(Reg.OUTPUT_CURRENT)
    assert round(tel.bus_v * 10) == drive.read(Reg.BUS_VOLTAGE)
    assert round(tel.temperature_c * 10) == drive.read(Reg.TEMPERATURE)
    assert (tel.supply_v, tel.load_torque_nm, tel.ambient_c) == (48.0, 1.6, 25.0)
    assert tel.steady  # settled: skipping ahead in closed form
    assert 0.0 < tel.motor_overload == drive.motion.motor_i2t < 0.8  # used, below the pre-warning
    assert 0.0 < tel.drive_overload == drive.motion.drive_i2t < 0.8


def test_telemetry_names_the_fault_and_a_look_changes_nothing(profile: Profile) -> None:
    drive = Drive(profile)
    drive.force_fault(0x15)
    first = snapshot(drive)
    assert (first.state, first.status, first.fault_code) == ("fault", 4, 0x15)
    assert first.fault_name == profile.fault_name(0x15) != ""
    assert asdict(snapshot(drive)) == asdict(first) == asdict(drive.telemetry())
    drive.write(Reg.SPEED_SETPOINT, 100)
    assert snapshot(drive).steady is False  # a write ends a segment
