"""The control API beyond loopback: only with a token (given, or generated into the ready file); 401 without it."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import aiohttp
import pytest

from c20sim.control.client import ControlClient, RemoteOps
from c20sim.control.http import is_loopback
from c20sim.control.ops import ControlError
from tests.conftest import wait_for_ready_file


def serve(tmp_path: Path, *options: str) -> Iterator[tuple[dict[str, str], str]]:
    ready = tmp_path / "ready.json"
    # a wire endpoint on port 0: with none, serve takes the default ports, which a running c20sim may hold
    argv = [sys.executable, "-m", "c20sim", "serve", "--clock", "virtual", "--tcp", "127.0.0.1:0"]
    argv += ["--ready-file", str(ready), *options]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        info = wait_for_ready_file(ready, proc)
        yield info, info["control"].replace("0.0.0.0", "127.0.0.1")
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=10)
        assert proc.returncode == 0, err
        assert "token in the ready file" in out or "token" not in info, out
        assert info.get("token", "@@") not in out, "the token is a secret: not in the ready line"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.fixture
def beyond_loopback(tmp_path: Path) -> Iterator[tuple[dict[str, str], str]]:
    yield from serve(tmp_path, "--control", "0.0.0.0:0")


def get(url: str, token: str | None = None) -> tuple[int, dict[str, object]]:
    request = urllib.request.Request(url)
    if token is not None:
        request.add_header("Authorization", f"Bearer {token}")
    try:
        with urllib.request.urlopen(request, timeout=5) as response:
            return response.status, json.loads(response.read())
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read())


def test_beyond_loopback_a_token_is_generated_and_asked_for(beyond_loopback: tuple[dict[str, str], str]) -> None:
    info, url = beyond_loopback
    token = info["token"]
    assert len(token) >= 32
    status, body = get(f"{url}/drives/1")
    assert status == 401
    assert body["error"] == (
        "GET /drives/1: no token; this control API needs its token: send Authorization: Bearer TOKEN "
        "(the token is in the server's ready file)"
    )
    status, body = get(f"{url}/drives/1", token + "x")
    assert (status, str(body["error"]).split(";")[0]) == (401, "GET /drives/1: a wrong token")
    status, body = get(f"{url}/drives/1", token)
    assert (status, body["address"]) == (200, 1)
    # the dashboard's client takes it from the ready file; without it, one clear error
    with pytest.raises(ControlError, match="no token") as refused:
        RemoteOps(ControlClient(url))
    assert refused.value.status == 401
    remote = RemoteOps(ControlClient(url, token))
    remote.call("set_conditions", address=1, values={"supply_v": 30})
    assert remote.conditions(1)["supply_v"] == 30.0


async def test_the_stream_needs_the_token_too(beyond_loopback: tuple[dict[str, str], str]) -> None:
    info, url = beyond_loopback
    async with aiohttp.ClientSession() as session:
        with pytest.raises(aiohttp.WSServerHandshakeError) as refused:
            await session.ws_connect(f"{url}/stream")
        assert refused.value.status == 401
        async with session.ws_connect(f"{url}/stream?token={info['token']}") as ws:  # a browser cannot set headers
            message = await ws.receive(timeout=10)
            assert json.loads(message.data)["type"] == "telemetry"
        headers = {"Authorization": f"Bearer {info['token']}"}
        async with session.ws_connect(f"{url}/stream", headers=headers) as ws:
            assert json.loads((await ws.receive(timeout=10)).data)["type"] == "telemetry"


def test_a_given_token_is_asked_for_on_loopback_too(tmp_path: Path) -> None:
    for info, url in serve(tmp_path, "--control", "127.0.0.1:0", "--control-token", "s3cret-token"):
        assert info["token"] == "s3cret-token"
        assert (tmp_path / "ready.json").stat().st_mode & 0o777 == 0o600  # only its owner reads the token
        assert get(f"{url}/")[0] == 401
        assert get(f"{url}/", "s3cret-token")[0] == 200


def test_loopback_without_a_token_asks_for_none(tmp_path: Path) -> None:
    for info, url in serve(tmp_path, "--control", "127.0.0.1:0"):
        assert "token" not in info
        assert get(f"{url}/drives/1")[0] == 200


def test_an_empty_token_is_one_line_and_exit_2() -> None:
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "c20sim",
            "serve",
            "--tcp",
            "127.0.0.1:0",
            "--control",
            "0.0.0.0:0",
            "--control-token",
            "",
        ],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert result.returncode == 2
    assert result.stderr == "c20sim: --control-token: empty; give a token, or leave the option out\n"


@pytest.mark.parametrize(
    ("host", "loopback"),
    [
        *[("127.0.0.1", True), ("127.1.2.3", True), ("::1", True), ("[::1]", True), ("localhost", True)],
        *[("0.0.0.0", False), ("::", False), ("192.168.1.10", False), ("lab-pc", False)],
    ],
)
def test_is_loopback(host: str, loopback: bool) -> None:
    assert is_loopback(host) is loopback
