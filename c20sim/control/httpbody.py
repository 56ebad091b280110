"""The operation rows' routes: a request's JSON body and path parameters, and the one handler every row with an
operation is served by (:func:`operation`); :func:`reply`, the API's JSON answer."""

from __future__ import annotations

import asyncio
import json
from collections.abc import Awaitable, Callable
from typing import Any

from aiohttp import web

from ..core.simulator import Simulator
from . import ops
from .ops import ControlError
from .routing import Route, invoke

__all__ = ["MAX_DIGITS", "Handler", "body", "operation", "reply"]

#: An aiohttp request handler.
Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]

#: The most digits a JSON integer of a request may have: every value the API takes fits in far fewer.
MAX_DIGITS = 30


def reply(data: object, status: int = 200) -> web.Response:
    """The API's JSON answer."""
    return web.json_response(data, status=status)


class _TooLong:
    """A JSON integer of more than :data:`MAX_DIGITS` digits, as parsed: its length only."""

    def __init__(self, digits: int) -> None:
        self.digits = digits


def _refuse_long_numbers(value: object, key: str = "") -> None:
    """400 naming the key of a number of thousands of digits (never a 500 from a float conversion)."""
    if isinstance(value, _TooLong):
        where = f"{key}: " if key else ""
        raise ControlError(f"{where}a number of {value.digits} digits; no value here has more than {MAX_DIGITS}")
    items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else ()
    for name, item in items:
        _refuse_long_numbers(item, f"{key}.{name}" if key else str(name))


def _not_json(name: str) -> object:
    raise ControlError(f"the body is not JSON: {name} is not a JSON number; give a finite number")


def _whole(text: str) -> int | _TooLong:
    """A JSON integer; one of thousands of digits is kept as its length, refused below by its key."""
    digits = len(text.lstrip("-"))
    return _TooLong(digits) if digits > MAX_DIGITS else int(text)


async def body(request: web.Request) -> dict[str, Any]:
    """The request's JSON object ({} for none); ControlError saying what is wrong with another."""
    if not request.body_exists:  # not can_read_body: the guard has read (and checked) the body already
        return {}
    text = await request.text()
    if not text.strip():
        return {}
    try:
        data = json.loads(text, parse_constant=_not_json, parse_int=_whole)
    except json.JSONDecodeError as exc:
        raise ControlError(f"the body is not JSON: {exc}") from None
    if not isinstance(data, dict):
        raise ControlError(f"the body must be a JSON object, not {type(data).__name__}")
    _refuse_long_numbers(data)
    return data


def address(sim: Simulator, request: web.Request) -> int:
    """The path's drive address; 404 for one that is not a number or not a drive."""
    text = request.match_info["address"]
    try:
        number = int(text)
    except ValueError:
        raise ControlError(f"drive address {text!r} is not a number", status=404) from None
    ops.drive(sim, number)
    return number


def operation(sim: Simulator, row: Route) -> Handler:
    """The handler of a row with an operation: its path parameters and body, checked and handed to the row."""

    async def handle(request: web.Request) -> web.StreamResponse:
        parameters: dict[str, Any] = {
            name: address(sim, request) if name == "address" else request.match_info[name] for name in row.parameters
        }
        data = await body(request) if row.method != "GET" else {}
        if row.offload is not None:  # what may block (a file read) runs in a worker thread, off the loop
            data = await asyncio.to_thread(row.offload, sim, data)
        return reply(invoke(sim, row, parameters, data, request.path, offloaded=True))

    return handle
