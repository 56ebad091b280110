"""``c20sim dashboard`` and bare ``c20sim``: serve's options go to the serve it starts; errors are one line."""

from __future__ import annotations

import argparse
import json
import socket
import sys
from pathlib import Path

import pytest

from c20sim import cli
from c20sim.tui import session
from c20sim.wire.errors import C20SimError


@pytest.fixture
def started(monkeypatch: pytest.MonkeyPatch) -> list[tuple[list[str], str | None]]:
    """What cli would start and attach to: the serve command line, and the --attach target (not run)."""
    calls: list[tuple[list[str], str | None]] = []

    def run_dashboard(args: argparse.Namespace, defaults: dict[str, object]) -> int:
        if args.attach:
            session.check_attach_options(args, defaults)
        calls.append((session.serve_argv(args, "READY"), args.attach))
        return 0

    monkeypatch.setattr(session, "run_dashboard", run_dashboard)
    return calls


def test_bare_c20sim_starts_serve_with_a_loopback_control_api(started: list[tuple[list[str], str | None]]) -> None:
    assert cli.main([]) == 0
    ((argv, attach),) = started
    assert argv[:4] == [sys.executable, "-m", "c20sim", "serve"]
    assert argv[4:] == [
        "--parity",
        "N",
        "--stopbits",
        "1",
        "--control",
        "127.0.0.1:0",
        "--profile",
        "c20-400hr",
        "--clock",
        "realtime",
        "--speed",
        "1.0",
        "--ready-file",
        "READY",
    ]  # fmt: skip (no --drives: serve takes $C20SIM_DRIVES, else drive 1)
    assert attach is None


def test_dashboard_passes_bus_timing_off_to_serve(started: list[tuple[list[str], str | None]]) -> None:
    assert cli.main(["dashboard", "--no-bus-timing"]) == 0
    assert cli.main(["dashboard", "--bus-timing"]) == 0
    (off, _), (on, _) = started
    assert "--no-bus-timing" in off  # on is serve's own default: only off is said
    assert not any("bus-timing" in word for word in on)


def test_dashboard_passes_the_tcp_ports_limits_to_serve(started: list[tuple[list[str], str | None]]) -> None:
    assert cli.main(["dashboard", "--tcp", "127.0.0.1:0", "--max-connections", "2", "--gateway-timeout", "0.5"]) == 0
    ((argv, _),) = started
    assert argv[argv.index("--max-connections") + 1] == "2"
    assert argv[argv.index("--gateway-timeout") + 1] == "0.5"


def test_dashboard_passes_every_option_to_serve(started: list[tuple[list[str], str | None]]) -> None:
    argv = ["dashboard", "--modbus-tcp", "127.0.0.1:0", "--drives", "1,2", "--clock", "virtual", "--line-timing"]
    argv += ["--pty", "--seed", "7", "--control", "127.0.0.1:8020", "--control-token", "s3cret"]
    assert cli.main(argv) == 0
    ((argv, _),) = started
    text = " ".join(argv)
    for part in (
        "--pty",
        "--modbus-tcp 127.0.0.1:0",
        "--line-timing",
        "--control 127.0.0.1:8020",
        "--drives 1,2",
        "--clock virtual",
        "--seed 7",
    ):
        assert part in text, text
    assert "--tcp" not in text  # serve picks its defaults itself when no endpoint is given
    assert "s3cret" not in text  # the token goes to serve in its environment, not where ps shows it


def test_attach_refuses_a_serve_option(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["dashboard", "--attach", "http://127.0.0.1:1", "--tcp", "127.0.0.1:0"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("c20sim: --attach: --tcp is the server's option;"), err
    assert err.count("\n") == 1


def test_attach_to_nothing_is_one_line(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    with socket.socket() as free:
        free.bind(("127.0.0.1", 0))
        port = free.getsockname()[1]
    assert cli.main(["dashboard", "--attach", f"http://127.0.0.1:{port}"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"c20sim: cannot attach to http://127.0.0.1:{port}: the control API"), err
    ready = tmp_path / "ready.json"
    ready.write_text(json.dumps({"tcp": "127.0.0.1:5020"}))
    assert cli.main(["dashboard", "--attach", str(ready)]) == 2
    assert "the ready file has no control address" in capsys.readouterr().err
    assert cli.main(["dashboard", "--attach", str(tmp_path / "missing.json")]) == 2
    assert "cannot read the ready file" in capsys.readouterr().err


def test_a_busy_port_ends_the_dashboard_with_the_servers_error(capsys: pytest.CaptureFixture[str]) -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert cli.main(["dashboard", "--tcp", f"127.0.0.1:{port}"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1, err
    assert err[0].startswith(f"c20sim: --tcp 127.0.0.1:{port}: "), err


def test_served_options_error_is_the_servers_own_line() -> None:
    args = cli.build_parser().parse_args(["dashboard", "--profile", "no-such-profile"])
    with pytest.raises(C20SimError, match="no-such-profile"), session.served(args):
        pass


def test_dashboard_passes_the_audit_metrics_and_log_rotation_to_serve(
    started: list[tuple[list[str], str | None]],
) -> None:
    assert cli.main(["dashboard", "--no-audit", "--metrics", "127.0.0.1:0", "--log-frames-max-mb", "5"]) == 0
    assert cli.main(["dashboard"]) == 0
    (given, _), (plain, _) = started
    text = " ".join(given)
    for part in ("--no-audit", "--metrics 127.0.0.1:0", "--log-frames-max-mb 5.0"):
        assert part in text, text
    assert not {"--no-audit", "--metrics", "--log-frames-max-mb"} & set(plain)
