"""What a new user meets in the dashboard in the first minutes: keys that act on the clock there is, and a word
when a Modbus TCP master was pointed at the RTU-over-TCP port."""

from __future__ import annotations

import pytest
from pymodbus.client import AsyncModbusTcpClient
from textual.widgets import Static
from textual.widgets._footer import FooterKey

from c20sim.core.clock import Clock, RealtimeClock, VirtualClock
from c20sim.tui import Dashboard
from tests.tui.conftest import attached, serving, until


def footer(app: Dashboard) -> dict[str, str]:
    """The keys the footer offers now (key -> description), and whether each is greyed out."""
    return {
        key.key: key.description + (" (disabled)" if key.disabled else "")
        for key in app.get_screen_main().query(FooterKey)
    }


@pytest.mark.parametrize(("clock", "advance"), [(VirtualClock(), True), (RealtimeClock(), False)])
async def test_the_footer_offers_t_only_on_a_virtual_clock(clock: Clock, advance: bool) -> None:
    """``t +1s`` advances a virtual clock; on a realtime clock it did nothing and was offered all the same. There
    the footer offers ``p Pause`` and ``<``/``>`` instead (tests/tui/test_title_footer.py: at 80 and 120 columns)."""
    with serving(clock=clock) as served:
        async with attached(served) as (app, pilot):
            await pilot.pause()
            keys = footer(app)
            assert keys == {
                "f": "Fwd",
                "r": "Rev",
                "s": "Stop",
                "j": "Jog",
                "x": "Reset",
                # the clock's keys (at 100 columns, wide enough for its second keys: FOOTER_WIDE)
                **(
                    {"t": "+1s", "T": "+10s"}
                    if advance
                    else {"p": "Pause", "less_than_sign": "Slower", "greater_than_sign": "Faster"}
                ),
                "question_mark": "Help",
                "q": "Quit",  # the frame log's space (pause) is in its own header: at 80 columns it pushed Quit off
                "ctrl+p": "palette",
            }
            t0 = served.sim.now()
            await pilot.press("t")
            await pilot.pause()
            if advance:
                await until(lambda: served.sim.now() == t0 + 1.0, "the virtual clock 1 s on")


async def test_a_modbus_tcp_master_on_the_rtu_port_is_told_where_to_go_on_the_dashboard() -> None:
    with serving(modbus_tcp=True) as served:
        assert served.server.endpoints.modbus_tcp is not None
        where = served.server.endpoints.modbus_tcp.name
        async with attached(served) as (app, _pilot):
            title = str(app.get_screen_main().query_one("#title", Static).render())
            assert f"connect: RTU/TCP 127.0.0.1:{served.port} · Modbus TCP {where} │" in title, title
            master = AsyncModbusTcpClient(
                "127.0.0.1", port=served.port, timeout=2, retries=0
            )  # connects on a loaded machine too
            assert await master.connect()
            try:
                for _ in range(2):
                    with pytest.raises(Exception, match="No response received"):
                        await master.read_holding_registers(0x2100, count=1, device_id=1)
            finally:
                master.close()
            said = (
                f"RTU over TCP 127.0.0.1:{served.port}: this looks like Modbus TCP: use --modbus-tcp (open on {where})"
            )

            def shown() -> list[str]:
                return [str(n.message) for n in app._notifications if n.severity == "warning"]

            await until(lambda: said in shown(), f"the notice on the dashboard; it shows {shown()}")
            assert shown().count(said) == 1


async def test_an_rtu_master_on_the_modbus_tcp_port_is_told_where_to_go_on_the_dashboard() -> None:
    from pymodbus import FramerType

    with serving(modbus_tcp=True) as served:
        assert served.server.endpoints.modbus_tcp is not None
        where = served.server.endpoints.modbus_tcp.name
        async with attached(served) as (app, _pilot):
            for _ in range(2):
                host, port = where.rsplit(":", 1)
                master = AsyncModbusTcpClient(host, port=int(port), framer=FramerType.RTU, timeout=2, retries=0)
                assert await master.connect()
                try:
                    with pytest.raises(Exception, match=r"Connection unexpectedly closed|No response received"):
                        await master.read_holding_registers(0x2100, count=1, device_id=1)
                finally:
                    master.close()
            said = (
                f"Modbus TCP {where}: this looks like Modbus RTU over TCP: use --tcp (RTU over TCP, open on "
                f"127.0.0.1:{served.port})"
            )

            def shown() -> list[str]:
                return [str(n.message) for n in app._notifications if n.severity == "warning"]

            await until(lambda: said in shown(), f"the notice on the dashboard; it shows {shown()}")
            assert shown().count(said) == 1
