"""``c20sim ctl``: the control API from a shell, with the standard library only.

Its calls go through the API's one HTTP client (:class:`~c20sim.control.client.ControlClient`), over one
kept-alive connection per action. Every action is an operation of the route table (:mod:`c20sim.control.routes`),
its arguments made from the row's fields; an error answer is
one line on stderr and exit 2, as for every other command. An action that
changes something (set, fault, clear, key, advance, ...) prints one line in
words of what it did; ``read`` prints the register's one line in its units
(``3006H motor speed: 1500 rpm``, as ``exercise read`` does); another reading
prints its JSON answer. An action the
drive refuses (a key press, a reset while the cause persists) prints the
answer, one line on stderr saying so, and exits 1. ``--format json`` prints
any answer as JSON, ``--format text`` as ``key: value`` lines (the frame log:
one line per frame); floats are rounded to 3 decimals (times to 6). A reader
that closes the pipe early (``ctl frames | head -1``) ends the output quietly.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import sys
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from ..drive.files import FileReadError, read_bytes
from ..drive.physics import STEP
from ..wire.errors import C20SimError
from ..wire.registers import RUN_CHANNELS, Command, RunChannel
from . import routes
from .client import ControlClient, Refused, Unreachable

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
            valid = parts.scheme == "http" and bool(parts.hostname) and parts.port is not None
        except ValueError:
            valid = False
        if not valid:
            raise C20SimError(
                f"--url {args.url!r}: give the API's address as http://HOST:PORT, such as http://127.0.0.1:8020"
            )
        return given, None
    if args.ready_file:
        try:
            data = json.loads(read_bytes(args.ready_file, "ready file"))
        except FileReadError as exc:
            raise C20SimError(f"--ready-file {exc}") from None
        except (json.JSONDecodeError, UnicodeDecodeError, RecursionError):
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
    url: str,
    method: str,
    path: str,
    data: object = None,
    timeout: float = 10.0,
    *,
    token: str | None = None,
    client: ControlClient | None = None,
) -> Any:
    """One API request through :class:`~c20sim.control.client.ControlClient` (``client``'s kept-alive connection,
    or one of its own); a 4xx/5xx answer, or an answer that is not the API's, raises C20SimError with one sentence
    saying what is wrong."""
    own = client is None
    api = ControlClient(url, token, timeout) if client is None else client
    try:
        return api.call(method, path, data, strict=True)
    except Refused as exc:
        raise C20SimError(f"{method} {path}: {exc.status}: {exc.said}") from None
    except Unreachable as exc:
        raise C20SimError(_unreachable(url, method, path, api.timeout, exc)) from None
    finally:
        if own:
            api.close()


def _unreachable(url: str, method: str, path: str, timeout: float, exc: Unreachable) -> str:
    """What ctl says of an API that did not answer as the API."""
    not_api = f"{url}: not c20sim's control API"
    if exc.stage == "connect":
        return f"{url}: cannot reach the control API ({exc.cause}); is c20sim serve --control running?"
    if exc.stage == "not json":
        return f"{not_api} (its answer to {method} {path} is not JSON); check --url or --ready-file"
    if exc.stage == "timeout":
        return (
            f"{not_api}, or it is stuck: no answer to {method} {path} within {timeout:g} s; check --url or --ready-file"
        )
    return f"{not_api} ({type(exc.cause).__name__}: {exc.cause}); check --url or --ready-file"


def _pairs(words: list[str], example: str = "supply_v=30") -> dict[str, object]:
    """``supply_v=30 hall_fault=stuck0 offline=true`` -> values, each read as JSON where it parses."""
    out: dict[str, object] = {}
    for word in words:
        key, eq, text = word.partition("=")
        if not eq or not key:
            raise C20SimError(f"{word!r}: give KEY=VALUE, such as {example}")
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
    no_fault = result.get("state") != "fault"
    if action == "key" and result.get("accepted") is False:
        if _is_reset(args.key) and no_fault:
            return None  # nothing to reset: the panel's reset does nothing then, and that is no refusal
        if result.get("refused"):
            return f"key {args.key}: refused by the drive: {result['refused']}"
        channel = result.get("run_channel")
        said = f"key {args.key}: refused by the drive ({result.get('state')}, run channel {channel}"
        if channel != RunChannel.KEYPAD and not _is_reset(args.key):
            said += f" = {RUN_CHANNELS.get(int(channel), channel) if isinstance(channel, int) else channel}"
            return said + "); the panel's run keys need the keypad channel: ctl run-channel keypad"
        return said + ")"
    if action == "clear" and not args.no_reset and result.get("reset") is False and not no_fault:
        why = result.get("refused") or f"{result.get('state')}, fault code {result.get('fault_code')}"
        return f"reset refused by the drive: {why}"
    return None


# --- The actions: one per operation of the route table (c20sim.control.routes), a few shaped by hand.

#: Actions whose arguments are written here, not derived from their rows: what they send is not one row's
#: fields (a fault by code or cause; clear ends the causes first; frames is a query; reset takes a local path).
SHAPED = ("fault", "clear", "frames", "reset")


def _actions() -> dict[str, list[routes.Route]]:
    """ctl's actions: each row of the route table that has one, grouped (state, link: by scope and verb)."""
    out: dict[str, list[routes.Route]] = {}
    for row in routes.table().values():
        if row.action is not None:
            out.setdefault(row.action, []).append(row)
    return out


def _kind(schema: Mapping[str, Any]) -> str:
    if "oneOf" in schema and any(s.get("type") == "number" for s in schema["oneOf"]):
        return "text"  # an amount in its units or a value's name: sent as typed, read by the server (parse_value)
    if schema.get("type") == "integer":
        return "integer"
    if schema.get("type") == "number":
        return "number"
    if schema.get("type") == "boolean":
        return "boolean"
    if "oneOf" in schema and any(s.get("type") == "integer" for s in schema["oneOf"]):
        return "name-or-number"
    return "text"


def _typed(schema: Mapping[str, Any]) -> Callable[[str], object]:
    """How a command-line word becomes the field's JSON value."""
    kind = _kind(schema)
    if kind == "integer":
        return _raw
    if kind == "number":
        return float
    if kind == "name-or-number":
        return lambda text: int(text) if text.isdigit() else text
    return str


def _help(rows: list[routes.Route]) -> str:
    first = next((r for r in rows if r.method == "GET"), rows[0])
    return _said(first)


def _said(row: routes.Route) -> str:
    """A row's help line (:attr:`~c20sim.control.routes.Route.said`)."""
    return row.said


def _add_derived(parser: argparse.ArgumentParser, rows: list[routes.Route]) -> None:
    """The arguments of an action made from its rows: path parameters and required fields as positionals,
    optional fields as options, a whole body as KEY=VALUE words, a DELETE beside other verbs as --clear."""
    seen: set[str] = set()
    verbs = {r.method for r in rows}
    for row in rows:
        for name in row.parameters:
            if name != "address" and name not in seen:
                parser.add_argument(name)
                seen.add(name)
        if row.whole is not None and "values" not in seen:
            parser.add_argument("values", nargs="*" if len(verbs) > 1 else "+", metavar="KEY=VALUE")
            seen.add("values")
        if row.method == "DELETE" and len(verbs) > 1:
            if "clear" in seen:
                continue
            if len(row.fields) == 1 and not row.fields[0].required:
                metavar = row.fields[0].name.upper()
                parser.add_argument("--clear", nargs="?", const="", metavar=metavar, help=_said(row))
            else:
                parser.add_argument("--clear", action="store_true", help=_said(row))
            seen.add("clear")
            continue
        for f in row.fields:
            if f.name in seen:
                continue
            seen.add(f.name)
            if f.required:
                parser.add_argument(f.name, type=_typed(f.schema), help=f.doc or None)
            elif f.positional:
                parser.add_argument(f.name, nargs="?", type=_typed(f.schema), help=f.doc or None)
            elif _kind(f.schema) == "boolean":
                parser.add_argument(f"--{f.name.replace('_', '-')}", dest=f.name, action="store_true")
            else:
                parser.add_argument(f"--{f.name.replace('_', '-')}", dest=f.name, type=_typed(f.schema))


def _choose(rows: list[routes.Route], args: argparse.Namespace) -> routes.Route:
    """The row an action's arguments ask for: by scope (--drive, where a row without a drive exists), then by
    verb (--clear: DELETE; KEY=VALUE words: the row that takes them; else GET)."""
    scoped = [r for r in rows if ("address" in r.parameters) == (args.drive is not None)]
    if scoped and len(scoped) < len(rows):
        rows = scoped
    if getattr(args, "clear", None) not in (None, False):
        return next(r for r in rows if r.method == "DELETE")
    if getattr(args, "values", None):
        return next(r for r in rows if r.whole is not None)
    return next((r for r in rows if r.method == "GET"), rows[0])


def _first_drive(api: Callable[..., Any]) -> int:
    """The first drive's address, from the API's index (``GET /``): the drive an action means without --drive."""
    index = routes.table().named("index")
    return int(api(index.method, index.path)["drives"][0])


def _derived_call(api: Callable[..., Any], row: routes.Route, args: argparse.Namespace) -> Any:
    parameters: dict[str, object] = {}
    for name in row.parameters:
        if name == "address":
            parameters[name] = args.drive if args.drive is not None else _first_drive(api)
        else:
            parameters[name] = getattr(args, name)
    data: dict[str, object] = {}
    if row.whole is not None:
        data = _pairs(args.values, "offline=true" if "link" in row.path else "supply_v=30")
    elif row.method == "DELETE" and isinstance(getattr(args, "clear", None), str):
        if args.clear:
            data = {row.fields[0].name: args.clear}
    else:
        for f in row.fields:
            value = getattr(args, f.name, None)
            if value is not None and value is not False:
                data[f.name] = value
    return api(row.method, row.url(**parameters), data if row.method != "GET" else None)


def _shaped_call(api: Callable[..., Any], action: str, args: argparse.Namespace) -> Any:
    table = routes.table()

    def at(name: str, **parameters: object) -> tuple[str, str]:
        row = table.named(name)
        if "address" in row.parameters:
            parameters["address"] = args.drive if args.drive is not None else _first_drive(api)
        return row.method, row.url(**parameters)

    if action == "fault":
        if args.code is not None and args.cause is not None:
            raise C20SimError("ctl fault: give a fault code or --cause NAME, not both")
        if args.code is None and args.cause is None:
            raise C20SimError("ctl fault: give a fault code (such as 16) or --cause NAME (such as undervoltage)")
        request = (
            {"cause": args.cause} if args.cause is not None else {"code": args.code, "persistent": args.persistent}
        )
        return api(*at("fault"), request)
    if action == "clear":
        body: dict[str, object] = {"reset": not args.no_reset}
        if args.cause is not None:
            body["cause"] = args.cause
        else:
            api(*at("clear_causes"))  # every cause ended (the supply back, the load off, ...), then reset
        return api(*at("clear_fault"), body)
    if action == "reset":
        setup = args.setup if args.setup == "defaults" else str(Path(args.setup).resolve())  # the server's cwd differs
        return api(*at("reset"), {"setup": setup})
    query = "&".join(f"{k}={v}" for k, v in (("last", args.last), ("slave", args.slave)) if v is not None)
    method, path = at("frames")
    return api(method, path + (f"?{query}" if query else ""))


#: How long ctl waits, on a running realtime clock, for a fault's cause to trip the drive before it describes it
#: (assumed: a supply sag or a jammed rotor trips within a fraction of a second; a hot cabinet takes minutes, and
#: is described as not tripped yet).
TRIP_WAIT_S = 2.0
#: How often ctl reads the drive again while it waits (a bounded poll of the API: no event to wait on over HTTP).
POLL_S = 0.02


def _acted(api: Callable[..., Any], action: str, result: Any) -> Any:
    """The answer of a change, its drive described after the change has acted: on a running realtime clock, read
    again once the model has stepped past the change (a fault's cause: once the drive has tripped, or
    :data:`TRIP_WAIT_S`); on a virtual or paused clock the answer is the drive at the model's time, which has not
    moved (``ctl advance`` moves it)."""
    if not (isinstance(result, dict) and "address" in result and "state" in result and "t" in result):
        return result
    table = routes.table()
    clock = table.named("clock")
    now = api(clock.method, clock.path)
    if now.get("clock") != "realtime" or now.get("paused"):
        return result
    drive = table.named("drive")
    path = drive.url(address=result["address"])
    tripping = action == "fault" and result.get("state") != "fault"
    deadline = time.monotonic() + TRIP_WAIT_S
    while True:
        state = api(drive.method, path)
        stepped = float(state["t"]) >= float(result["t"]) + STEP
        if (stepped and (not tripping or state["state"] == "fault")) or time.monotonic() >= deadline:
            return {**result, **state}
        time.sleep(POLL_S)


def _drive_words(state: Mapping[str, Any]) -> str:
    fault = "no fault" if not state.get("fault_code") else f"fault {state['fault_code']} {state.get('fault_name', '')}"
    return (
        f"drive {state['address']}: {state['state']}, {state['speed_rpm']:.0f} rpm, bus {state['bus_v']:.1f} V, "
        f"{fault.strip()}"
    )


def _is_reset(key: object) -> bool:
    return str(key) in ("reset", str(int(Command.RESET)))


def summary(action: str, result: Any, key: object = None) -> str:
    """One line in words of what an action did, read from its answer (``--format json`` prints the answer)."""
    if not isinstance(result, dict):
        return json.dumps(result)
    said: list[str] = []
    if result.get("note"):
        said.append(str(result["note"]))
    if "accepted" in result:
        if action == "key" and not result["accepted"] and result.get("state") != "fault" and _is_reset(key):
            said.append("no fault to reset")
        else:
            said.append("accepted" if result["accepted"] else "refused")
    if action == "clear" and "reset" in result:
        no_fault = result.get("state") != "fault"
        said.append("reset done" if result["reset"] else ("no fault to reset" if no_fault else "no reset"))
    if "state" in result and "address" in result:
        said.append(_drive_words(result))
        if action == "fault" and result["state"] != "fault":
            said.append("not tripped yet: the drive trips when its physics says (ctl advance 1 moves a virtual clock)")
    elif "register" in result and "text" in result:
        said.append(f"{result['register']} = {result['text']}")
    elif "active" in result:
        said.append("link faults: " + (", ".join(result["active"]) or "none"))
    elif "setup" in result:
        said.append(f"every drive anew from {result['setup']}: " + "; ".join(_drive_words(d) for d in result["drives"]))
    elif "clock" in result and "paused" in result:
        speed = f", x{result['speed']:g}" if result.get("speed") is not None else ""
        said.append(
            f"{result['clock']} clock at t = {result['t']:.6g} s, {'paused' if result['paused'] else 'running'}{speed}"
        )
    elif "generators" in result:  # the action is named generators: its words need no second name
        running = ", ".join(result["generators"]) or "none running"
        said.append(running if action == "generators" else f"generators: {running}")
    elif "causes" in result:
        said.append("causes now: " + (", ".join(k for k, v in result["causes"].items() if v) or "none"))
    elif "frames" in result:
        said.append("frame log emptied")
    elif set(result) == {"t"}:
        said.append(f"t = {result['t']:.6g} s")
    return "; ".join(said) if said else json.dumps(rounded(result))


def _asked(action: str, args: argparse.Namespace) -> str:
    """The action as the user asked for it, in the words they typed: ``set supply_v=30``, ``key reset``."""
    names: list[str] = []
    flagged: set[str] = set()  # an option beside a positional word, said as typed: write accel --raw 5
    for row in _actions().get(action, []):
        names += [n for n in row.parameters if n != "address"] + [f.name for f in row.fields]
        if any(f.positional for f in row.fields):
            flagged |= {f.name for f in row.fields if not f.positional and not f.required}
    words = [action]
    for name in dict.fromkeys([*names, "code", "cause", "setup"]):
        value = getattr(args, name, None)
        if value is not None and value is not False and value != "defaults":
            words += [f"--{name}", str(value)] if name in flagged else [str(value)]
    words += list(getattr(args, "values", None) or [])
    cleared = getattr(args, "clear", None)
    if cleared not in (None, False):
        words += ["--clear", cleared] if isinstance(cleared, str) and cleared else ["--clear"]
    if getattr(args, "persistent", False):
        words.append("persistent")
    return " ".join(words)


def _changes(action: str) -> bool:
    """Whether ``action`` changes the drives, the clock or the log (its default output is then one line)."""
    return action in ("fault", "clear", "reset") or any(r.changes for r in _actions().get(action, []))


def cmd_ctl(args: argparse.Namespace) -> int:
    url, token = _ctl_target(args)
    client = ControlClient(url, token, timeout=10.0)  # one kept-alive connection for the action's calls
    api = functools.partial(call, url, client=client)
    action: str = args.action
    try:
        if action in SHAPED:
            result = _shaped_call(api, action, args)
        else:
            result = _derived_call(api, _choose(_actions()[action], args), args)
        if _changes(action):
            result = _acted(api, action, result)
    finally:
        client.close()
    if action == "frames" and args.format != "json" and not args.json:
        _write(_frame_lines(result["frames"]))
        return 0
    if args.format is None and action == "read" and isinstance(result, dict) and "text" in result:
        _write(f"{result['register']} {result['name']}: {result['text']}\n")  # as exercise read prints it
    elif args.format is None and _changes(action):
        _write(f"{_asked(action, args)}: {summary(action, result, getattr(args, 'key', None))}\n")
    else:
        _write(render(result, args.format or "json"))
    why = _refused(action, args, result)
    if why is not None:
        print(f"c20sim: {why}", file=sys.stderr)
        return 1
    return 0


def add_ctl_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """``c20sim ctl``: the subcommand and its actions, one per operation of the route table."""
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
        help="print the answer as JSON or as key: value lines (default: one line in words for an action that "
        "changes something and for read, JSON for another reading, one line per frame for frames)",
    )
    # --drive is taken before or after the action; after, it must not reset the value given before
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--drive", type=int, metavar="N", default=argparse.SUPPRESS, help="drive address")
    common.add_argument("--format", choices=["text", "json"], default=argparse.SUPPRESS, help="json or text")
    actions = ctl.add_subparsers(dest="action", metavar="ACTION", required=True)

    def action(name: str, help: str) -> argparse.ArgumentParser:
        return actions.add_parser(name, help=help, parents=[common])

    for name, rows in _actions().items():
        parser = action(name, _help(rows))
        if name not in SHAPED:
            _add_derived(parser, rows)
    shaped = actions.choices
    fault = shaped["fault"]
    fault.add_argument("code", type=_raw, nargs="?", help="a fault code to latch, such as 16 or 0x10")
    fault.add_argument("--cause", metavar="NAME", help="a cause, such as undervoltage (see: ctl causes)")
    fault.add_argument("--persistent", action="store_true", help="a reset fails until the fault is cleared")
    clear = shaped["clear"]
    clear.add_argument("--cause", metavar="NAME", help="the cause to end, such as undervoltage")
    clear.add_argument("--no-reset", action="store_true", help="release the cause only")
    reset = shaped["reset"]
    reset.add_argument("setup", nargs="?", default="defaults", help='"defaults" (the default) or a state file path')
    log = shaped["frames"]
    log.add_argument("--last", type=_at_least_one, metavar="N", help="only the newest N frames (N >= 1)")
    log.add_argument("--slave", type=int, metavar="N")
    log.add_argument("--json", action="store_true", help="print JSON, not one line per frame (as --format json)")
    ctl.set_defaults(func=cmd_ctl)
