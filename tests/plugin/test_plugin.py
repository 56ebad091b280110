"""The c20sim pytest plugin as a user meets it: test files of their own, run by pytester."""

from __future__ import annotations

import fnmatch

import pytest
from pymodbus import FramerType
from pymodbus.client import ModbusTcpClient

from c20sim.testing import C20Sim

pytest_plugins = ["pytester"]


def run(pytester: pytest.Pytester, source: str, *args: str) -> pytest.RunResult:
    pytester.makepyfile(test_user=source)
    return pytester.runpytest(
        "-p",
        "no:cacheprovider",
        "-p",
        "no:textual-snapshot",
        "-p",
        "no:syrupy",
        "-p",
        "no:hypothesispytest",
        "-o",
        "asyncio_mode=auto",
        "-o",
        "asyncio_default_fixture_loop_scope=function",
        *args,
    )


def test_plain_test_runs_a_drive_over_rtu_over_tcp(pytester: pytest.Pytester) -> None:
    result = run(
        pytester,
        """
        from pymodbus import FramerType
        from pymodbus.client import ModbusTcpClient

        def test_forward_run(c20sim):
            assert c20sim.pty is None and c20sim.modbus_tcp_port is None
            client = ModbusTcpClient(c20sim.host, port=c20sim.port, framer=FramerType.RTU, timeout=2, retries=0)
            assert client.connect()
            client.write_register(0x2001, 1500, device_id=1)
            client.write_register(0x2000, 1, device_id=1)
            assert c20sim.advance(2.0) == 2.0
            assert client.read_holding_registers(0x3006, count=1, device_id=1).registers == [1500]
            client.close()
            c20sim.assert_written("2001H", 1500)
            c20sim.assert_written(0x2000, 1)
            c20sim.assert_register("status1", 1)
            assert c20sim.state().speed_rpm == 1500.0
        """,
    )
    result.assert_outcomes(passed=1)


def test_async_test_with_an_async_client(pytester: pytest.Pytester) -> None:
    result = run(
        pytester,
        """
        from pymodbus import FramerType
        from pymodbus.client import AsyncModbusTcpClient

        async def test_trip(c20sim):
            client = AsyncModbusTcpClient(c20sim.host, port=c20sim.port, framer=FramerType.RTU, timeout=2, retries=0)
            assert await client.connect()
            await client.write_register(0x2001, 1500, device_id=1)
            await client.write_register(0x2000, 1, device_id=1)
            c20sim.advance(1.0)
            c20sim.set(supply_v=15)
            c20sim.advance(0.1)
            reply = await client.read_holding_registers(0x2102, count=1, device_id=1)
            assert reply.registers == [0x0A]
            client.close()
            c20sim.assert_fault(0x0A)
        """,
    )
    result.assert_outcomes(passed=1)


def test_assert_written_shows_the_frames(pytester: pytest.Pytester) -> None:
    result = run(
        pytester,
        """
        from pymodbus import FramerType
        from pymodbus.client import ModbusTcpClient

        def test_wrong_speed(c20sim):
            client = ModbusTcpClient(c20sim.host, port=c20sim.port, framer=FramerType.RTU, timeout=2, retries=0)
            assert client.connect()
            client.write_register(0x2001, 1400, device_id=1)
            client.close()
            c20sim.assert_written("2001H", 1500)
        """,
    )
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(
        [
            "E       AssertionError: drive 1: no accepted write of 1500 (0x05DC) to 2001H; writes to 2001H seen: 1400",
            "E       frames on the line:",
            "E         +  0.0000 s rx 01 06 20 01 05 78 D0 B8    write 2001H = 0578: 1400 rpm",
            "E         +  0.014* s tx 01 06 20 01 05 78 D0 B8    write 2001H = 0578: 1400 rpm",
        ]
    )


def test_a_refused_write_is_not_written(pytester: pytest.Pytester) -> None:
    result = run(
        pytester,
        """
        from pymodbus import FramerType
        from pymodbus.client import ModbusTcpClient

        def test_locked(c20sim):
            client = ModbusTcpClient(c20sim.host, port=c20sim.port, framer=FramerType.RTU, timeout=2, retries=0)
            assert client.connect()
            assert client.write_register(0x000A, 2500, device_id=1).isError()  # function codes locked (200EH = 0)
            client.close()
            c20sim.assert_written("F00.10", 2500)
        """,
    )
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(
        [
            "E       AssertionError: drive 1: no accepted write of 2500 (0x09C4) to F00.10; writes to F00.10 seen: 2500, refused: *"
        ]
    )


def test_a_write_the_drive_never_received_is_not_written(pytester: pytest.Pytester) -> None:
    result = run(
        pytester,
        """
        import pytest
        from pymodbus import FramerType
        from pymodbus.client import ModbusTcpClient
        from pymodbus.exceptions import ModbusIOException

        def test_offline(c20sim):
            c20sim.link_faults(1, offline=True)
            client = ModbusTcpClient(c20sim.host, port=c20sim.port, framer=FramerType.RTU, timeout=0.2, retries=0)
            assert client.connect()
            with pytest.raises(ModbusIOException):
                client.write_register(0x2001, 1500, device_id=1)
            client.close()
            assert c20sim.read("2001H") == 0
            c20sim.assert_written("2001H", 1500)
        """,
    )
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(
        [
            "E       AssertionError: drive 1: no accepted write of 1500 (0x05DC) to 2001H; "
            "writes to 2001H seen: 1500, not received (drive offline (injected))",
            "E       frames on the line:",
            "E         +  0.0000 s rx 01 06 20 01 05 DC D1 03    write 2001H = 05DC: 1500 rpm  (drive offline (injected))",
        ]
    )


def test_assert_written_matches_the_reply_to_its_own_request(pytester: pytest.Pytester) -> None:
    result = run(
        pytester,
        """
        import pytest
        from pymodbus import FramerType
        from pymodbus.client import ModbusTcpClient
        from pymodbus.exceptions import ModbusIOException

        @pytest.mark.c20sim(drives=(1, 2))
        def test_refused_then_another_drive_answers(c20sim):
            c20sim.link_faults(1, forced_exception=4, drop_next=1)  # refused, and the refusal lost
            client = ModbusTcpClient(c20sim.host, port=c20sim.port, framer=FramerType.RTU, timeout=0.2, retries=0)
            assert client.connect()
            with pytest.raises(ModbusIOException):
                client.write_register(0x2001, 1500, device_id=1)
            assert not client.read_holding_registers(0x2103, count=1, device_id=2).isError()
            with pytest.raises(ModbusIOException):  # broadcast: taken by both, unanswered
                client.write_register(0x2001, 1500, device_id=0)
            client.close()
            assert [(r.direction, r.slave, r.kind) for r in c20sim.frames()] == [
                ("rx", 1, "request"), ("tx", 1, "dropped"), ("rx", 2, "request"), ("tx", 2, "reply"),
                ("rx", 0, "request"),
            ]
            c20sim.assert_written("2001H", 1500, drive=2)  # by the broadcast
            c20sim.clear_frames()
            c20sim.link_faults(1, forced_exception=4, drop_next=1)
            client.connect()
            with pytest.raises(ModbusIOException):
                client.write_register(0x2001, 1500, device_id=1)
            client.read_holding_registers(0x2103, count=1, device_id=2)
            client.close()
            c20sim.assert_written("2001H", 1500, drive=1)
        """,
    )
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(
        [
            "E       AssertionError: drive 1: no accepted write of 1500 (0x05DC) to 2001H; "
            "writes to 2001H seen: 1500, refused: *",
        ]
    )


def test_assert_register_failure_says_what_it_read(pytester: pytest.Pytester) -> None:
    result = run(
        pytester,
        """
        def test_status(c20sim):
            c20sim.assert_register("2100H", 1, tolerance=0)
        """,
    )
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(
        [
            "E       AssertionError: drive 1: 2100H (status word 1) reads 3 (stopped), expected 1; t = 0 s",
            "E       no frames on the line",
        ]
    )


def test_overridden_fixtures_and_the_marker(pytester: pytest.Pytester) -> None:
    pytester.makeconftest(
        """
        import pytest

        @pytest.fixture
        def c20sim_drives():
            return (3, 4)

        @pytest.fixture
        def c20sim_transport():
            return ("tcp", "modbus-tcp")
        """
    )
    result = run(
        pytester,
        """
        import os
        import pytest
        from pymodbus.client import ModbusSerialClient

        def test_fixtures(c20sim):
            assert c20sim.addresses == (3, 4)
            assert c20sim.port and c20sim.modbus_tcp_port and c20sim.pty is None
            assert c20sim.read("address", drive=4) == 4
            assert c20sim.profile.name == "c20-400hr"

        @pytest.mark.c20sim(profile="c20-2200hv", transport="pty", drives=(7,))
        def test_marker(c20sim):
            assert (c20sim.addresses, c20sim.profile.name, c20sim.port) == ((7,), "c20-2200hv", None)
            assert os.path.exists(c20sim.pty)
            client = ModbusSerialClient(c20sim.pty, timeout=2, retries=0)
            assert client.connect()
            assert client.read_holding_registers(0x2103, count=1, device_id=7).registers == [0x20]
            client.close()
            assert [r.direction for r in c20sim.frames(drive=7)] == ["rx", "tx"]

        @pytest.mark.c20sim(clock="realtime")
        def test_realtime(c20sim):
            with pytest.raises(Exception, match="only be advanced with the virtual clock"):
                c20sim.advance(1)
        """,
    )
    result.assert_outcomes(passed=3)


def test_faults_link_faults_and_drives(pytester: pytest.Pytester) -> None:
    result = run(
        pytester,
        """
        import pytest
        from pymodbus import FramerType
        from pymodbus.client import ModbusTcpClient
        from pymodbus.exceptions import ModbusIOException
        from c20sim import C20SimError

        @pytest.mark.c20sim(drives=(1, 2))
        def test_everything(c20sim):
            one, two = c20sim.drives
            two.inject_fault(17, persistent=True)
            assert two.state().fault_code == 17 and one.state().fault_code == 0
            assert two.press("reset") is False
            assert two.clear_fault() is True
            assert c20sim.drive(2).read("fault_code") == 0

            one.link_faults(offline=True)
            client = ModbusTcpClient(c20sim.host, port=c20sim.port, framer=FramerType.RTU, timeout=0.3, retries=0)
            assert client.connect()
            with pytest.raises(ModbusIOException):
                client.read_holding_registers(0x2103, count=1, device_id=1)
            assert client.read_holding_registers(0x2103, count=1, device_id=2).registers == [0x20]
            c20sim.clear_link_faults(1)
            assert client.read_holding_registers(0x2103, count=1, device_id=1).registers == [0x20]
            client.close()
            assert [r.note for r in c20sim.frames(drive=1)][0] == "drive offline (injected)"

            with pytest.raises(C20SimError, match="unknown condition 'supply'; did you mean 'supply_v'"):
                c20sim.set(supply=3)
            with pytest.raises(C20SimError, match="no drive at address 5; drives: 1, 2"):
                c20sim.drive(5)
            with pytest.raises(C20SimError, match="^seconds: expected a finite number, got nan$"):
                c20sim.advance(float("nan"))
            assert c20sim.now() == 0.0
        """,
    )
    result.assert_outcomes(passed=1)


def test_bad_marker_is_a_usage_error(pytester: pytest.Pytester) -> None:
    result = run(
        pytester,
        """
        import pytest

        @pytest.mark.c20sim(transport="serial")
        def test_bad(c20sim):
            pass
        """,
    )
    result.assert_outcomes(errors=1)
    assert setup_error(result) == ["c20sim: unknown transport 'serial'; use one or more of tcp, pty, modbus-tcp"]


def setup_error(result: pytest.RunResult) -> list[str]:
    """What the run said between the header of the one set-up error and the next section: the plugin's words."""
    lines = result.stdout.lines
    start = next(i for i, line in enumerate(lines) if "ERROR at setup of" in line)
    end = next(i for i in range(start + 1, len(lines)) if lines[i].startswith(("=====", "_____")))
    return lines[start + 1 : end]


@pytest.mark.parametrize(
    ("source", "message"),
    [
        (
            "@pytest.mark.c20sim(profil='c20-2200hv')",
            "c20sim marker: unknown setting profil (did you mean 'profile'?); "
            "use profile, transport, drives, clock, speed, seed, bus_timing",
        ),
        (
            "@pytest.mark.c20sim(profile='c20-400hx')",
            "c20sim: profile: c20-400hx: no such profile; shipped profiles: c20-2200hv, c20-400hr "
            "(did you mean 'c20-400hr'?)",
        ),
        (
            "@pytest.mark.c20sim('c20-400hr')",
            "c20sim marker: give keywords, such as @pytest.mark.c20sim(drives=(1, 2))",
        ),
        (
            "@pytest.fixture\ndef c20sim_profile():\n    return 'c20-400'\n",
            "c20sim: profile: c20-400: no such profile; shipped profiles: c20-2200hv, c20-400hr "
            "(did you mean 'c20-400hr'?)",
        ),
    ],
)
def test_a_set_up_error_is_one_line_without_the_plugins_traceback(
    pytester: pytest.Pytester, source: str, message: str
) -> None:
    """A typo in the marker or a profile: the one line that says what is wrong, and nothing of the plugin's code."""
    result = run(pytester, f"import pytest\n\n{source}\ndef test_bad(c20sim):\n    pass\n")
    result.assert_outcomes(errors=1)
    assert setup_error(result) == [message]
    assert "pytest_plugin.py" not in result.stdout.str()


def test_none_in_the_marker_leaves_the_setting_to_the_fixture(pytester: pytest.Pytester) -> None:
    result = run(
        pytester,
        """
        import pytest

        @pytest.fixture
        def c20sim_drives():
            return (4,)

        @pytest.mark.c20sim(profile=None, transport=None, drives=None, clock=None, speed=None, seed=None)
        def test_defaults(c20sim):
            assert (c20sim.profile.name, c20sim.addresses, c20sim.port is not None) == ("c20-400hr", (4,), True)
            assert c20sim.advance(1) == 1.0
        """,
    )
    result.assert_outcomes(passed=1)


@pytest.mark.parametrize(
    ("marker", "message"),
    [
        ("drives=(1, 1)", "c20sim: drives (1, 1): address 1 is listed twice"),
        ("drives=(0,)", "c20sim: drives (0,): address 0 is outside 1-247"),
        ("drives=(248,)", "c20sim: drives (248,): address 248 is outside 1-247"),
        ("drives=()", "c20sim: drives (): give drive addresses 1-247, such as (1, 2)"),
        ("drives=('1',)", "c20sim: drives ('1',): give drive addresses 1-247, such as (1, 2)"),
        ("transport=5", "c20sim: transport 5: give a name or a sequence of tcp, pty, modbus-tcp"),
        ("clock='wall'", "c20sim: unknown clock 'wall'; use 'virtual' or 'realtime'"),
        ("speed=0", "c20sim: speed 0: give a positive number of model seconds per wall second"),
        ("speed='fast'", "c20sim: speed 'fast': give a positive number of model seconds per wall second"),
        ("seed='x'", "c20sim: seed 'x': give a whole number"),
        ("profile=3", "c20sim: profile 3: give a profile name, a path or a Profile"),
        ("profile='c20-9999'", "c20sim: profile: *c20-9999*"),
    ],
)
def test_a_bad_marker_setting_says_what_is_wrong(pytester: pytest.Pytester, marker: str, message: str) -> None:
    result = run(
        pytester,
        f"""
        import pytest

        @pytest.mark.c20sim({marker})
        def test_bad(c20sim):
            pass
        """,
    )
    result.assert_outcomes(errors=1)
    [said] = setup_error(result)
    assert fnmatch.fnmatchcase(said, message), said


def test_trip_by_cause_and_never_written(c20sim: C20Sim) -> None:
    client = ModbusTcpClient(c20sim.host or "", port=c20sim.port or 0, framer=FramerType.RTU, timeout=2, retries=0)
    assert client.connect()
    try:
        assert not client.write_register(0x2001, 1500, device_id=1).isError()
        assert not client.write_register(0x2000, 1, device_id=1).isError()
    finally:
        client.close()
    c20sim.advance(2.0)
    c20sim.trip("overvoltage")
    assert c20sim.drive().conditions()["supply_v"] == 68.2  # 110 % of the 62 V trip level
    c20sim.advance(0.5)
    c20sim.assert_fault(0x09)  # OV3: at constant speed
    c20sim.assert_written("2001H", 1500, count=1)
    c20sim.assert_written("2000H", count=1)
    c20sim.assert_written("F00.10", count=0)
    with pytest.raises(AssertionError, match=r"^drive 1: 1 accepted write\(s\) of any value to 2001H, expected 0"):
        c20sim.assert_written("2001H", count=0)


def test_the_handle_reads_the_fault_record_a_master_reads(pytester: pytest.Pytester) -> None:
    """Issue 42: c20sim.fault_record() is the record in words; the same cells over the wire hold the raw values."""
    result = run(
        pytester,
        """
        from pymodbus import FramerType
        from pymodbus.client import ModbusTcpClient

        def test_record(c20sim):
            client = ModbusTcpClient(c20sim.host, port=c20sim.port, framer=FramerType.RTU, timeout=2, retries=0)
            assert client.connect()
            client.write_register(0x2001, 1500, device_id=1)
            client.write_register(0x2000, 1, device_id=1)
            c20sim.advance(3.0)
            c20sim.set(supply_v=15)
            c20sim.advance(0.2)
            record = c20sim.fault_record()
            assert record["faults"] == [0x0A, 0, 0, 0, 0, 0]
            at = record["at_fault"]
            assert at["running_hz"] == 100.0 and at["outputs"] == 1 and 19.5 <= at["bus_v"] <= 20.0
            assert record["at_previous"]["running_hz"] == 0
            raw = [client.read_holding_registers(a, count=1, device_id=1).registers[0] for a in (0x071B, 0x0721)]
            assert raw == [0x0A, 10000]
            assert c20sim.drive(1).fault_record() == record
            client.close()
        """,
    )
    result.assert_outcomes(passed=1)
