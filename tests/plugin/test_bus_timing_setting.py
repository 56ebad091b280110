"""The test handle's ``bus_timing`` setting: on by default, as ``c20sim serve``; off where asked; checked."""

from __future__ import annotations

import pytest

from c20sim.testing import C20Sim, check_settings
from c20sim.wire.errors import C20SimError


def test_the_handle_holds_the_line_by_default_and_not_when_asked() -> None:
    assert check_settings({}).bus_timing is True
    with C20Sim.start() as sim:
        assert sim._server.line.bus_timing is True
    with C20Sim.start(bus_timing=False) as sim:
        assert sim._server.line.bus_timing is False


def test_a_bad_bus_timing_says_what_is_wrong() -> None:
    with pytest.raises(C20SimError, match=r"^c20sim: bus_timing 'yes': give True or False$"):
        check_settings({"bus_timing": "yes"})


@pytest.mark.c20sim(bus_timing=False)
def test_the_marker_turns_it_off(c20sim: C20Sim) -> None:
    assert c20sim._server.line.bus_timing is False
