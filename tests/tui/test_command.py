"""``c20sim dashboard`` and bare ``c20sim``: the same endpoint options as serve, and errors as one line."""

from __future__ import annotations

import socket
from typing import Any

import pytest

from c20sim import cli
from c20sim.clock import VirtualClock
from c20sim.errors import C20SimError
from c20sim.profile import load_profile
from c20sim.serve import ServeOptions
from c20sim.simulator import Simulator
from c20sim.tui import Dashboard


@pytest.fixture
def runs(monkeypatch: pytest.MonkeyPatch) -> list[Dashboard]:
    """Dashboards that cli would run, not run."""
    started: list[Dashboard] = []

    def run(self: Dashboard, *args: Any, **kwargs: Any) -> None:
        started.append(self)

    monkeypatch.setattr(Dashboard, "run", run)
    return started


def test_bare_c20sim_runs_the_dashboard_on_the_default_endpoints(runs: list[Dashboard]) -> None:
    assert cli.main([]) == 0
    (app,) = runs
    assert (app.options.pty, app.options.tcp) == (True, "127.0.0.1:5020")
    assert not app.sim.virtual


def test_dashboard_takes_the_endpoint_options(runs: list[Dashboard]) -> None:
    assert cli.main(["dashboard", "--modbus-tcp", "127.0.0.1:0", "--drives", "1,2", "--clock", "virtual"]) == 0
    (app,) = runs
    assert (app.options.pty, app.options.tcp, app.options.modbus_tcp) == (False, None, "127.0.0.1:0")
    assert list(app.sim.drives) == [1, 2]
    assert app.sim.virtual


async def test_a_busy_port_ends_the_dashboard_with_its_error() -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        sim = Simulator(load_profile(), (1,), clock=VirtualClock())
        app = Dashboard(sim, ServeOptions(tcp=f"127.0.0.1:{port}"))
        async with app.run_test() as pilot:
            await pilot.pause()
        assert isinstance(app.error, C20SimError)
        assert str(port) in str(app.error)
        assert app.return_code == 2
