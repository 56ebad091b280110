"""The service rows the API answers itself: the index, the telemetry, the profile, the health, the OpenAPI
document and the metrics (:func:`handlers`)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any, Protocol

from aiohttp import web

from ..core.simulator import Simulator
from ..drive.files import FileReadError, read_text
from .httpbody import Handler, reply
from .openapi import document
from .ops import ControlError
from .routing import Table

__all__ = ["ServedHost", "handlers"]


class ServedHost(Protocol):
    """What the service rows read of the API (:class:`c20sim.control.http.ControlApi`)."""

    sim: Simulator
    #: where masters connect (the ready file's endpoints)
    endpoints: Callable[[], dict[str, str]]
    readers: int
    serving: bool

    def snapshot(self) -> dict[str, Any]: ...

    async def scrape(self, accept: str) -> tuple[bytes, str]: ...


def handlers(api: ServedHost, table: Table) -> dict[str, Handler]:
    """The handlers of the service rows, by the row's name (``table``: the rows this listener serves, which the
    index and the document list)."""
    sim = api.sim

    async def index(request: web.Request) -> web.Response:
        sim.sync()
        return reply(
            {
                "profile": sim.profile.name,
                "drives": list(sim.drives),
                "clock": "virtual" if sim.virtual else "realtime",
                "t": sim.now(),
                "endpoints": api.endpoints(),
                "stream_readers": api.readers,
                "routes": table.listing(),
            }
        )

    async def get_telemetry(request: web.Request) -> web.Response:
        return reply(api.snapshot())

    async def get_profile(request: web.Request) -> web.Response:
        return await _profile(sim)

    async def health(request: web.Request) -> web.Response:
        if not api.serving:
            return reply({"status": "starting"}, 503)
        return reply({"status": "serving", "profile": sim.profile.name, "drives": list(sim.drives), "t": sim.now()})

    async def openapi(request: web.Request) -> web.Response:
        return reply(document(table))

    async def metrics(request: web.Request) -> web.Response:
        body, content_type = await api.scrape(request.headers.get("Accept", ""))
        response = web.Response(body=body)
        response.headers["Content-Type"] = content_type
        return response

    return {
        "index": index,
        "telemetry": get_telemetry,
        "profile": get_profile,
        "health": health,
        "openapi": openapi,
        "metrics": metrics,
    }


async def _profile(sim: Simulator) -> web.Response:
    """``GET /profile``: the served profile's TOML, read again from its file."""
    path = sim.profile.path
    if path is None:
        raise ControlError(f"the profile {sim.profile.name} was not loaded from a file", status=404)
    try:  # off the loop, and bounded: the file may have changed since it was loaded
        text = await asyncio.to_thread(read_text, path, "profile")
    except FileReadError as exc:
        raise ControlError(f"GET /profile: {exc}", status=410) from None
    return web.Response(text=text, content_type="application/toml")
