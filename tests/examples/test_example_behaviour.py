"""Example: a package adds named behaviours (device quirks) through the ``c20sim.behaviours`` entry points.

The package here is ``tests/examples/c20_quirks``; a real one declares its entry points in its
pyproject.toml (see that module's docstring). The fixture below installs the same entry points for
the test by writing the metadata pip would write, so ``importlib.metadata`` finds them as it would
after ``pip install``. A profile selects them with ``behaviours = [...]``.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from pymodbus import FramerType
from pymodbus.client import ModbusTcpClient

from c20sim.core.simulator import Simulator
from c20sim.drive.behaviours import GROUP, available
from c20sim.drive.profile import load_profile, profile_path
from c20sim.testing import C20Sim
from c20sim.wire.errors import ProfileError

HERE = Path(__file__).resolve().parent
ENTRY_POINTS = f"""[{GROUP}]
quantised-speed = c20_quirks:QuantisedSpeed
no-setpoint-in-fault = c20_quirks:NoSetpointInFault
weak-supply = c20_quirks:WeakSupply
"""


@pytest.fixture
def installed(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """c20_quirks as pip would install it: the package on the path and its dist-info with entry points."""
    site = tmp_path / "site"
    info = site / "c20_quirks-1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: c20-quirks\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(ENTRY_POINTS)
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.syspath_prepend(str(HERE))


def profile_with(tmp_path: Path, *behaviours: str) -> Path:
    path = tmp_path / "quirky.toml"
    names = ", ".join(f'"{b}"' for b in behaviours)
    path.write_text(f"behaviours = [{names}]\n" + profile_path("c20-400hr").read_text())
    return path


@pytest.fixture
def quirky(installed: None, tmp_path: Path) -> Iterator[tuple[C20Sim, ModbusTcpClient]]:
    path = profile_with(tmp_path, "quantised-speed", "no-setpoint-in-fault", "weak-supply")
    with C20Sim.start(path) as sim:
        assert sim.host is not None and sim.port is not None
        client = ModbusTcpClient(sim.host, port=sim.port, framer=FramerType.RTU, timeout=2, retries=0)
        assert client.connect()
        yield sim, client
        client.close()


def test_the_entry_points_are_found(installed: None) -> None:
    assert {"quantised-speed", "no-setpoint-in-fault", "weak-supply"} <= set(available())


def test_register_reads_writes_and_the_step_hooked_by_the_profile(quirky: tuple[C20Sim, ModbusTcpClient]) -> None:
    sim, client = quirky
    client.write_register(0x2001, 1234, device_id=1)
    client.write_register(0x2000, 1, device_id=1)
    sim.advance(3.0)
    speed = client.read_holding_registers(0x3006, count=1, device_id=1).registers[0]
    assert speed == 1230  # the drive runs at 1234 rpm; the firmware reports it to 10 rpm
    assert sim.state().speed_rpm == pytest.approx(1234, abs=0.5)
    state = sim.state()
    assert state.current_a > 0.1
    assert state.supply_v == pytest.approx(48.0 - 0.5 * state.current_a, abs=0.05)  # the weak supply droops
    sim.inject_fault(16)
    refused = client.write_register(0x2001, 1000, device_id=1)
    assert refused.isError() and refused.exception_code == 0x04
    sim.clear_fault()
    assert not client.write_register(0x2001, 1000, device_id=1).isError()


def test_a_profile_without_behaviours_reads_the_plain_value(installed: None) -> None:
    with C20Sim.start() as sim:
        assert sim.host is not None and sim.port is not None
        client = ModbusTcpClient(sim.host, port=sim.port, framer=FramerType.RTU, timeout=2, retries=0)
        assert client.connect()
        client.write_register(0x2001, 1234, device_id=1)
        client.write_register(0x2000, 1, device_id=1)
        sim.advance(3.0)
        assert client.read_holding_registers(0x3006, count=1, device_id=1).registers == [1234]
        client.close()


def test_an_unknown_behaviour_names_the_profile_and_what_is_installed(installed: None, tmp_path: Path) -> None:
    path = profile_with(tmp_path, "quantized-speed")
    with pytest.raises(ProfileError) as caught:
        Simulator(load_profile(str(path)))
    assert str(caught.value).startswith(
        f"{path}: behaviours: no behaviour 'quantized-speed' is installed (entry-point group c20sim.behaviours; "
        "installed: "
    )
    assert "quantised-speed" in str(caught.value)
