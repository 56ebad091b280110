"""Profiles load, and a bad one names the file, the key and what is allowed."""

from __future__ import annotations

from pathlib import Path

import pytest

from c20sim.drive.profile import DEFAULT_PROFILE, FaultCause, available_profiles, load_profile, profile_path
from c20sim.wire.errors import ProfileError
from c20sim.wire.registers import Access, Reg, parse_fcode

DEFAULT_TEXT = profile_path(DEFAULT_PROFILE).read_text()


def test_shipped_profiles_load() -> None:
    assert set(available_profiles()) >= {"c20-400hr", "c20-2200hv"}
    for name in available_profiles():
        profile = load_profile(name)
        assert profile.name == name
        assert profile.fault_code(FaultCause.UNDERVOLTAGE) == 0x0A


def test_default_profile_facts() -> None:
    profile = load_profile()
    assert profile.name == "c20-400hr"
    assert profile.supply.voltage_v == 48.0
    assert profile.default(0x000A) == 5000  # F00.10 = 50.00 Hz, the sheet's example
    assert profile.default(Reg.RUN_CHANNEL) == 2  # communication
    assert profile.default(Reg.SPEED_SOURCE) == 3  # Modbus
    assert profile.default(Reg.ADDRESS) == 1
    assert profile.default(Reg.BAUD) == 4  # 19200
    assert profile.registers.canonical(Reg.ADDRESS) == 0x0800
    assert profile.registers[0x0200].access is Access.RW_STOPPED
    assert profile.protocol.reply_to_bad_crc is True
    assert profile.protocol.max_read_registers == 1


def test_mains_profile_is_a_310_v_model() -> None:
    profile = load_profile("c20-2200hv")
    assert 300 <= profile.supply.voltage_v <= 320


def bad(tmp_path: Path, text: str) -> str:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ProfileError) as info:
        load_profile(str(path))
    message = str(info.value)
    assert message.startswith(str(path))
    return message


def test_out_of_range_names_key_and_range(tmp_path: Path) -> None:
    message = bad(tmp_path, DEFAULT_TEXT.replace("voltage_v = 48.0", "voltage_v = 900.0"))
    assert message.endswith("supply.voltage_v: 900.0 is out of range; allowed 5 to 800 V")


def test_misspelt_key_gets_did_you_mean(tmp_path: Path) -> None:
    message = bad(tmp_path, DEFAULT_TEXT.replace("turnaround_ms =", "turnarround_ms ="))
    assert "protocol.turnarround_ms: unknown key (did you mean 'turnaround_ms'?)" in message


def test_misspelt_fault_cause(tmp_path: Path) -> None:
    message = bad(tmp_path, DEFAULT_TEXT.replace('cause = "undervoltage"', 'cause = "undervoltag"'))
    assert "fault[9].cause: unknown cause 'undervoltag' (did you mean 'undervoltage'?)" in message


def test_missing_key(tmp_path: Path) -> None:
    message = bad(tmp_path, DEFAULT_TEXT.replace("kt_nm_per_a = 0.127", ""))
    assert "motor.kt_nm_per_a: missing; allowed 0.001 to 20 N m/A" in message


def test_parameter_default_outside_its_range(tmp_path: Path) -> None:
    message = bad(tmp_path, DEFAULT_TEXT.replace("default = 5000", "default = 50000"))
    assert "parameter F00.10.default: 50000 is out of range; allowed 0 to 40000" in message


def test_missing_mirror(tmp_path: Path) -> None:
    message = bad(tmp_path, DEFAULT_TEXT.replace('mirror = "2008H"', ""))
    assert "no function code mirrors 2008H (address)" in message


def test_bad_toml(tmp_path: Path) -> None:
    assert "not valid TOML" in bad(tmp_path, DEFAULT_TEXT + "\n[motor\n")


def test_unknown_profile_name_suggests_one() -> None:
    with pytest.raises(ProfileError, match="did you mean 'c20-400hr'"):
        load_profile("c20-400h")


def test_a_mirror_cannot_widen_the_sheets_range(tmp_path: Path) -> None:
    # F08.00 mirrors 2008H, 1-247 in the sheet: 250 would put the drive on a reserved address.
    text = DEFAULT_TEXT.replace("min = 1\nmax = 247", "min = 1\nmax = 250")
    assert text != DEFAULT_TEXT
    message = bad(tmp_path, text)
    assert message.endswith("parameter F08.00.max: 1-250 goes beyond 2008H's range in the sheet, 1-247")


MOTOR_CURVE = "motor_overload_curve = [[1.16, 3600.0], [1.5, 720.0], [1.8, 300.0], [2.0, 60.0]]"


def test_overload_curves_and_new_keys_load() -> None:
    profile = load_profile()
    assert profile.protection.motor_overload_curve == ((1.16, 3600.0), (1.5, 720.0), (1.8, 300.0), (2.0, 60.0))
    assert profile.protection.drive_overload_curve == ((1.1, 3600.0), (1.5, 60.0), (1.8, 10.0))
    assert (profile.supply.undervoltage_v, profile.supply.undervoltage_recover_v) == (20.0, 22.0)
    assert profile.control.min_speed_rpm == 100.0
    for code, default in (("F02.27", 1000), ("F08.03", 0), ("F11.03", 1), ("F11.04", 120)):
        spec = profile.registers[parse_fcode(code)]
        assert (profile.defaults[spec.address], spec.source) == (default, "assumed")


@pytest.mark.parametrize(
    ("curve", "message"),
    [
        ("[[1.5, 720.0], [1.16, 3600.0]]", "protection.motor_overload_curve[1]: multiples must rise and times fall"),
        ("[[1.16, 3600.0], [1.5, 3600.0]]", "protection.motor_overload_curve[1]: multiples must rise and times fall"),
        ("[[0.9, 3600.0]]", "protection.motor_overload_curve[0][0]: 0.9 is out of range; allowed 1.01 to 20 x rated"),
        ("[[1.5]]", "protection.motor_overload_curve[0]: must be a pair [multiple, seconds], not [1.5]"),
        (
            "[[1.5, nan]]",
            "protection.motor_overload_curve[0][1]: must be a finite number, not nan; allowed 0.01 to 36000 s",
        ),
        ("60.0", "protection.motor_overload_curve: must be a non-empty array [[multiple of rated current, seconds]"),
    ],
)
def test_a_bad_overload_curve_is_one_clear_line(tmp_path: Path, curve: str, message: str) -> None:
    assert MOTOR_CURVE in DEFAULT_TEXT
    assert message in bad(tmp_path, DEFAULT_TEXT.replace(MOTOR_CURVE, f"motor_overload_curve = {curve}"))


def test_the_recover_level_lies_between_the_trip_and_the_supply(tmp_path: Path) -> None:
    text = DEFAULT_TEXT.replace("undervoltage_recover_v = 22.0", "undervoltage_recover_v = 19.0")
    assert "supply.undervoltage_recover_v: 19 V must be between supply.undervoltage_v = 20 V" in bad(tmp_path, text)


def test_the_active_loads_free_speed_lies_above_the_rated_speed(tmp_path: Path) -> None:
    text = DEFAULT_TEXT.replace("active_load_free_rpm = 3300", "active_load_free_rpm = 2500")
    assert "motor.active_load_free_rpm: 2500 rpm must be above motor.rated_speed_rpm = 3000 rpm" in bad(tmp_path, text)


def test_protocol_quirks_of_the_sheets_edges(tmp_path: Path) -> None:
    protocol = load_profile().protocol
    assert (protocol.run_while_faulted_exception, protocol.byte_count_exception) == (1, 6)
    assert (protocol.simple_plc, protocol.lacking_feature_exception) == (True, 3)  # the F10 programme (issue 42)
    path = tmp_path / "bad.toml"
    path.write_text(DEFAULT_TEXT.replace("byte_count_exception = 6", "byte_count_exception = 4"))
    with pytest.raises(ProfileError) as info:
        load_profile(str(path))
    assert "protocol.byte_count_exception: 4 is not allowed; allowed: 3, 6" in str(info.value)
