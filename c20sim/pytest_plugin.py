"""pytest glue for the ``c20sim`` fixture: the marker, the overridable fixtures, nothing else.

The handle itself, usable without pytest, is :class:`c20sim.testing.C20Sim`.
Settings come from three overridable fixtures, ``c20sim_profile``,
``c20sim_transport`` and ``c20sim_drives``, and per test from the marker::

    @pytest.mark.c20sim(profile="c20-2200hv", transport="pty", drives=(1, 2), clock="virtual", speed=1.0, seed=1,
                        bus_timing=True)

The marker wins over the fixtures; a setting given as None is left to the
fixture. ``clock`` is ``virtual`` (the default: time stands still until the
test calls ``advance``) or ``realtime`` (times ``speed``); ``seed`` seeds the
random link faults; ``bus_timing`` (on by default, as ``c20sim serve``) holds the line for each
transaction's RS485 time, so a master meets the real line's throughput.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterator, Sequence
from typing import Any

import pytest

from .drive.profile import DEFAULT_PROFILE, Profile
from .testing import SETTINGS, C20Sim, Settings, check_settings, start, transports
from .wire.errors import C20SimError

__all__ = ["c20sim", "c20sim_drives", "c20sim_profile", "c20sim_transport", "settings_for"]


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers",
        "c20sim(profile=None, transport=None, drives=None, clock='virtual', speed=1.0, seed=1, bus_timing=True): "
        f"settings of the c20sim fixture for this test (transport: {', '.join(transports())}, or several)",
    )


@pytest.fixture
def c20sim_profile() -> str | Profile:
    """The profile name, path or :class:`Profile` of the simulated drives (override to change)."""
    return DEFAULT_PROFILE


@pytest.fixture
def c20sim_transport() -> str | Sequence[str]:
    """``tcp`` (RTU over TCP, port 0), ``pty``, ``modbus-tcp``, or several: any transport the test handle opens
    (:func:`c20sim.testing.transports`, one row each); override to change."""
    return "tcp"


@pytest.fixture
def c20sim_drives() -> Sequence[int]:
    """Drive addresses on the bus (override to change)."""
    return (1,)


def settings_for(request: pytest.FixtureRequest, profile: object, transport: object, drives: object) -> Settings:
    """The fixtures' values, overridden by the test's ``c20sim`` marker; a bad setting is a
    :class:`pytest.UsageError` saying what is wrong."""
    marker = request.node.get_closest_marker("c20sim")
    if marker is not None and marker.args:
        raise pytest.UsageError("c20sim marker: give keywords, such as @pytest.mark.c20sim(drives=(1, 2))")
    given: dict[str, Any] = {"profile": profile, "transport": transport, "drives": drives}
    if marker is not None:
        unknown = sorted(set(marker.kwargs) - set(SETTINGS))
        if unknown:
            close = difflib.get_close_matches(unknown[0], SETTINGS, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise pytest.UsageError(
                f"c20sim marker: unknown setting {', '.join(unknown)}{hint}; use {', '.join(SETTINGS)}"
            )
        given.update({k: v for k, v in marker.kwargs.items() if v is not None})
    try:
        return check_settings(given)
    except C20SimError as exc:
        raise pytest.UsageError(str(exc)) from None


@pytest.fixture
def c20sim(
    request: pytest.FixtureRequest,
    c20sim_profile: str | Profile,
    c20sim_transport: str | Sequence[str],
    c20sim_drives: Sequence[int],
) -> Iterator[C20Sim]:
    """A running C20 simulator, clean for each test: RTU over TCP on port 0 and a virtual clock by default.

    A bad setting (the marker's, a fixture's) or a simulator that cannot start is the test's error in one line,
    without the plugin's traceback: the fault is in the test, not here."""
    try:
        running = start(settings_for(request, c20sim_profile, c20sim_transport, c20sim_drives))
    except (pytest.UsageError, C20SimError) as exc:
        message = str(exc) if str(exc).startswith("c20sim") else f"c20sim: {exc}"
    else:
        message = ""
    if message:  # failed outside the handler, so that no "during handling of the above exception" follows
        pytest.fail(message, pytrace=False)
    with running:
        yield running
