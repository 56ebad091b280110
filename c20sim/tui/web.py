"""``c20sim web``: the dashboard in a browser (textual-serve), attached to a serve as the terminal one is.

The web process starts ``c20sim serve`` (or takes ``--attach``) exactly as
``c20sim dashboard`` does, then serves textual-serve's page on ``--web
HOST:PORT`` (127.0.0.1:8000 unless told; port 0 picks a free one). Each
browser tab runs its own ``c20sim dashboard --attach URL`` process, so tabs
are dashboards attached at once; closing a tab ends only its dashboard. The
control API's token reaches them in the environment
(``C20SIM_CONTROL_TOKEN``), never on a command line.

Until its dashboard's first byte the page says that it is starting (:data:`SPLASH`): a headless screenshot
taken at page load shows that, never a blank page.

The page is a dashboard with every switch: beyond loopback it asks for a
token (``--web-token``, or generated), given once as ``?token=`` in the URL
and kept in a cookie for the page's WebSocket; the ready line prints the URL
to open. It stops on SIGINT or SIGTERM, and stops the serve it started.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import hmac
import os
import shlex
import signal
import sys
from typing import Any

from ..control.client import TOKEN_ENV, attach_target
from ..transport.tcp import parse_host_port
from ..wire.errors import C20SimError
from .session import check_attach_options, served

__all__ = ["run_web"]

COOKIE = "c20sim_web_token"

#: What the page shows until its dashboard's first byte: each tab starts a dashboard process of its own, which
#: takes a second or two, so the page's first paint cannot be the dashboard. A screenshot taken at page load
#: (``chromium --headless --screenshot``, which does not wait for the page's WebSocket) shows this, and says so.
SPLASH = (
    "c20sim: the dashboard of this page is starting (a second or two). A screenshot taken as the page loads shows "
    "only this: take it once the dashboard shows (docs/dashboard.md)."
)


def dashboard_command(url: str) -> str:
    """The shell command textual-serve runs for each browser tab."""
    return shlex.join([sys.executable, "-m", "c20sim", "dashboard", "--attach", url])


def run_web(args: argparse.Namespace, parser_defaults: dict[str, object]) -> int:
    """``c20sim web``: serve the dashboard to browsers until SIGINT or SIGTERM."""
    try:
        import textual_serve  # noqa: F401
    except ImportError:
        raise C20SimError("c20sim web needs textual-serve: pip install textual-serve (or c20sim[web])") from None
    host, port = parse_host_port(args.web, "--web")
    with contextlib.ExitStack() as stack:
        if args.attach:
            check_attach_options(args, parser_defaults)
            url, token = attach_target(args.attach, args.control_token)
        else:
            url, token = stack.enter_context(served(args))
        from ..control.http import is_loopback, new_token

        web_token = args.web_token
        if web_token is not None and not web_token.strip():
            raise C20SimError("--web-token: empty; give a token, or leave the option out")
        if web_token is None and not is_loopback(host):
            web_token = new_token()
        if token is not None:
            os.environ[TOKEN_ENV] = token
        from ..serve import run

        run(_serve_web(host, port, url, web_token))
    return 0


async def _serve_web(host: str, port: int, control: str, web_token: str | None) -> None:
    from aiohttp import web
    from textual_serve.server import Server

    server = Server(dashboard_command(control), host=host, port=port, title=SPLASH)

    @web.middleware
    async def guard(request: web.Request, handler: Any) -> web.StreamResponse:
        given = request.query.get("token") or request.cookies.get(COOKIE, "")
        if web_token is not None and not hmac.compare_digest(given.encode(), web_token.encode()):
            return web.Response(
                status=401, text="c20sim web: open the URL with its token (?token=...), as the ready line prints it\n"
            )
        server.public_url = f"{request.scheme}://{request.host}"  # the page's WebSocket goes back where it came from
        response: web.StreamResponse = await handler(request)
        if web_token is not None and "token" in request.query and request.path == "/":
            response.set_cookie(COOKIE, web_token, httponly=True, samesite="Strict")
        return response

    app = await server._make_app()
    app.on_startup.clear()  # textual-serve's banner: the ready line below says where instead
    app.middlewares.append(guard)
    runner = web.AppRunner(app, access_log=None)
    await runner.setup()
    site = web.TCPSite(runner, host, port)
    try:
        await site.start()
    except OSError as exc:
        await runner.cleanup()
        raise C20SimError(f"--web {host}:{port}: cannot listen: {exc.strerror or exc}") from None
    bound = next((a[1] for a in runner.addresses if isinstance(a, tuple)), port)
    shown = f"[{host}]" if ":" in host else host
    page = f"http://{shown}:{bound}/" + (f"?token={web_token}" if web_token is not None else "")
    print(f"c20sim web ready: {page} (attached to {control})", flush=True)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    try:
        await stop.wait()
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)
        await runner.cleanup()  # closes the pages' WebSockets: each tab's dashboard is told to quit
