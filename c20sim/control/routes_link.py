"""The link faults' routes: a drive's link, and the whole bus's."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ..core.simulator import Simulator
from . import ops
from .routing import Route, Schema
from .schemas import link_schema


def _link(sim: Simulator, address: int | None = None) -> dict[str, Any]:
    return ops.link_state(ops.links(sim, address))


def _set_link(sim: Simulator, values: Mapping[str, object], address: int | None = None) -> dict[str, Any]:
    return ops.link_state(ops.set_link_faults(sim, address, values))


def _clear_link(sim: Simulator, address: int | None = None) -> dict[str, Any]:
    return ops.link_state(ops.clear_link_faults(sim, address))


def _link_body() -> Schema:
    return link_schema()


_D = "/drives/{address}"

#: A drive's link faults, then the bus's.
LINK: tuple[Route, ...] = (
    Route(
        "GET",
        f"{_D}/link",
        "drive_link",
        "-",
        _link,
        cli="link",
        help="show, set (KEY=VALUE) or --clear link faults (the bus without --drive)",
    ),
    Route(
        "PATCH",
        f"{_D}/link",
        "set_drive_link",
        '{"offline": true, "drop_next": 2, "delay": 0.5, ...}',
        _set_link,
        whole="values",
        body_schema=_link_body,
        changes=True,
        help="set a drive's link faults: offline, drop_next, delay, corrupt_crc, ...",
        cli="link",
    ),
    Route(
        "DELETE",
        f"{_D}/link",
        "clear_drive_link",
        "- (clears every link fault of the drive)",
        _clear_link,
        changes=True,
        cli="link",
    ),
    Route("GET", "/link", "link", "- (the whole bus's link faults; PATCH and DELETE as for a drive)", _link),
    Route(
        "PATCH",
        "/link",
        "set_link",
        '{"offline": true, ...}: as for a drive, on the whole bus',
        _set_link,
        whole="values",
        body_schema=_link_body,
        changes=True,
        help="set the whole bus's link faults: offline, drop_next, delay, corrupt_crc, ...",
        cli="link",
        listed=False,
    ),
    Route(
        "DELETE",
        "/link",
        "clear_link",
        "- (clears every link fault of the bus)",
        _clear_link,
        changes=True,
        cli="link",
        listed=False,
    ),
)
