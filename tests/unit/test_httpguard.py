"""The control API guard's pure rules: which Host is ours, how deep a body nests, when to warn on a bind."""

from __future__ import annotations

import pytest

from c20sim.control.httpguard import check_bind, host_allowed, is_loopback, json_depth
from c20sim.transport.tcp import host_port, parse_host_port


@pytest.mark.parametrize(
    ("host", "local", "bound", "allowed"),
    [
        ("127.0.0.1:8020", "127.0.0.1", "127.0.0.1", True),
        ("localhost:8020", "127.0.0.1", "127.0.0.1", True),
        ("api.localhost", "127.0.0.1", "127.0.0.1", True),
        ("[::1]:8020", "::1", "::1", True),
        ("127.1.2.3", "127.0.0.1", "127.0.0.1", True),
        ("192.168.1.5:8020", "192.168.1.5", "0.0.0.0", True),  # the address the request came in on
        ("bench-pc:8020", "192.168.1.5", "bench-pc", True),  # the name the API was bound to
        ("attacker.example:8020", "127.0.0.1", "127.0.0.1", False),  # DNS rebinding
        ("attacker.example", "192.168.1.5", "0.0.0.0", False),
        ("0.0.0.0:8020", "192.168.1.5", "0.0.0.0", False),
        ("[::1", "::1", "::1", True),
        ("", "127.0.0.1", "", False),
    ],
)
def test_host_allowed(host: str, local: str, bound: str, allowed: bool) -> None:
    assert host_allowed(host, local, bound) is allowed


def test_loopback_names() -> None:
    assert [is_loopback(h) for h in ("localhost", "LOCALHOST.", "127.0.0.1", "::1", "[::1]", "10.0.0.1", "x")] == [
        True,
        True,
        True,
        True,
        True,
        False,
        False,
    ]


def test_json_depth_skips_strings() -> None:
    assert json_depth(b'{"a": [1, {"b": "[[[[{{{{"}]}') == 3
    assert json_depth(b'{"a": "\\"[["}') == 1
    assert json_depth(b"[" * 100) == 100
    assert json_depth(b"") == 0


def test_check_bind_warns_beyond_loopback_only() -> None:
    assert check_bind("127.0.0.1") is None and check_bind("::1") is None and check_bind("localhost") is None
    warning = check_bind("0.0.0.0")
    assert warning is not None and warning.startswith("warning: --control 0.0.0.0: the control API is reachable")
    assert (check_bind("fe80::1%eth0") or "").startswith("warning: --control [fe80::1%eth0]:")


@pytest.mark.parametrize(
    ("text", "host", "port"),
    [("127.0.0.1:5020", "127.0.0.1", 5020), ("[::1]:0", "::1", 0), ("[fe80::1%lo]:502", "fe80::1%lo", 502)],
)
def test_parse_host_port(text: str, host: str, port: int) -> None:
    assert parse_host_port(text, "--tcp") == (host, port)
    assert host_port(host, port) == text
