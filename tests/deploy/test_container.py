"""The image and the plant, for real: deploy/build-image, podman run -P, podman kube play.

Builds the image from Debian's packages (mmdebstrap) and the project's wheels,
runs it with its EXPOSEd ports published and reads 2103H through them with
pymodbus, then plays a 3-bus x 4-drive plant from ``c20sim plant`` and reads
every drive through its bus's published ports. Everything it made (containers,
pods, images) is removed at the end, also when a step fails. Needs root,
podman, runc, catatonit and mmdebstrap (``deploy/ci-install`` installs them);
skips with the reason where they are absent, and such a skip fails the run
(tests/conftest.py). It runs on whatever Python runs the suite: deploy/build-image
fetches the image's CPython 3.11 wheels from any Python 3.11 or newer. It prints its
timings.

Where a sandbox cannot set containers' default ulimits, podman fails with
"error setting rlimit type 7: operation not permitted"; the test runs podman
with its own containers.conf (``default_ulimits = []``, ``runtime = "runc"``)
through CONTAINERS_CONF, as a user in such a sandbox would.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from prometheus_client.parser import text_string_to_metric_families
from pymodbus import FramerType
from pymodbus.client import ModbusTcpClient

from .conftest import TIMINGS

ROOT = Path(__file__).resolve().parents[2]
TOOLS = ("podman", "runc", "catatonit", "mmdebstrap")
BUSES, DRIVES = 3, (1, 2, 3, 4)
#: start-up deadlines: generous for a loaded 2-core machine; the figures are printed
READY_DEADLINE = 90.0

missing = [tool for tool in TOOLS if shutil.which(tool) is None]
pytestmark = [
    pytest.mark.skipif(os.name != "posix" or os.geteuid() != 0, reason="needs root: mmdebstrap and rootful podman"),
    pytest.mark.skipif(
        bool(missing), reason=f"{', '.join(missing)} absent: run deploy/ci-install as root to install them"
    ),
]


def run(*args: str, env: dict[str, str], check: bool = True, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    result = subprocess.run(args, env=env, capture_output=True, text=True, timeout=timeout, check=False)
    if check and result.returncode != 0:
        raise AssertionError(f"{' '.join(args)} exited {result.returncode}:\n{result.stdout}\n{result.stderr}")
    return result


def wait_for(what: str, condition: Callable[[], object], deadline: float = READY_DEADLINE) -> None:
    """Poll until ``condition()`` is truthy, or fail after ``deadline``."""
    start = time.monotonic()
    last: object = None
    while time.monotonic() - start < deadline:
        try:
            if condition():
                return
        except Exception as exc:
            last = exc
        time.sleep(0.05)
    raise AssertionError(f"{what}: not within {deadline:g} s (last error: {last!r})")


def read(port: int, drive: int, register: int, *, rtu: bool) -> list[int]:
    framer = FramerType.RTU if rtu else FramerType.SOCKET
    client = ModbusTcpClient("127.0.0.1", port=port, framer=framer, timeout=2, retries=0)
    try:
        if not client.connect():
            raise ConnectionError(f"cannot connect to 127.0.0.1:{port}")
        reply = client.read_holding_registers(register, count=1, device_id=drive)
        if reply.isError():
            raise AssertionError(f"drive {drive} at 127.0.0.1:{port} answered {reply}")
        return list(reply.registers)
    finally:
        client.close()


def free_port_bases(count: int) -> tuple[int, int, int]:
    """Three bases whose next ``count`` ports are free now, for the plant's hostPorts."""
    for _ in range(100):
        probe = socket.socket()
        probe.bind(("127.0.0.1", 0))
        base = probe.getsockname()[1]
        probe.close()
        if base + 3 * count > 65535:
            continue
        sockets = []
        try:
            for port in range(base, base + 3 * count):
                s = socket.socket()
                sockets.append(s)
                s.bind(("0.0.0.0", port))
        except OSError:
            continue
        finally:
            for s in sockets:
                s.close()
        return base, base + count, base + 2 * count
    raise AssertionError("no free run of ports for the plant")


@pytest.fixture(scope="module")
def podman_env(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    conf = tmp_path_factory.mktemp("podman") / "containers.conf"
    conf.write_text('[containers]\ndefault_ulimits = []\n\n[engine]\nruntime = "runc"\n')
    return {**os.environ, "CONTAINERS_CONF": str(conf), "PYTHON": sys.executable}


@pytest.fixture(scope="module")
def timings() -> dict[str, float]:
    """Printed at the end of the run by tests/deploy/conftest.py."""
    return TIMINGS


@pytest.fixture(scope="module")
def image(podman_env: dict[str, str], timings: dict[str, float]) -> Iterator[str]:
    tag = f"localhost/c20sim-test-{os.getpid()}:latest"
    base = f"localhost/c20sim-test-base-{os.getpid()}:bookworm"
    start = time.monotonic()
    try:
        built = run(str(ROOT / "deploy/build-image"), "--tag", tag, "--base", base, env=podman_env, timeout=600)
        timings["build"] = time.monotonic() - start
        assert built.stdout.strip().splitlines()[-1] == tag, built.stdout
        yield tag
    finally:
        run("podman", "rmi", "--force", tag, base, env=podman_env, check=False)


def test_image_serves_on_its_published_ports(image: str, podman_env: dict[str, str], timings: dict[str, float]) -> None:
    name = f"c20sim-test-{os.getpid()}"
    start = time.monotonic()
    try:
        run("podman", "run", "--detach", "--name", name, "--publish-all", image, env=podman_env)
        ports = run("podman", "port", name, env=podman_env).stdout.split("\n")
        published = {line.split(" -> ")[0]: int(line.rsplit(":", 1)[1]) for line in ports if " -> " in line}
        # the wire ports and nothing else: the control API is not published
        assert sorted(published) == ["1502/tcp", "5020/tcp"], ports
        wait_for(
            "drive 1 answering 2103H through the published RTU port",
            lambda: read(published["5020/tcp"], 1, 0x2103, rtu=True) == [0x20],
        )
        timings["one container ready"] = time.monotonic() - start
        assert read(published["1502/tcp"], 1, 0x2103, rtu=False) == [0x20]
        assert read(published["5020/tcp"], 1, 0x2101, rtu=True) == [0x41]  # status word 2, the sheet's example
        config = run("podman", "inspect", "--format", "{{.Config.User}}", name, env=podman_env).stdout.strip()
        assert config == "10020:10020"
        assert run("podman", "exec", name, "id", "-u", env=podman_env).stdout.strip() == "10020"
        # the image's health check: a Modbus read from inside the container
        assert run("podman", "healthcheck", "run", name, env=podman_env, check=False).returncode == 0
    finally:
        run("podman", "rm", "--force", "--time", "5", name, env=podman_env, check=False)


def test_plant_of_three_buses_answers_on_every_published_port(
    image: str, podman_env: dict[str, str], timings: dict[str, float], tmp_path: Path
) -> None:
    rtu_base, modbus_base, metrics_base = free_port_bases(BUSES)
    manifest = tmp_path / "plant.yaml"
    name = f"c20sim-test-{os.getpid()}"
    run(
        sys.executable,
        "-m",
        "c20sim",
        "plant",
        "--buses",
        str(BUSES),
        "--drives",
        "1-4",
        "--image",
        image,
        "--name",
        name,
        "--rtu-port-base",
        str(rtu_base),
        "--modbus-port-base",
        str(modbus_base),
        "--metrics-port-base",
        str(metrics_base),
        "--output",
        str(manifest),
        env=podman_env,
    )
    start = time.monotonic()
    try:
        run("podman", "kube", "play", str(manifest), env=podman_env, timeout=180)
        buses = [(rtu_base + bus, modbus_base + bus) for bus in range(BUSES)]
        wait_for(
            "every drive of every bus answering 2103H",
            lambda: all(read(rtu, drive, 0x2103, rtu=True) == [0x20] for rtu, _ in buses for drive in DRIVES),
        )
        timings["3-bus plant ready"] = time.monotonic() - start
        for rtu, modbus in buses:
            for drive in DRIVES:
                assert read(modbus, drive, 0x2103, rtu=False) == [0x20], (modbus, drive)
                assert read(rtu, drive, 0x2100, rtu=True) == [3], (rtu, drive)  # status word 1: stopped
        check = run(
            sys.executable,
            "-m",
            "c20sim",
            "plant-check",
            "--drives",
            "1-4",
            *(f"127.0.0.1:{rtu}" for rtu, _ in buses),
            env=podman_env,
            check=False,
        )
        assert check.returncode == 0, check.stdout + check.stderr
        lines = check.stdout.splitlines()
        assert lines[-1] == f"{BUSES * len(DRIVES)} of {BUSES * len(DRIVES)} drives on {BUSES} bus(es) answered"
        rows = [line.split() for line in lines[1:-1]]
        assert [(row[0], int(row[1]), row[2], " ".join(row[3:])) for row in rows] == [
            (f"127.0.0.1:{rtu}", drive, "0", "stopped") for rtu, _ in buses for drive in DRIVES
        ]
        # each pod answers Prometheus on its metrics port: its own drives, with the reads just made
        for bus in range(BUSES):
            with urllib.request.urlopen(f"http://127.0.0.1:{metrics_base + bus}/metrics", timeout=10) as response:
                text = response.read().decode()
            requests = {
                s.labels["drive"]: s.value
                for family in text_string_to_metric_families(text)
                for s in family.samples
                if s.name == "c20sim_requests_total"
            }
            assert sorted(requests) == [str(d) for d in DRIVES], bus
            assert all(count >= 3 for count in requests.values()), (bus, requests)
    finally:
        run("podman", "kube", "down", str(manifest), env=podman_env, check=False, timeout=120)
    left = run("podman", "ps", "--all", "--filter", f"name={name}", "--format", "{{.Names}}", env=podman_env)
    pods = run("podman", "pod", "ps", "--filter", f"name={name}", "--format", "{{.Name}}", env=podman_env)
    assert (left.stdout + pods.stdout).strip() == "", left.stdout + pods.stdout
