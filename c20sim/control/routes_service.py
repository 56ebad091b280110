"""The routes the API serves itself: the index, the telemetry, the profile, the stream, the metrics, the health and
the OpenAPI document (their handlers: :mod:`c20sim.control.httpserved`, :mod:`c20sim.control.httpstream`)."""

from __future__ import annotations

from .routing import Route

#: The index, the telemetry, the profile and the stream (first in the table).
FIRST: tuple[Route, ...] = (
    Route("GET", "/", "index", "-", cli="info", help="profile, drives, clock and the API's routes"),
    Route(
        "GET",
        "/telemetry",
        "telemetry",
        "- (every drive's telemetry, conditions, causes and link faults: one stream message)",
        help="every drive's state at once, as one stream message",
    ),
    Route("GET", "/profile", "profile", "- (the served profile's TOML)", cli=None),
    Route(
        "GET",
        "/stream",
        "stream",
        "WebSocket (query: hz=0.1-50, frame_hz=0.1-100, buffer=1-10000, frames=0|1): telemetry, frames",
        cli=None,
        tool=False,
    ),
)

#: The metrics, the health and the document.
SERVICE: tuple[Route, ...] = (
    Route(
        "GET",
        "/metrics",
        "metrics",
        "- (Prometheus text format: each drive's counters, state and telemetry, the line's reply latency)",
        cli=None,
    ),
    Route(
        "GET",
        "/health",
        "health",
        "- (200 once serving, 503 before; for orchestrators)",
        help="whether the server is serving",
    ),
    Route("GET", "/openapi.json", "openapi", "- (this API as OpenAPI 3.1)", cli=None),
)
