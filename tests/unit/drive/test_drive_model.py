"""The drive's registers, ramps, control channels and speed sources, in virtual time."""

from __future__ import annotations

import itertools
from collections.abc import Callable

import pytest

from c20sim.drive.base import DrivePort
from c20sim.drive.model import F_CURRENT_LIMITING, STEP, Drive, HallFault
from c20sim.drive.profile import Profile, load_profile
from c20sim.drive.terminals import Input, Output
from c20sim.wire.errors import ModbusError
from c20sim.wire.protocol import ExceptionCode
from c20sim.wire.registers import FIXED_REGISTERS, Reg


@pytest.fixture(scope="module")
def profile() -> Profile:
    return load_profile("c20-400hr")


def cell(profile: Profile, register: int) -> int:
    """The storage cell the slave hands the drive for a register."""
    return profile.registers.canonical(register)


def test_drive_satisfies_the_port(profile: Profile) -> None:
    assert isinstance(Drive(profile), DrivePort)


def test_fresh_drive_reads_as_the_sheet_says(profile: Profile) -> None:
    drive = Drive(profile)
    assert drive.read(Reg.STATUS1) == 3
    assert drive.read(Reg.STATUS2) == 0x0041
    assert drive.read(Reg.DRIVE_ID) == 0x0020
    assert drive.read(Reg.FAULT_CODE) == 0
    assert drive.read(Reg.SOFTWARE_VERSION) == 100
    assert drive.read(Reg.TEMPERATURE) == 250
    assert drive.read(Reg.BUS_VOLTAGE) == 480
    assert drive.read(Reg.MOTOR_SPEED) == 0
    assert drive.read(Reg.RESTORE_DEFAULTS) == 0
    assert drive.read(cell(profile, Reg.POLE_PAIRS)) == 4
    assert drive.read(0x000A) == 5000  # F00.10, the sheet's example: 50.00 Hz
    assert not drive.running


def test_every_register_and_function_code_reads(profile: Profile) -> None:
    drive = Drive(profile)
    for address in list(FIXED_REGISTERS) + list(profile.defaults):
        value = drive.read(cell(profile, address))
        assert 0 <= value <= 0xFFFF
    with pytest.raises(KeyError):
        drive.read(0x0032)


def test_ram_registers_read_back(profile: Profile) -> None:
    drive = Drive(profile)
    for register, value in ((Reg.SPEED_SETPOINT, 1234), (Reg.VIRTUAL_OUTPUTS, 0x4), (Reg.WRITE_ENABLE, 1)):
        drive.write(register, value)
        assert drive.read(register) == value
    drive.write(Reg.COMMAND, 5)
    assert drive.read(Reg.COMMAND) == 5


def test_ramp_reaches_half_speed_at_half_time(profile: Profile) -> None:
    drive = Drive(profile)
    drive.write(cell(profile, Reg.ACCEL_TIME), 50)
    drive.write(Reg.SPEED_SETPOINT, 3000)
    drive.write(Reg.COMMAND, 1)
    drive.advance_to(2.5)
    assert drive.telemetry().speed_rpm == pytest.approx(1500.0, abs=1.0)
    assert drive.read(Reg.MOTOR_SPEED) == 1500
    assert drive.read(Reg.STATUS1) == 1
    assert drive.running
    drive.advance_to(5.0)
    assert drive.read(Reg.MOTOR_SPEED) == 3000


def test_frequencies_follow_pole_pairs(profile: Profile) -> None:
    drive = Drive(profile)
    drive.write(Reg.SPEED_SETPOINT, 3000)
    assert drive.read(Reg.SET_FREQUENCY) == 20000  # 200.00 Hz at 4 pole pairs, even before running
    assert drive.read(Reg.SET_SPEED) == 3000
    drive.write(Reg.COMMAND, 1)
    drive.advance_to(2.0)
    assert drive.read(Reg.MOTOR_SPEED) == 3000
    assert drive.read(Reg.OUTPUT_FREQUENCY) == 20000
    assert drive.read(Reg.RAMP_FREQUENCY) == 20000
    assert drive.read(Reg.OUTPUT_TERMINALS) == Output.RUN


def test_pole_pairs_change_the_frequency(profile: Profile) -> None:
    drive = Drive(profile)
    drive.write(cell(profile, Reg.POLE_PAIRS), 2)
    drive.write(Reg.SPEED_SETPOINT, 1500)
    assert drive.read(Reg.SET_FREQUENCY) == 5000  # 1500 rpm x 2 / 60 = 50.00 Hz


def test_electrical_quantities_are_consistent(profile: Profile) -> None:
    m = profile.motor
    drive = Drive(profile)
    drive.write(Reg.SPEED_SETPOINT, 3000)
    drive.write(Reg.COMMAND, 1)
    drive.set_load_torque(0.5)
    drive.advance_to(3.0)
    tel = drive.telemetry()
    torque = m.friction_nm + 0.5 + m.viscous_nm_per_krpm * 3.0
    assert tel.current_a == pytest.approx(torque / m.kt_nm_per_a)
    emf = m.kt_nm_per_a * 3000 * 2 * 3.141592653589793 / 60
    assert tel.output_voltage_v == pytest.approx(emf + tel.current_a * m.resistance_ohm)
    assert drive.read(Reg.OUTPUT_CURRENT) == round(tel.current_a * 100)
    assert drive.read(Reg.OUTPUT_POWER) == round(tel.output_voltage_v * tel.current_a)
    assert drive.read(Reg.OUTPUT_VOLTAGE) == round(tel.output_voltage_v * 10)
    assert tel.bus_v < profile.supply.voltage_v - 0.5  # the bus sags under load
    assert tel.temperature_c > profile.thermal.ambient_c


def test_stop_ramps_down_through_the_electronic_brake(profile: Profile) -> None:
    drive = Drive(profile)
    drive.write(Reg.SPEED_SETPOINT, 3000)
    drive.write(Reg.COMMAND, 1)
    drive.advance_to(1.0)
    drive.write(Reg.COMMAND, 5)  # 2004H = 0.5 s from 3000 rpm
    drive.advance_to(1.25)
    assert drive.read(Reg.STATUS1) == 1
    assert abs(drive.read(Reg.MOTOR_SPEED) - 1500) <= 6  # the loop trails by 1.5 rpm, the Hall reading by a sector
    drive.advance_to(1.6)
    assert drive.read(Reg.STATUS1) == 6
    assert drive.read(Reg.MOTOR_SPEED) == 0
    drive.advance_to(2.1)
    assert drive.read(Reg.STATUS1) == 3
    assert not drive.running


def test_free_stop_coasts_without_output(profile: Profile) -> None:
    drive = Drive(profile)
    drive.write(Reg.SPEED_SETPOINT, 3000)
    drive.write(Reg.COMMAND, 1)
    drive.advance_to(1.0)
    drive.write(Reg.COMMAND, 6)
    drive.advance_to(1.1)
    assert drive.read(Reg.STATUS1) == 3
    assert drive.read(Reg.OUTPUT_CURRENT) == 0
    assert 0 < drive.read(Reg.MOTOR_SPEED) < 3000
    assert not drive.running
    drive.advance_to(60.0)
    assert drive.read(Reg.MOTOR_SPEED) == 0


def test_reversing_decelerates_through_zero(profile: Profile) -> None:
    drive = Drive(profile)
    drive.write(Reg.SPEED_SETPOINT, 3000)
    drive.write(Reg.COMMAND, 1)
    drive.advance_to(1.0)
    drive.write(Reg.COMMAND, 2)
    drive.advance_to(1.25)
    tel = drive.telemetry()
    assert drive.read(Reg.STATUS1) == 2
    assert tel.speed_rpm == pytest.approx(1500.0, abs=2.0)  # still turning forward, slowing
    drive.advance_to(1.75)
    assert drive.telemetry().speed_rpm == pytest.approx(-1500.0, abs=2.0)
    drive.advance_to(3.0)
    assert drive.telemetry().speed_rpm == -3000.0
    assert drive.read(Reg.MOTOR_SPEED) == 3000


def test_jog_runs_at_the_jog_speed(profile: Profile) -> None:
    drive = Drive(profile)
    drive.write(Reg.COMMAND, 4)
    drive.advance_to(1.0)
    assert drive.telemetry().speed_rpm == -300.0
    assert drive.read(Reg.STATUS1) == 2
    assert drive.read(Reg.SET_SPEED) == 300
    drive.write(Reg.COMMAND, 8)
    drive.advance_to(2.0)
    assert drive.read(Reg.STATUS1) == 3


@pytest.mark.parametrize("limiting", [1, 0])
def test_current_limit_slows_a_heavy_ramp(profile: Profile, limiting: int) -> None:
    drive = Drive(profile)
    drive.write(F_CURRENT_LIMITING, limiting)
    drive.set_load_inertia(0.01)
    drive.write(cell(profile, Reg.ACCEL_TIME), 10)  # 1 s asks 26 A: limited (0.5 s asks 51 A: OC1 without limiting)
    drive.write(Reg.SPEED_SETPOINT, 3000)
    drive.write(Reg.COMMAND, 1)
    drive.advance_to(0.5)
    # On: the limiting level, 160 % of the drive's 11 A; off: the hardware clamp.
    amps = profile.protection.drive_rated_current_a * 1.6 if limiting else profile.protection.current_limit_a
    assert drive.read(Reg.OUTPUT_CURRENT) == round(amps * 100)
    assert drive.read(Reg.MOTOR_SPEED) < 2000
    assert drive.read(Reg.RAMP_FREQUENCY) == drive.read(Reg.OUTPUT_FREQUENCY)  # the ramp waits for the motor
    drive.advance_to(5.0)
    assert drive.read(Reg.MOTOR_SPEED) == 3000


def test_hall_steps_through_the_six_codes(profile: Profile) -> None:
    drive = Drive(profile)
    drive.write(cell(profile, Reg.POLE_PAIRS), 1)
    drive.write(Reg.COMMAND, 3)  # jog 300 rpm x 1 pole pair = 5 Hz: a sector every 33 ms
    drive.advance_to(1.0)
    seen: list[int] = []
    for i in range(1, 250):
        drive.advance_to(1.0 + i * STEP)
        code = drive.read(Reg.HALL)
        if not seen or seen[-1] != code:
            seen.append(code)
    assert len(seen) >= 7
    assert set(seen) == {1, 2, 3, 4, 5, 6}
    forward = [1, 3, 2, 6, 4, 5]
    for a, b in itertools.pairwise(seen):
        assert forward[(forward.index(a) + 1) % 6] == b


def test_run_command_is_refused_when_not_under_communication(profile: Profile) -> None:
    drive = Drive(profile)
    drive.write(cell(profile, Reg.RUN_CHANNEL), 1)
    assert drive.read(Reg.STATUS2) == 0x0021
    with pytest.raises(ModbusError) as info:
        drive.check_write(Reg.COMMAND, 1)
    assert info.value.code is ExceptionCode.OPERATION_FAILED
    drive.check_write(Reg.COMMAND, 5)  # stop and reset are always taken
    drive.check_write(Reg.COMMAND, 7)


def test_terminals_run_the_drive(profile: Profile) -> None:
    drive = Drive(profile)
    drive.write(cell(profile, Reg.RUN_CHANNEL), 1)
    drive.write(Reg.SPEED_SETPOINT, 1200)
    drive.write(Reg.VIRTUAL_INPUTS, Input.FWD)
    drive.advance_to(1.0)
    assert drive.read(Reg.STATUS1) == 1
    assert drive.read(Reg.INPUT_TERMINALS) == Input.FWD
    drive.set_terminal_inputs(Input.REV)  # physical REV with virtual FWD: both, so stop
    assert drive.read(Reg.INPUT_TERMINALS) == Input.FWD | Input.REV
    drive.advance_to(3.0)
    assert drive.read(Reg.STATUS1) == 3
    drive.write(Reg.VIRTUAL_INPUTS, 0)
    drive.advance_to(4.0)
    assert drive.read(Reg.STATUS1) == 2
    assert drive.telemetry().speed_rpm == -1200.0


def test_keypad_runs_only_on_the_keypad_channel(profile: Profile) -> None:
    drive = Drive(profile)
    assert drive.keypad(1) is False
    drive.write(cell(profile, Reg.RUN_CHANNEL), 0)
    drive.write(cell(profile, Reg.SPEED_SOURCE), 0)  # keypad speed F00.10 = 50.00 Hz
    assert drive.keypad(1) is True
    drive.advance_to(2.0)
    assert drive.read(Reg.MOTOR_SPEED) == 750  # 50 Hz x 60 / 4 pole pairs
    assert drive.read(Reg.STATUS2) == 0x0001


@pytest.mark.parametrize(
    ("source", "setup", "rpm"),
    [
        (1, lambda d: d.set_ai(1, 5.0), 1500),
        (2, lambda d: d.set_ai(2, 2.5), 750),
        (3, lambda d: d.write(Reg.SPEED_SETPOINT, 2222), 2222),
        (4, lambda d: d.set_terminal_inputs(Input.S1 | Input.S2), 1500),  # F05.03
    ],
)
def test_speed_sources(profile: Profile, source: int, setup: Callable[[Drive], None], rpm: int) -> None:
    drive = Drive(profile)
    drive.write(cell(profile, Reg.SPEED_SOURCE), source)
    setup(drive)
    drive.write(Reg.COMMAND, 1)
    drive.advance_to(3.0)
    assert drive.read(Reg.MOTOR_SPEED) == rpm
    assert drive.read(Reg.SET_SPEED) == rpm


def test_analog_inputs_read_back(profile: Profile) -> None:
    drive = Drive(profile)
    drive.set_ai(1, 3.3)
    drive.set_ai(3, 12.0)
    assert drive.read(Reg.AI1_VOLTAGE) == 330
    assert drive.read(Reg.AI3_VOLTAGE) == 1000
    with pytest.raises(ValueError):
        drive.set_ai(4, 1.0)


def test_virtual_outputs_or_into_the_output_terminals(profile: Profile) -> None:
    drive = Drive(profile)
    drive.write(Reg.VIRTUAL_OUTPUTS, Output.Y4)
    assert drive.read(Reg.OUTPUT_TERMINALS) == Output.Y4


def test_restore_defaults(profile: Profile) -> None:
    drive = Drive(profile)
    drive.write(0x000A, 2500)
    drive.write(Reg.RESTORE_DEFAULTS, 1)
    assert drive.read(0x000A) == 5000
    assert drive.read(Reg.RESTORE_DEFAULTS) == 0


def test_power_cycle_clears_ram_and_faults_and_keeps_parameters(profile: Profile) -> None:
    drive = Drive(profile)
    drive.write(Reg.SPEED_SETPOINT, 1000)
    drive.write(Reg.COMMAND, 1)
    drive.write(0x000A, 2500)
    drive.force_fault(0x11)
    drive.power_cycle()
    assert drive.read(Reg.SPEED_SETPOINT) == 0
    assert drive.read(Reg.COMMAND) == 0
    assert drive.read(Reg.FAULT_CODE) == 0
    assert drive.read(Reg.STATUS1) == 3
    assert drive.read(0x000A) == 2500


def test_idle_drive_skips_ahead(profile: Profile) -> None:
    drive = Drive(profile)
    drive.advance_to(1e6)
    tel = drive.telemetry()
    assert tel.steady
    assert drive._k == round(1e6 / STEP)
    assert drive.read(Reg.STATUS1) == 3


def test_other_profile_runs(profile: Profile) -> None:
    hv = load_profile("c20-2200hv")
    drive = Drive(hv)
    assert drive.read(Reg.BUS_VOLTAGE) == 3100
    drive.write(Reg.SPEED_SETPOINT, 3000)
    drive.write(Reg.COMMAND, 1)
    drive.advance_to(2.0)
    assert drive.read(Reg.MOTOR_SPEED) == 3000
    drive.write(Reg.COMMAND, 5)
    drive.advance_to(4.0)
    assert drive.read(Reg.STATUS1) == 3


def test_injected_conditions_read_back(profile: Profile) -> None:
    drive = Drive(profile)
    assert (drive.physical_inputs, drive.hall_fault, drive.ai(1), drive.held_fault) == (0, None, 0.0, None)
    drive.set_terminal_inputs(int(Input.EF))
    drive.write(Reg.VIRTUAL_INPUTS, int(Input.S1))
    assert drive.physical_inputs == Input.EF  # the virtual terminal is not a physical one
    assert drive.telemetry().input_terminals == Input.EF | Input.S1
    drive.set_hall_fault("stuck7")
    assert drive.hall_fault is HallFault.STUCK7
    drive.set_ai(2, 12.0)
    assert drive.ai(2) == 10.0
    with pytest.raises(ValueError):
        drive.ai(0)
    drive.force_fault(0x15, persistent=True)
    assert drive.held_fault == 0x15
    drive.release_fault()
    assert drive.held_fault is None
    drive.force_fault(0x0E)  # not persistent: nothing held
    assert drive.held_fault is None
