"""The control surface, one row per operation: method, path, the function that does it, its fields, its doc.

Every front end is derived from :data:`TABLE`: the aiohttp app
(:mod:`c20sim.control.http` serves a row with an operation by one handler,
and the API's own rows by their kind), the OpenAPI document
(:mod:`c20sim.control.openapi`), the remote client and the dashboard's
operations (:mod:`c20sim.control.client`), ``c20sim ctl``
(:mod:`c20sim.control.ctl`) and the MCP tools of ``c20sim mcp``
(:mod:`c20sim.mcpserver`). Nothing else writes a path or a field list.

The rows are declared by family, each with the functions that answer them:
a drive's (:mod:`.routes_drive`), the link faults' (:mod:`.routes_link`),
the clock's (:mod:`.routes_clock`), the frame log's, the audit's and the
drill's (:mod:`.routes_records`) and the API's own (:mod:`.routes_service`);
this module gathers them in the order ``GET /`` lists them. A new operation
is its function plus one row in its family: ``call(sim, **path parameters,
**fields)`` returns the JSON answer.

A row's fields are checked by :func:`~c20sim.control.routing.invoke`, the
same way for every caller: an unknown field names the known ones, a missing
one says what to send; the values are then checked by the operation itself
(:mod:`c20sim.control.ops`). A row with ``whole`` takes the request body as
one value (the conditions, the link faults, a fault request) and leaves its
checking to the operation.
"""

from __future__ import annotations

from . import routes_clock, routes_drive, routes_link, routes_records, routes_service
from .routing import Field, Route, Schema, Table, invoke, path_parameters

__all__ = ["TABLE", "Field", "Route", "Schema", "Table", "invoke", "path_parameters", "table"]

#: The control surface. ``listed=False`` rows are second methods of a listed row (its doc says so).
TABLE = Table(
    [
        *routes_service.FIRST,
        *routes_clock.TIME,
        *routes_drive.DRIVES,
        *routes_link.LINK,
        *routes_records.RECORDS,
        # the service routes: health, the document, the clock, set-ups, generators
        *routes_service.SERVICE,
        *routes_clock.CLOCK,
        *routes_drive.GENERATORS,
    ]
)


def table() -> Table:
    """The control surface's rows (a test may add one, and every front end built after sees it)."""
    return TABLE
