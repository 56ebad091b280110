"""The control API's service routes: health, the OpenAPI document, the clock, set-ups, generators.

Added to the app by :func:`c20sim.control.http.make_app`, with its helpers
(the JSON body, the drive address, the allowed fields), so each route checks
its input as the others do. Each is one operation of :mod:`.ops`.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Mapping
from typing import Any, Protocol

from aiohttp import web

from ..core.simulator import Simulator
from . import ops
from .ops import ControlError

__all__ = ["ROUTES", "add_routes"]


class Served(Protocol):
    sim: Simulator
    serving: bool


#: The service routes, for GET / and the docs: method path -> body.
ROUTES: Mapping[str, str] = {
    "GET /health": "- (200 once serving, 503 before; for orchestrators)",
    "GET /openapi.json": "- (this API as OpenAPI 3.1)",
    "GET /clock": "- (clock, t, paused, speed)",
    "POST /clock/pause": "- (realtime clock: model time stops; 409 for a virtual clock)",
    "POST /clock/resume": "- (realtime clock: model time runs on)",
    "PUT /clock/speed": '{"speed": 10} (realtime clock: model seconds per wall second, 0.001-1000)',
    "POST /reset": '{"setup": "defaults"} or {"setup": "PATH of a state file"}: every drive anew, no restart',
    "GET /drives/{address}/generators": "- (the generators running on the drive's conditions)",
    "DELETE /drives/{address}/generators": '{"condition": "supply_v"} (optional; all without)',
}


def add_routes(
    app: web.Application,
    api: Served,
    *,
    body: Callable[[web.Request], Awaitable[dict[str, Any]]],
    address: Callable[[web.Request], int],
    only: Callable[..., None],
) -> None:
    """Serve :data:`ROUTES` on ``app``."""
    sim = api.sim

    def reply(data: object, status: int = 200) -> web.Response:
        return web.json_response(data, status=status)

    async def health(request: web.Request) -> web.Response:
        if not api.serving:
            return reply({"status": "starting"}, 503)
        return reply({"status": "serving", "profile": sim.profile.name, "drives": list(sim.drives), "t": sim.now()})

    async def openapi(request: web.Request) -> web.Response:
        from .http import ROUTES as ALL
        from .openapi import document

        return reply(document(ALL))

    async def get_clock(request: web.Request) -> web.Response:
        return reply(ops.clock_state(sim))

    async def no_fields(request: web.Request) -> None:
        data = await body(request)
        if data:
            raise ControlError(f"{request.method} {request.path} takes no fields; got {', '.join(map(repr, data))}")

    async def pause(request: web.Request) -> web.Response:
        await no_fields(request)
        return reply(ops.pause(sim))

    async def resume(request: web.Request) -> web.Response:
        await no_fields(request)
        return reply(ops.resume(sim))

    async def speed(request: web.Request) -> web.Response:
        data = await body(request)
        only(data, "speed")
        if "speed" not in data:
            raise ControlError('give the speed factor, such as {"speed": 10}')
        return reply(ops.set_speed(sim, data["speed"]))

    async def reset(request: web.Request) -> web.Response:
        data = await body(request)
        only(data, "setup")
        return reply(ops.reset(sim, data.get("setup", ops.DEFAULTS)))

    async def get_generators(request: web.Request) -> web.Response:
        return reply({"generators": ops.generators(sim, address(request))})

    async def delete_generators(request: web.Request) -> web.Response:
        where = address(request)
        data = await body(request)
        only(data, "condition")
        return reply({"generators": ops.clear_generators(sim, where, data.get("condition"))})

    r = app.router
    r.add_get("/health", health)
    r.add_get("/openapi.json", openapi)
    r.add_get("/clock", get_clock)
    r.add_post("/clock/pause", pause)
    r.add_post("/clock/resume", resume)
    r.add_put("/clock/speed", speed)
    r.add_post("/reset", reset)
    r.add_get("/drives/{address}/generators", get_generators)
    r.add_delete("/drives/{address}/generators", delete_generators)
