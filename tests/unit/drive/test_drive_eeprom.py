"""Function codes as EEPROM: on disk before the write returns, atomic, and a bad file is named, not a traceback."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from c20sim.drive.model import Drive
from c20sim.drive.params import ParameterStore, StateFileError
from c20sim.drive.profile import Profile, load_profile
from c20sim.wire.errors import C20SimError
from c20sim.wire.registers import Reg

F00_10 = 0x000A


@pytest.fixture(scope="module")
def profile() -> Profile:
    return load_profile("c20-400hr")


def on_disk(path: Path) -> dict[str, int]:
    parameters: dict[str, int] = json.loads(path.read_text())["parameters"]
    return parameters


def test_without_a_state_file_nothing_is_written(
    profile: Profile, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    drive = Drive(profile)
    drive.write(F00_10, 2500)
    assert list(tmp_path.iterdir()) == []


def test_a_write_is_on_disk_before_it_returns(profile: Profile, tmp_path: Path) -> None:
    path = tmp_path / "drive.json"
    drive = Drive(profile, state_path=path)
    assert on_disk(path)["F00.10"] == 5000  # created at once, with the defaults
    drive.write(F00_10, 2500)
    assert on_disk(path)["F00.10"] == 2500
    drive.write(profile.registers.canonical(Reg.ACCEL_TIME), 77)  # a 20xxH mirror lands in its function code
    assert on_disk(path)["F00.11"] == 77
    assert [p.name for p in tmp_path.iterdir()] == ["drive.json"]  # no temporary file left behind


def test_parameters_survive_a_restart_and_a_power_cycle(profile: Profile, tmp_path: Path) -> None:
    path = tmp_path / "drive.json"
    drive = Drive(profile, state_path=path)
    drive.write(F00_10, 2500)
    drive.write(Reg.SPEED_SETPOINT, 1000)
    drive.power_cycle()
    assert drive.read(F00_10) == 2500
    assert drive.read(Reg.SPEED_SETPOINT) == 0
    again = Drive(profile, state_path=path)
    assert again.read(F00_10) == 2500


def test_restore_defaults_is_persisted(profile: Profile, tmp_path: Path) -> None:
    path = tmp_path / "drive.json"
    drive = Drive(profile, state_path=path)
    drive.write(F00_10, 2500)
    drive.write(Reg.RESTORE_DEFAULTS, 1)
    assert on_disk(path)["F00.10"] == 5000
    assert Drive(profile, state_path=path).read(F00_10) == 5000


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"\x00\xff\xfe garbage", "not a c20sim state file"),
        (b'{"format": "c20sim-eeprom/1", "profile": "c20-400hr", "parameters": {"F00.10": 25', "corrupt state file"),
        (b"[]", "not a c20sim state file"),
        (b'{"format": "c20sim-eeprom/1", "profile": "c20-2200hv", "parameters": {}}', "written for profile"),
        (b'{"format": "c20sim-eeprom/1", "profile": "c20-400hr", "parameters": {"F00.00": 5}}', "out of range"),
        (b'{"format": "c20sim-eeprom/1", "profile": "c20-400hr", "parameters": {"F00.10": "x"}}', "16-bit"),
        (b'{"format": "c20sim-eeprom/1", "profile": "c20-400hr", "parameters": {"bad": 1}}', "corrupt"),
        (b'{"format": "c20sim-eeprom/1", "profile": "c20-400hr", "parameters": 3}', "must be a table"),
    ],
)
def test_a_bad_state_file_is_named_in_a_clear_error(
    profile: Profile, tmp_path: Path, content: bytes, message: str
) -> None:
    path = tmp_path / "drive.json"
    path.write_bytes(content)
    with pytest.raises(StateFileError) as info:
        Drive(profile, state_path=path)
    assert isinstance(info.value, C20SimError)
    assert str(path) in str(info.value)
    assert message in str(info.value)
    assert path.read_bytes() == content  # never overwritten behind the user's back


def test_an_unwritable_place_is_a_clear_error(profile: Profile, tmp_path: Path) -> None:
    with pytest.raises(StateFileError, match="cannot write"):
        Drive(profile, state_path=tmp_path / "missing-dir" / "drive.json")


def test_a_crash_before_the_rename_leaves_the_old_file(
    profile: Profile, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "drive.json"
    store = ParameterStore(profile, path)
    store.set(F00_10, 2500)

    def killed(*args: object) -> None:
        raise KeyboardInterrupt  # the process dies between fsync and rename

    monkeypatch.setattr(os, "replace", killed)
    with pytest.raises(KeyboardInterrupt):
        store.set(F00_10, 1234)
    monkeypatch.undo()
    assert Drive(profile, state_path=path).read(F00_10) == 2500


CHILD = """
import sys
from c20sim.drive.params import ParameterStore
from c20sim.drive.profile import load_profile
store = ParameterStore(load_profile("c20-400hr"), sys.argv[1])
i = 0
while True:
    i += 1
    store.set(0x000A, i % 40000)
    if i % 20 == 0:
        print(i, flush=True)
"""


def test_kill_at_any_moment_leaves_a_whole_file(profile: Profile, tmp_path: Path) -> None:
    path = tmp_path / "drive.json"
    for round_ in range(4):
        child = subprocess.Popen(
            [sys.executable, "-c", CHILD, str(path)], stdout=subprocess.PIPE, text=True, cwd=Path(__file__).parent
        )
        assert child.stdout is not None
        for _ in range(round_ + 1):
            child.stdout.readline()  # wait for progress, then kill mid-stream
        child.send_signal(signal.SIGKILL)
        child.wait()
        child.stdout.close()
        value = Drive(profile, state_path=path).read(F00_10)
        assert 0 < value < 40000


def test_temporaries_left_by_a_kill_are_removed_at_the_next_start(profile: Profile, tmp_path: Path) -> None:
    state = tmp_path / "drive.json"
    ParameterStore(profile, state).set(F00_10, 2500)
    stale = tmp_path / ".drive.json.k3x9.tmp"  # what a kill between mkstemp and os.replace leaves
    stale.write_text("{half a file")
    other = tmp_path / ".other.json.k3x9.tmp"  # another file's temporary is not ours to remove
    other.write_text("{")
    store = ParameterStore(profile, state)
    assert store.get(F00_10) == 2500
    assert sorted(p.name for p in tmp_path.iterdir()) == [".other.json.k3x9.tmp", "drive.json"]
