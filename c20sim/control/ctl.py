"""``c20sim ctl``: the control API from a shell, with the standard library only.

Every action is one route of :mod:`c20sim.control.http`; an error answer is
one line on stderr and exit 2, as for every other command. An action the
drive refuses (a key press, a reset while the cause persists) prints the
answer, one line on stderr saying so, and exits 1. ``--format json`` prints
the answer as JSON, ``--format text`` as ``key: value`` lines (the frame log:
one line per frame); floats are rounded to 3 decimals (times to 6). A reader
that closes the pipe early (``ctl frames | head -1``) ends the output quietly.
"""

from __future__ import annotations

import argparse
import functools
import http.client
import json
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..wire.errors import C20SimError
from .ops import CONDITIONS, KEYS

__all__ = ["add_ctl_command", "call", "render", "rounded"]

#: Keys whose floats are times: kept to the microsecond, where other floats get 3 decimals.
TIME_KEYS = ("t", "model_t", "seconds")


def _ctl_target(args: argparse.Namespace) -> tuple[str, str | None]:
    """The API's address and token: --url (with --token), or the ready file serve wrote (its token, if any)."""
    url, token = _ctl_url(args)
    return url, args.token if getattr(args, "token", None) else token


def _ctl_url(args: argparse.Namespace) -> tuple[str, str | None]:
    if args.url:
        from urllib.parse import urlsplit

        given = str(args.url).rstrip("/")
        try:
            parts = urlsplit(given)
            valid = parts.scheme in ("http", "https") and bool(parts.hostname) and parts.port is not None
        except ValueError:
            valid = False
        if not valid:
            raise C20SimError(
                f"--url {args.url!r}: give the API's address as http://HOST:PORT, such as http://127.0.0.1:8020"
            )
        return given, None
    if args.ready_file:
        try:
            data = json.loads(Path(args.ready_file).read_text())
        except OSError as exc:
            raise C20SimError(f"--ready-file {args.ready_file}: cannot read: {exc.strerror}") from None
        except json.JSONDecodeError:
            raise C20SimError(f"--ready-file {args.ready_file}: not JSON; is it the file serve wrote?") from None
        url = data.get("control") if isinstance(data, dict) else None
        if not isinstance(url, str):
            raise C20SimError(
                f"--ready-file {args.ready_file}: no control address; start the server with --control 127.0.0.1:0"
            )
        token = data.get("token")
        return url.rstrip("/"), token if isinstance(token, str) else None
    raise C20SimError("give the API's address: --url http://HOST:PORT or --ready-file PATH (from serve --ready-file)")


def call(
    url: str, method: str, path: str, data: object = None, timeout: float = 10.0, *, token: str | None = None
) -> Any:
    """One API request with urllib; a 4xx/5xx answer, or an answer that is not the API's, raises C20SimError
    with one sentence saying what is wrong."""
    import urllib.error
    import urllib.request

    payload = json.dumps(data).encode() if data is not None else None
    request = urllib.request.Request(url + path, data=payload, method=method)
    if method != "GET":  # the API takes state changes only as JSON, even without a body
        request.add_header("Content-Type", "application/json")
    if token is not None:
        request.add_header("Authorization", f"Bearer {token}")
    not_api = f"{url}: not c20sim's control API"
    try:
        with urllib.request.urlopen(request, timeout=timeout) as response:
            body = response.read()
        return json.loads(body or b"null")
    except json.JSONDecodeError:
        raise C20SimError(
            f"{not_api} (its answer to {method} {path} is not JSON); check --url or --ready-file"
        ) from None
    except TimeoutError:
        raise C20SimError(
            f"{not_api}, or it is stuck: no answer to {method} {path} within {timeout:g} s; check --url or --ready-file"
        ) from None
    except (http.client.HTTPException, ConnectionError) as exc:
        raise C20SimError(f"{not_api} ({type(exc).__name__}: {exc}); check --url or --ready-file") from None
    except urllib.error.HTTPError as exc:
        text = exc.read().decode(errors="replace")
        try:
            message = json.loads(text)["error"]
        except (ValueError, KeyError, TypeError):
            message = text.strip() or exc.reason
        raise C20SimError(f"{method} {path}: {exc.code}: {message}") from None
    except urllib.error.URLError as exc:
        raise C20SimError(
            f"{url}: cannot reach the control API ({exc.reason}); is c20sim serve --control running?"
        ) from None


def _pairs(words: list[str]) -> dict[str, object]:
    """``supply_v=30 hall_fault=stuck0 offline=true`` -> values, each read as JSON where it parses."""
    out: dict[str, object] = {}
    for word in words:
        key, eq, text = word.partition("=")
        if not eq or not key:
            raise C20SimError(f"{word!r}: give KEY=VALUE, such as supply_v=30")
        try:
            out[key] = json.loads(text)
        except json.JSONDecodeError:
            out[key] = text
    return out


def _raw(text: str) -> int:
    try:
        return int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a raw value such as 1500 or 0x5DC") from None


def _at_least_one(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value} must be at least 1")
    return value


#: Actions on the whole simulator (no drive): the service routes (c20sim.control.service).
GLOBAL_ACTIONS = ("health", "clock", "pause", "resume", "speed", "reset")


def _service(api: Callable[..., Any], args: argparse.Namespace, at: str) -> Any:
    action: str = args.action
    if action == "health":
        return api("GET", "/health")
    if action == "clock":
        return api("GET", "/clock")
    if action in ("pause", "resume"):
        return api("POST", f"/clock/{action}")
    if action == "speed":
        return api("PUT", "/clock/speed", {"speed": args.factor})
    if action == "reset":
        setup = args.setup if args.setup == "defaults" else str(Path(args.setup).resolve())  # the server's cwd differs
        return api("POST", "/reset", {"setup": setup})
    if args.clear is not None:  # generators --clear [CONDITION]
        return api("DELETE", f"{at}/generators", {"condition": args.clear} if args.clear else {})
    return api("GET", f"{at}/generators")


def rounded(value: Any, key: str = "") -> Any:
    """``value`` with its floats rounded: 3 decimals, 6 for times (:data:`TIME_KEYS`)."""
    if isinstance(value, float):
        return round(value, 6 if key in TIME_KEYS else 3)
    if isinstance(value, dict):
        return {k: rounded(v, k) for k, v in value.items()}
    if isinstance(value, list):
        return [rounded(v, key) for v in value]
    return value


def _text_lines(value: Any, prefix: str = "") -> list[str]:
    if isinstance(value, dict):
        if not value:
            return [f"{prefix}: (none)"] if prefix else []
        lines: list[str] = []
        for key, item in value.items():
            lines += _text_lines(item, f"{prefix}.{key}" if prefix else str(key))
        return lines
    if isinstance(value, list) and any(isinstance(v, dict | list) for v in value):
        lines = []
        for i, item in enumerate(value):
            lines += _text_lines(item, f"{prefix}[{i}]")
        return lines
    if isinstance(value, list):
        shown = ", ".join(map(_scalar, value)) or "(none)"
    else:
        shown = _scalar(value)
    return [f"{prefix}: {shown}" if prefix else shown]


def _scalar(value: object) -> str:
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    return str(value)


def render(result: Any, fmt: str) -> str:
    """The answer as printed: JSON, or ``key: value`` lines (nested keys joined with dots)."""
    result = rounded(result)
    if fmt == "json":
        return json.dumps(result, indent=2) + "\n"
    return "\n".join(_text_lines(result)) + "\n"


def _frame_lines(records: list[dict[str, Any]]) -> str:
    out = []
    for record in records:
        note = f"  ({record['note']})" if record["note"] else ""
        out.append(f"{record['t']:>12.6f} {record['dir']} {record['hex']:<26} {record['text']}{note}\n")
    return "".join(out)


def _write(text: str) -> None:
    """Print ``text``; a reader that closed the pipe ends the output, with no traceback."""
    try:
        sys.stdout.write(text)
        sys.stdout.flush()
    except BrokenPipeError:
        # the interpreter flushes stdout again at exit: point it at /dev/null so that flush is quiet too
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)


def _refused(action: str, args: argparse.Namespace, result: Any) -> str | None:
    """Why the drive refused what was asked, or None if it did it."""
    if not isinstance(result, dict):
        return None
    if action == "key" and result.get("accepted") is False:
        return f"key {args.key}: refused by the drive ({result.get('state')}, run channel {result.get('run_channel')})"
    if action == "clear" and not args.no_reset and result.get("reset") is False:
        return (
            f"reset refused by the drive: {result.get('state')}, fault code {result.get('fault_code')}; "
            "the cause is ended, but the drive may need time to recover (the bus to charge, the module to cool): "
            "let time pass (ctl advance 1 on a virtual clock) and press reset (ctl key reset)"
        )
    return None


def cmd_ctl(args: argparse.Namespace) -> int:
    url, token = _ctl_target(args)
    api = functools.partial(call, url, token=token)
    action: str = args.action
    drive = args.drive
    if drive is None and action not in ("time", "advance", "frames", "info", "link", *GLOBAL_ACTIONS):
        drive = api("GET", "/")["drives"][0]
    at = f"/drives/{drive}"
    result: Any
    if action == "info":
        result = api("GET", "/")
    elif action == "state":
        result = api("GET", at if args.drive is not None else "/drives")
    elif action == "read":
        result = api("GET", f"{at}/registers/{args.register}")
    elif action == "write":
        result = api("PUT", f"{at}/registers/{args.register}", {"value": args.value})
    elif action == "registers":
        result = api("GET", f"{at}/registers")
    elif action == "counters":
        result = api("GET", f"{at}/counters")
    elif action == "set":
        result = api("PUT", f"{at}/conditions", _pairs(args.values))
    elif action == "fault":
        if (args.code is None) == (args.cause is None):
            raise C20SimError("ctl fault: give a fault code (such as 16) or --cause NAME (such as undervoltage)")
        if args.cause is not None:
            result = api("POST", f"{at}/fault", {"cause": args.cause})
        else:
            result = api("POST", f"{at}/fault", {"code": args.code, "persistent": args.persistent})
    elif action == "clear":
        body: dict[str, object] = {"reset": not args.no_reset}
        if args.cause is not None:
            body["cause"] = args.cause
        else:
            api("DELETE", f"{at}/causes")  # every cause ended (the supply back, the load off, ...), then reset
        result = api("DELETE", f"{at}/fault", body)
    elif action == "causes":
        result = api("GET", f"{at}/causes")
    elif action == "key":
        key: object = int(args.key) if args.key.isdigit() else args.key
        result = api("POST", f"{at}/keypad", {"key": key})
    elif action == "power-cycle":
        result = api("POST", f"{at}/power-cycle")
    elif action == "link":
        where = f"/drives/{drive}/link" if drive is not None else "/link"
        if args.clear:
            result = api("DELETE", where)
        elif args.values:
            result = api("PATCH", where, _pairs(args.values))
        else:
            result = api("GET", where)
    elif action == "advance":
        result = api("POST", "/time/advance", {"seconds": args.seconds})
    elif action in GLOBAL_ACTIONS or action == "generators":
        result = _service(api, args, at)
    elif action == "time":
        result = api("GET", "/time")
    else:  # frames
        query = "&".join(f"{k}={v}" for k, v in (("last", args.last), ("slave", args.slave)) if v is not None)
        result = api("GET", "/frames" + (f"?{query}" if query else ""))
        if args.format != "json" and not args.json:
            _write(_frame_lines(result["frames"]))
            return 0
    _write(render(result, args.format or "json"))
    why = _refused(action, args, result)
    if why is not None:
        print(f"c20sim: {why}", file=sys.stderr)
        return 1
    return 0


def add_ctl_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """``c20sim ctl``: the subcommand and its actions."""
    ctl = sub.add_parser(
        "ctl",
        help="call a running server's control API (serve --control)",
        description="Call the control API of c20sim serve --control HOST:PORT; prints the JSON answer.",
    )
    where = ctl.add_mutually_exclusive_group()
    where.add_argument("--url", help="the API's address, such as http://127.0.0.1:8020")
    where.add_argument(
        "--ready-file", metavar="PATH", help="read the API's address (and token) from serve's ready file"
    )
    ctl.add_argument("--token", help="the API's token, for a server beyond loopback (default: the ready file's)")
    ctl.add_argument("--drive", type=int, metavar="N", help="drive address (default: the first drive)")
    ctl.add_argument(
        "--format",
        choices=["text", "json"],
        help="print the answer as JSON or as key: value lines (default: json; text for frames)",
    )
    # --drive is taken before or after the action; after, it must not reset the value given before
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--drive", type=int, metavar="N", default=argparse.SUPPRESS, help="drive address")
    common.add_argument("--format", choices=["text", "json"], default=argparse.SUPPRESS, help="json or text")
    actions = ctl.add_subparsers(dest="action", metavar="ACTION", required=True)

    def action(name: str, help: str) -> argparse.ArgumentParser:
        return actions.add_parser(name, help=help, parents=[common])

    action("info", help="profile, drives, clock and the API's routes")
    action("state", help="a drive's telemetry (every drive without --drive)")
    read = action("read", help="read a register: 2100H, 0x2100, F00.10 or status1")
    read.add_argument("register")
    write = action("write", help="write a register by a master's rules (a refusal names its exception code)")
    write.add_argument("register")
    write.add_argument("value", type=_raw, help="the raw value: 1500, 0x5DC")
    action("registers", help="every register and function code with its value, access and group")
    action("counters", help="the drive's traffic: requests, replies, exceptions by code, CRC errors, silences")
    conditions = action("set", help=f"set conditions: {', '.join(CONDITIONS)}")
    conditions.add_argument("values", nargs="+", metavar="KEY=VALUE")
    fault = action("fault", help="bring about a fault's cause (--cause undervoltage), or latch a fault by code")
    fault.add_argument("code", type=int, nargs="?", help="a fault code to latch, such as 16")
    fault.add_argument("--cause", metavar="NAME", help="a cause, such as undervoltage (see: ctl causes)")
    fault.add_argument("--persistent", action="store_true", help="a reset fails until the fault is cleared")
    clear = action("clear", help="end a fault's cause (--cause NAME; default: every cause) and press reset")
    clear.add_argument("--cause", metavar="NAME", help="the cause to end, such as undervoltage")
    clear.add_argument("--no-reset", action="store_true", help="release the cause only")
    action("causes", help="every fault cause of the profile, and whether it is there now")
    key = action("key", help=f"press a keypad key: {', '.join(KEYS)}")
    key.add_argument("key")
    action("power-cycle", help="switch the drive off and on")
    link = action("link", help="show, set (KEY=VALUE) or --clear link faults (the bus without --drive)")
    link.add_argument("values", nargs="*", metavar="KEY=VALUE")
    link.add_argument("--clear", action="store_true")
    advance = action("advance", help="advance virtual time (serve --clock virtual)")
    advance.add_argument("seconds", type=float)
    action("time", help="the model's time")
    action("health", help="whether the server is serving")
    action("clock", help="the clock: virtual or realtime, t, paused, speed")
    action("pause", help="stop the model's time (realtime clock)")
    action("resume", help="let the model's time run on (realtime clock)")
    speed = action("speed", help="set the realtime clock's speed factor, such as 10")
    speed.add_argument("factor", type=float)
    reset = action("reset", help="every drive anew, no restart: defaults, or a state file's function codes")
    reset.add_argument("setup", nargs="?", default="defaults", help='"defaults" (the default) or a state file path')
    generators = action("generators", help="the generators on a drive's conditions; --clear [CONDITION] stops them")
    generators.add_argument("--clear", nargs="?", const="", metavar="CONDITION", help="stop one generator, or all")
    log = action("frames", help="the frame log")
    log.add_argument("--last", type=_at_least_one, metavar="N", help="only the newest N frames (N >= 1)")
    log.add_argument("--slave", type=int, metavar="N")
    log.add_argument("--json", action="store_true", help="print JSON, not one line per frame (as --format json)")
    ctl.set_defaults(func=cmd_ctl)
